"""The film camera's spec and the physics of its radiance chain (seed 003, eq. 3, 10, 11).

Every frame carries a 10-step optical wedge exposed by a xenon flash; a step ``j`` of
transmittance ``T_j`` reproduces the radiance (eq. 10)::

    L*_j = (T_j / T_M) L*_rho

where ``L*_rho`` is the ground target's band radiance measured by a multispectral radiance
meter whose reading passes a correction chain (eq. 3)::

    L* = L / (alpha beta tau_max),   L = R_meter I

(spectral-mismatch factors ``alpha``, ``beta``, filter peak transmittance ``tau_max``, meter
responsivity ``R_meter`` and current ``I``).  Other exposure times and apertures scale the
radiance by ``(t*/t) ((D*/f*) / (D/f))`` (eq. 11, :func:`convert_exposure`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import pandas as pd

from bayescal.errors import SpecError, TableError
from bayescal.io.toml import build, dumps

__all__ = ["FilmBand", "FilmSpec", "TABLE1", "correction_chain", "table1_check", "convert_exposure"]

#: seed 003 Table 1 as printed: alpha, beta, tau_max, L (meter), L* (printed), mW sr^-1 cm^-2
TABLE1 = pd.DataFrame(
    {
        "band": ["B", "G", "R", "IR"],
        "alpha": [1.17, 1.10, 1.11, 1.43],
        "beta": [1.04, 1.02, 0.98, 1.70],
        "tau_max": [0.730, 0.655, 0.625, 0.860],
        "L": [4.13, 3.39, 3.02, 5.17],
        "L_star_printed": [4.44, 5.22, 4.31, 2.49],
    }
)


def correction_chain(L, alpha, beta, tau_max):
    """Eq. 3: the meter reading corrected for spectral mismatch and filter peak, ``L / (alpha beta tau_max)``."""
    return L / (alpha * beta * tau_max)


def table1_check(tolerance: float = 0.01) -> pd.DataFrame:
    """What eq. 3 gives for each column of Table 1 beside what is printed, flagged where they disagree.

    The IR column follows eq. 3 (2.47 against the printed 2.49, 0.7 %); the
    visible columns do not (the formula gives 4.65, 4.61, 4.44 for B, G, R
    against the printed 4.44, 5.22, 4.31: the scan may have shuffled them --
    the printed B value is the formula's R value).
    """
    t = TABLE1.copy()
    t["L_star_eq3"] = correction_chain(t["L"], t["alpha"], t["beta"], t["tau_max"])
    t["rel_diff"] = t["L_star_eq3"] / t["L_star_printed"] - 1
    t["follows_eq3"] = t["rel_diff"].abs() <= tolerance
    return t


def convert_exposure(radiance, t_star: float, t: float, aperture_star: float, aperture: float, aperture_power=2):
    """Eq. 11: step radiances calibrated at ``t*``, ``D*/f*`` re-expressed for exposure ``t`` and aperture ``D/f``.

    ``L_j(t, D/f) = (t* / t) ((D*/f*) / (D/f))^k L_j(t*, D*/f*)``: the same film
    density needs the same exposure ``H ~ L t (D/f)^2``.  The scan of the paper
    prints the aperture ratio to the first power; image irradiance goes with
    the square of the relative aperture, so ``k = 2`` by default
    (``aperture_power=1`` reproduces the printed form).
    """
    if min(t_star, t, aperture_star, aperture) <= 0:
        raise SpecError("exposure times and relative apertures must be positive")
    return np.asarray(radiance, dtype=float) * (t_star / t) * (aperture_star / aperture) ** aperture_power


@dataclass(frozen=True)
class FilmBand:
    """One band's chain inputs: nominal values and relative standard uncertainties."""

    name: str
    alpha: float
    beta: float
    tau_max: float
    meter_responsivity: float  # mW sr^-1 cm^-2 per unit meter current
    u_alpha: float = 0.05
    u_beta: float = 0.05
    u_tau: float = 0.02
    u_meter: float = 0.05

    def __post_init__(self) -> None:
        values = (self.alpha, self.beta, self.tau_max, self.meter_responsivity)
        if min(values) <= 0 or min(self.u_alpha, self.u_beta, self.u_tau, self.u_meter) < 0:
            raise SpecError(f"band {self.name}: chain inputs must be > 0 and their uncertainties >= 0")


@dataclass(frozen=True)
class FilmSpec:
    """Film camera: bands, the wedge, and the density model (a model spec of ``kind = "film"``).

    ``wedge`` holds the nominal transmittances of the 10 steps (step M is the
    reference the ground target is matched to, ``reference_step``);
    ``u_wedge`` their relative standard uncertainty; ``density_sd`` the
    densitometer's reading precision (known; a free noise scale would trade
    off against the ten per-step wedge errors); ``toe_shoulder`` switches to the
    logistic curve; ``chains``, ``draws``, ``warmup`` set the sampler.
    """

    kind: ClassVar[str] = "film"

    bands: tuple[FilmBand, ...]
    wedge: tuple[float, ...]
    name: str = "film"
    reference_step: int = 5
    u_wedge: float = 0.02
    density_sd: float = 0.05
    toe_shoulder: bool = False
    draws: int = 1000
    warmup: int = 500
    chains: int = 4
    stated_uncertainty: dict[str, float] = field(default_factory=lambda: {"B": 0.15, "G": 0.15, "R": 0.15, "IR": 0.20})

    def __post_init__(self) -> None:
        if not self.bands:
            raise SpecError("a film spec needs at least one band")
        if len(self.wedge) < 3 or min(self.wedge) <= 0:
            raise SpecError(f"wedge: {len(self.wedge)} transmittances; expected three or more, each > 0")
        if not 0 <= self.reference_step < len(self.wedge):
            raise SpecError(f"reference_step {self.reference_step} outside the {len(self.wedge)}-step wedge")
        if self.density_sd <= 0 or self.u_wedge < 0:
            raise SpecError("density_sd must be > 0 and u_wedge >= 0")
        if self.chains < 1 or self.draws < 10 or self.warmup < 10:
            raise SpecError("film sampling needs chains >= 1, draws >= 10 and warmup >= 10")

    @property
    def inference(self):
        """The sampler settings as the backends read them."""
        from bayescal.model.spec import InferenceSpec

        return InferenceSpec(chains=self.chains, draws=self.draws, warmup=self.warmup, target_accept=0.9)

    def band(self, name: str) -> FilmBand:
        """The named band; a clear error otherwise."""
        for b in self.bands:
            if b.name == name:
                return b
        raise TableError(f"band '{name}' is not in the film spec (bands {[b.name for b in self.bands]})", column="band")

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, source: str = "<dict>") -> FilmSpec:
        """From the TOML layout (``[bands.B]`` tables, see ``models/seed003_film.toml``); every key checked."""
        data = dict(data)
        data.pop("kind", None)
        bands = data.pop("bands", None)
        if not isinstance(bands, dict) or not bands:
            raise SpecError(f"{source}: a film spec needs a [bands.<name>] table per band")
        for k, v in bands.items():
            if not isinstance(v, dict):
                raise SpecError(f"{source}: [bands.{k}] must be a table of the band's chain inputs")
        parsed = [build(FilmBand, {"name": str(k), **v}, source, f"bands.{k}.") for k, v in bands.items()]
        return build(cls, {**data, "bands": [dataclasses.asdict(b) for b in parsed]}, source)

    def to_dict(self) -> dict[str, Any]:
        """The TOML layout."""
        d = dataclasses.asdict(self)
        d["bands"] = {b["name"]: {k: v for k, v in b.items() if k != "name"} for b in d["bands"]}
        return {"kind": self.kind, **d}

    def to_toml(self) -> str:
        """Serialise as TOML (round-trips through :func:`bayescal.load_spec`)."""
        return dumps(self.to_dict())
