"""Fuzzing table loading and fitting: whatever a file holds, only bayescal's own errors escape.

Tables are built by hypothesis from the real columns with values that are valid, borderline or
nonsense (blank, text, negative, infinite, huge, duplicated); loading and a least-squares fit
either succeed or raise :class:`bayescal.BayescalError` (which the command line turns into exit 2).
A few hundred cases run by default, thousands in the slow suite.
"""

import io

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bayescal as bc
from tests.conftest import MODELS

COLUMNS = [
    "channel",
    "radiance",
    "irradiance",
    "exposure_s",
    "gain",
    "dn_mean",
    "level",
    "tdi_stages",
    "temperature_c",
    "n_frames",
    "n_pixels",
    "dn_var",
    "radiance_u_rel",
    "replicate",
    "comment",
]
CELL = st.one_of(
    st.sampled_from(["", "nan", "inf", "-1", "0", "1", "2", "R", "G", "B", "dark", "1e308", "0.004", "x", " 3 "]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(min_value=0, max_value=4095).map(lambda v: f"{v:.6g}"),
    st.integers(min_value=-5, max_value=5000).map(str),
)


@st.composite
def tables(draw):
    required = ["channel", "exposure_s", "gain", "dn_mean", draw(st.sampled_from(["radiance", "irradiance"]))]
    extra = draw(st.lists(st.sampled_from(COLUMNS), max_size=5, unique=True))
    columns = list(dict.fromkeys(required + extra))
    if draw(st.booleans()):
        columns = draw(st.permutations(columns))[: draw(st.integers(1, len(columns)))]
    n = draw(st.integers(0, 14))
    rows = [[draw(CELL) for _ in columns] for _ in range(n)]
    return pd.DataFrame(rows, columns=columns, dtype=str)


def _plausible(rng_seed: int) -> pd.DataFrame:
    """A mostly valid table (so that fitting is reached), with one cell made odd."""
    rng = np.random.default_rng(rng_seed)
    rows = []
    for channel in "RG":
        for radiance in (0.0, 5.0, 10.0, 20.0, 30.0):
            for gain in (1.0, 2.0):
                dn = 50 * gain + 60 * radiance * gain + rng.normal(0, 2)
                rows.append([channel, radiance, 0.004, gain, dn])
    df = pd.DataFrame(rows, columns=["channel", "radiance", "exposure_s", "gain", "dn_mean"]).astype(str)
    i, j = rng.integers(len(df)), rng.integers(df.shape[1])
    df.iat[i, j] = rng.choice(["", "nan", "-inf", "0", "-1", "4096", "5000", "1e-300", "9e9", "x", df.iat[0, j]])
    return df


def _load_and_fit(df: pd.DataFrame, spec) -> None:
    text = df.to_csv(index=False)
    path = io.StringIO(text)
    try:
        table = bc.MeasurementTable.from_frame(pd.read_csv(path, dtype=str, skipinitialspace=True), source="fuzz")
        result = bc.fit(table, spec, "lsq")
    except bc.BayescalError:
        return
    if result.ok:  # "ok" means every channel got a finite least-squares fit
        lsq = result.lsq
        assert set(lsq["channel"]) == set(table.channels)
        for _, row in lsq.iterrows():
            assert np.all(np.isfinite([row[f"A{k}"] for k in range(int(row["order"]) + 1)])), row
    else:
        assert result.diagnostics.problems


@pytest.fixture(scope="module")
def spec():
    return bc.load_spec(MODELS / "seed000_bayer.toml")


@settings(max_examples=250, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(df=tables())
def test_random_tables_raise_only_bayescal_errors(spec, df):
    _load_and_fit(df, spec)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1))
def test_nearly_valid_tables_raise_only_bayescal_errors(spec, seed):
    _load_and_fit(_plausible(seed), spec)


@pytest.mark.slow
@settings(max_examples=3000, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(df=tables())
def test_random_tables_many(spec, df):
    _load_and_fit(df, spec)


@pytest.mark.slow
@settings(max_examples=3000, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1))
def test_nearly_valid_tables_many(spec, seed):
    _load_and_fit(_plausible(seed), spec)
