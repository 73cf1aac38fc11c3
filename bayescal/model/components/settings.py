"""Setting factors: the camera's settings are measurements too.

Physics: a gain step labelled ``g`` multiplies the signal by ``g f_g`` with
``f_g`` near 1, an exposure setting ``t`` integrates for ``t f_t`` (a shutter
offset or non-proportionality), ``M`` TDI stages add ``M f_M`` (seed 000
Table 2: at 1/100 s the measured slope of R is 163.3 against 155.2 derived
from 1/250 s, +5 %; seed 002 section 6: settings chosen by eq. 12 read 6.6 %
above and 8.8 % below their targets).  A model that takes settings as exact
absorbs these errors into its noise and reports confident, wrong intervals.

Each measured setting's log factor has the prior ``Normal(0, tol)``, the
lab's stated tolerance (:class:`~bayescal.model.spec.SettingsSpec`).  The spread of
a kind, ``tau``, is learned from the factors afterwards, per posterior draw,
by the conjugate update of ``log f_k ~ Normal(0, tau)`` with an inverse-gamma
prior whose mean is ``tol^2`` (shape 2).  Sampling ``tau`` jointly instead
makes a funnel: a sphere sweep pins each factor to ~1e-4, three such values
say almost nothing about ``tau``, and the joint density runs off to ``tau -> 0``
(measured on seed 000: MAP at tau = 1e-17, NUTS R-hat 2.5, ESS 5, 60-90 s in
both the centred and the non-centred form).  The measured factors are
data-dominated, so the fixed prior costs them nothing; where a factor is weak
the tolerance is what the lab said.  Only settings with illuminated rows get
a factor: a setting seen only in dark frames tells nothing about it.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist

from bayescal.model.spec import SettingsSpec

__all__ = ["SettingFactors", "KINDS", "SPREAD_PRIOR_SHAPE"]

#: shape of the inverse-gamma prior of a kind's tau^2 (its mean is then the tolerance squared)
SPREAD_PRIOR_SHAPE = 2.0

#: kind -> (table column, data index field, spec tolerance field)
KINDS = {
    "gain": ("gain", "fset", "gain_tolerance"),
    "exposure": ("exposure_s", "eset", "exposure_tolerance"),
    "tdi": ("tdi_stages", "mset", "tdi_tolerance"),
}


@dataclass(frozen=True)
class SettingFactors:
    """Per-kind multiplicative factors on the effective stimulus.

    ``sizes[kind]`` is the number of values of the kind measured with
    illumination and ``ref_index[kind]`` the position of the reference value
    among them (-1: the reference value was not measured, every value gets a
    factor).
    """

    spec: SettingsSpec
    sizes: tuple[tuple[str, int], ...]
    ref_index: tuple[tuple[str, int], ...]

    def active(self) -> list[str]:
        """Kinds whose factors are free: a tolerance > 0 and a measured non-reference value."""
        sizes, refs = dict(self.sizes), dict(self.ref_index)
        return [
            k for k in KINDS if getattr(self.spec, KINDS[k][2]) > 0 and sizes.get(k, 0) - (refs.get(k, -1) >= 0) > 0
        ]

    def log_factors(self, kind: str, logf, xp=jnp):
        """Log factor of every measured value, the reference's 0 inserted (numpy or jax arrays)."""
        ref = dict(self.ref_index)[kind]
        if ref < 0:
            return logf
        zero = xp.zeros(logf.shape[:-1] + (1,))
        return xp.concatenate([logf[..., :ref], zero, logf[..., ref:]], axis=-1)

    def sample(self, data) -> jnp.ndarray | float:
        """Per-row multiplier of the effective stimulus (1 when no kind is active)."""
        total = 0.0
        sizes, refs = dict(self.sizes), dict(self.ref_index)
        for kind in self.active():
            n_free = sizes[kind] - (refs[kind] >= 0)
            tol = getattr(self.spec, KINDS[kind][2])
            logf = numpyro.sample(f"{kind}_log", dist.Normal(0.0, tol).expand([n_free]).to_event(1))
            total = total + self.log_factors(kind, logf)[getattr(data, KINDS[kind][1])]
        return 1.0 if isinstance(total, float) else jnp.exp(total)

    def physical(self, draws: dict[str, np.ndarray], rng: np.random.Generator) -> dict[str, np.ndarray]:
        """Factor of each measured setting, and per draw the kind's spread of log factors.

        The spread ``tau`` is drawn from its conjugate posterior given that
        draw's log factors: ``tau^2 ~ InvGamma(2 + n / 2, tol^2 + sum(log f^2) / 2)``.
        """
        out = {}
        for kind in self.active():
            logf = draws[f"{kind}_log"]
            tol = getattr(self.spec, KINDS[kind][2])
            shape = SPREAD_PRIOR_SHAPE + 0.5 * logf.shape[-1]
            rate = tol**2 * (SPREAD_PRIOR_SHAPE - 1) + 0.5 * np.sum(logf**2, axis=-1)
            out[f"setting_factor_{kind}"] = np.exp(self.log_factors(kind, logf, xp=np))
            out[f"setting_spread_{kind}"] = np.sqrt(rate / rng.gamma(shape, 1.0, size=rate.shape))
        return out
