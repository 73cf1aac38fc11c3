"""Each bad input gets its own clear error naming the row and column."""

import numpy as np
import pandas as pd
import pytest

import bayescal as bc
from bayescal.cli import main


def good_frame():
    rows = []
    for lum in [0.0, 5.0, 10.0, 15.0, 20.0]:
        for ch, gain in (("R", 60.0), ("G", 30.0)):
            rows.append(dict(channel=ch, radiance=lum, exposure_s=0.004, gain=1.0, dn_mean=50 + gain * lum))
    return pd.DataFrame(rows)


def spec1():
    return bc.ModelSpec(name="t", bits=12, reference=bc.Reference(0.004))


def error_of(df, spec=None):
    with pytest.raises(bc.TableError) as exc:
        table = bc.MeasurementTable.from_frame(df, source="t.csv")
        if spec is not None:
            bc.build_model(table, spec)
    return exc.value


def test_good_table_loads():
    table = bc.MeasurementTable.from_frame(good_frame())
    assert len(table) == 10 and table.channels == ["R", "G"]
    assert table.is_dark.sum() == 2


def test_missing_column():
    err = error_of(good_frame().drop(columns="exposure_s"))
    assert err.column == "exposure_s" and "missing required column" in str(err)


def test_nan_value():
    df = good_frame().astype({"dn_mean": object})
    df.loc[3, "dn_mean"] = np.nan
    err = error_of(df)
    assert (err.row, err.column) == (4, "dn_mean") and "missing value" in str(err)


def test_non_numeric():
    df = good_frame().astype({"gain": object})
    df.loc[6, "gain"] = "high"
    err = error_of(df)
    assert (err.row, err.column) == (7, "gain") and "'high' is not a number" in str(err)


def test_negative_radiance():
    df = good_frame()
    df.loc[2, "radiance"] = -1.0
    err = error_of(df)
    assert (err.row, err.column) == (3, "radiance") and "negative" in str(err)


def test_negative_exposure():
    df = good_frame()
    df.loc[5, "exposure_s"] = -0.004
    err = error_of(df)
    assert (err.row, err.column) == (6, "exposure_s") and "not positive" in str(err)


def test_conflicting_duplicates():
    df = pd.concat([good_frame(), good_frame().iloc[[3]].assign(dn_mean=999.0)], ignore_index=True)
    err = error_of(df)
    assert err.row == 11 and "conflicts with (dn_mean" in str(err) and "row 4" in str(err)


def test_too_few_levels_for_order():
    df = good_frame()
    df = df[df["radiance"] <= 10.0]  # two illuminated levels
    err = error_of(df, spec1().replace(response={"order": 2}))
    assert "channel 'R' has 2 distinct unsaturated stimulus levels" in str(err) and "needs at least 3" in str(err)


def test_all_points_saturated():
    df = good_frame()
    df.loc[(df.channel == "R") & (df.radiance > 0), "dn_mean"] = 4095.0
    err = error_of(df, spec1())
    assert "every illuminated point of channel 'R' is saturated" in str(err)


def test_over_full_scale_names_bit_depth():
    df = good_frame()
    df.loc[9, "dn_mean"] = 5000.0
    err = error_of(df, spec1())
    assert err.row == 10 and "12-bit" in str(err)


def test_cli_bad_input_exits_2_and_writes_nothing(tmp_path, capsys):
    df = good_frame().astype({"dn_mean": object})
    df.loc[1, "dn_mean"] = "n/a"
    path = tmp_path / "bad.csv"
    df.to_csv(path, index=False)
    out = tmp_path / "out"
    code = main(["fit", str(path), "--model", "models/seed000_bayer.toml", "--out", str(out), "--quiet"])
    assert code == 2
    assert "row 2, column 'dn_mean'" in capsys.readouterr().err
    assert not out.exists()


def test_spec_unknown_key_is_named():
    with pytest.raises(bc.SpecError, match="response.ordr"):
        bc.ModelSpec.from_dict({"name": "x", "bits": 12, "reference": {"exposure_s": 1.0}, "response": {"ordr": 2}})


def test_csv_roundtrip(tmp_path, seed000):
    spec, design = seed000
    sim = bc.simulate(spec, design, seed=3)
    sim.table.write_csv(tmp_path / "d.csv")
    again = bc.load_table(tmp_path / "d.csv")
    pd.testing.assert_frame_equal(again.frame[sim.table.frame.columns], sim.table.frame, check_dtype=False, rtol=1e-9)


def test_a_filtered_frame_keeps_its_rows(seed000):
    """A DataFrame with gaps in its index (a filter's result) is read row by row, not by index label."""
    import bayescal as bc

    spec, design = seed000
    frame = bc.simulate(spec, design, seed=2).table.to_frame()
    part = frame[frame.gain == 1.0]
    assert part.index.to_numpy().max() >= len(part)  # the filter left gaps
    table = bc.MeasurementTable.from_frame(part)
    assert len(table) == len(part)
    assert table.frame["dn_mean"].tolist() == part["dn_mean"].tolist()
