"""Time of the fleet hierarchy's stage two beside stage one, and of its gradient.

A fleet of 20 cameras x 3 campaigns x 12 radiance levels (the independent simulator,
bayescal.validation.fleet).  In one run, on the same data:

- stage one: the 60 units fitted separately with ``fit_many`` (Laplace), cold and warm;
- stage two: NUTS on the hierarchy's scales with every other quantity integrated out
  (:func:`bayescal.fleet.marginal.log_marginal`), cold (compiling) and warm, with its
  divergences, R-hat and ESS;
- the warmup's baseline: the same potential sampled by numpyro's own adaptation (step size
  and diagonal mass matrix in windows, 300 warmup + 600 draws from starts about scales of
  0.5, the sampler before the Laplace start), its time and gradient evaluations beside
  stage two's chains;
- one gradient of the log marginal likelihood: the closed form (posterior mean and
  covariance blocks) against reverse-mode differentiation through the factorisations.

Usage: ``python benchmarks/fleet_speed.py [--cameras 20] [--repeats 8]``; results in
``benchmarks/results/fleet_speed.{csv,md}``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal import load_spec
from bayescal._config import enable_numerics
from bayescal._parallel import cores
from bayescal.fleet import fit_fleet
from bayescal.fleet.data import fleet_data
from bayescal.fleet.excess import excess_of, weighted
from bayescal.fleet.marginal import _integrated, block_scales, integrated_value
from bayescal.fleet.sampling import _convergence, _potential, _unpack
from bayescal.fleet.stage1 import fit_units
from bayescal.fleet.units import fleet_from_frame
from bayescal.validation.fleet import FleetDesign, simulate_fleet

ROOT = Path(__file__).resolve().parents[1]


def _gradient_ms(data, plan, repeats: int = 100, blocks: int = 8) -> dict:
    """Milliseconds per value-and-gradient call: the two implementations in alternating blocks
    of ``repeats`` calls, the fastest block of each (this machine's timing noise is +-30 %)."""
    import jax
    import jax.numpy as jnp

    arrays = {k: jnp.asarray(v) for k, v in data.arrays().items()}
    dim = sum(plan.sampled().values())
    u = jnp.full(dim, np.log(0.5))
    hyper = _unpack(plan, u, arrays["walk_interval"], jnp)
    sc = block_scales(plan, hyper, jnp)[:, None, :] * arrays["active"]
    kappa = excess_of(plan, hyper, jnp)

    def closed(s, k, a):  # the Gram arrays weighted inside, as the sampler's potential does
        return _integrated()(s, weighted(plan, a, k, jnp))

    def reverse(s, k, a):
        return integrated_value(s, weighted(plan, a, k, jnp))[0]

    fs = {
        "closed_form": jax.jit(jax.value_and_grad(closed, argnums=(0, 1))),
        "reverse_mode": jax.jit(jax.value_and_grad(reverse, argnums=(0, 1))),
    }
    best = dict.fromkeys(fs, np.inf)
    for f in fs.values():
        jax.block_until_ready(f(sc, kappa, arrays))
    for _ in range(blocks):
        for name, f in fs.items():
            t = time.perf_counter()
            for i in range(repeats):
                jax.block_until_ready(f(sc * (1.0 + 1e-6 * i), kappa, arrays))
            best[name] = min(best[name], (time.perf_counter() - t) / repeats * 1e3)
    out = {f"gradient_{name}_ms": v for name, v in best.items()}
    out["gradient_speedup"] = out["gradient_reverse_mode_ms"] / out["gradient_closed_form_ms"]
    return out


def _window_adapted(data, plan, seed: int, chains: int = 4, warmup: int = 300, draws: int = 600) -> dict:
    """The baseline sampler: numpyro's window adaptation from dispersed fixed starts, chains on
    the same thread pool; seconds, gradient evaluations, divergences, R-hat and ESS of the scales."""
    from concurrent.futures import ThreadPoolExecutor

    import jax
    from numpyro.infer.hmc import hmc

    arrays = {k: jax.numpy.asarray(v) for k, v in data.arrays().items()}
    potential = _potential(plan)
    dim = sum(plan.sampled().values())

    def chain(key, u0):
        init_kernel, sample_kernel = hmc(potential_fn=lambda u: potential(u, arrays), algo="NUTS")
        state = init_kernel(u0, num_warmup=warmup, target_accept_prob=0.9, rng_key=key)

        def step(st, _):
            st = sample_kernel(st)
            return st, (st.z, st.diverging, st.num_steps)

        return jax.lax.scan(step, state, None, length=warmup + draws)[1]

    run = jax.jit(chain)
    rng = np.random.default_rng(seed)
    u0 = np.log(0.5) + rng.uniform(-0.5, 0.5, (chains, dim))
    keys = jax.random.split(jax.random.PRNGKey(seed), chains)
    jax.block_until_ready(run(keys[0], u0[0]))  # compiled before the clock starts
    t = time.perf_counter()
    with ThreadPoolExecutor(cores()) as pool:
        outs = list(pool.map(lambda c: jax.block_until_ready(run(keys[c], u0[c])), range(chains)))
    seconds = time.perf_counter() - t
    z = np.stack([np.asarray(o[0])[warmup:] for o in outs])
    conv = _convergence(_unpack(plan, z, arrays["walk_interval"]))
    return {
        "baseline_chains_s": seconds,
        "baseline_gradients": int(sum(np.sum(np.asarray(o[2])) for o in outs)),
        "baseline_divergences": int(sum(np.sum(np.asarray(o[1])[warmup:]) for o in outs)),
        "baseline_max_rhat": conv["max_rhat"],
        "baseline_min_ess_scales": min(conv["min_ess_bulk"], conv["min_ess_tail"]),
    }


def _time_chains() -> list[float]:
    """Seconds of every run of stage two's chains (warmup and draws, a retry counted apart),
    appended as they finish: the sampler is wrapped, not changed."""
    import bayescal.fleet.sampling as sampling

    seconds: list[float] = []
    original = sampling._run_chains

    def timed(*args, **kwargs):
        t = time.perf_counter()
        out = original(*args, **kwargs)
        seconds.append(time.perf_counter() - t)
        return out

    sampling._run_chains = timed
    return seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=8, help="warm stage-two fits (seeds 1, 2, ...)")
    args = ap.parse_args()
    enable_numerics()
    spec = load_spec(ROOT / "models" / "fleet_seed000.toml")
    table, _ = simulate_fleet(FleetDesign(n_cameras=args.cameras), seed=5)
    fleet = fleet_from_frame(table.astype(str), source=f"fleet of {args.cameras}")
    row: dict = {"cameras": args.cameras, "units": len(fleet.units)}
    t = time.perf_counter()
    fits = fit_units(fleet, spec, "laplace", seed=5)
    row["stage1_cold_s"] = time.perf_counter() - t
    t = time.perf_counter()
    fits = fit_units(fleet, spec, "laplace", seed=6)
    row["stage1_warm_s"] = time.perf_counter() - t
    t = time.perf_counter()
    fit_fleet(fleet, spec, fits=fits, seed=0)
    row["stage2_cold_s"] = time.perf_counter() - t
    warm, diags, kept, chain_s = [], [], [], []
    timed = _time_chains()
    for seed in range(1, args.repeats + 1):
        t = time.perf_counter()
        result = fit_fleet(fleet, spec, fits=fits, seed=seed)
        warm.append(time.perf_counter() - t)
        chain_s.append(sum(timed))
        timed.clear()
        diags.append(result.draws.diagnostics)
        kept.append(result.draws.log_likelihood.shape[1])
        print(f"seed {seed}: {warm[-1]:.1f} s, {kept[-1]} draws per chain, {result.draws.diagnostics}", flush=True)
    row["stage2_warm_s"] = float(np.median(warm))
    row["stage2_over_stage1_warm"] = row["stage2_warm_s"] / row["stage1_warm_s"]
    row["draws"] = f"{spec.fleet.chains} x {spec.fleet.draws} (+{spec.fleet.warmup} warmup)"
    row["warm_runs_s"] = " ".join(f"{t:.1f}" for t in warm)
    row["draws_per_chain_kept"] = " ".join(str(k) for k in kept)  # more than draws: continued for the ESS
    row["gradients_per_fit"] = " ".join(str(d["gradients"]) for d in diags)
    row["chains_s"] = " ".join(f"{t:.1f}" for t in chain_s)
    row["retried_seeds"] = sum("first_divergences" in d for d in diags)
    row["divergences"] = max(d["divergences"] for d in diags)
    row["max_rhat"] = max(d["max_rhat"] for d in diags)
    row["min_ess"] = min(min(d["min_ess_bulk"], d["min_ess_tail"]) for d in diags)
    data, plan = fleet_data(fits, spec.fleet, spec.sphere.common_rel)
    row |= _window_adapted(data, plan, seed=1)
    median_gradients = float(np.median([d["gradients"] for d in diags]))
    row["baseline_over_stage2_gradients"] = row["baseline_gradients"] / median_gradients
    row["baseline_over_stage2_chains_s"] = row["baseline_chains_s"] / float(np.median(chain_s))
    row |= _gradient_ms(data, plan)
    df = pd.DataFrame([row])
    out = ROOT / "benchmarks" / "results"
    df.to_csv(out / "fleet_speed.csv", index=False, float_format="%.4g")
    lines = [
        "# Fleet stage two beside stage one (same run, 2 cores)",
        "",
        f"{args.cameras} cameras x 3 campaigns x 12 levels; stage one = every unit fitted alone with",
        "`fit_many` (Laplace); stage two = NUTS on the scales, the rest integrated out and drawn",
        "exactly; warm = a second fit of the same structure (median of the warm repeats).",
        "",
    ]
    lines += [f"- {k}: {v:.4g}" if isinstance(v, float) else f"- {k}: {v}" for k, v in row.items()]
    (out / "fleet_speed.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
