"""Inversion coverage and exposure planning on simulated cameras with known truth (3 % sphere systematic).

Each calibration is a fresh simulated dataset (its own sphere-scale error) fitted
with the Laplace backend; new readings come from the true camera.  Coverage is
pooled over many calibrations so the sphere's common error is sampled, not fixed.
"""

import numpy as np
import pytest

import bayescal as bc

#: calibrations in the default run; the slow suite's test uses 160 (README numbers)
N_CAL = 24
N_CAL_SLOW = 160
VALUES_PER_CAL = 12
EXPOSURES = [0.001, 0.002, 0.004, 0.008, 0.016]


@pytest.fixture(scope="module")
def trials(seed000):
    return run_trials(seed000, N_CAL)


def run_trials(seed000, n_cal):
    """Fresh calibrations (each its own sphere error), readings from the true camera, plans checked."""
    spec, design = seed000
    spec = spec.replace(inference={"holdout_check": False})  # coverage is the point here, not the misfit checks
    rng = np.random.default_rng(2026)
    out = {"hit": [], "lsq_hit": [], "p": [], "realised": [], "width": [], "lsq_width": []}
    setting = bc.Setting(0.004, 1.0)
    sims = [bc.simulate(spec, design, seed=5000 + k) for k in range(n_cal)]
    batch = bc.fit_many([sim.table for sim in sims], spec, "laplace", seeds=range(n_cal))  # one vmapped program
    for k, sim in enumerate(sims):
        fit = batch.fit(k)
        cal = bc.Calibration.from_fit(fit)
        # readings spanning the dynamic range of G (about 60 .. 3900 DN), one pixel each
        true_l = rng.uniform(0.5, 125.0, VALUES_PER_CAL)
        dn = sim.reading(spec, "G", true_l, 0.004, 1.0, rng=rng)
        res = bc.invert(cal, dn, "G", setting, seed=k)
        two = res.bound == 0
        hit = np.where(two, (res.lower <= true_l) & (true_l <= res.upper), False)
        hit = np.where(res.bound == 2, true_l <= res.upper, hit)
        out["hit"].extend(hit[dn < cal.saturation_dn])
        out["width"].extend(((res.upper - res.lower) / true_l)[two])
        # least-squares plug-in: point coefficients at the reference setting, noise from the fit's RMSE
        lsq = fit.lsq
        row = lsq[(lsq.channel == "G") & np.isclose(lsq.exposure_s, 0.004) & (lsq.order == 1)].iloc[0]
        a0, a1 = row["A0"], row["A1"]
        point = (dn - a0) / a1
        sig = np.maximum(dn - a0, 0)
        pixel_var = cal.read_noise_dn**2 + cal.conversion_gain * sig + 1 / 12 + (cal.prnu * sig) ** 2
        half = 1.96 * np.sqrt(row["rmse"] ** 2 + pixel_var) / a1
        lsq_hit = (point - half <= true_l) & (true_l <= point + half)
        out["lsq_hit"].extend(lsq_hit[dn < cal.saturation_dn])
        out["lsq_width"].extend((2 * half / true_l)[two])
        # planning: a region mean of 64 pixels read at 1/250 s, choose among coarse exposure steps
        scene = rng.uniform(3.0, 60.0)
        now = sim.reading(spec, "G", np.array([scene]), 0.004, 1.0, n_avg=64, rng=rng)[0]
        plan = bc.plan_exposure(cal, "G", dn=now, current=setting, exposures=EXPOSURES, n_avg=64, seed=k)
        b = plan.best
        nxt = sim.reading(spec, "G", np.array([scene]), b.exposure_s, b.gain, n_avg=64, rng=rng)[0]
        out["p"].append(plan.probability)
        out["realised"].append(1080 <= nxt <= 1920)
    return {k: np.asarray(v) for k, v in out.items()}


def test_inversion_coverage_is_nominal(trials):
    cover = trials["hit"].mean()
    lsq_cover = trials["lsq_hit"].mean()
    print(
        f"\n95 % interval coverage of the true radiance over {trials['hit'].size} readings: "
        f"bayescal {cover:.3f} (median relative width {np.median(trials['width']):.3f}); "
        f"least-squares plug-in {lsq_cover:.3f} (median relative width {np.median(trials['lsq_width']):.3f})"
    )
    # 288 readings in 24 clusters (one sphere draw each): sd of the rate ~0.025 at 0.95 -> 3 sd band
    assert trials["hit"].size >= 250
    assert 0.87 <= cover <= 0.995
    assert lsq_cover < cover


@pytest.mark.slow
def test_inversion_coverage_over_160_calibrations(seed000):
    full = run_trials(seed000, N_CAL_SLOW)
    cover = full["hit"].mean()
    print(f"\n160 calibrations: coverage {cover:.3f} over {full['hit'].size} readings")
    assert 0.92 <= cover <= 0.98  # ~1900 readings in 160 clusters: sd ~0.008
    assert full["lsq_hit"].mean() < cover


def test_planning_probability_matches_realised_frequency(trials):
    p, realised = trials["p"], trials["realised"]
    expected, observed = p.mean(), realised.mean()
    mc_sd = np.sqrt(np.sum(p * (1 - p))) / p.size  # independent calibrations and scenes
    print(f"\nplanning: mean reported P(in window) {expected:.3f}, realised {observed:.3f} (MC sd {mc_sd:.3f})")
    assert 0.2 < expected < 0.98  # the coarse grid leaves real uncertainty to get right
    assert abs(observed - expected) <= 3 * mc_sd + 1e-9
