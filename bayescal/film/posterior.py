"""A calibrated film: each band's posterior, and the band radiance behind a density.

On the straight part of the characteristic curve ``D = gamma lg L* + D0`` (seed 003 eq. 5-6), a
target's density ``d`` inverts per posterior draw to ``L* = 10^((d - e - D0) / gamma)`` with ``e``
the densitometer's reading noise; the draws give the median and the interval.  Densities whose
radiance lies outside the wedge's steps are flagged (the curve is not calibrated there).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bayescal.errors import PosteriorError, TableError
from bayescal.film.spec import FilmSpec
from bayescal.io.fit_folder import POSTERIOR
from bayescal.prediction.invert import Inversion

__all__ = ["FilmCalibration", "UNIT"]

#: the unit of a band radiance (seed 003 Table 1)
UNIT = "mW sr^-1 cm^-2"


@dataclass(frozen=True)
class FilmCalibration:
    """Per band, the posterior draws ``(n_draws, ...)`` of the curve (``gamma``, ``D0``), the reading noise
    (``density_sd``) and the step radiances (``L_steps``)."""

    draws: dict[str, dict[str, np.ndarray]]
    spec: FilmSpec | None = None
    source: str = ""
    stimulus: str = "radiance"
    unit: str = UNIT
    reference = None  # a film has no camera settings: readings are densities at the frame's exposure

    @property
    def channels(self) -> tuple[str, ...]:
        """The calibrated bands."""
        return tuple(self.draws)

    def band(self, name: str) -> dict[str, np.ndarray]:
        """One band's draws; a clear error for a band not calibrated."""
        if str(name) not in self.draws:
            raise TableError(
                f"band '{name}' was not calibrated; calibrated bands: {list(self.draws)}", column="channel"
            )
        return self.draws[str(name)]

    @classmethod
    def from_fit(cls, fit) -> FilmCalibration:
        """From a :class:`~bayescal.film.fit.FilmFit`."""
        names = ("gamma", "D0", "density_sd", "L_steps")
        draws = {b: {k: f.flat(k) for k in names} for b, f in fit.bands.items()}
        return cls(draws, fit.spec, f"film fit backend={fit.backend} seed={fit.seed}")

    @classmethod
    def load(cls, path: str | os.PathLike, tree=None) -> FilmCalibration:
        """From a fit directory's ``posterior.nc`` written by a film fit."""
        path = Path(path)
        if tree is None:
            import xarray as xr

            tree = xr.open_datatree(path / POSTERIOR if path.is_dir() else path)
        if tree.attrs.get("kind") != "film" or "posterior" not in tree.children:
            raise PosteriorError(f"{path} was not written by a film fit (no kind = 'film' posterior)")
        post = tree["posterior"]
        bands = [str(b) for b in post["band"].values]
        draws: dict[str, dict[str, np.ndarray]] = {}
        for i, b in enumerate(bands):
            draws[b] = {}
            for k in ("gamma", "D0", "density_sd", "L_steps"):
                a = np.asarray(post[k])
                a = np.take(a, i, axis=2)
                draws[b][k] = a.reshape((-1,) + a.shape[2:])
        import tomllib

        spec = FilmSpec.from_dict(tomllib.loads(tree.attrs["spec_toml"]), source=str(path))
        return cls(draws, spec, str(path))

    def invert(
        self,
        dn,
        channel: str,
        setting=None,
        *,
        n_avg: float = 1.0,
        prnu=None,
        level: float = 0.95,
        noise: bool = True,
        seed: int = 0,
    ) -> Inversion:
        """Band radiance of target densities ``dn`` of band ``channel``: median and ``level`` interval per value.

        Vectorised over any array of densities (a scanned density image is flattened and reshaped
        by the caller).  ``setting``, ``n_avg`` and ``prnu`` belong to cameras and are not used;
        ``noise`` includes the densitometer's reading noise.
        """
        d = np.asarray(dn, dtype=float)
        if d.size and not np.all(np.isfinite(d)):
            raise TableError("a density is not a finite number", column="dn")
        b = self.band(channel)
        gamma, d0 = b["gamma"][:, None], b["D0"][:, None]
        rng = np.random.default_rng(np.random.SeedSequence([seed, 0xF11]))  # the density noise draws
        sd = np.broadcast_to(np.asarray(b["density_sd"], dtype=float).reshape(-1, 1), gamma.shape)
        e = sd * rng.standard_normal(gamma.shape) if noise else 0.0
        radiance = 10.0 ** ((d.ravel()[None, :] - e - d0) / gamma)
        tail = (1 - level) / 2
        lo, med, hi = np.quantile(radiance, [tail, 0.5, 1 - tail], axis=0)
        steps = np.quantile(b["L_steps"], 0.5, axis=0)
        outside = (med < steps.min()) | (med > steps.max())
        shape = d.shape
        return Inversion(
            dn=d,
            median=med.reshape(shape),
            lower=lo.reshape(shape),
            upper=hi.reshape(shape),
            bound=np.zeros(shape, dtype=np.int8),
            extrapolated=outside.reshape(shape),
            channel=str(channel),
            setting=None,
            unit=self.unit,
            level=level,
        )
