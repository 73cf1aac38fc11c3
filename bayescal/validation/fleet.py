"""An independent fleet simulator: many cameras of one type, calibrated over several campaigns.

Written apart from the model (it imports only numpy, pandas and the bench of
:mod:`.bench`), in the terms a production line and a calibration lab would use,
not the fleet model's parametrisation, and with its departures from it:

- **production spread**: each camera's responsivity is the type's times a factor
  drawn *uniformly* within +-``production_band`` (a tolerance band, not a Normal),
  times a per-colour factor (log-normal, ``colour_spread``);
- **ageing that settles**: responsivity falls as ``1 - loss (1 - exp(-t / settle_years))``
  with each camera's ``loss`` uniform in ``loss_range``: curved, not the model's
  straight trend in log gain; plus an independent per-campaign jitter
  (``campaign_jitter``, not a random walk); optionally a random walk of the gain
  (``walk_rel`` per campaign, log-normal steps shared by the channels): the drift a
  fleet's drift probabilities must be calibrated against;
- **offset creep**: each camera's dark offset moves by ``offset_creep_dn`` per year
  (per-camera, uniform within +-50 %) from a per-camera start (Normal, ``offset_spread_dn``);
- **nonlinearity spread**: the compression is the type's times a factor uniform in 0.7-1.3;
- **one sphere per campaign**: its scale error (3 %) and lamp-level errors (0.5 %) are
  shared by every camera measured in that campaign;
- each camera's gain steps sit off their labels (``gain_step_error``) as in the bench.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from bayescal.validation.bench import BenchCamera, Departures, simulate_bench

__all__ = ["FleetDesign", "SMALL_FLEET", "simulate_fleet", "design_from_dict"]


@dataclass(frozen=True)
class FleetDesign:
    """A fleet and its calibration campaigns (defaults: a seed-000-type aerial camera).

    ``levels_per_camera``: radiance levels each camera is swept over (every level by
    default); ``brief``: cameras measured with only ``brief_levels`` levels (a unit that
    came back from the field for a quick check); ``absent``: (camera, campaign) pairs not
    measured.

    Examples
    --------
    >>> import bayescal as bc
    >>> design = bc.FleetDesign(n_cameras=5)  # the default campaigns, another fleet size
    >>> design.n_cameras, len(design.campaigns)
    (5, 3)
    """

    n_cameras: int = 20
    campaigns: tuple[str, ...] = ("2024-03-01", "2025-03-01", "2026-03-01")
    production_band: float = 0.08
    colour_spread: float = 0.02
    loss_range: tuple[float, float] = (0.01, 0.06)
    settle_years: float = 1.5
    campaign_jitter: float = 0.002
    walk_rel: float = 0.0
    offset_spread_dn: float = 4.0
    offset_creep_dn: float = 1.5
    compression_band: tuple[float, float] = (0.7, 1.3)
    gain_step_error: float = 0.03
    sphere_common_rel: float = 0.03
    sphere_level_rel: float = 0.005
    levels: tuple[float, ...] = (1.5, 3.0, 5.0279, 7.5, 10.0, 12.5, 15.0, 17.5, 21.559, 24.0, 27.0, 30.0)
    brief: tuple[str, ...] = ()
    brief_levels: tuple[int, ...] = (2, 6, 10)
    absent: tuple[tuple[str, str], ...] = ()
    n_frames: int = 20
    n_pixels: int = 256
    camera: BenchCamera = field(default_factory=BenchCamera)

    def names(self) -> list[str]:
        """Camera serial numbers."""
        return [f"SN{i + 1:03d}" for i in range(self.n_cameras)]


#: the design's numbers: (minimum, whether 0 itself is allowed); counts are whole numbers
_COUNTS = {"n_cameras": 2, "n_frames": 1, "n_pixels": 1}
_AMOUNTS = {
    "production_band": True,
    "colour_spread": True,
    "settle_years": False,
    "campaign_jitter": True,
    "walk_rel": True,
    "offset_spread_dn": True,
    "gain_step_error": True,
    "sphere_common_rel": True,
    "sphere_level_rel": True,
}
_RANGES = ("loss_range", "compression_band")


def design_from_dict(raw: dict, source: str) -> FleetDesign:
    """A :class:`FleetDesign` from a TOML table, every key and value checked (the key named on error)."""
    import dataclasses

    from bayescal.errors import SpecError
    from bayescal.io import checks

    fields = [f.name for f in dataclasses.fields(FleetDesign) if f.name != "camera"]
    kw: dict = {}
    for key, value in raw.items():
        what = f"{source}: {key}"
        if key not in fields:
            raise SpecError(f"{source}: unknown key '{key}'; expected one of {', '.join(fields)}")
        if key in _COUNTS:
            kw[key] = checks.count(value, what, minimum=_COUNTS[key])
        elif key in _AMOUNTS or key == "offset_creep_dn":
            zero = _AMOUNTS.get(key)
            x = checks.number(value, what, positive=zero is False, minimum=0.0 if zero else None)
            kw[key] = x
        elif key in _RANGES:
            pair = _list(value, what)
            if len(pair) != 2:
                raise SpecError(f"{what} = {value!r}; expected [LOW, HIGH]")
            lo, hi = (checks.number(v, what, minimum=0.0) for v in pair)
            if lo > hi:
                raise SpecError(f"{what} = {value!r}; expected LOW <= HIGH")
            kw[key] = (lo, hi)
        elif key == "campaigns":
            dates = [checks.date(v, f"{what} entry") for v in _list(value, what)]
            if not dates or any(b <= a for a, b in zip(dates, dates[1:], strict=False)):
                raise SpecError(f"{what} = {value!r}; expected one or more ISO dates in increasing order")
            kw[key] = tuple(d.date().isoformat() for d in dates)
        elif key == "levels":
            levels = tuple(checks.number(v, f"{what} entry", positive=True) for v in _list(value, what))
            if not levels:
                raise SpecError(f"{what} = []; expected the radiance levels (positive numbers)")
            kw[key] = levels
        elif key == "brief":
            kw[key] = tuple(str(v) for v in _list(value, what))
        elif key == "brief_levels":
            kw[key] = tuple(checks.count(v, f"{what} entry", minimum=0) for v in _list(value, what))
        elif key == "absent":
            pairs = [_list(v, f"{what} entry") for v in _list(value, what)]
            if any(len(v) != 2 for v in pairs):
                raise SpecError(f"{what} = {value!r}; expected [[CAMERA, CAMPAIGN], ...]")
            kw[key] = tuple((str(c), checks.date(d, f"{what} campaign").date().isoformat()) for c, d in pairs)
    design = FleetDesign(**kw)
    names = set(design.names())
    for cam in design.brief + tuple(c for c, _ in design.absent):
        if cam not in names:
            raise SpecError(
                f"{source}: camera '{cam}' is not among the design's cameras (SN001-SN{design.n_cameras:03d})"
            )
    for d in (d for _, d in design.absent):
        if d not in design.campaigns:
            raise SpecError(f"{source}: absent campaign {d} is not one of the campaigns {', '.join(design.campaigns)}")
    if design.brief and any(i >= len(design.levels) for i in design.brief_levels):
        raise SpecError(f"{source}: brief_levels {design.brief_levels} index past the {len(design.levels)} levels")
    return design


def _list(value, what: str) -> list:
    from bayescal.errors import SpecError

    if not isinstance(value, (list, tuple)):
        raise SpecError(f"{what} = {value!r}; expected a list")
    return list(value)


#: a small fleet for tests and sampler checks: 6 cameras over 3 yearly campaigns, one swept at
#: 3 levels only, one absent from the last campaign
SMALL_FLEET = FleetDesign(
    n_cameras=6,
    campaigns=("2024-03-01", "2025-03-01", "2026-03-01"),
    n_pixels=64,
    n_frames=10,
    brief=("SN006",),
    absent=(("SN005", "2026-03-01"),),
)


def simulate_fleet(design: FleetDesign | None = None, seed: int = 0) -> tuple[pd.DataFrame, pd.DataFrame]:
    """A fleet measurement table (``camera`` and ``campaign`` columns) and the truth per unit.

    The truth has one row per (camera, campaign, channel): ``gain`` (true ``A1``, DN per
    W m^-2 sr^-1 at the reference setting), ``offset`` (``A0``, DN), ``compression``
    (``A2``), and the campaign's ``sphere_scale``.

    Examples
    --------
    >>> import bayescal as bc
    >>> design = bc.FleetDesign(n_cameras=2, campaigns=("2024-03-01", "2025-03-01"), n_pixels=8, n_frames=2)
    >>> table, truth = bc.simulate_fleet(design, seed=1)
    >>> sorted(table["camera"].unique()), sorted(truth["campaign"].unique())
    (['SN001', 'SN002'], ['2024-03-01', '2025-03-01'])
    """
    d = design or FleetDesign()
    rng = np.random.default_rng(seed)
    base = replace(d.camera, n_frames=d.n_frames, n_pixels=d.n_pixels)
    chans = base.channels
    origin = pd.Timestamp(d.campaigns[0])
    years = [(pd.Timestamp(c) - origin).days / 365.25 for c in d.campaigns]
    sphere = [
        (
            float(np.exp(d.sphere_common_rel * rng.standard_normal())),
            d.sphere_level_rel * rng.standard_normal(len(d.levels)),
        )
        for _ in d.campaigns
    ]
    frames, truth = [], []
    for name in d.names():
        band = 1.0 + rng.uniform(-d.production_band, d.production_band)
        colour = {c: float(np.exp(d.colour_spread * rng.standard_normal())) for c in chans}
        loss = rng.uniform(*d.loss_range)
        comp = {c: rng.uniform(*d.compression_band) for c in chans}
        offset0 = rng.normal(0.0, d.offset_spread_dn)
        creep = d.offset_creep_dn * rng.uniform(0.5, 1.5)
        level_idx = d.brief_levels if name in d.brief else tuple(range(len(d.levels)))
        walk = np.ones(len(d.campaigns))
        if d.walk_rel:  # (drawn only when asked for: the other designs keep their random numbers)
            steps = d.walk_rel * rng.standard_normal(len(d.campaigns))
            walk = np.exp(np.cumsum(np.where(np.arange(len(d.campaigns)) > 0, steps, 0.0)))
        for j, campaign in enumerate(d.campaigns):
            if (name, campaign) in d.absent:
                continue
            t = years[j]
            age = 1.0 - loss * (1.0 - np.exp(-t / d.settle_years))
            jitter = float(np.exp(d.campaign_jitter * rng.standard_normal()))
            factor = {c: band * colour[c] * age * jitter * walk[j] for c in chans}
            cam = replace(
                base,
                levels=tuple(d.levels[i] for i in level_idx),
                responsivity={c: base.responsivity[c] * factor[c] for c in chans},
                compression={c: base.compression[c] * comp[c] * factor[c] for c in chans},
                channel_offset_dn={c: base.channel_offset_dn[c] + offset0 + creep * t for c in chans},
                sweeps=tuple(
                    (ex, gs, None if lv is None else tuple(i for i in lv if i < len(level_idx)))
                    for ex, gs, lv in base.sweeps
                ),
            )
            scale, level_err = sphere[j]
            table, real = simulate_bench(
                cam,
                Departures(gain_step_error=d.gain_step_error),
                seed=int(rng.integers(2**31)),
                sphere_scale=scale,
                level_errors=level_err[list(level_idx)],
            )
            table.insert(0, "campaign", campaign)
            table.insert(0, "camera", name)
            frames.append(table)
            for c in chans:
                a = real.true_coefficients(c)
                truth.append(
                    {
                        "camera": name,
                        "campaign": campaign,
                        "channel": c,
                        "gain": a[1],
                        "offset": a[0],
                        "compression": a[2],
                        "sphere_scale": scale,
                    }
                )
    return pd.concat(frames, ignore_index=True), pd.DataFrame(truth)
