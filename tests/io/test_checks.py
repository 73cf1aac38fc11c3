"""Property tests of the boundary checks: whatever a user hands in, a frame, a date, a fleet design
or a fleet table is either accepted with every promise kept or refused with bayescal's own error
naming the source; never another exception, never nonsense accepted."""

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from bayescal.errors import SpecError, TableError
from bayescal.io import checks
from bayescal.validation.fleet import FleetDesign, design_from_dict, simulate_fleet

DTYPES = st.sampled_from(["uint8", "uint16", "int16", "int32", "float32", "float64", "complex64", "bool"])


@settings(max_examples=150, deadline=None)
@given(hnp.arrays(DTYPES, hnp.array_shapes(min_dims=1, max_dims=4, min_side=0, max_side=4)))
def test_a_frame_is_accepted_only_when_it_is_real_finite_and_not_negative(img):
    try:
        out = checks.image(img, "frame.npy")
    except TableError as exc:
        assert str(exc).startswith("frame.npy: ")
        return
    assert out is img
    assert img.dtype.kind in "uif" and img.ndim in (2, 3) and img.size > 0
    assert np.isfinite(img.astype(float)).all() and (img >= 0).all()


@settings(max_examples=150, deadline=None)
@given(st.one_of(st.text(max_size=20), st.dates().map(str), st.datetimes().map(str), st.integers().map(str)))
def test_a_date_is_a_timestamp_or_a_named_refusal(text):
    try:
        when = checks.date(text, "--date")
    except SpecError as exc:
        assert str(exc).startswith("--date ")
        return
    assert isinstance(when, pd.Timestamp) and when == when.normalize()


@settings(max_examples=150, deadline=None)
@given(
    st.one_of(
        st.integers(-5, 10**6), st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=6), st.booleans()
    )
)
def test_counts_and_probabilities(value):
    try:
        n = checks.count(value, "n")
    except SpecError as exc:
        assert str(exc).startswith("n = ")
    else:
        assert isinstance(n, int) and n >= 1 and not isinstance(value, bool)
    try:
        p = checks.probability(value, "p")
    except SpecError as exc:
        assert str(exc).startswith("p = ")
    else:
        assert 0.0 < p < 1.0


VALUES = st.one_of(
    st.integers(-3, 40),
    st.floats(allow_nan=True, allow_infinity=True, width=32),
    st.text(max_size=8),
    st.booleans(),
    st.lists(st.one_of(st.floats(-1, 40), st.sampled_from(["2024-03-01", "2025-03-01", "SN001", "x"])), max_size=4),
)
KEYS = st.sampled_from(
    ["n_cameras", "campaigns", "levels", "n_frames", "n_pixels", "settle_years", "loss_range", "brief", "absent"]
    + ["brief_levels", "campaign_jitter", "offset_creep_dn", "nframes"]
)


@settings(max_examples=200, deadline=None)
@given(st.dictionaries(KEYS, VALUES, max_size=4))
def test_a_fleet_design_is_valid_or_refused_naming_its_file(raw):
    try:
        design = design_from_dict(raw, "design.toml")
    except SpecError as exc:
        assert str(exc).startswith("design.toml: ")
        return
    assert isinstance(design, FleetDesign)
    assert design.n_cameras >= 2 and design.n_frames >= 1 and design.n_pixels >= 1
    assert design.campaigns and list(design.campaigns) == sorted(set(design.campaigns))
    assert design.levels and all(v > 0 for v in design.levels)
    assert design.loss_range[0] <= design.loss_range[1] and design.settle_years > 0


@pytest.fixture(scope="module")
def fleet_frame():
    table, _ = simulate_fleet(
        FleetDesign(n_cameras=2, campaigns=("2024-03-01", "2025-03-01"), n_pixels=16, n_frames=4), seed=2
    )
    return table


CELLS = st.one_of(
    st.text(max_size=12),
    st.dates().map(str),
    st.sampled_from(["2024-03-01", "2124-01-01", "", " ", "nan", "2024-02-30"]),
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(row=st.integers(0, 10), column=st.sampled_from(["campaign", "camera"]), value=CELLS)
def test_a_fleet_table_cell_is_accepted_or_refused_by_row_and_column(fleet_frame, tmp_path_factory, row, column, value):
    from bayescal.fleet import load_fleet_table

    frame = fleet_frame.astype({"campaign": str, "camera": str}).copy()
    frame.loc[row, column] = value
    path = tmp_path_factory.mktemp("t") / "fleet.csv"
    frame.to_csv(path, index=False)
    try:
        fleet = load_fleet_table(path)
    except TableError as exc:
        assert "fleet.csv" in str(exc)
        return
    today = pd.Timestamp.now().normalize()
    assert all(u.campaign is None or pd.Timestamp("1950-01-01") <= u.campaign <= today for u in fleet.units)
