"""Output folders: bayescal replaces only what its own record says it wrote, never deletes a file
it did not write, and readers refuse folders that mix runs or come from an older format."""

import json
import signal

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bayescal.errors import OutputError, PosteriorError
from bayescal.io.outputs import (
    FORMAT,
    MARKER,
    check_output_dir,
    interrupts_held,
    read_marker,
    staged_directory,
    verify_output,
    write_text_atomic,
)


def _run(out, kind="fit", files=None):
    """Write an output of ``kind`` holding ``files`` (name -> text); returns its run id."""
    files = files or {"summary.json": '{"a": 1}', "posterior.nc": "draws"}
    with staged_directory(out, kind=kind) as stage:
        for name, text in files.items():
            stage(name).write_text(text)
        run_id = stage.run_id
    return run_id


def _snapshot(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


def test_an_output_lists_its_files_and_replaces_only_its_own_kind(tmp_path):
    out = tmp_path / "fit"
    first = _run(out)
    marker = read_marker(out)
    assert marker["format"] == FORMAT and marker["kind"] == "fit" and marker["run_id"] == first
    assert set(marker["files"]) == {"summary.json", "posterior.nc"}
    assert marker["files"]["posterior.nc"]["size"] == 5 and len(marker["files"]["posterior.nc"]["sha256"]) == 64
    second = _run(out, files={"summary.json": "{}"})  # a later fit replaces it whole
    assert read_marker(out)["run_id"] == second != first
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "summary.json"]
    before = _snapshot(out)
    with pytest.raises(OutputError, match="holds a calibration fit .* this run writes per-pixel maps"):
        check_output_dir(out, "maps")
    assert _snapshot(out) == before
    assert [p.name for p in tmp_path.iterdir()] == ["fit"]  # no staging or old folder left


@pytest.mark.parametrize(
    ("setup", "why"),
    [
        (lambda d: (d / "thesis.docx").write_text("mine"), "files bayescal did not write .*thesis.docx"),
        (  # an older bayescal output: recognised, but its files cannot be told from the user's
            lambda d: [(d / "summary.json").write_text("{}"), (d / "data_2019.csv").write_text("1,2")],
            "older bayescal, which wrote no record",
        ),
        (lambda d: (d / MARKER).write_text('{"kind": "fit"}'), "older output format"),
    ],
)
def test_a_folder_with_anything_not_bayescal_s_is_refused_before_work(tmp_path, setup, why):
    out = tmp_path / "out"
    out.mkdir()
    setup(out)
    before = _snapshot(out)
    with pytest.raises(OutputError, match=why):
        _run(out)
    assert _snapshot(out) == before


def test_a_file_added_or_changed_after_the_run_keeps_the_folder(tmp_path):
    out = tmp_path / "fit"
    _run(out)
    (out / "notes.txt").write_text("my notes on this fit")
    with pytest.raises(OutputError, match="did not write .*notes.txt"):
        _run(out)
    assert (out / "notes.txt").read_text() == "my notes on this fit"
    (out / "notes.txt").unlink()
    (out / "summary.json").write_text('{"a": 2}')  # same size, other content: the user edited it
    with pytest.raises(OutputError, match=r"changed after it wrote them \(summary.json\)"):
        _run(out)
    assert (out / "summary.json").read_text() == '{"a": 2}'


def test_a_user_file_arriving_during_the_run_is_kept(tmp_path):
    out = tmp_path / "fit"
    _run(out)
    with pytest.raises(OutputError, match="late.txt"), staged_directory(out, kind="fit") as stage:
        stage("summary.json").write_text("{}")
        (out / "late.txt").write_text("saved while the fit ran")
    assert (out / "late.txt").read_text() == "saved while the fit ran"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fit"]


names = st.sampled_from(
    ["summary.json", "posterior.nc", "radiance.nc", "fleet.nc", "thesis.docx", "data_2019.csv", MARKER, "maps.zarr"]
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    files=st.dictionaries(names, st.binary(max_size=40), max_size=5),
    marker=st.sampled_from(["none", "garbage", "old", "copied", "other-kind"]),
)
def test_no_file_bayescal_did_not_write_is_ever_deleted(tmp_path_factory, files, marker):
    """Any folder: a fit either refuses it, leaving every byte as it was, or replaces a folder
    every file of which an earlier fit wrote (its record lists it, unchanged)."""
    root = tmp_path_factory.mktemp("p")
    out = root / "out"
    if marker in ("copied", "other-kind"):  # a real output, then the drawn files on top
        _run(out, kind="fit" if marker == "copied" else "maps")
    out.mkdir(exist_ok=True)
    for name, data in files.items():
        if name != MARKER or marker in ("garbage", "old"):
            (out / name).write_bytes(data)
    if marker == "old":
        (out / MARKER).write_text(json.dumps({"kind": "fit", "bayescal_version": "0.9"}))
    before = _snapshot(out)
    record = read_marker(out)
    ours = (
        set(record.get("files", {})) if record and record.get("format") == FORMAT and record["kind"] == "fit" else set()
    )
    try:
        _run(out)
    except OutputError:
        assert _snapshot(out) == before
    else:  # replaced: only files of an earlier run's record, unchanged, went
        gone = set(before) - {MARKER}
        assert gone <= ours
        for name in gone:
            assert record["files"][name]["size"] == len(before[name])
    assert sorted(p.name for p in root.iterdir()) == ["out"]


def test_readers_refuse_mixed_older_or_foreign_folders(tmp_path):
    lsq, bayes = tmp_path / "lsq", tmp_path / "bayes"
    _run(lsq, files={"summary.json": '{"backend": "lsq"}'})
    _run(bayes, files={"summary.json": '{"backend": "laplace"}', "posterior.nc": "draws"})
    assert verify_output(bayes, ("fit",), needs=("posterior.nc",)).kind == "fit"
    (lsq / "posterior.nc").write_bytes((bayes / "posterior.nc").read_bytes())  # two runs in one folder
    with pytest.raises(PosteriorError, match=r"posterior.nc was not written by the run that wrote .*lsq"):
        verify_output(lsq, ("fit",), needs=("posterior.nc",))
    with pytest.raises(PosteriorError, match="not written by the run"):
        verify_output(lsq / "posterior.nc", ("fit",))  # the file named directly
    (bayes / "summary.json").write_text('{"backend": "nuts"}')  # replaced by another run's file
    with pytest.raises(PosteriorError, match="bytes where .* wrote"):
        verify_output(bayes, ("fit",))
    (bayes / "summary.json").write_text('{"backend": "laplacX"}')  # the same size
    with pytest.raises(PosteriorError, match="differs from what"):
        verify_output(bayes, ("fit",))
    fleet = tmp_path / "fleet"
    _run(fleet, kind="fleet", files={"fleet.nc": "x"})
    with pytest.raises(PosteriorError, match=r"holds a fleet fit \(`bayescal fleet`\); report needs a calibration"):
        verify_output(fleet, ("fit",), verb="report")
    old = tmp_path / "old"
    old.mkdir()
    (old / "summary.json").write_text('{"status": "ok"}')  # an older release's output: no record
    with pytest.raises(PosteriorError, match="older bayescal"):
        verify_output(old, ("fit",))
    (old / MARKER).write_text('{"kind": "fit"}')  # the first format's marker
    with pytest.raises(PosteriorError, match="older output format"):
        verify_output(old, ("fit",))
    lone = tmp_path / "lone.nc"
    lone.write_text("draws")
    assert verify_output(lone, ("fit",)) is None  # a file outside any output folder cannot mix runs


def test_a_report_written_later_joins_the_run_and_a_user_s_file_is_kept(tmp_path):
    out = tmp_path / "fit"
    _run(out)
    write_text_atomic(out / "report.html", "<html>")
    assert "report.html" in read_marker(out)["files"]
    verify_output(out, ("fit",), needs=("report.html",))
    write_text_atomic(out / "report.html", "<html>again")  # the run's own file: replaced
    verify_output(out, ("fit",))
    (out / "mine.md").write_text("keep")
    with pytest.raises(OutputError, match="refusing to overwrite .*mine.md"):
        write_text_atomic(out / "mine.md", "report")
    assert (out / "mine.md").read_text() == "keep"
    assert not [p for p in out.iterdir() if p.name.endswith(".tmp")]


def test_interrupts_are_held_back_for_the_swap_and_acted_on_after(tmp_path):
    # Python's own handler, whatever an earlier test in this worker left installed
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        steps = []
        with pytest.raises(KeyboardInterrupt), interrupts_held():
            signal.raise_signal(signal.SIGINT)
            steps.append("the step went on to its end")
        assert steps == ["the step went on to its end"]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, before)
