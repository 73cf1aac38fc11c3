"""The shipped posterior backends: Laplace, NUTS (numpyro), emcee; each registers itself.

All three start from the Laplace result at the posterior mode: Laplace draws
from it (the excess-scatter scale integrated numerically), NUTS runs in
coordinates whitened by its covariance, emcee starts its walkers around it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bayescal.inference.diagnostics import Diagnostics, mcmc_diagnostics
from bayescal.inference.emcee_backend import run_emcee
from bayescal.inference.laplace import LaplaceResult, integrated_draws, laplace_draws
from bayescal.inference.nuts import run_nuts_many
from bayescal.inference.program import Program
from bayescal.inference.registry import SHIPPED, Draws, OneByOne, Progress, Sampled, Stage, Tuned, register

__all__ = [
    "LaplaceBackend",
    "NutsBackend",
    "EmceeBackend",
    "chains_dataset",
    "laplace_z",
    "note_retry",
    "nuts_stats",
    "refuse_pooled",
]


def laplace_z(model, program, result, seed: int, extra: dict) -> np.ndarray:
    """Laplace draws ``(1, n, dim)``, the excess-scatter scale integrated numerically when present."""
    settings = model.spec.inference
    scale = program.site_index("excess")
    if scale is not None and settings.laplace_integrate and result.positive_definite:
        z, info = integrated_draws(program, model.data, result, scale, settings.laplace_draws, seed)
        extra["integrated_scale_edge_weight"] = info["edge_weight"]
        if "failed" in info:
            extra["integrated_scale_failed"] = info["failed"]
    else:
        z = laplace_draws(result, settings.laplace_draws, seed)
    return z[None]


def refuse_pooled(spec) -> None:
    """The Laplace backend does not handle pooling scales (the Gaussian at the joint mode
    collapses them to zero); say so before any work."""
    from bayescal.errors import SpecError

    if spec.response.pooled or spec.dark.pooled or spec.response.gain_prior == "pooled":
        raise SpecError(
            "the laplace backend cannot fit pooled channels (response.pooled, dark.pooled or gain_prior = "
            "'pooled'): the Gaussian at the joint mode collapses the pooling scales to zero; use --backend nuts, "
            "or pool across cameras and channels with `bayescal fleet` (its hierarchy integrates the scales)"
        )


#: a Laplace draw is far off its Gaussian when its log-likelihood lies below the best draw's by more than half
#: the chi-square quantile of this upper-tail probability (dimension: the unconstrained parameters)
FAR_TAIL = 1e-9
#: ... and the draws are refused when more than this fraction of them is that far off
FAR_FRACTION = 1e-3


def far_fraction(loglik: np.ndarray, dim: int) -> float:
    """The fraction of the draws (pointwise ``loglik (n, rows)``) whose total log-likelihood lies further
    below the best draw's than a Gaussian posterior allows (``chi2_dim(1 - FAR_TAIL) / 2``; ``-2 log p``
    of a Gaussian's draws is chi-square with ``dim`` degrees of freedom, and the likelihood carries nearly
    all of it here).

    Such draws mean the posterior is not the Gaussian at its mode: a parameter the data bound on one side
    only (a roll-off's knee above the readings: the Gaussian spills past the cliff where the knee meets
    the data), or a mode far from the bulk.
    """
    from scipy.stats import chi2

    total = np.asarray(loglik).sum(axis=-1)
    total = np.where(np.isfinite(total), total, -np.inf)
    limit = 0.5 * float(chi2.isf(FAR_TAIL, dim))
    return float(np.mean(total < np.max(total) - limit))


def laplace_problems(result, extra: dict) -> list[str]:
    """Why Laplace draws cannot be used: the mode search did not converge, the integration grid is cut,
    or the draws reach far beyond what the Gaussian allows (:func:`far_fraction`)."""
    problems = [] if (result.positive_definite and result.converged) else ["MAP did not converge"]
    far = extra.get("draws_far_off", 0.0)
    if far > FAR_FRACTION:
        problems.append(
            f"{far:.1%} of the Laplace draws lie where the likelihood is far lower than a Gaussian posterior "
            "allows (the posterior is not the Gaussian at its mode, e.g. a parameter bounded by the data on one "
            "side); use nuts"
        )
    if "integrated_scale_failed" in extra:
        problems.append(f"the excess-scatter integration failed ({extra['integrated_scale_failed']}); use nuts")
    elif extra.get("integrated_scale_edge_weight", 0.0) > 0.01:
        problems.append("the excess-scatter integration grid is truncated (posterior far from its mode); use nuts")
    return problems


def note_retry(out, settings, extra: dict) -> None:
    """Record in ``extra`` that the chains were rerun with smaller steps after divergences."""
    if out.first_divergences:
        extra["retried"] = (
            f"{out.first_divergences} divergent transitions at target_accept {settings.target_accept:g}; "
            f"chains rerun at {out.rerun_at:g}"
        )


def nuts_stats(out) -> dict:
    """Per-draw NUTS statistics for arviz's ``sample_stats``."""
    return {
        "diverging": out.diverging,
        "tree_steps": out.num_steps,
        "accept_prob": out.accept_prob,
        "energy": out.energy,
    }


def chains_dataset(posterior: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Physical draws ``(chain, draw, ...)`` for R-hat and ESS; the reference constants left out."""
    return {
        k: v
        for k, v in posterior.items()
        if k != "sphere_scale" and not k.startswith("setting_factor_")  # constants at the reference
    }


@dataclass(frozen=True)
class LaplaceBackend(OneByOne):
    """Gaussian at the mode (the fast path; the excess-scatter scale integrated on a grid)."""

    name: str = "laplace"
    batched: bool = SHIPPED["laplace"].batched
    reads_loglik: bool = True  # the far-draw check

    def sample(
        self, model: Sampled, program: Program, mode: LaplaceResult, seed: int, progress: Progress | None, stage: Stage
    ) -> Draws:
        extra: dict = {}
        z = laplace_z(model, program, mode, seed, extra)
        return Draws(z, extra=extra)

    def verdict(
        self, draws: Draws, posterior: Mapping[str, np.ndarray], spec: Tuned, mode: LaplaceResult
    ) -> Diagnostics:
        if draws.loglik is None:
            raise ValueError(
                "the Laplace verdict reads the draws' pointwise log-likelihood: pass them through judged()"
            )
        extra = dict(draws.extra, draws_far_off=far_fraction(draws.loglik[0], draws.z.shape[-1]))
        problems = laplace_problems(mode, extra)
        return Diagnostics(not problems, tuple(problems), extra=extra)


@dataclass(frozen=True)
class NutsBackend:
    """numpyro NUTS in Laplace-whitened coordinates, rerun with smaller steps after divergences."""

    name: str = "nuts"
    batched: bool = SHIPPED["nuts"].batched

    def sample_many(
        self,
        models: Sequence[Sampled],
        program: Program,
        modes: Sequence[LaplaceResult],
        seeds: Sequence[int],
        *,
        progress: Progress | None = None,
        iterations: Progress | None = None,
        stage: Stage | None = None,
    ) -> list[Draws]:
        """Every (dataset, chain) pair on one thread pool (:func:`~bayescal.inference.nuts.run_nuts_many`)."""
        inf = models[0].spec.inference
        if stage is not None:
            many = f"{len(models)} datasets x " if len(models) > 1 else ""
            stage(f"sampling: NUTS, {many}{inf.chains} chains x ({inf.warmup} warmup + {inf.draws} draws)")
        outs = run_nuts_many(
            program,
            [m.data for m in models],
            [r.mode for r in modes],
            [r.cov for r in modes],
            inf,
            list(seeds),
            progress,
            iterations=iterations,
        )
        draws = []
        for out in outs:
            extra: dict = {}
            note_retry(out, inf, extra)
            draws.append(Draws(out.z, int(out.diverging.sum()), nuts_stats(out), extra))
        return draws

    def verdict(
        self, draws: Draws, posterior: Mapping[str, np.ndarray], spec: Tuned, mode: LaplaceResult
    ) -> Diagnostics:
        return mcmc_diagnostics(chains_dataset(posterior), draws.divergences, spec.inference, draws.extra)


@dataclass(frozen=True)
class EmceeBackend(OneByOne):
    """emcee's affine-invariant ensemble, walkers started around the mode."""

    name: str = "emcee"
    batched: bool = SHIPPED["emcee"].batched

    def sample(
        self, model: Sampled, program: Program, mode: LaplaceResult, seed: int, progress: Progress | None, stage: Stage
    ) -> Draws:
        inf = model.spec.inference
        stage(f"sampling: emcee, {inf.emcee_burn} burn-in + {inf.emcee_steps} steps")
        out = run_emcee(program, model.data, mode.mode, mode.cov, inf, seed, progress)
        extra = dict(
            acceptance_fraction=out.acceptance, max_autocorr_steps=out.autocorr_steps, n_eff=out.n_eff, thin=out.thin
        )
        return Draws(out.z, extra=extra)

    def verdict(
        self, draws: Draws, posterior: Mapping[str, np.ndarray], spec: Tuned, mode: LaplaceResult
    ) -> Diagnostics:
        # walkers are not independent chains: judge ESS from the autocorrelation time
        n_eff, need = draws.extra["n_eff"], spec.inference.min_ess
        problems = () if n_eff >= need else (f"effective sample size {n_eff:.0f} < {need:.0f}",)
        return Diagnostics(not problems, problems, min_ess_bulk=n_eff, extra=draws.extra)


for _backend in (NutsBackend(), LaplaceBackend(), EmceeBackend()):
    register(_backend)
