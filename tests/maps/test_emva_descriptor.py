"""Per-pixel maps from an EMVA 1288 descriptor and its images, in both of the standard's layouts.

The exposure sweep is the real refset001 crop written out as a descriptor with
PNG images: it must give the very stacks the cropped arrays give.  The
illumination sweep (one exposure, one dark group for all bright groups) comes
from the independent pixel simulator, so its truth is known.
"""

import numpy as np
import pandas as pd
import pytest
from PIL import Image

import bayescal as bc
from bayescal.cli import main
from bayescal.maps.stacks import write_emva_stacks
from bayescal.validation.sensor import PixelSensor, write_stacks
from tests.conftest import DATA

CROP = DATA / "emva1288" / "refset001_ccd_12bit" / "crop128.npz"


def write_descriptor(folder, bits, groups):
    """A descriptor in the refset's own form: ``b``/``d`` lines, each followed by ``i`` lines of PNG files."""
    (folder / "images").mkdir(parents=True, exist_ok=True)
    lines = ["# written by the test", "v 3.0", f"n {bits} {groups[0][2].shape[-1]} {groups[0][2].shape[-2]}"]
    for g, (kind, texp_ns, frames, *photons) in enumerate(groups):
        lines.append(f"b {texp_ns} {photons[0]}" if kind == "b" else f"d {texp_ns}")
        for f, frame in enumerate(frames):
            name = f"{kind}_{g:03d}_snap_{f:03d}.png"
            Image.fromarray(np.asarray(frame, dtype=np.uint16)).save(folder / "images" / name)
            lines.append(f"i images\\{name}")  # the refset's Windows separators
    path = folder / "EMVA1288_Data.txt"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_descriptor_gives_the_stacks_of_the_cropped_arrays(tmp_path):
    """Every 5th step of the crop (two above 70 % of full scale) and 8 frames of each stack, written both ways."""
    z = np.load(CROP)
    steps, frames = slice(0, None, 5), slice(0, 8)
    subset = {k: z[k] for k in z.files}
    for k in ("bright_texp", "bright_photons", "bright_pairs", "dark_texp", "dark_pairs"):
        subset[k] = z[k][steps]
    for k in ("bright_stack", "dark_stack"):
        subset[k] = z[k][frames]
    np.savez(tmp_path / "subset.npz", **subset)
    groups = []
    for i in range(len(subset["bright_texp"])):
        groups.append(("b", subset["bright_texp"][i], subset["bright_pairs"][i], subset["bright_photons"][i]))
        groups.append(("d", subset["dark_texp"][i], subset["dark_pairs"][i]))
    groups.append(("b", z["bright_stack_texp"], subset["bright_stack"], z["bright_stack_photons"]))
    groups.append(("d", z["dark_stack_texp"], subset["dark_stack"]))
    descriptor = write_descriptor(tmp_path / "set", int(z["bits"]), groups)
    a = write_emva_stacks(tmp_path / "subset.npz", tmp_path / "from_npz")
    b = write_emva_stacks(descriptor, tmp_path / "from_txt")
    ta, tb = pd.read_csv(a / "conditions.csv"), pd.read_csv(b / "conditions.csv")
    pd.testing.assert_frame_equal(ta, tb)
    full = 2 ** int(z["bits"]) - 1
    below = int((subset["bright_pairs"].mean(axis=(1, 2, 3)) <= 0.7 * full).sum())
    assert 0 < below < len(subset["bright_texp"])  # the subset has steps on both sides of the cut
    assert (ta.kind == "flat").sum() == below + 1  # the pairs below 70 % of full scale, and the stack
    assert (ta.kind == "dark").sum() == below + 1  # each with the dark group of its exposure
    for name in ta.file:
        np.testing.assert_array_equal(np.load(a / name), np.load(b / name))
    # the characterization reads the same descriptor to the same per-step statistics as the arrays
    from bayescal.io.emva import load_steps

    sa, sb = load_steps(tmp_path / "subset.npz"), load_steps(descriptor)
    np.testing.assert_allclose(sb.bright.mean_dn, sa.bright.mean_dn, rtol=1e-12)
    np.testing.assert_allclose(sb.dark.var_dn2, sa.dark.var_dn2, rtol=1e-12)
    assert sb.stack["n_images"] == 8


@pytest.fixture(scope="module")
def illumination_sweep(tmp_path_factory):
    """One exposure, one dark stack, three bright stacks: the standard's other layout."""
    root = tmp_path_factory.mktemp("sweep")
    sensor = PixelSensor(height=128, width=128)
    truth = write_stacks(sensor, root / "sim", photons=[0.0, 3000.0, 10000.0, 30000.0], exposure_s=0.1, seed=5)
    sim = pd.read_csv(root / "sim" / "conditions.csv")
    groups = [("d", 1e8, np.load(root / "sim" / sim.file[0]))]
    for _, row in sim[sim.kind == "flat"].iterrows():
        groups.append(("b", 1e8, np.load(root / "sim" / row.file), row.photons))
    return write_descriptor(root / "set", sensor.bits, groups), truth


def test_illumination_sweep_maps_cover_the_truth(illumination_sweep, tmp_path):
    descriptor, truth = illumination_sweep
    out = tmp_path / "maps"
    assert main(["maps", str(descriptor), "--out", str(out), "--quiet"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["maps"]  # the converted stacks are gone
    maps = bc.read_maps(out)
    assert maps.attrs["stacks"] == str(descriptor.resolve())
    assert len(maps.attrs["source_sha256"]) == 64
    # one exposure: the dark current cannot be told from the offset, so the offset map carries offset + D t
    assert "dark_current_dn_s" not in maps
    normal = truth.defect == 0
    for name, true in (
        ("relative_gain", truth.relative_gain),
        ("offset_dn", truth.offset_dn + truth.dark_current_dn_s * 0.1),
    ):
        est, sd = maps[name].to_numpy(), maps[f"u_random_{name}"].to_numpy()
        cover = np.mean((np.abs(est - true) <= 1.96 * sd)[normal])
        print(f"\n{name}: 95 % coverage {cover:.4f} over {normal.sum()} pixels")
        assert 0.93 <= cover <= 0.97, name  # Monte Carlo sd of the rate ~0.0017


def test_bad_descriptors_are_refused_by_line(illumination_sweep, tmp_path):
    descriptor, _ = illumination_sweep
    text = descriptor.read_text().splitlines()
    first_bright = next(i for i, line in enumerate(text) if line.startswith("b "))

    def refused(lines, match):
        bad = descriptor.parent / "bad.txt"
        bad.write_text("\n".join(lines) + "\n")
        with pytest.raises(bc.TableError, match=match):
            write_emva_stacks(bad, tmp_path / "out")
        assert main(["maps", str(bad), "--out", str(tmp_path / "cli"), "--quiet"]) == 2

    # a bright group at an exposure no dark group has
    refused(
        [*text[:first_bright], "b 2e8 3000", *text[first_bright + 1 :]],
        rf"line {first_bright + 1}: bright group at 2e\+08 ns has no dark group",
    )
    # a bit depth the images exceed
    refused(["n 8 128 128" if line.startswith("n ") else line for line in text], "outside 0..255 of a 8-bit ADC")
    # an image of another shape
    small = descriptor.parent / "images" / "small.png"
    Image.fromarray(np.zeros((64, 128), np.uint16)).save(small)
    last_image = max(i for i, line in enumerate(text) if line.startswith("i "))
    refused([*text[:last_image], "i images\\small.png"], "small.png has shape")
    # a listed image that is not there
    refused([*text, "i images\\gone.png"], "missing, e.g.")
    # a line that is no tag of the format, one image where a pair or stack belongs, numbers out of range
    refused([*text, "hello world"], rf"line {len(text) + 1} 'hello world': unknown tag 'hello'")
    refused([*text, "b 1e8 500", text[-1]], "has 1 image")
    refused([*text[:first_bright], "b -5 3000", *text[first_bright + 1 :]], "exposure \\(ns\\) -5; expected")
    refused(["n 40 128 128" if line.startswith("n ") else line for line in text], "40 bits; expected 1-24")
    # the standard's bias step (a dark group at exposure 0) is accepted beside the groups it needs
    first_dark = next(i for i, line in enumerate(text) if line.startswith("d "))
    images = [line for line in text[first_dark + 1 :] if line.startswith("i ")][:2]
    ok = descriptor.parent / "bias.txt"
    ok.write_text("\n".join([*text, "d 0", *images]) + "\n")
    write_emva_stacks(ok, tmp_path / "bias")
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())
