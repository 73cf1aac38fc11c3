"""The measurement equation's skeleton, written once (docs/architecture.md, section 2).

Every component fills one place (its ``role``)::

    x   = u  f_settings  prod(factor terms)          effective stimulus ("settings", "factor")
    S   = R_g(x)                                      response at the row's effective gain ("response")
    DN  = sum(offset terms) + S                       expected reading ("offset")
    var = noise(S);  reading = ADC(DN + noise)        ("noise", "observation")

``u`` is the stimulus times the settings' nominal ratio ``t M g / (t_ref M_ref g_ref)``; the
settings' effective factors also set the gain ``g`` at which a charge-domain response is evaluated
(:meth:`~bayescal.model.components.response.Response.coefficients_at`).  The offset terms are the
dark level (:class:`~bayescal.model.components.dark.Dark`) and the offset effects; the factor terms
the sphere's level errors and the factor effects.

Three places evaluate the equation, each with the values it has:

- the numpyro model (:func:`bayescal.model.assemble.numpyro_model`): sampled terms, scaled units,
  ``jax.numpy``;
- a calibration's predictions (:meth:`bayescal.posterior.calibration.Calibration.expected_dn`):
  posterior draws in physical units, one value per draw;
- the simulator (:func:`bayescal.model.simulate.simulate`): the truth, in physical units.

All three call :func:`reading`, so the order in which terms compose is written here alone.  Its
inverse, :func:`stimulus`, undoes the same terms in the reverse order (the inversion of readings,
:mod:`bayescal.prediction.invert`); the noise and the clipping of a reading are composed in
:mod:`bayescal.model.observation`.  Its
arguments are consumed in the equation's order (the factors, then the response, then the offsets),
so terms that sample as they are evaluated draw their sites in that order.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any, NamedTuple

__all__ = ["ROLES", "Reading", "reading", "stimulus"]

#: the places a component fills in the equation
ROLES = ("settings", "factor", "response", "offset", "noise", "observation")


class Reading(NamedTuple):
    """The expected reading and its signal (any array namespace, broadcast shapes)."""

    signal: Any  # the response's signal S(x), in the offsets' units
    mean: Any  # the expected reading before noise and clipping: the offsets plus S


def reading(u: Any, factors: Iterable[Any], response: Callable[[Any], Any], offsets: Iterable[Any]) -> Reading:
    """The expected reading ``sum(offsets) + R(u prod(factors))``.

    Parameters
    ----------
    u : array
        Stimulus times the settings' nominal ratio (0 for a dark row).
    factors : iterable of arrays or floats
        Factors on the effective stimulus, broadcast against ``u`` (consumed first).
    response : callable
        ``x -> S(x)``: the response at the row's effective gain, its roll-off included.
    offsets : iterable of arrays or floats
        Levels added to the reading in the signal's units (consumed last).
    """
    x = u
    for factor in factors:
        x = x * factor
    signal = response(x)
    offset: Any = 0.0
    for term in offsets:
        offset = offset + term
    return Reading(signal, offset + signal)


def stimulus(
    dn: Any,
    factors: Iterable[Any],
    inverse_response: Callable[[Any], Any],
    offsets: Iterable[Any],
    noise: Callable[[Any], Any] | None = None,
) -> Any:
    """The inverse of :func:`reading`: the stimulus ``u`` that reads ``dn``,
    ``R^-1(dn - sum(offsets) - e(S)) / prod(factors)``.

    Parameters
    ----------
    dn : array
        Readings, broadcast against the offsets and the factors.
    factors : iterable of arrays or floats
        The factors on the effective stimulus (divided out last).
    inverse_response : callable
        ``S -> x``: the response's inverse at the row's effective gain.
    offsets : iterable of arrays or floats
        Levels added to the reading (subtracted first).
    noise : callable, optional
        ``S -> e``: the reading's noise at signal ``S``, subtracted before the response is inverted
        (a posterior draw of what the reading's noise was); None inverts the expected reading.
    """
    signal = dn
    for term in offsets:
        signal = signal - term
    if noise is not None:
        signal = signal - noise(signal)
    x = inverse_response(signal)
    for factor in factors:
        x = x / factor
    return x
