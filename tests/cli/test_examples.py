"""Shipped examples by name, from a folder outside the repository, against the installed package (the
command line in this process, its working folder the test's own; the wheel's slow test runs the same
names from a clean environment)."""

from bayescal.cli import main


def test_examples_by_name_from_any_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)

    def _bayescal(_cwd, *args):
        rc = main(list(args))
        said = capsys.readouterr()
        return rc, said.out + said.err

    rc, out = _bayescal(tmp_path, "examples")
    assert rc == 0 and "seed000_bayer" in out and "seed002_tdi" in out and "fleet_seed000_design" in out
    rc, out = _bayescal(tmp_path, "simulate", "--design", "seed000", "--out", "d.csv", "--seed", "1")
    assert rc == 0 and (tmp_path / "d.csv").is_file(), out
    rc, out = _bayescal(tmp_path, "fit", "d.csv", "--model", "seed000", "--backend", "lsq", "--out", "f", "--quiet")
    assert rc == 0 and (tmp_path / "f" / "summary.json").is_file(), out
    rc, out = _bayescal(tmp_path, "fleet-simulate", "fleet", "--out", "fleet.csv")
    assert rc == 0 and "20 cameras" in out, out
    # copied out to edit: a name gives its spec and design, a design comes with the spec it names, and
    # nothing of the user's is overwritten
    rc, out = _bayescal(tmp_path, "examples", "--copy", "seed002", "--to", "mine")
    assert rc == 0 and sorted(p.name for p in (tmp_path / "mine").iterdir()) == [
        "seed002_design.toml",
        "seed002_tdi.toml",
    ]
    rc, out = _bayescal(tmp_path, "examples", "--copy", "seed000_design", "--to", "mine")
    assert rc == 0 and {"seed000_design.toml", "seed000_bayer.toml"} <= {p.name for p in (tmp_path / "mine").iterdir()}
    (tmp_path / "mine" / "seed002_tdi.toml").write_text("# my edits\n")
    rc, out = _bayescal(tmp_path, "examples", "--copy", "seed002", "--to", "mine")
    assert rc == 2 and "does not overwrite your files" in out
    assert (tmp_path / "mine" / "seed002_tdi.toml").read_text() == "# my edits\n"
    rc, out = _bayescal(tmp_path, "examples", "--copy", "nonesuch")
    assert rc == 2 and "no shipped example 'nonesuch'" in out


def test_a_mistyped_name_gets_a_did_you_mean(tmp_path, capsys):
    """A name cut short or misspelt: the closest shipped example, or the closest file beside the path."""
    from bayescal.io.resources import did_you_mean

    assert did_you_mean("seed00") == "; did you mean 'seed000' (a shipped example; `bayescal examples` lists them)?"
    assert "'emva'" in did_you_mean("emvaa")
    (tmp_path / "campaign_2026.csv").write_text("x\n")
    assert did_you_mean(tmp_path / "campaing_2026.csv") == "; did you mean 'campaign_2026.csv'?"
    assert did_you_mean(tmp_path / "zzz.csv") == ""  # nothing close: nothing suggested
    code = main(["fit", str(tmp_path / "campain_2026.csv"), "--model", "seed000", "--out", str(tmp_path / "F")])
    assert code == 2 and "did you mean 'campaign_2026.csv'?" in capsys.readouterr().err
