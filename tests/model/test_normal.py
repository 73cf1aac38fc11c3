"""The model's normal CDF and log-CDF (one erfc each) against scipy's, in value and derivative."""

import numpy as np
import pytest
from scipy import special

#: from deep in the lower tail (asymptotic series) through zero to where 1 - Phi underflows
X = np.concatenate([np.linspace(-60.0, 40.0, 20001), [-20.0, -20.0 - 1e-9, -20.0 + 1e-9, -1e-300, 0.0, 1e-300]])


@pytest.fixture
def normal(float64):
    from bayescal.model import normal

    return normal


def test_ndtr_matches_scipy_to_rounding(normal):
    import jax.numpy as jnp

    ours, ref = np.asarray(normal.ndtr(jnp.asarray(X))), special.ndtr(X)
    normal_range = ref > 1e-290  # scipy keeps subnormals, XLA flushes them
    assert np.max(np.abs(ours - ref)[normal_range] / ref[normal_range]) < 1e-14
    assert float(normal.ndtr(0.0)) == 0.5


def test_log_ndtr_matches_scipy_in_both_tails(normal):
    import jax.numpy as jnp

    ours, ref = np.asarray(normal.log_ndtr(jnp.asarray(X))), special.log_ndtr(X)
    kept = np.abs(ref) > 1e-290
    assert np.max(np.abs(ours - ref)[kept] / np.abs(ref[kept])) < 1e-14  # the upper tail's log1p included
    # on either side of the switch to the series, one curve
    assert np.max(np.abs(np.diff(ours[-6:-3]))) < 1e-7


def test_log_ndtr_derivatives_are_the_mills_ratio_and_finite(normal):
    import jax
    import jax.numpy as jnp

    x = jnp.asarray(X)
    grad = np.asarray(jax.vmap(jax.grad(normal.log_ndtr))(x))
    second = np.asarray(jax.vmap(jax.grad(jax.grad(normal.log_ndtr)))(x))
    assert np.isfinite(grad).all() and np.isfinite(second).all()
    # d/dx log Phi = phi / Phi; from logs, since both underflow in the lower tail
    mills = np.exp(-0.5 * X**2 - 0.5 * np.log(2 * np.pi) - special.log_ndtr(X))
    kept = mills > 1e-290  # beyond, both are (sub)normal zeros
    assert np.max(np.abs(grad - mills)[kept] / mills[kept]) < 1e-12 and np.max(np.abs(grad[~kept])) < 1e-290
    # d2/dx2 log Phi = -r (x + r), r the inverse Mills ratio (between -1 and 0); the reference's own
    # x + r cancels to ~1e-10 at x = -60
    assert np.max(np.abs(second - (-mills * (X + mills)))) < 1e-8
    assert second.min() >= -1.0 - 1e-9 and second.max() <= 1e-12
