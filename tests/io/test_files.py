"""Output directories and scratch folders: nothing half-written or left behind."""

import pytest

from bayescal.io.outputs import discard_staging, scratch_directory, staged_directory


def test_scratch_directory_is_removed_after_use_on_error_and_on_interrupt(tmp_path):
    out = tmp_path / "maps"
    with scratch_directory(out, "work") as scratch:
        (scratch / "a.npy").write_bytes(b"x")
        assert scratch.parent == tmp_path and scratch.name.startswith(".maps.work-")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(RuntimeError), scratch_directory(out, "work"):
        raise RuntimeError("a bad input half way")
    assert list(tmp_path.iterdir()) == []
    # Ctrl-C: the CLI's handler discards what is registered, then leaves with os._exit (no finally runs)
    with (
        pytest.raises(KeyboardInterrupt),
        scratch_directory(out, "work") as scratch,
        staged_directory(out, kind="fit") as stage,
    ):
        stage("x.txt").write_text("half")
        discard_staging()
        assert not scratch.exists() and not stage.root.exists()
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []
