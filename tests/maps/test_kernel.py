"""The compiled streaming pass against the numpy mapping of the same model, and its reading and reduction.

The compiled block program (:mod:`bayescal.maps.kernel`) reads frames with
positioned reads, reduces them in XLA and maps every pixel; the numpy path
(:meth:`bayescal.maps.model.MapModel.block` on :func:`block_statistics` of
memory-mapped frames) is the reference.  The two agree to float32 rounding;
the defect code, a threshold decision, may differ only for a pixel whose
probability sits on the threshold.
"""

import numpy as np
import pytest

from bayescal.maps.kernel import block_maps, sub_block_rows
from bayescal.maps.model import fit_map_model
from bayescal.maps.stacks import block_statistics, load_manifest
from bayescal.validation.sensor import PixelSensor, write_stacks


def _numpy_maps(model, manifest, r0, r1):
    stats = [block_statistics(s[:, r0:r1]) for s in manifest.stacks]
    means, variances = np.stack([m for m, _ in stats]), np.stack([v for _, v in stats])
    out = np.empty((len(model.outputs()), r1 - r0, manifest.shape[1]), np.float32)
    k = model.step
    for name, dy, dx in model.planes:
        sub = means[:, dy::k, dx::k]
        flat = model.models[name].block(sub.reshape(len(stats), -1), variances[:, dy::k, dx::k].reshape(len(stats), -1))
        out[:, dy::k, dx::k] = flat.reshape(-1, *sub.shape[1:])
    return out


@pytest.mark.parametrize("bayer", [None, "RGGB"])
def test_compiled_pass_matches_numpy(tmp_path, bayer):
    sensor = PixelSensor(height=96, width=80, bayer=bayer)
    write_stacks(sensor, tmp_path, photons=[0.0, 3000.0, 10000.0], exposure_s=[0.05, 0.1, 0.3], frames=3, seed=4)
    manifest = load_manifest(tmp_path)
    model = fit_map_model(manifest, rows_per_chunk=40, cfa=bayer)  # blocks of 40, 40 and 16 rows
    names = model.outputs()
    for r0, r1 in ((0, 40), (80, 96)):  # a whole block and the short last one (padded sub-block)
        got, want = block_maps(model, manifest.stacks, r0, r1), _numpy_maps(model, manifest, r0, r1)
        code = names.index("defect")
        cont = [i for i in range(len(names)) if i != code]
        scale = np.maximum(np.abs(want[cont]), 1e-3 * np.abs(want[cont]).max(axis=(1, 2), keepdims=True))
        assert np.max(np.abs(got[cont] - want[cont]) / scale) < 1e-4
        assert np.mean(got[code] == want[code]) > 0.99


def test_sixteen_bit_reduction_is_exact_at_the_extremes(tmp_path):
    """Frames alternating 0 and 65535: a squared deviation of 65535^2 overflows 32-bit integers; the
    compiled reduction widens first, so mean and variance are the closed-form values."""
    import jax.numpy as jnp

    from bayescal._config import numerics

    frames = np.zeros((16, 4, 6), np.uint16)
    frames[1::2] = 65535
    with numerics():
        mean, var = (np.asarray(a) for a in block_statistics(jnp.asarray(frames), jnp))
    assert mean == pytest.approx(np.full((4, 6), 32767.5), rel=1e-12)
    assert var == pytest.approx(np.full((4, 6), 16 * 32767.5**2 / 15), rel=1e-12)


def test_read_rows_in_every_layout(tmp_path):
    """Positioned reads give the memory map's rows for native and big-endian .npy files."""
    rng = np.random.default_rng(0)
    data = rng.integers(0, 4096, (3, 10, 7)).astype(np.uint16)
    write_stacks(PixelSensor(height=10, width=7), tmp_path, photons=[0.0, 1000.0], exposure_s=0.1, frames=3, seed=1)
    np.save(tmp_path / "c00_dark.npy", data.astype(">u2"))
    manifest = load_manifest(tmp_path)
    stack = next(s for s in manifest.stacks if s.path.endswith("c00_dark.npy"))
    rows = stack.read_rows(2, 6)
    assert rows.dtype == np.dtype("=u2") and np.array_equal(rows, data[:, 2:6])
    buf = np.zeros((3, 8, 7), np.uint16)  # into part of a larger buffer, as the compiled pass reads
    stack.read_rows(1, 4, buf[:, 2:5])
    assert np.array_equal(buf[:, 2:5], data[:, 1:4]) and not buf[:, :2].any() and not buf[:, 5:].any()
    with pytest.raises(IndexError):
        stack.read_rows(5, 11)


def test_sub_blocks_split_a_block_evenly_on_whole_cells():
    from types import SimpleNamespace

    stack = SimpleNamespace(shape=(100, 8, 1000), dtype=np.dtype(np.uint16))
    stacks = [stack, stack]  # 2 stacks x 100 frames x 1000 px x 2 bytes = 400 kB per row: 60 rows in 24 MB
    assert sub_block_rows(130, 1, stacks) == 44  # 3 sub-blocks of 44 rows
    assert sub_block_rows(121, 2, stacks) == 42  # 3 sub-blocks of 41 rows, rounded up to whole 2-row cells
    assert sub_block_rows(30, 1, stacks) == 30  # a block that fits is one sub-block
