"""The one schema of a fit folder's summary.json: what each reader relies on is checked where it is read."""

import pytest

from bayescal.errors import PosteriorError
from bayescal.io.summary import FitSummary


def _camera() -> dict:
    return {
        "model_kind": "calibration",
        "status": "ok",
        "backend": "laplace",
        "seed": 4,
        "model": {"name": "m", "components": {}},
        "diagnostics": {"verdict": "ok", "problems": []},
        "parameters": [{"parameter": "gain[R]", "mean": 1.0}],
        "stimulus_unit": "W m^-2 sr^-1",
        "comparison_at_reference": [],
        "lsq": [],
    }


def test_a_summary_reads_back_what_was_written():
    summary = FitSummary.from_json(_camera(), "F/summary.json")
    assert summary.ok and summary.seed == 4 and summary.parameters[0]["parameter"] == "gain[R]"
    assert FitSummary.from_json(summary.to_json()) == summary
    assert "source" not in summary.to_json()  # only an export carries one
    exported = FitSummary.from_json(_camera() | {"backend": "fleet", "source": {"camera": "SN001"}})
    assert exported.source == {"camera": "SN001"} and exported.to_json()["source"] == {"camera": "SN001"}


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"lsq": None}, "key 'lsq' should be a list, got NoneType"),
        ({"seed": "4"}, "key 'seed' should be a int, got str"),
        ({"diagnostics": {"verdict": "ok"}}, "key 'diagnostics.problems' is missing"),
        ({"model": {"components": {}}}, "key 'model.name' is missing"),
    ],
)
def test_a_short_or_mistyped_summary_names_the_file_and_the_key(change, message):
    with pytest.raises(PosteriorError, match="F/summary.json") as err:
        FitSummary.from_json(_camera() | change, "F/summary.json")
    assert message in str(err.value)


def test_each_kind_needs_its_own_keys():
    camera = _camera()
    del camera["stimulus_unit"]
    with pytest.raises(PosteriorError, match="key 'stimulus_unit' is missing"):
        FitSummary.from_json(camera, "F/summary.json")
    film = {k: v for k, v in _camera().items() if k not in ("stimulus_unit", "comparison_at_reference", "lsq")}
    assert FitSummary.from_json(film | {"model_kind": "film"}).model_kind == "film"  # a film has no baseline
    with pytest.raises(PosteriorError, match="expected a JSON object, got list"):
        FitSummary.from_json([], "F/summary.json")
