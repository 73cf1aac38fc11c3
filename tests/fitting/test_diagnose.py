"""A fit that does not describe its data tries the library's components and names the one that
does, by PSIS-LOO; measured on the independent bench (bayescal.validation.bench), whose cameras
depart from the model one way at a time."""

import warnings

import numpy as np
import pytest

import bayescal as bc
from bayescal.fitting.diagnosis import candidates
from bayescal.fitting.diagnosis.search import alternatives
from bayescal.fitting.modegain import SCREEN_SE, ModeFit, paired_gain, screen
from bayescal.model.components.glow import Glow
from bayescal.model.components.sphere import fold_common_scale
from bayescal.validation import BenchCamera, Departures, simulate_bench, with_held_out
from tests.conftest import MODELS

SPEC = MODELS / "seed000_bayer.toml"


def _table(departures, seed, timed=True, temperatures=()):
    camera = with_held_out(BenchCamera(temperatures_c=temperatures), exposures=(0.01,))
    frame, real = simulate_bench(camera, departures, seed=seed)
    if not timed:
        frame = frame.drop(columns="time_s")
    return bc.MeasurementTable.from_frame(frame), real


def test_candidates_are_the_switches_the_table_can_inform():
    spec = bc.load_spec(SPEC)
    timed, _ = _table(Departures(), 1)
    untimed, _ = _table(Departures(), 1, timed=False)
    names = set(candidates(spec, untimed))
    assert any("over the run (the rows' order)" in n for n in names)  # no time_s: the rows' order
    timed_offered = candidates(spec, timed)
    # time_s: dark.drift and offset_drift ("auto") already fit an additive drift; only the stimulus's is offered
    assert not any("dark" in c or "offset_drift" in c for c in timed_offered.values())
    assert any(c.get("stimulus_drift") == {"enabled": True, "over": "time_s"} for c in timed_offered.values())
    assert any("nonlinearity of the output" in n for n in names)  # several illuminated gains
    assert any("glow" in n for n in names)  # dark rows at four exposures
    assert any("response order 3" in n for n in names)
    assert "a soft roll-off towards full scale (not a polynomial)" in names  # readings reach 60 % of full scale
    assert "a soft roll-off towards full scale, with the nonlinearity of the output" in names
    assert "a monotone roll-off towards full scale of any smooth shape, with the nonlinearity of the output" in names
    assert not any("sensor temperature" in n for n in names)  # one temperature: nothing to inform it
    thermal, _ = _table(Departures(), 1, temperatures=(10.0, 30.0))
    assert "an offset that drifts with the sensor temperature (per channel)" in candidates(spec, thermal)
    # one illuminated gain: the domain of the nonlinearity cannot be told
    frame, _ = simulate_bench(BenchCamera(), Departures(), seed=1)
    one_gain = bc.MeasurementTable.from_frame(frame[frame.gain == 1.0].reset_index(drop=True))
    assert not any("nonlinearity" in n for n in candidates(spec, one_gain))


def test_an_adopted_switch_meets_its_alternatives_with_the_others_on():
    """A roll-off shape chosen before the glow was on is judged again with the glow on: each alternative (the
    other shapes, the other domain) replaces it while the glow stays; a switch with no alternative is kept."""
    spec = bc.load_spec(SPEC)
    table, _ = _table(Departures(), 1)
    offered = candidates(spec, table)
    soft = "a soft roll-off towards full scale (not a polynomial)"
    glow = next(n for n in offered if "glow" in n)
    swaps = alternatives(spec, table, {soft: offered[soft], glow: offered[glow]}, candidates)
    replaced = {name.split(" (in place of ")[0]: old for name, (old, _, _) in swaps.items()}
    assert replaced["a monotone roll-off towards full scale of any smooth shape"] == soft
    assert (
        replaced["a monotone roll-off towards full scale of any smooth shape, with the nonlinearity of the output"]
        == soft
    )
    assert "nonlinearity of the output (after the gain)" not in replaced  # it sets no key the soft roll-off sets
    assert glow not in replaced.values()  # nothing else sets the glow's keys
    for _, trial, changes in swaps.values():
        assert trial.effect("glow").enabled is True
        assert trial.response.rolloff == changes["response"]["rolloff"]


@pytest.mark.slow  # the whole diagnosis, every candidate in three steps (about two minutes)
def test_a_dark_drift_without_times_is_named_not_blamed_on_something_else():
    """The dark level drifts 3 DN over a run whose table has no time_s: the spec's fit fails its checks;
    the diagnosis adopts the drift over the rows' order, which passes every check, and the offsets A0
    then cover the truth (the spec alone: 0.31 of them, flagged)."""
    spec = bc.load_spec(SPEC)
    table, real = _table(Departures(dark_drift_dn=3.0), 11, timed=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result, found = bc.fit_diagnosed(table, spec, "laplace", seed=3)
    assert found is not None and found.adopted == ("a dark level that drifted over the run (the rows' order)",)
    assert found.explained and result.ok
    best = found.steps[0].iloc[0]
    assert best.elpd_diff > 2 * best.dse
    # the screen: the adopted switch's in-sample gain at its mode is not below its elpd_loo gain by its margin
    # (one in-sample se; 0.71 at most on the independent simulators), and what it kept out gained at most that
    assert best.mode_gain >= best.elpd_diff - SCREEN_SE * best.mode_dse
    screened = found.steps[0][found.steps[0].screened]
    assert len(screened) and (screened.mode_gain <= SCREEN_SE * screened.mode_dse).all()
    assert screened.elpd_diff.isna().all()
    assert result.diagnostics.extra["diagnosis"]["changes"] == {"dark": {"drift": "order"}}
    a0 = result.draws("A_rel")[..., 0]
    for c, ch in enumerate(result.model.layout.channels):
        lo, hi = np.quantile(a0[:, c], [0.005, 0.995])
        assert lo <= real.true_coefficients(ch, relative=True)[0] <= hi


#: a roll-off is named by either roll-off term: the soft one, or the monotone one of any shape where the data
#: cannot tell them apart (the more flexible rival's rule, test_a_rigid_roll_off_the_data_cannot_tell_...)
ROLL_OFF = ("a soft roll-off towards full scale", "a monotone roll-off towards full scale")


@pytest.mark.slow
@pytest.mark.parametrize(
    ("departures", "adopted", "temperatures"),
    [
        (Departures(spectral_level_rel=0.01, channel_scale_rel=0.015), "lamp errors that differ by channel", ()),
        (Departures(glow_dn_s2=2e4), "amplifier glow", ()),
        (Departures(rolloff=True), ROLL_OFF, ()),
        (Departures(rolloff=True, rolloff_shape="tanh"), ROLL_OFF, ()),
        (Departures(bias_dn_per_c=0.8), "an offset that drifts with the sensor temperature", (10.0, 20.0, 30.0)),
    ],
)
def test_each_departure_is_named(departures, adopted, temperatures):
    spec = bc.load_spec(SPEC)
    table, _ = _table(departures, 21, temperatures=temperatures)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result, found = bc.fit_diagnosed(table, spec, "laplace", seed=1)
    assert found is not None and any(a.startswith(adopted) for a in found.adopted), found.describe()
    assert result.ok, result.diagnostics.verdict


def test_glow_and_channel_scale_terms():
    """The glow adds glow t^2 g / g_ref to the dark level; a channel's own scale error widens its
    absolute coefficients by its relative sd (log-normal, independent of the common scale)."""
    assert Glow.forward(4.0, 0.5, 2.0) == pytest.approx(4.0 * 0.25 * 2.0)
    rng = np.random.default_rng(0)
    coef = np.ones((4, 20_000, 3, 2))
    _, common = fold_common_scale(coef, 0.0, rng, channel_rel=0.02)
    folded, _ = fold_common_scale(coef, 0.0, np.random.default_rng(1), channel_rel=0.02)
    assert np.allclose(common, 1.0)
    assert np.std(np.log(folded[..., 1]), axis=(0, 1)) == pytest.approx([0.02] * 3, rel=0.03)
    assert abs(np.corrcoef(folded[..., 0, 1].ravel(), folded[..., 1, 1].ravel())[0, 1]) < 0.02


def test_a_roll_off_is_absorbed_not_refused():
    """The bench's signal rolls off as S / (1 + (S / 1.6 FS)^4)^(1/4): with the roll-off component the fit
    passes its checks, its knee and power cover the bench's, the offsets and gains cover the truth, and a
    reading near full scale inverts to the stimulus that made it (a polynomial of order 3 bent A1 by 23 sd)."""
    spec = bc.load_spec(SPEC).replace(response={"rolloff": True})
    table, real = _table(Departures(rolloff=True), 10_000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = bc.fit(table, spec, "laplace", seed=10_000)
    assert result.ok, result.diagnostics.verdict
    knee, power = result.draws("rolloff_knee_dn"), result.draws("rolloff_power")
    # the two are correlated and each lies ~2.6 sd from the bench's (knee 6458 +- 40 DN against 6552, power
    # 4.09 +- 0.034 against 4): within 3.5 sd, a bias of twice that fails
    for draws, truth in ((knee, 1.6 * 4095), (power, 4.0)):
        assert abs(draws.mean() - truth) < 3.5 * draws.std(), (draws.mean(), draws.std(), truth)
    rel = result.draws("A_rel")
    for c, ch in enumerate(result.model.layout.channels):
        lo, hi = np.quantile(rel[:, c, :2], [0.005, 0.995], axis=0)
        truth = real.true_coefficients(ch, relative=True)[:2]
        assert np.all((lo <= truth) & (truth <= hi)), (ch, lo, truth, hi)
    cal = bc.Calibration.from_fit(result)
    setting = bc.Setting(0.004, 1.0)
    stimulus = 110.0  # G reads ~3400 DN there, where the roll-off compresses the signal by ~2 %
    dn = float(np.median(cal.expected_dn("G", stimulus, setting)))
    assert 3000 < dn < cal.saturation_dn
    inv = bc.invert(cal, [dn], "G", setting, noise=False)
    assert inv.median[0] == pytest.approx(stimulus, rel=0.01)
    assert inv.lower[0] < stimulus < inv.upper[0]
    linear = bc.Calibration(**{f: getattr(cal, f) for f in cal.__dataclass_fields__ if f not in ("tables", "rolloff")})
    assert bc.invert(linear, [dn], "G", setting, noise=False).median[0] < 0.99 * stimulus  # the roll-off undone


def test_a_candidate_the_data_cannot_tell_apart_that_moves_a_coefficient_is_reported():
    """structure_doubt: a passing candidate within 2 se of the spec's elpd that moves a coefficient by more
    than 2 posterior sd is named, with what it moved; one the data reject, one that fails its checks, or one
    that moves nothing is not (draws with known means and sds: the z-scores are exact)."""
    from types import SimpleNamespace

    import pandas as pd

    from bayescal.fitting.diagnosis import DOUBT_Z, Diagnosis, rival_doubt, structure_doubt

    rng = np.random.default_rng(3)
    unit = rng.standard_normal((4000, 2, 2))
    unit = (unit - unit.mean(axis=0)) / unit.std(axis=0)  # mean 0, sd 1 exactly

    def fake(shift):
        a = np.zeros((4000, 2, 3))
        a[..., :2] = unit + shift
        return SimpleNamespace(
            posterior=object(), model=SimpleNamespace(layout=SimpleNamespace(channels=("R", "G"))), draws=lambda n: a
        )

    base = fake(np.zeros((2, 2)))
    moved = np.zeros((2, 2))
    moved[1, 0] = DOUBT_Z + 1.0  # G's A0 by 3 sd

    def found(diff, ok, shift):
        step = pd.DataFrame([{"candidate": "c", "elpd_diff": diff, "dse": 2.0, "fit_ok": ok, "changes": {}}])
        return Diagnosis((), None, True, [step], trials={"c": (None, fake(shift))})

    # the other structure (the spec the candidate nests) is named for `design --after`: these fakes carry no spec
    expected = {"candidate": "c", "moved_sd": {"G A0": 3.0}, "carried": True, "other": "the spec without it"}
    expected["other_spec"] = None
    assert structure_doubt(base, found(-1.0, True, moved)) == ("c", expected)
    assert structure_doubt(base, found(-5.0, True, moved)) is None  # the data prefer the spec by 2.5 se
    assert structure_doubt(base, found(0.5, False, moved)) is None  # the candidate's own fit fails
    assert structure_doubt(base, found(0.5, True, moved / 2)) is None  # 1.5 sd: within the intervals

    # a rival of an adopted model (it does not nest it): named, and said not to be carried by the intervals
    rivals = Diagnosis(("a",), None, True, [], rivals={"r": (-1.0, 2.0, fake(moved)), "s": (0.5, 1.0, fake(moved / 2))})
    assert rival_doubt(base, rivals) == {
        "candidate": "r",
        "moved_sd": {"G A0": 3.0},
        "elpd_diff": -1.0,
        "dse": 2.0,
        "other_spec": None,
        "carried": False,
    }
    assert rival_doubt(base, Diagnosis(("a",), None, True, [], rivals={"s": (0.5, 1.0, fake(moved / 2))})) is None


def test_rivals_are_the_passing_fits_the_data_cannot_tell_from_the_winner():
    """rivals_of: elpd_loo differences paired over the same rows; a fit within 2 se of the winner's that passes is
    a rival; one 3 se below, or one that fails its checks, is not (pointwise elpds with exact sums and sds)."""
    from types import SimpleNamespace

    from bayescal.fitting.diagnosis.search import rivals_of

    n = 100
    noise = np.tile([1.0, -1.0], n // 2)  # mean 0, sd 1: the paired difference's se is sqrt(n) * sd
    winner = SimpleNamespace(elpd_i=np.zeros(n))

    def entry(shift_se, ok=True):
        loo = SimpleNamespace(elpd_i=noise + shift_se * np.sqrt(n) / n)  # sum = shift_se * se
        return (None, SimpleNamespace(ok=ok, posterior=object()), loo)

    fits = {"w": (None, SimpleNamespace(ok=True, posterior=object()), winner), "near": entry(-1.5), "far": entry(-3.0)}
    fits["failing"] = entry(0.5, ok=False)
    found = rivals_of(winner, fits, "w")
    assert set(found) == {"near"}
    diff, se, _ = found["near"]
    assert diff == pytest.approx(-1.5 * np.sqrt(n)) and se == pytest.approx(np.sqrt(n))


@pytest.mark.slow  # the whole diagnosis on a camera nobody described (about three minutes)
def test_a_rigid_roll_off_the_data_cannot_tell_from_the_flexible_one_gives_way_to_it():
    """A tanh roll-off from the independent simulator of cameras nobody described (its seed 24: darks at the
    session's end too): the knee family and the monotone shape both pass and predict the data within 2 se;
    the knee left A0 about 3 sd off in every channel.  The monotone shape is reported, the knee named as the
    rival whose doubt the reported posterior carries, and A0 and A1 of every channel cover the truth."""
    from bayescal.validation.wild import simulate_wild

    frame, session = simulate_wild(24)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result, found = bc.fit_diagnosed(bc.MeasurementTable.from_frame(frame), bc.load_spec(SPEC), "laplace", seed=24)
    assert result.ok and found is not None
    assert found.spec.response.rolloff == "monotone", found.describe()
    assert found.preferred["over"].startswith("a soft roll-off"), found.preferred
    structure = result.diagnostics.extra["structure"]
    assert structure["carried"] and structure["reported"] == found.preferred["candidate"]
    truth = session.truth().set_index("channel")
    rel = result.draws("A_rel")[..., :2]
    for c, channel in enumerate(result.model.layout.channels):
        for k, name in enumerate(("A0", "A1")):
            lo, hi = np.quantile(rel[:, c, k], [0.025, 0.975])
            assert lo <= truth.loc[channel, name] <= hi, (channel, name)


@pytest.mark.slow  # the lamp candidates fitted in full (about a minute cold); the rule itself is tested below
def test_a_lamp_error_size_the_data_cannot_tell_gives_way_to_the_wider():
    """Lamp errors of 1 % per level and channel on the independent bench (its seed 10004, the misspecification
    benchmark's fifth dataset): PSIS-LOO cannot tell 0.3 % from 1 % per level (elpd within 1 of each other);
    the narrower prior left three of the six A0, A1 outside their 95 % intervals.  Whichever size the elpd's
    coin picks, the wider one is reported (it draws the narrower one's errors too) and every A0, A1 covers."""
    from bayescal.fitting.diagnosis import diagnose

    spec = bc.load_spec(SPEC)
    table, real = _table(Departures(spectral_level_rel=0.01, channel_scale_rel=0.015), 10_004)

    def lamps(s, t):
        return {name: changes for name, changes in candidates(s, t).items() if name.startswith("lamp errors")}

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        found = diagnose(table, spec, seed=10_004, offered=lamps)
    assert found.explained and found.spec.sphere.channel_level_rel == 0.01, found.describe()
    assert "0.3% per level" in found.preferred.get("over", "") or "0.3% per level" in " ".join(found.rivals)
    rel = found.fit.draws("A_rel")[..., :2]
    for c, channel in enumerate(found.fit.model.layout.channels):
        truth = real.true_coefficients(channel, relative=True)
        for k in range(2):
            lo, hi = np.quantile(rel[:, c, k], [0.025, 0.975])
            assert lo <= truth[k] <= hi, (channel, k)


def test_the_flexible_rival_is_wider_lamp_errors_or_the_monotone_roll_off_and_nothing_else():
    """more_flexible: the rule that reports a rival in place of the adopted model.  It holds for the same
    model with wider per-channel lamp errors and for the monotone roll-off against the knee; it fails for
    narrower lamp errors, for no lamp errors at all, for wider lamp errors that come with another change,
    and for the knee against the monotone shape."""
    from bayescal.fitting.diagnosis.search import more_flexible

    spec = bc.load_spec(SPEC)
    lamp = {size: spec.replace(sphere={"channel_level_rel": size}) for size in (0.0, 0.003, 0.01)}
    assert more_flexible(lamp[0.01], lamp[0.003])
    assert not more_flexible(lamp[0.003], lamp[0.01])
    assert not more_flexible(lamp[0.01], lamp[0.0])  # switching the errors on is a new term, not a wider one
    assert not more_flexible(lamp[0.01], lamp[0.01])
    assert not more_flexible(lamp[0.01].replace(response={"order": 3}), lamp[0.003])
    knee, monotone = spec.replace(response={"rolloff": True}), spec.replace(response={"rolloff": "monotone"})
    assert more_flexible(monotone, knee) and not more_flexible(knee, monotone)


def test_paired_gain_is_the_sum_and_its_standard_error():
    """paired_gain: the sum of the row-wise differences and sqrt(n) times their sd (exact on a two-valued
    difference: n = 100 rows alternating 1 and 3 over a zero baseline, sum 200, sd 1, se 10)."""
    current = np.zeros(100)
    candidate = np.tile([1.0, 3.0], 50)
    gain, se = paired_gain(current, candidate)
    assert gain == pytest.approx(200.0) and se == pytest.approx(10.0)


def test_the_screen_keeps_out_only_a_found_mode_that_gains_at_most_one_se():
    """screen: the paired in-sample gain (200 +- 10 above) is kept when it exceeds one se, kept out at or below
    it, and never kept out when either mode was not found."""
    current = ModeFit(np.zeros(100), True)
    rows = np.tile([1.0, 3.0], 50)  # gain 200, se 10
    assert screen(current, ModeFit(rows, True)) == (pytest.approx(200.0), pytest.approx(10.0), False)
    small = rows - 1.95  # gain 5, se 10: at most one se
    assert screen(current, ModeFit(small, True)).out
    assert (
        not screen(current, ModeFit(small, False)).out
        and not screen(ModeFit(np.zeros(100), False), ModeFit(small, True)).out
    )
