"""GPU check: warm Laplace/NUTS fits and a JAX inversion look-up table on the device, beside the numpy path.

Run on a GPU machine from the repository root: ``python benchmarks/gpu_bench.py`` (jax with CUDA; results
go to ``$OUT/gpu.json`` when ``OUT`` is set).  The README's GPU numbers came from this script on a lent
H100.  The shipped inversion is the numpy path; the JAX table here is the prototype that was measured.
"""

from __future__ import annotations

import json
import os
import time
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import bayescal as bc

ROOT = Path(__file__).resolve().parents[1]


@jax.jit
def lut(v, dark, coef, excess, z, read, kconv, prnu):
    """Median and 95 % interval of radiance per DN value (quadratic response, one pixel, reference setting)."""
    sig = v[:, None] - dark[None, :]
    pos = jnp.maximum(sig, 0.0)
    var = read**2 + kconv * pos + 1 / 12 + excess[None] ** 2 + (prnu * pos) ** 2
    y = sig - jnp.sqrt(var) * z[None]
    a1, a2 = coef[None, :, 0], coef[None, :, 1]
    disc = a1 * a1 + 4 * a2 * y
    x = jnp.where(disc >= 0, 2 * y / (a1 + jnp.sqrt(jnp.maximum(disc, 0))), -a1 / (2 * a2))
    srt = jnp.sort(x, axis=1)
    n = srt.shape[1]
    return srt[:, jnp.array([int(p * (n - 1)) for p in (0.025, 0.5, 0.975)])]


def main() -> None:
    print("devices", jax.devices(), "jax", jax.__version__)
    spec = bc.load_spec(ROOT / "models/seed000_bayer.toml")
    sim = bc.simulate(spec, bc.load_design(ROOT / "models/seed000_design.toml"), seed=0)
    res = {}
    parts = os.environ.get("GPU_BENCH_PARTS", "fit,fit_many,invert").split(",")  # a lease is short: pick
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for backend in ("laplace", "nuts") if "fit" in parts else ("laplace",):
            t = time.perf_counter()
            f = bc.fit(sim.table, spec, backend, seed=0)
            cold = time.perf_counter() - t
            warm = []
            for r in range(3):
                t = time.perf_counter()
                f = bc.fit(sim.table, spec, backend, seed=r + 1)
                warm.append(time.perf_counter() - t)
            res[backend] = {"cold_s": cold, "warm_s": float(np.median(warm)), "stages": f.timings}
            print(backend, res[backend], flush=True)
        # many datasets of one structure: fit_many (the MAP searches vmapped on an accelerator)
        tables = [
            bc.simulate(spec, bc.load_design(ROOT / "models/seed000_design.toml"), seed=s).table for s in range(32)
        ]
        for backend in ("laplace", "nuts") if "fit_many" in parts else ():
            bc.fit_many(tables[:2], spec, backend, seeds=[0, 1])  # compile
            t = time.perf_counter()
            batch = bc.fit_many(tables, spec, backend, seeds=list(range(32)))
            wall = time.perf_counter() - t
            ok = int(np.sum(batch.diagnostics["ok"])) if "ok" in batch.diagnostics else None
            res[f"fit_many_{backend}_32"] = {"wall_s": wall, "per_fit_s": wall / 32, "ok": ok}
            print(f"fit_many {backend}", res[f"fit_many_{backend}_32"], flush=True)
    cal = bc.Calibration.from_fit(f)
    s = bc.Setting(0.004, 1.0)
    z = jnp.asarray(np.random.default_rng(0).standard_normal(cal.n_draws))
    v = jnp.arange(4096.0)
    args = {
        c: (jnp.asarray(cal.dark_dn(c, s)), jnp.asarray(cal.coef[:, cal.channel_index(c)]), jnp.asarray(cal.excess_dn))
        for c in cal.channels
    }
    consts = (cal.read_noise_dn, cal.conversion_gain, cal.prnu)
    for c in cal.channels:
        lut(v, *args[c], z, *consts).block_until_ready()
    t = time.perf_counter()
    tables = jax.block_until_ready({c: lut(v, *args[c], z, *consts) for c in cal.channels})
    res["lut_s"] = time.perf_counter() - t
    img = np.random.default_rng(1).integers(0, 4096, (4000, 6000)).astype(np.uint16)
    dev = jnp.asarray(img.astype(np.int32))
    gather = jax.jit(lambda tab, im: jnp.take(tab[:, 1], im))
    gather(tables["G"], dev[::2, ::2]).block_until_ready()
    t = time.perf_counter()
    for c, (dy, dx) in zip("RGGB", ((0, 0), (0, 1), (1, 0), (1, 1)), strict=True):
        gather(tables[c], dev[dy::2, dx::2]).block_until_ready()
    res["gather_24mpix_s"] = time.perf_counter() - t
    t = time.perf_counter()
    bc.invert_image(cal, img, s, cfa="RGGB")
    res["numpy_invert_image_24mpix_s"] = time.perf_counter() - t
    print(res, flush=True)
    out_dir = os.environ.get("OUT")
    if out_dir:
        os.makedirs(out_dir, exist_ok=True)
        with open(os.path.join(out_dir, "gpu.json"), "w") as fh:
            json.dump(res, fh, indent=1, default=str)


if __name__ == "__main__":
    main()
