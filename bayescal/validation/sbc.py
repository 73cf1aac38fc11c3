"""Simulation-based calibration (SBC): is the posterior computation right for this model?

Talts et al. (2018, arXiv:1804.06788): draw parameters from the model's prior,
data from its likelihood given them, fit, and record the rank of each true
parameter among ``L`` (thinned) posterior draws.  If the sampler computes the
posterior correctly the ranks are uniform on ``0..L`` for every parameter,
and every central 95 % interval covers its truth 95 % of the time.

The data are simulated with the *model's own* generative process over the
design of a given table (its rows, settings and stimulus levels): each row's
mean reading is Normal with the model's ``row_mean`` and ``row_sd``
(right-censored at the threshold when saturation is modelled).  Datasets a
user's table could never be (readings below 0 or above full scale, a channel
without enough unsaturated levels for the response order, which
:func:`bayescal.fitting.fit.fit` refuses) are redrawn; since that choice depends on
the data alone, the ranks stay uniform (the posterior given each kept
dataset is unchanged).  Fits run through :func:`bayescal.fitting.batch.fit_models`,
one compilation for all datasets.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass

import jax
import numpy as np
import pandas as pd
from numpyro.infer import Predictive
from scipy import stats

from bayescal._config import computes
from bayescal.errors import SpecError, TableError
from bayescal.fitting.batch import FitBatch, fit_models, with_data
from bayescal.fitting.result import SAMPLED
from bayescal.inference.program import program_for
from bayescal.io.outputs import write_text_atomic
from bayescal.model.assemble import CalibrationModel
from bayescal.model.data import check_levels_per_channel
from bayescal.report.text import markdown_table

__all__ = ["CAMERA_CLASS_PRIORS", "RankStatistics", "SBCResult", "prior_datasets", "rank_statistics", "run_sbc"]

#: what a lab knows about a camera class, in the model's scaled units (``spec.replace(**CAMERA_CLASS_PRIORS)``):
#: the brightest level reads ~50 % of full scale (a factor 1.6 either way), offsets 5 +- 5 % of full scale,
#: a dark slope within ~1 %, nonlinearity coefficients of a few %.  The defaults are far wider.
CAMERA_CLASS_PRIORS = {
    "response": {"gain_prior_median": 0.5, "gain_prior_log_sd": 0.5, "nonlinearity_prior_sd": 0.05},
    "dark": {"offset_prior_mean": 0.05, "offset_prior_sd": 0.05, "slope_prior_sd": 0.01},
}


@dataclass(frozen=True)
class RankStatistics:
    """The ranks of the truths among their posterior draws and the coverage of the 95 % intervals,
    with the tests every SBC run reads (a single camera's, :class:`SBCResult`; a fleet's stage two,
    :class:`~bayescal.validation.fleet_sbc.FleetSBC`).

    Attributes
    ----------
    ranks : pandas.DataFrame
        One row per simulated dataset, one column per scalar parameter:
        the number of the ``n_draws`` thinned posterior draws below the truth.
    covered : pandas.DataFrame
        Whether each central 95 % interval covered the truth.
    n_draws : int
        ``L``: ranks run over ``0..L``.
    bins : int
        Histogram bins of the uniformity test.
    """

    ranks: pd.DataFrame
    covered: pd.DataFrame
    n_draws: int
    bins: int

    @property
    def n_sims(self) -> int:
        """Number of fitted datasets."""
        return len(self.ranks)

    def p_values(self) -> pd.Series:
        """Chi-square test of uniform ranks per parameter (``bins`` equal bins of ``0..L``)."""
        counts = self.histograms()
        expected = self.n_sims / self.bins
        chi2 = ((counts - expected) ** 2 / expected).sum(axis=0)
        return pd.Series(stats.chi2.sf(chi2, self.bins - 1), index=counts.columns, name="p_uniform")

    def histograms(self) -> pd.DataFrame:
        """Rank counts per bin (rows) and parameter (columns)."""
        edges = np.linspace(0, self.n_draws + 1, self.bins + 1)
        return pd.DataFrame(
            {c: np.histogram(self.ranks[c], bins=edges)[0] for c in self.ranks.columns},
        )

    def summary(self) -> pd.DataFrame:
        """Per parameter: uniformity p-value, 95 % coverage, its binomial Monte Carlo sd and
        the mean normalised rank (0.5 when unbiased)."""
        cov = self.covered.mean()
        return pd.DataFrame(
            {
                "p_uniform": self.p_values(),
                "coverage95": cov,
                "coverage_mc_sd": np.sqrt(0.95 * 0.05 / self.n_sims),
                "mean_rank": self.ranks.mean() / self.n_draws,
            }
        )

    def plot(self, path: str | os.PathLike | None = None, title: str = ""):
        """Rank histograms, one panel per parameter, with the 99 % band of a uniform histogram
        (written atomically to ``path`` when given)."""
        from bayescal.report.figures import rank_histograms, save_figure

        title = title or f"SBC rank histograms ({self.n_sims} datasets; grey: 99 % band)"
        fig = rank_histograms(self.histograms(), self.n_sims, self.p_values(), title)
        if path is not None:
            save_figure(fig, path)
        return fig


@dataclass(frozen=True, kw_only=True)
class SBCResult(RankStatistics):
    """Ranks, coverage and sampler health of an SBC run of a single camera's model.

    Attributes (beyond :class:`RankStatistics`)
    -------------------------------------------
    truths : dict of str to ndarray
        The prior draws the datasets were simulated from, ``(sim, ...)``.
    batch : FitBatch
        The fits (draws, diagnostics).
    rejected : int
        Simulated datasets redrawn because no table could hold them.
    seconds : float
        Wall time of the whole run (simulation, fits, ranks).
    """

    truths: dict[str, np.ndarray]
    batch: FitBatch
    rejected: int
    seconds: float

    @property
    def divergence_free(self) -> float:
        """Fraction of fits without a divergent transition (NaN for Laplace)."""
        diag = self.batch.diagnostics
        return float((diag["divergences"] == 0).mean()) if "divergences" in diag else float("nan")

    def to_markdown(self) -> str:
        """Headline numbers and the per-parameter table."""
        summ = self.summary()
        lines = [
            f"SBC: {self.n_sims} datasets, backend {self.batch.backend}, L = {self.n_draws}, {self.bins} bins, "
            f"{self.rejected} redrawn, {self.seconds:.0f} s",
            "",
            f"- smallest uniformity p-value: {summ.p_uniform.min():.3g} ({summ.p_uniform.idxmin()}); "
            f"parameters with p <= 0.01: {int((summ.p_uniform <= 0.01).sum())} of {len(summ)}",
            f"- 95 % coverage over all parameters: {float(self.covered.to_numpy().mean()):.3f} "
            f"(per parameter {summ.coverage95.min():.3f}-{summ.coverage95.max():.3f})",
            f"- fits without divergences: {self.divergence_free:.1%}",
            f"- fits whose inference passed its checks (misfit aside): {float(self.batch.converged.mean()):.1%}",
            "",
            markdown_table(summ.reset_index(names="parameter")),
        ]
        return "\n".join(lines) + "\n"

    def plot(self, path: str | os.PathLike | None = None, title: str = ""):
        """Rank histograms, one panel per parameter, with the 99 % band of a uniform histogram."""
        title = title or f"SBC rank histograms ({self.n_sims} datasets, {self.batch.backend}; grey: 99 % band)"
        return super().plot(path, title)

    def save(self, stem: str | os.PathLike) -> None:
        """Write ``<stem>.csv`` (per-parameter summary), ``<stem>.md`` and ``<stem>.png`` atomically."""
        stem = str(stem)
        write_text_atomic(stem + ".csv", self.summary().to_csv(index_label="parameter", float_format="%.6g"))
        write_text_atomic(stem + ".md", self.to_markdown())
        self.plot(stem + ".png")


@computes
def prior_datasets(
    model: CalibrationModel, n: int, seed: int = 0, per_round: int = 20_000, max_rounds: int = 100
) -> tuple[list[CalibrationModel], dict[str, np.ndarray], int]:
    """``n`` datasets simulated from ``model``'s prior over its table's design.

    Returns ``(models, truths, rejected)``: the models (same structure, new
    readings), the true sampled parameters ``name -> (n, ...)`` in the
    model's scaled units, and how many draws were rejected (see module doc).
    The weakly informative fitting priors put most of their mass on
    impossible readings (an offset prior N(0.05, 0.25) of full scale per
    channel and gain reads below zero 42 % of the time each), so prior draws
    are made ``per_round`` at a time, vectorised.
    """
    program = program_for(model)
    data, spec = model.data, model.spec
    latent = [k for k in program.unravel(program.z0) if k in SAMPLED]
    predictive = Predictive(program.model, num_samples=per_round, return_sites=latent + ["row_mean", "row_sd"])
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5BC]))
    frame = model.table.frame
    dark = np.asarray(data.u) == 0
    threshold = float(data.threshold)
    upper = 1.0 + 0.5 / model.layout.dn_scale
    kept: list[CalibrationModel] = []
    truths: dict[str, list] = {k: [] for k in latent}
    rejected = 0
    for attempt in range(max_rounds):
        draws = predictive(jax.random.PRNGKey(seed * 1000 + attempt), data)
        draws = {k: np.asarray(v) for k, v in draws.items()}
        y = draws["row_mean"] + draws["row_sd"] * rng.standard_normal(draws["row_mean"].shape)
        if spec.saturation.censor:
            y = np.minimum(y, 1.0)  # the censored likelihood ignores the value above the threshold
        possible = np.all((y >= 0) & (y <= upper), axis=1)
        rejected += int((~possible).sum())
        for i in np.flatnonzero(possible):
            yi = y[i]
            saturated = yi >= threshold
            try:
                check_levels_per_channel(frame, dark, saturated, np.asarray(data.u), spec)
            except TableError:
                rejected += 1
                continue
            censored = saturated & spec.saturation.censor
            kept.append(with_data(model, y=np.asarray(yi, dtype=float), censored=np.asarray(censored, dtype=bool)))
            for k in latent:
                truths[k].append(draws[k][i])
            if len(kept) == n:
                return kept, {k: np.stack(v) for k, v in truths.items()}, rejected
    raise SpecError(
        f"only {len(kept)} of {n} prior datasets were possible readings after {max_rounds * per_round} draws "
        f"({rejected} rejected): the priors put most mass where this design saturates or reads below zero"
    )


@computes
def run_sbc(
    model: CalibrationModel,
    n_sims: int = 200,
    backend: str = "nuts",
    *,
    seed: int = 0,
    n_draws: int = 99,
    bins: int = 20,
    progress: Callable[[int], None] | None = None,
) -> SBCResult:
    """Simulation-based calibration of ``model``'s structure over its table's design.

    Parameters
    ----------
    model : CalibrationModel
        Spec and design (``build_model(table, spec)``); its readings are not used.
    n_sims : int
        Datasets to simulate and fit.
    backend : {"nuts", "laplace"}
    seed : int
        Seed of the prior draws, the simulated readings and the fits (dataset ``i``: ``seed + i``).
    n_draws : int
        ``L``, thinned posterior draws per rank (``L + 1`` divisible by ``bins``).
    """
    if (n_draws + 1) % bins:
        raise SpecError(f"n_draws + 1 = {n_draws + 1} must be divisible by bins = {bins}")
    t0 = time.perf_counter()
    models, truths, rejected = prior_datasets(model, n_sims, seed)
    batch = fit_models(models, backend, [seed + i for i in range(n_sims)], progress)
    ranks, covered = rank_statistics(batch.draws, truths, n_draws)
    return SBCResult(
        ranks=ranks,
        covered=covered,
        truths=truths,
        n_draws=n_draws,
        bins=bins,
        batch=batch,
        rejected=rejected,
        seconds=time.perf_counter() - t0,
    )


def rank_statistics(
    draws: dict[str, np.ndarray], truths: dict[str, np.ndarray], n_draws: int = 99
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Ranks of the truths among ``n_draws`` evenly thinned draws, and 95 % interval coverage.

    ``draws[name]`` is ``(sim, chain, draw, ...)`` and ``truths[name]`` ``(sim, ...)``;
    one column per scalar parameter (``name[i,j]``).  Thinning across the
    chains (every ~40th of 4 x 1000 draws) leaves the kept draws nearly
    independent, which uniformity needs.
    """
    ranks, covered = {}, {}
    for name, true in truths.items():
        post = draws[name]
        flat = post.reshape(post.shape[0], -1, *post.shape[3:])
        pick = np.linspace(0, flat.shape[1] - 1, n_draws).round().astype(int)
        below = (flat[:, pick] < true[:, None]).sum(axis=1)
        lo, hi = np.quantile(flat, [0.025, 0.975], axis=1)
        inside = (lo <= true) & (true <= hi)
        for idx in np.ndindex(true.shape[1:]):
            label = name + ("[" + ",".join(map(str, idx)) + "]" if idx else "")
            ranks[label] = below[(slice(None),) + idx]
            covered[label] = inside[(slice(None),) + idx]
    return pd.DataFrame(ranks), pd.DataFrame(covered)
