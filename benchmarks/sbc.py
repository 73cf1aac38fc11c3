"""Simulation-based calibration of the main models (issue 5's acceptance).

Run: ``python benchmarks/sbc.py [--sims 200] [--backends nuts,laplace]``.

For the seed 000 Bayer camera and the seed 002 TDI camera, with camera-class
priors (the weakly informative defaults put almost all their mass on
impossible readings, see :mod:`bayescal.sbc`): draw parameters from the
prior, readings from the model over the shipped design, fit each dataset
(:func:`bayescal.fitting.batch.fit_models`, one compilation), and test that the ranks
of the truths among 99 thinned posterior draws are uniform.  Writes
``benchmarks/results/sbc_<scenario>_<backend>.{csv,md,png}`` and
``benchmarks/results/sbc.md`` (other ``--sims``/``--seed`` values add ``_n<sims>_s<seed>``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import bayescal as bc
from bayescal.cli.progress import progress_bar
from bayescal.validation.sbc import CAMERA_CLASS_PRIORS, run_sbc

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def scenarios() -> dict[str, bc.CalibrationModel]:
    out = {}
    for name, spec_file, design_file in (
        ("seed000", "seed000_bayer.toml", "seed000_design.toml"),
        ("seed002", "seed002_tdi.toml", "seed002_design.toml"),
    ):
        spec = bc.load_spec(ROOT / "models" / spec_file).replace(**CAMERA_CLASS_PRIORS)
        design = bc.load_design(ROOT / "models" / design_file)
        out[name] = bc.build_model(bc.simulate(spec, design, seed=1).table, spec)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sims", type=int, default=200)
    parser.add_argument("--backends", default="nuts,laplace")
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--only", help="run only this scenario (seed000 or seed002)")
    args = parser.parse_args()
    lines = ["# Simulation-based calibration", ""]
    tag = "" if (args.sims, args.seed) == (200, 2026) else f"_n{args.sims}_s{args.seed}"
    for name, model in scenarios().items():
        if args.only and args.only != name:
            continue
        for backend in args.backends.split(","):
            with progress_bar(args.sims, f"SBC {name} {backend}", quiet=False) as bar:
                res = run_sbc(model, args.sims, backend, seed=args.seed, progress=bar)
            res.save(RESULTS / f"sbc_{name}_{backend}{tag}")
            summ = res.summary()
            cov_all = float(res.covered.to_numpy().mean())
            mc_sd = np.sqrt(0.0475 / res.n_sims / len(summ))
            passing = f"{res.divergence_free:.1%}; passing all diagnostics: {res.batch.converged.mean():.1%}"
            lines += [
                f"## {name}, {backend}",
                "",
                f"{res.n_sims} datasets ({res.rejected} prior draws redrawn as impossible readings), "
                f"{len(summ)} parameters, {res.seconds:.0f} s; fit stages {res.batch.timings}",
                "",
                f"- uniformity (chi-square, 20 bins): min p = {summ.p_uniform.min():.3g} ({summ.p_uniform.idxmin()}), "
                f"{int((summ.p_uniform <= 0.01).sum())} of {len(summ)} at p <= 0.01 "
                f"(expected by chance: {0.01 * len(summ):.2f}); Bonferroni min p x {len(summ)} = "
                f"{min(1.0, summ.p_uniform.min() * len(summ)):.3g}",
                f"- 95 % coverage: {cov_all:.3f} over all parameters (MC sd {mc_sd:.3f} "
                f"if independent), per parameter {summ.coverage95.min():.3f}-{summ.coverage95.max():.3f}",
                f"- fits without divergences: {passing}",
                "",
            ]
            print("\n".join(lines[-8:]), flush=True)
    (RESULTS / f"sbc{tag}.md").write_text("\n".join(lines))


if __name__ == "__main__":
    main()
