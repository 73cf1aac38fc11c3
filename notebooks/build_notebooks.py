"""Write the example notebooks and execute them in place (outputs committed).

Run from the repository root: ``python notebooks/build_notebooks.py``.  The tests
execute the same notebooks with ``BAYESCAL_NB_BACKEND=laplace`` (fast).
"""

from pathlib import Path

import nbformat
from nbclient import NotebookClient

HERE = Path(__file__).resolve().parent

QUICKSTART = [
    (
        "md",
        """# Quickstart: the seed 000 Bayer CCD

A 12-bit aerial camera with R, G, B channels, calibrated against an integrating sphere at
12 radiance levels, three exposure times and four gain steps (seed 000). We simulate the
bench with known truth, fit the Bayesian model, compare it with the least-squares
polynomials the paper used, and use the posterior: derived settings, radiance inversion
and exposure planning.""",
    ),
    (
        "code",
        """import os
import warnings
warnings.filterwarnings("ignore", message="IProgress not found")  # tqdm in a notebook without widgets
import numpy as np
import bayescal as bc
from pathlib import Path

BACKEND = os.environ.get("BAYESCAL_NB_BACKEND", "nuts")  # the tests use "laplace" for speed
spec = bc.load_spec("seed000")  # the shipped examples, by name (`bayescal examples` lists them)
design = bc.load_design("seed000")
sim = bc.simulate(spec, design, seed=1)
sim.table.frame.head()""",
    ),
    ("md", "The truth has a 3 % sphere-scale error drawn for this dataset; the model does not know it:"),
    (
        "code",
        """print(f"sphere scale error of this bench: {sim.sphere_scale - 1:+.2%}")
fit = bc.fit(sim.table, spec, BACKEND, seed=1)
print(fit.diagnostics.verdict, "| timings (s):", {k: round(v, 3) for k, v in fit.timings.items()})""",
    ),
    (
        "md",
        """## Coefficients beside least squares

`bayes_abs` includes the sphere's common 3 % uncertainty (what an absolute calibration can
claim); `bayes_rel` is against the sphere's own scale, comparable with least squares.""",
    ),
    ("code", """fit.comparison.round(4)"""),
    (
        "code",
        """truth = {c: v[0] for c, v in sim.truth.response.items()}
s = fit.summary
for c in fit.model.layout.channels:
    row = s.loc[f"A_abs[{c}, 1]"]
    print(f"{c}: true A1 {truth[c]:7.3f}   posterior {row['mean']:7.3f}  95 % [{row['q2.5']:.3f}, {row['q97.5']:.3f}]")""",
    ),
    ("md", "## Derived settings: what will the camera read at 1/100 s (seed 000 Table 2)?"),
    (
        "code",
        """cal = bc.Calibration.from_fit(fit)
bc.predict(cal, [5.0, 15.9973, 25.0], bc.Setting(0.01, 1.0)).round(2)""",
    ),
    ("md", "## The response of G at 1/100 s (its predictive band) beside the readings at 1/250 s"),
    (
        "code",
        """import matplotlib.pyplot as plt
grid = np.linspace(0.5, 30, 40)
p = bc.predict(cal, list(grid), bc.Setting(0.01, 1.0), "G")
frame = sim.table.frame
seen = frame[(frame.channel == "G") & (frame.exposure_s == 0.004) & (frame.gain == 1.0) & (frame.stimulus > 0)]
fig, ax = plt.subplots(figsize=(6, 4))
ax.fill_between(p.stimulus, p.pi_lo, p.pi_hi, alpha=0.25, label="1/100 s: 95 % predictive band")
ax.plot(p.stimulus, p.dn_median, label="1/100 s: posterior median")
ax.plot(seen.stimulus, seen.dn_mean, "o", ms=3, color="k", label="1/250 s: the readings fitted")
ax.set(xlabel="radiance (W m^-2 sr^-1)", ylabel="DN")
ax.legend();""",
    ),
    ("md", "## Radiance inversion with credible intervals (one pixel, 1/250 s, gain 1)"),
    ("code", """bc.invert(cal, np.array([60, 534, 2000, 4095]), "G", bc.Setting(0.004, 1.0)).to_frame()"""),
    (
        "md",
        """## Exposure planning

A frame read 534 DN in G at 1/250 s. Which exposure puts the next one in 1080-1920 DN?""",
    ),
    (
        "code",
        """plan = bc.plan_exposure(cal, "G", dn=534, current=bc.Setting(0.004), exposures=[0.004, 0.006, 0.008, 0.01],
                        gains=[1.0, 2.0], n_avg=1024)
plan.table.head()""",
    ),
    ("md", "## Report\n\nThe same fit as a self-contained HTML report (figures embedded):"),
    (
        "code",
        """import tempfile
with tempfile.TemporaryDirectory() as tmp:
    fit.save(Path(tmp) / "fit")
    page = bc.write_report(Path(tmp) / "fit")
    print(f"{page.name}: {page.stat().st_size / 1e6:.1f} MB, {page.read_text().count('<img')} figures embedded")""",
    ),
]

TDI = [
    (
        "md",
        """# Seed 002: a 10-bit TDI camera, derived settings and exposure planning

TDI stages M = 8-96, line time T_int and video gain g all scale the signal
(eq. 11-12), so one fit in the effective stimulus x = E T M g covers every setting. The
paper then planned exposures: 405 DN at the default setting -> E = 0.1167 W m^-2, and
M = 96, g = 1.26 to reach 900 DN (measured 959.4).""",
    ),
    (
        "code",
        """import os
import warnings
warnings.filterwarnings("ignore", message="IProgress not found")  # tqdm in a notebook without widgets
import numpy as np
import bayescal as bc
from pathlib import Path

BACKEND = os.environ.get("BAYESCAL_NB_BACKEND", "nuts")  # the tests use "laplace" for speed
MODELS = Path.cwd().parent / "models"  # notebooks run from notebooks/
spec = bc.load_spec(MODELS / "seed002_tdi.toml")
design = bc.load_design(MODELS / "seed002_design.toml")
sim = bc.simulate(spec, design, seed=2)
fit = bc.fit(sim.table, spec, BACKEND, seed=2)
print(fit.diagnostics.verdict)
fit.comparison.round(4)""",
    ),
    ("md", "## The paper's own numbers through the same code (published coefficients, fixed)"),
    (
        "code",
        """ref = bc.Reference(105e-6, 1.0, 48)
quad = bc.Calibration.from_coefficients({"pan": [2.154, 3755.0, -2582.0]}, reference=ref, bits=10,
                                        stimulus="irradiance")
eq12 = bc.Calibration.from_coefficients({"pan": [28.72, 0.583 * 48 * 105]}, reference=ref, bits=10,
                                        stimulus="irradiance", dark_proportional=True)
e = float(bc.invert(quad, 405.0, "pan", noise=False).median)
print(f"405 DN -> E = {e:.5f} W m^-2 (paper: 0.1167)")
print(f"eq. 12 at M = 96, g = 1.26: {eq12.expected_dn('pan', e, bc.Setting(105e-6, 1.26, 96)).item():.1f} DN "
      "(paper's target 900, measured 959.4)")""",
    ),
    ("md", "## Derived settings across TDI stages, with credible and predictive intervals"),
    (
        "code",
        """cal = bc.Calibration.from_fit(fit)
rows = [bc.predict(cal, 0.1167, bc.Setting(105e-6, 1.26, m), n_avg=4096) for m in (48, 72, 96)]
import pandas as pd
pd.concat(rows)[["tdi_stages", "dn_median", "ci_lo", "ci_hi", "pi_lo", "pi_hi", "extrapolated"]].round(1)""",
    ),
    (
        "code",
        """import matplotlib.pyplot as plt
import numpy as np
levels = list(np.linspace(0.01, 0.2, 30))
fig, ax = plt.subplots(figsize=(6, 4))
for m in (48, 72, 96):
    p = bc.predict(cal, levels, bc.Setting(105e-6, 1.26, m), n_avg=4096)
    ax.fill_between(p.stimulus, p.pi_lo, p.pi_hi, alpha=0.25)
    ax.plot(p.stimulus, p.dn_median, label=f"M = {m}: median and 95 % predictive band")
ax.set(xlabel="irradiance", ylabel="DN (10 bits)", title="derived settings: g = 1.26 at three TDI stage counts")
ax.legend();""",
    ),
    (
        "md",
        """## Planning over the camera's grid

The scene read 405 DN (region mean) at the default setting; aim at 850-950 DN.""",
    ),
    (
        "code",
        """plan = bc.plan_exposure(cal, "PAN", dn=405.0, current=bc.Setting(105e-6, 1.0, 48), exposures=[105e-6],
                        gains=[1.0, 1.26, 1.7, 2.0], tdi_stages=[8, 16, 32, 48, 72, 96], window=(850, 950),
                        n_avg=4096)
plan.table.head(6)""",
    ),
    (
        "md",
        """The chosen setting and its probability account for the calibration's uncertainty,
including the sphere's 3 %: a point plan from eq. 12 alone cannot say how likely it is to land
in the window (the paper's 959.4 DN overshot its 900 target by 6.6 %).""",
    ),
]


CCD = [
    (
        "md",
        """# A real CCD: EMVA 1288 characterisation with credible intervals

EMVA 1288 reference data set 001 (Basler AG, CC BY-SA 3.0): a 12-bit monochrome CCD,
640 x 480, exposure swept at fixed irradiance in 50 steps of bright and dark image pairs,
plus 50-frame stacks. The reference implementation gives point values only, and its two
dark-current estimates disagree by 2.5x. Here the standard's formulas (our own
implementation) sit beside posteriors of the same quantities.""",
    ),
    (
        "code",
        """import warnings
warnings.filterwarnings("ignore", message="IProgress not found")
from pathlib import Path
import json
import bayescal as bc

DATA = Path.cwd().parent / "tests" / "data" / "emva1288" / "refset001_ccd_12bit"
steps = bc.load_steps(DATA / "steps.csv")          # reduction of the full 640 x 480 images
res = bc.characterize(steps, seed=0)
res.table""",
    ),
    ("md", "## Against the reference implementation's numbers (same images)"),
    (
        "code",
        """ref = json.loads((DATA / "emva1288_reference_results.json").read_text())["emva1288_results"]
for ours, theirs in [("K", "K"), ("QE", "QE"), ("sigma_y_dark", "sigma_y_dark"),
                     ("dark_current_mean", "u_I_mean"), ("dark_current_var", "u_I_var")]:
    print(f"{ours:18s} ours {res.standard[ours]:10.5g}   reference {ref[theirs]:10.5g}")""",
    ),
    (
        "md",
        """## Are the two dark-current estimates compatible?

From the mean (slope of the dark level in exposure) and from the variance (slope of the
dark noise): the posterior of their difference says whether the 2.5x disagreement is
real or within what the data can resolve.""",
    ),
    (
        "code",
        """t = res.table.set_index("quantity")
print(t.loc[["dark_current_mean", "dark_current_var", "dark_current_difference"], ["median", "q2.5", "q97.5"]])
print("compatible:", res.dark_current_compatible)""",
    ),
    ("md", "## The same from the 128 x 128 crop, reduced from the raw image pairs"),
    (
        "code",
        """crop = bc.characterize(bc.load_steps(DATA / "crop128.npz"), seed=0)
crop.table.set_index("quantity").loc[["K", "QE", "sigma_y_dark"], ["standard", "median", "q2.5", "q97.5"]]""",
    ),
    (
        "code",
        """import tempfile
from IPython.display import Image
png = bc.write_curves(res, Path(tempfile.mkdtemp()) / "photon_transfer.png")  # the datasheet's bands
Image(str(png))""",
    ),
    ("md", "## The datasheet's SNR: measured steps against the posterior's band"),
    (
        "code",
        """import matplotlib.pyplot as plt
import numpy as np
c = res.curves
lit = (c["photons"] > 0) & (c["photons"] <= res.standard["u_p_sat"])
photons = c["photons"][lit].to_numpy()
fig, ax = plt.subplots(figsize=(6, 4))
ax.loglog(photons, c["signal"][lit] / np.sqrt(c["s2_y"][lit]), "o", ms=3, color="k", label="steps")
grid = np.geomspace(photons.min(), photons.max(), 60)
qe, k, sd = (res.draws[q][:1000, None] for q in ("QE", "K", "sigma_d"))
snr = qe / 100 * grid / np.sqrt(sd**2 + 1 / 12 / k**2 + qe / 100 * grid)
lo, hi = np.quantile(snr, [0.025, 0.975], axis=0)
ax.fill_between(grid, lo, hi, alpha=0.3, label="posterior 95 % band")
ax.set(xlabel="photons per pixel", ylabel="SNR")
ax.legend();""",
    ),
]

PIXEL_MAPS = [
    (
        "md",
        """# Per-pixel maps of a real CCD: EMVA 1288 reference set 001

The central 128 x 128 pixels of every image of EMVA 1288 reference data set 001 (a 12-bit
monochrome CCD, (c) 2011 Basler AG, CC BY-SA 3.0): 50 bright/dark pairs over an exposure sweep
and a 50-frame bright and dark stack. `bayescal maps` fits every pixel's offset, dark current and
relative gain (1 + PRNU deviation) with a hierarchical population (normal pixels and a wide defect
component), in closed form, and gives each an interval.""",
    ),
    (
        "code",
        """import json
import tempfile
from pathlib import Path
import numpy as np
import bayescal as bc

DATA = Path.cwd().parent / "tests" / "data" / "emva1288" / "refset001_ccd_12bit"
stacks = bc.write_emva_stacks(DATA / "crop128.npz", Path(tempfile.mkdtemp()) / "stacks")
print(open(stacks / "conditions.csv").read()[:400])""",
    ),
    (
        "md",
        "Pairs brighter than 70 % of full scale are left out (the standard measures non-uniformity below saturation).",
    ),
    (
        "code",
        """maps = bc.build_maps(stacks).compute()
a = maps.attrs
for name in a["parameters"]:
    print(f"spread of {name:18s} {a[f'spread_{name}']:.5g} +- {a[f'spread_{name}_se']:.2g}")
print("defect fraction", f"{a['population_weights'][1]:.2e}", "| noisy fraction", f"{a['noisy_fraction']:.2e}")""",
    ),
    (
        "md",
        """## PRNU beside the standard

EMVA 1288 computes PRNU from the 50-frame stacks' mean images, with the temporal noise removed
(release 4.0, eq. 44-45). On the same 128 x 128 pixels, and beside the reference implementation's
full-frame pixel PRNU (its full-frame PRNU1288 also holds row and column patterns that a central
crop does not see):""",
    ),
    (
        "code",
        """z = np.load(DATA / "crop128.npz")
ref = json.loads((DATA / "emva1288_reference_results.json").read_text())["emva1288_results"]
b, d = z["bright_stack"].astype(float), z["dark_stack"].astype(float)
n = b.shape[0]
s2y = b.mean(0).var() - b.var(0, ddof=1).mean() / n
s2d = d.mean(0).var() - d.var(0, ddof=1).mean() / n
prnu, (lo, hi) = a["spread_relative_gain"], a["spread_relative_gain_95"]
print(f"PRNU bayescal      {100 * prnu:.4f} %  95 % [{100 * lo:.4f}, {100 * hi:.4f}]")
print(f"PRNU standard, crop {100 * np.sqrt(s2y - s2d) / (b.mean() - d.mean()):.4f} %")
print(f"PRNU1288_pixel, full frame (reference implementation) {ref['PRNU1288_pixel']:.4f} %;"
      f" PRNU1288 {ref['PRNU1288']:.4f} %")""",
    ),
    (
        "md",
        """## DSNU beside the standard

The dark signal non-uniformity at the stacks' exposure: bayescal's population spread of
`offset + dark current x t`, and the standard's formula on the crop's dark stack. The standard's
DSNU1288 is in electrons (divided by K = 0.2801 DN/e-).""",
    ),
    (
        "code",
        """t = float(z["dark_stack_texp"]) * 1e-9
i = int(np.argmin(np.abs(np.array(a["dsnu_exposure_s"]) - t)))
dsnu, (lo, hi) = a["dsnu_dn"][i], a["dsnu_dn_95"][i]
K = ref["K"]
print(f"DSNU bayescal at {t * 1e3:.2f} ms: {dsnu:.3f} DN = {dsnu / K:.3f} e-  95 % [{lo / K:.3f}, {hi / K:.3f}] e-")
print(f"DSNU standard, crop: {np.sqrt(max(s2d, 0)) / K:.3f} e-;  DSNU1288 full frame {ref['DSNU1288']:.3f} e-"
      f" (pixel part s2_y_pixel_dark = {ref['s_2_y_pixel_dark']:.4f} DN^2)")""",
    ),
    (
        "md",
        """Both put this CCD's pixel-level dark non-uniformity at a fraction of an electron (the
full-frame DSNU1288 is row and column structure: its pixel part `s_2_y_pixel_dark` is zero within
its noise). They differ in what they use: the standard reads the 50-frame dark stack alone, while
the maps fit every pixel's offset and dark current over the whole exposure sweep (27 dark pairs
and the stack) and give the non-uniformity that a straight line in exposure implies at 5.16 ms.
Fitted to the stacks alone, the maps reproduce the standard's number:""",
    ),
    (
        "code",
        """import pandas as pd
only = Path(tempfile.mkdtemp()) / "stack_only"
only.mkdir()
table = pd.read_csv(stacks / "conditions.csv")
table = table[table.condition.str.endswith("_stack")]  # the stacks: conditions named t<ns>ns_stack
for f in table.file:
    (only / f).write_bytes((stacks / f).read_bytes())
table.to_csv(only / "conditions.csv", index=False)
b = bc.build_maps(only).attrs
print(f"DSNU from the stacks alone: {b['dsnu_dn'][0] / K:.3f} e-  95 % [{b['dsnu_dn_95'][0][0] / K:.3f}, "
      f"{b['dsnu_dn_95'][0][1] / K:.3f}] e-  (standard on the crop: {np.sqrt(max(s2d, 0)) / K:.3f} e-)")""",
    ),
    (
        "md",
        """The gap between the two bayescal numbers (0.2 e- against 0.03 e-) says this camera's dark
level is not quite a straight line in exposure pixel by pixel over 0.04-8 ms; the stack-only
figure is the one to quote at the stack's exposure.

## The maps and the report""",
    ),
    (
        "code",
        """out = Path(tempfile.mkdtemp()) / "maps"
bc.write_maps(bc.build_maps(stacks), out)
page = bc.maps_report(bc.read_maps(out), out)
print("defective pixels:", int((maps["defect"] > 0).sum()), "| report:", page.name)""",
    ),
    (
        "code",
        """import matplotlib.pyplot as plt
fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
for ax, name, title in zip(axes, ["relative_gain", "u_random_relative_gain"], ["relative gain", "its posterior sd"]):
    im = ax.imshow(maps[name], cmap="viridis")
    ax.set_title(title)
    fig.colorbar(im, ax=ax)""",
    ),
]

FLEET = [
    (
        "md",
        """# A fleet over three campaigns: pooling, a briefly measured unit, a recalibration decision

Twenty cameras of the seed 000 type, each calibrated on the integrating sphere in three
yearly campaigns, simulated by an independent simulator (`bayescal.validation.fleet`: a
uniform production band, ageing that settles, a sphere per campaign, gain steps off their
labels). Camera SN020 was only checked at three radiance levels; SN019 missed the last
campaign. We fit every unit alone, then the fleet hierarchy, and ask the fleet's questions.""",
    ),
    (
        "code",
        """import warnings
warnings.filterwarnings("ignore")  # each unit's own verdict is listed below, not as warnings
import numpy as np
import pandas as pd
import bayescal as bc
from pathlib import Path

MODELS = Path.cwd().parent / "models"  # notebooks run from notebooks/
spec = bc.load_spec(MODELS / "fleet_seed000.toml")
design = bc.FleetDesign(brief=("SN020",), absent=(("SN019", "2026-03-01"),))
table, truth = bc.simulate_fleet(design, seed=11)
fleet = bc.fleet_from_frame(table.astype(str), source="simulated fleet")
print(len(fleet.units), "units;", len(fleet.cameras), "cameras; campaigns", [d.date().isoformat() for d in fleet.campaigns])""",
    ),
    (
        "code",
        """result = bc.fit_fleet(fleet, spec, "laplace", seed=0)
d = result.draws.diagnostics
print(f"hierarchy: {d['divergences']} divergences, R-hat {d['max_rhat']:.3f}, ESS {min(d['min_ess_bulk'], d['min_ess_tail']):.0f}")
print("status:", "ok" if result.ok else result.problems)
print(len(result.warnings), "units whose own fit flags a row the channel model does not describe")
result.hyperparameters().round(5)""",
    ),
    (
        "md",
        """`interval inflation sqrt(kappa)` is the fleet's check of the units' own intervals, one
where the channels move together and one where they differ: the units' relative gains
scatter about the hierarchy several times more than their single-camera intervals allow
where the channels differ (this simulator compresses the signal before the gain amplifier,
which the channel model does not), and little more where they move together, so the fleet
widens each direction of a unit's gain interval by its own factor.

## Shrinkage, against the truth

Per unit and channel, the gain against that campaign's sphere reading (what a unit's data
measure) and the offset, alone and with the fleet:""",
    ),
    (
        "code",
        """s = result.summary().merge(truth, on=["camera", "campaign", "channel"], suffixes=("", "_true"))
rel = np.exp(result.unit_values(relative=True)[:, :, 0, :])
lo, hi = np.quantile(rel, [0.025, 0.975], axis=0)
t = truth.set_index(["camera", "campaign", "channel"])
keys = [(u.camera, u.campaign.date().isoformat()) for u in fleet.units]
true_rel = np.array([[t.loc[(c, dd, ch), "gain"] * t.loc[(c, dd, ch), "sphere_scale"] for ch in result.channels] for c, dd in keys])
off_cov = ((s.offset_lo <= s.offset_true) & (s.offset_true <= s.offset_hi)).mean()
print(f"gain vs sphere reading: 95 % coverage {((lo <= true_rel) & (true_rel <= hi)).mean():.3f}")
print(f"offset: 95 % coverage {off_cov:.3f}; RMSE alone {np.sqrt(np.mean((s.offset_alone - s.offset_true)**2)):.3f} DN, "
      f"with the fleet {np.sqrt(np.mean((s.offset - s.offset_true)**2)):.3f} DN")
brief = s[s.camera == "SN020"]
print("SN020 (3 levels) nonlinearity interval width, fleet / alone:",
      np.round((brief.eta1_hi - brief.eta1_lo).to_numpy() / (2 * 1.96 * brief.eta1_alone_sd.to_numpy()), 2))""",
    ),
    (
        "md",
        """## A camera never measured, and the future

The population predictive for a new unit of the type, and SN001 one and three years after
its last campaign: the interval grows with time. The fleet-wide drift is confounded with
the sphere's scale error of each campaign (recalibrated between campaigns, 3 % each), so the
absolute drift stays uncertain; a sphere calibration traceable across campaigns
(`sphere = "shared"`) would pin it.""",
    ),
    (
        "code",
        """def interval(v):
    lo, med, hi = np.quantile(v, [0.025, 0.5, 0.975])
    return f"{med:.3f} [{lo:.3f}, {hi:.3f}]"

g = result.kinds.index("log_gain")
print("new camera, G gain:", interval(np.exp(result.at(None, "2026-03-01")[:, g, 1])))
for date in ("2026-03-01", "2027-03-01", "2029-03-01"):
    print(f"SN001 at {date}, G gain:", interval(np.exp(result.at("SN001", date)[:, g, 1])))""",
    ),
    (
        "code",
        """import matplotlib.pyplot as plt
dates = pd.date_range("2024-03-01", "2029-03-01", freq="6MS")
bands = np.array([np.quantile(np.exp(result.at("SN001", d.date().isoformat())[:, g, 1]), [0.025, 0.5, 0.975]) for d in dates])
fig, ax = plt.subplots(figsize=(7, 3.5))
ax.fill_between(dates, bands[:, 0], bands[:, 2], alpha=0.3, label="SN001, G gain: 95 % band")
ax.plot(dates, bands[:, 1], label="posterior median")
for d in fleet.campaigns:
    ax.axvline(d, color="0.6", lw=0.8)
ax.set(ylabel="gain (DN per radiance unit)", title="the band grows after the last campaign (grey lines)")
ax.legend();""",
    ),
    (
        "md",
        """## A recalibration decision

How likely is it that SN001's gain has moved by more than 2 % since its last campaign, and
by when does that risk pass 5 %?""",
    ),
    (
        "code",
        """for date in ("2026-09-01", "2027-03-01", "2028-03-01"):
    print(f"P(|gain change| > 2 % by {date}) = {result.drift_probability('SN001', date, 2.0):.3f}")
when = result.recalibration_date("SN001", 2.0, probability=0.05)
print("recalibrate SN001 by", None if when is None else when.date())""",
    ),
    (
        "md",
        """## Pooling or not: PSIS-LOO over units

No pooling fits every camera alone; complete pooling makes the cameras one; partial pooling
is the hierarchy. Each unit's leave-one-out density integrates out every latent (its own
jitter and walk step included), so PSIS reweights only the scales and few units have
Pareto k > 0.7 (`n_high_k`).""",
    ),
    ("code", """bc.compare_pooling(fleet, spec, result.fits, seed=0).round(2)"""),
]


def build(name: str, cells) -> Path:
    nb = nbformat.v4.new_notebook()
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nb.cells = [
        nbformat.v4.new_markdown_cell(src) if kind == "md" else nbformat.v4.new_code_cell(src) for kind, src in cells
    ]
    path = HERE / name
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(HERE)}}).execute()
    nbformat.write(nb, path)
    return path


if __name__ == "__main__":
    books = (
        ("quickstart_seed000.ipynb", QUICKSTART),
        ("seed002_tdi_planning.ipynb", TDI),
        ("ccd_emva1288.ipynb", CCD),
        ("pixel_maps_emva1288.ipynb", PIXEL_MAPS),
        ("fleet_campaigns.ipynb", FLEET),
    )
    import sys

    wanted = set(sys.argv[1:])  # notebook names to build (default all)
    for name, cells in books:
        if not wanted or name in wanted:
            print("wrote", build(name, cells))
