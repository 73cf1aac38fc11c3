"""``[fleet]``: the hierarchy over a fleet of cameras of one type (docs/architecture.md, section 8).

The section belongs to the fleet; a camera's spec (:class:`~bayescal.model.spec.ModelSpec`) carries
it as a section this package registers (``pyproject.toml``'s ``bayescal.spec_sections`` entry points,
:mod:`bayescal.model.plugins`) and reads it as
``spec.fleet``.  What the sampler's settings were measured against is in
``benchmarks/results/fleet_speed.md`` and the fleet guide (``docs/guides/fleet.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from bayescal.errors import SpecError

__all__ = ["FleetSpec"]


@dataclass(frozen=True)
class FleetSpec:
    """The hierarchy over a fleet of cameras of one type.

    Per channel, a camera's log gain, offset and nonlinearity are its type's mean plus a camera
    effect shared by its channels plus a channel-within-camera deviation, each Normal with a fitted
    spread (``pooling``: ``partial``; ``none`` fits every camera on its own; ``complete`` makes the
    cameras one).  With campaigns at two or more dates (and ``drift`` on), log gain and offset drift: a trend per
    camera, its rate drawn from the fleet's (mean and spread fitted), plus a random walk (``walk``)
    whose diffusion is fitted, plus each campaign's own state of the camera (``jitter``: a remount,
    a thermal state; Normal, its spread fitted, prior HalfNormal(``jitter_prior``)).  ``sphere``:
    the sphere's common scale error, a factor on every gain of one campaign (``per_campaign``:
    recalibrated between campaigns) or of all (``shared``: one calibration for every campaign),
    log-normal with the spec's ``[sphere] common_rel``.

    Hyperpriors, in units of the spread of the units' estimates of each quantity (so they adapt to
    gains and offsets alike): spreads HalfNormal(``spread_prior``), the mean drift rate Normal(0,
    ``rate_prior``) per year, the rates' spread HalfNormal(``rate_prior``) per year and the walk's
    diffusion HalfNormal(``walk_prior``) per sqrt(year).

    ``excess``: each unit's stage-one covariance is scaled, per quantity kind, by a fitted
    ``kappa = 1 + HalfNormal(excess_prior)`` where the channels move together and by another where
    they differ (``T Sigma T``, :mod:`bayescal.fleet.plan`): when the channel model does not
    describe a camera exactly, a unit's own intervals are too narrow, and the scatter of the units
    about the hierarchy says by how much and in which direction (``sqrt(kappa)`` is reported, and a
    widening of a unit's own interval of a channel by over 3x fails the fit).  The two directions
    need different factors (the channels' common part carries the sphere's lamp-level errors, shared
    by a campaign's units).  ``excess_together_prior`` replaces ``excess_prior`` where the channels
    move together in a kind that has a campaign jitter: there the excess and the jitter each add one
    variance per unit to the same value and the data cannot tell them apart, so the excess is held
    near 1 and the jitter, the physical reading carried into predictions, takes it.

    ``shared_error``: the fraction of a unit's stage-one error variance that repeats in every
    campaign of its camera (the same channel model's systematic misfit of the same camera): a
    camera-level error term carries it, so three campaigns do not shrink a camera's interval by
    sqrt(3) when their errors are not independent (0: independent).

    ``campaign_sd``: a common effect on every log gain measured in one campaign (Normal, this sd)
    beside the sphere's: a fleet that does not age along the straight line (it settles), or a bench
    that differs between campaigns beyond the sphere's scale.  It is not extrapolated: the drift
    ahead is the cameras' trends, walk and jitter.

    ``chains``, ``warmup``, ``draws``, ``target_accept``: NUTS on the scales
    (:func:`bayescal.inference.phases.run_phases`: the Laplace approximation's mass matrix, the step
    size adapted in warmup); while their bulk or tail ESS is below ``[inference] min_ess`` (or their
    R-hat above ``max_rhat``) every chain continues for another ``draws`` draws, ``extend`` times at
    most.  Divergences are run again by the inference layer's retry policy
    (:func:`bayescal.inference.chains.retry_target`); one left after it fails the fit.
    """

    pooling: Literal["partial", "none", "complete"] = "partial"
    drift: bool = True
    walk: bool = True
    sphere: Literal["per_campaign", "shared"] = "per_campaign"
    spread_prior: float = 1.0
    rate_prior: float = 0.5
    walk_prior: float = 0.3
    excess: bool = True
    excess_prior: float = 2.0
    excess_together_prior: float = 0.1
    jitter: bool = True
    jitter_prior: float = 0.3
    shared_error: float = 0.5
    campaign_sd: float = 0.02
    chains: int = 4
    draws: int = 500
    warmup: int = 150
    target_accept: float = 0.9
    extend: int = 2

    def __post_init__(self) -> None:
        priors = (
            self.spread_prior,
            self.rate_prior,
            self.walk_prior,
            self.excess_prior,
            self.excess_together_prior,
            self.jitter_prior,
        )
        checks = [
            (
                min(priors) > 0,
                "fleet.spread_prior, rate_prior, walk_prior, excess_prior, excess_together_prior and jitter_prior"
                " must be > 0",
            ),
            (self.chains >= 1 and self.draws >= 10, "fleet needs chains >= 1 and draws >= 10"),
            (self.warmup >= 10, f"fleet.warmup = {self.warmup}; expected >= 10"),
            (0 < self.target_accept < 1, "fleet.target_accept must be in (0, 1)"),
            (self.extend >= 0, f"fleet.extend = {self.extend}; expected >= 0"),
            (0 <= self.shared_error < 1, "fleet.shared_error must be in [0, 1)"),
            (self.campaign_sd >= 0, "fleet.campaign_sd must be >= 0"),
        ]
        for ok, message in checks:
            if not ok:
                raise SpecError(message)
