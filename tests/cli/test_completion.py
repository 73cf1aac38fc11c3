"""``bayescal completion bash``: a completion script made from the parser, so it knows every verb and option."""

import argparse
import shutil
import subprocess
import sys

import pytest

from bayescal.cli.parser import build


def _script(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "bayescal.cli", "completion", "bash"], capture_output=True, text=True, check=True
    )
    path = tmp_path / "bayescal.bash"
    path.write_text(done.stdout)
    return path


@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")
def test_bash_completes_verbs_options_and_example_names(tmp_path):
    script = _script(tmp_path)

    def complete(*words: str) -> list[str]:
        line = " ".join(words)
        program = (
            f"source {script}; COMP_WORDS=({line}); COMP_CWORD={len(words) - 1}; _bayescal; "
            'printf "%s\\n" "${COMPREPLY[@]}"'
        )
        out = subprocess.run(["bash", "-c", program], capture_output=True, text=True, check=True, cwd=tmp_path)
        return out.stdout.split()

    sub = next(a for a in build()._actions if isinstance(a, argparse._SubParsersAction))
    verbs = set(sub.choices)
    assert len(verbs) >= 18
    assert set(complete("bayescal", "")) >= verbs
    assert complete("bayescal", "fi") == ["fit"]
    assert "--no-diagnose" in complete("bayescal", "fit", "data.csv", "--no")
    assert complete("bayescal", "fit", "data.csv", "--model", "seed000_") == [
        "seed000_bayer",
        "seed000_design",
        "seed000_frame",
    ]
    (tmp_path / "campaign.csv").write_text("x\n")
    assert complete("bayescal", "fit", "camp") == ["campaign.csv"]  # files elsewhere
