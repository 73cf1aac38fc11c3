"""float64 and the compilation cache are switched on where bayescal computes, and put back after."""

import json
import subprocess
import sys

import numpy as np

import bayescal as bc
from tests.conftest import MODELS


def test_a_fit_leaves_jax_as_it_found_it(tmp_path):
    """A user's JAX code before and after ``bayescal.fit`` runs in float32 without bayescal's cache; the
    fit itself computed in float64 (its draws are float64) and wrote its programs to bayescal's cache."""
    cache = tmp_path / "cache"
    code = f"""
import json, warnings
import jax, jax.numpy as jnp
import bayescal as bc
state = lambda: [jax.config.jax_enable_x64, jax.config.jax_compilation_cache_dir, str(jnp.ones(2).dtype)]
before = state()
import dataclasses
spec = bc.load_spec({str(MODELS / "seed000_bayer.toml")!r})
design = bc.load_design({str(MODELS / "seed000_design.toml")!r})
dark = dataclasses.replace(design.dark[0], gain=(1.0,))  # one channel, one gain: a small program to compile
design = dataclasses.replace(design, channels=("G",), illuminated=design.illuminated[:1], dark=(dark,))
table = bc.simulate(spec, design, seed=1).table
spec = spec.replace(inference={{"holdout_check": False}})  # no holdout refits: fewer programs to compile
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    fit = bc.fit(table, spec, "laplace", seed=0)
after = state()
user = jax.jit(lambda x: x * 2.0)(jnp.ones(3))
print(json.dumps([before, after, str(fit.draws("gain").dtype), str(user.dtype)]))
"""
    env = {"BAYESCAL_CACHE_DIR": str(cache), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    before, after, fit_dtype, user_dtype = json.loads(out.stdout.strip().splitlines()[-1])
    assert before == [False, None, "float32"] and after == before
    assert fit_dtype == "float64" and user_dtype == "float32"
    assert any(cache.iterdir()), "the fit's programs were not written to bayescal's compilation cache"


def test_numerics_is_reentrant_and_restores_a_users_own_setting():
    import jax

    prior = jax.config.jax_enable_x64
    try:
        jax.config.update("jax_enable_x64", False)
        with bc.numerics():
            with bc.numerics():
                assert jax.config.jax_enable_x64
            assert jax.config.jax_enable_x64  # the outer scope still holds
            x = jax.numpy.asarray(np.float64(1.0) / 3.0)
            assert x.dtype == np.float64
        assert not jax.config.jax_enable_x64
    finally:
        jax.config.update("jax_enable_x64", prior)
