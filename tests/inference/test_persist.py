"""Traced programs kept on disk: a later build loads them without running the model's Python, computes
what the plain jit computes, and survives a damaged file; nothing is kept without an exact key."""

from typing import NamedTuple

import numpy as np
import numpyro
import numpyro.distributions as dist
import pytest
from scipy import stats

import bayescal as bc
from bayescal.inference import persist
from bayescal.inference.program import clear_program_cache, program_of


class Line(NamedTuple):
    x: np.ndarray
    y: np.ndarray


#: how often the model's Python ran (each trace runs it once)
TRACES: list[int] = []


def line(data: Line) -> None:
    TRACES.append(1)
    a = numpyro.sample("a", dist.Normal(0.0, 10.0))
    b = numpyro.sample("b", dist.Normal(0.0, 10.0))
    s = numpyro.sample("s", dist.HalfNormal(1.0))
    numpyro.sample("obs", dist.StudentT(5.0, a + b * data.x, s), obs=data.y)


@pytest.fixture
def data():
    rng = np.random.default_rng(0)
    x = np.linspace(0.0, 1.0, 30)
    return Line(x, 0.5 + 2.0 * x + 0.1 * rng.standard_normal(30))


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("BAYESCAL_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("BAYESCAL_NO_CACHE", raising=False)
    clear_program_cache()
    yield tmp_path / "programs"
    clear_program_cache()


def _outputs(program, data):
    z = np.array([0.3, 1.7, -1.2])
    batch = z + np.linspace(-0.5, 0.5, 7)[:, None]
    value, grad = program.value_and_grad(z, data)
    sites = program.constrain(batch, data)
    values = {"a": np.asarray(sites["a"][0]), "b": np.asarray(sites["b"][0]), "s": np.asarray(sites["s"][0])}
    return {
        "value": np.asarray(value),
        "grad": np.asarray(grad),
        "hessian": np.asarray(program.hessian(z, data)),
        "a": np.asarray(sites["a"]),
        "b": np.asarray(sites["b"]),
        "s": np.asarray(sites["s"]),
        "loglik": np.asarray(program.loglik(batch, data)),
        "unconstrain": np.asarray(program.unconstrain(values, data)),
    }


def test_a_kept_program_is_loaded_without_tracing_and_computes_the_same(cache, data):
    plain = _outputs(program_of(line, data), data)  # no structure: the plain jit, nothing kept
    assert not cache.exists() or not any(cache.iterdir())
    clear_program_cache()
    first = _outputs(program_of(line, data, structure="line v1"), data)
    kept = sorted(p.name for p in cache.iterdir())
    # value, gradient and Hessian in one; the constrained sites with the log-likelihood; unconstrain
    assert sum(n.endswith(".jaxexport") for n in kept) == 3 and sum(n.endswith("-latent.json") for n in kept) == 1
    clear_program_cache()
    TRACES.clear()
    again = _outputs(program_of(line, data, structure="line v1"), data)
    assert TRACES == []  # loaded: the model's Python did not run
    for name, expected in plain.items():
        np.testing.assert_allclose(first[name], expected, rtol=1e-12, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(again[name], expected, rtol=1e-12, atol=1e-12, err_msg=name)
    assert np.isfinite(plain["value"]) and plain["loglik"].shape == (7, 30)
    # the log-likelihood the constrain program carries is the model's, in closed form
    t = stats.t.logpdf(data.y, 5.0, loc=plain["a"][:, None] + plain["b"][:, None] * data.x, scale=plain["s"][:, None])
    np.testing.assert_allclose(plain["loglik"], t, rtol=1e-10)


def test_another_structure_or_shape_is_kept_apart(cache, data):
    program_of(line, data, structure="line v1").value_and_grad(np.zeros(3), data)
    clear_program_cache()
    program_of(line, data, structure="line v2").value_and_grad(np.zeros(3), data)
    clear_program_cache()
    longer = Line(np.linspace(0.0, 1.0, 31), np.zeros(31))
    program_of(line, longer, structure="line v1").value_and_grad(np.zeros(3), longer)
    assert len(list(cache.glob("*.jaxexport"))) == 3
    keys = {persist.structure_key(s, d, "obs") for s, d in [("line v1", data), ("line v2", data), ("line v1", longer)]}
    assert len(keys) == 3


def test_a_damaged_file_is_traced_again_and_replaced(cache, data):
    expected = _outputs(program_of(line, data, structure="line v1"), data)
    for path in cache.glob("*.jaxexport"):
        path.write_bytes(b"not a program")
    clear_program_cache()
    TRACES.clear()
    got = _outputs(program_of(line, data, structure="line v1"), data)
    assert TRACES  # traced again
    for name in expected:
        np.testing.assert_allclose(got[name], expected[name], rtol=1e-12, atol=1e-12, err_msg=name)
    clear_program_cache()
    TRACES.clear()
    _outputs(program_of(line, data, structure="line v1"), data)
    assert TRACES == []  # the rewritten files load


def test_nothing_is_kept_without_an_exact_key_or_with_caching_off(cache, data, monkeypatch):
    assert persist.structure_key("Parts(levels=array([1., 2., ..., 9.]))", data, "obs") is None
    program_of(line, data, structure="array([0., ..., 1.])").value_and_grad(np.zeros(3), data)
    assert not cache.exists() or not any(cache.glob("*.jaxexport"))
    clear_program_cache()
    monkeypatch.setenv("BAYESCAL_NO_CACHE", "1")
    program_of(line, data, structure="line v1").value_and_grad(np.zeros(3), data)
    assert not cache.exists() or not any(cache.glob("*.jaxexport"))


def test_a_calibration_program_is_kept_and_loaded(cache, seed000):
    """The camera model's program (its data a named tuple with a dict in it) round-trips: the gradient
    from the loaded program equals the traced one's."""
    spec, design = seed000
    model = bc.build_model(bc.simulate(spec, design, seed=0).table, spec)
    from bayescal.inference.program import program_for

    with bc.numerics():
        program = program_for(model)
        z = np.asarray(program.z0) + 0.01
        traced = np.asarray(program.value_and_grad(z, model.data)[1])
        clear_program_cache()
        loaded = np.asarray(program_for(model).value_and_grad(z, model.data)[1])
    assert any(cache.glob("*.jaxexport"))
    np.testing.assert_allclose(loaded, traced, rtol=1e-12, atol=1e-12 * np.abs(traced).max())


def test_the_oldest_are_removed_beyond_the_limit(cache, data, monkeypatch):
    monkeypatch.setattr(persist, "MAX_FILES", 3)
    for version in range(3):  # each writes its latent layout and one program
        program_of(line, data, structure=f"line v{version}").value_and_grad(np.zeros(3), data)
        clear_program_cache()
    assert len(list(cache.iterdir())) == 3
    TRACES.clear()
    program_of(line, data, structure="line v2").value_and_grad(np.zeros(3), data)
    assert TRACES == []  # the newest is kept


def test_the_key_follows_the_source_the_trace_runs_and_no_other():
    """The model, its data and spec, and the programs are in the digest; the command line and the
    checks after a fit are not (a change there keeps the programs)."""
    from pathlib import Path

    root = Path(bc.__file__).parent
    names = {p.relative_to(root).as_posix() for p in persist.traced_files(root)}
    assert {
        "model/assemble.py",
        "model/data.py",
        "inference/program.py",
        "model/spec.py",
        "io/table.py",
        "_config.py",
    } <= names
    assert not {n for n in names if n.startswith(("cli/", "fitting/", "report/", "fleet/"))}


def test_a_kept_program_is_compiled_once_for_device_and_host_arguments(cache, data):
    """A mode search starts from a device array and steps on host arrays: both kinds of argument run the one
    compiled program (the jit keyed them apart, and each new structure's programs were loaded twice)."""
    import jax
    import jax.numpy as jnp
    from jax import monitoring

    compiled: list[str] = []

    def listen(event: str, seconds: float, **kw) -> None:
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(event)

    with bc.numerics():
        program_of(line, data, structure="line v1").value_and_grad(np.zeros(3), data)  # traced and kept
        clear_program_cache()
        program = program_of(line, data, structure="line v1")
        monitoring.register_event_duration_secs_listener(listen)
        try:
            on_device = jax.device_put(jnp.asarray([0.3, 1.7, -1.2]), jax.devices()[0])
            first = program.value_and_grad(on_device, data)
            loaded = len(compiled)
            second = program.value_and_grad(np.array([0.3, 1.7, -1.2]), data)
        finally:
            monitoring.unregister_event_duration_listener(listen)
    assert loaded >= 1 and len(compiled) == loaded  # the host call compiled nothing more
    np.testing.assert_array_equal(np.asarray(first[1]), np.asarray(second[1]))
