"""The ``characterize`` verb: EMVA 1288 characterisation."""

from __future__ import annotations

import sys
from pathlib import Path


def cmd_characterize(args) -> int:
    import dataclasses

    from bayescal.characterization.datasheet import write_curves, write_datasheet, write_datasheet_pdf
    from bayescal.characterization.emva1288 import characterize
    from bayescal.cli.progress import stage_reporter
    from bayescal.io.emva import load_steps
    from bayescal.io.outputs import check_output_dir, staged_directory, write_json_atomic

    out = check_output_dir(args.out, "characterization")
    stage = stage_reporter()
    stage(f"reading {args.input} (image pairs and stacks are reduced streaming)")
    from bayescal.io.resources import example_path

    path = example_path(args.input, "data")
    steps = load_steps(path)
    stage("standard method and posteriors")
    res = characterize(steps, seed=args.seed)
    if path != Path(args.input):  # a shipped example by name: named so, not by where the package is installed
        res = dataclasses.replace(res, source=f"the shipped example {args.input}")
    with staged_directory(out, kind="characterization") as staged:
        res.table.to_csv(staged("characterization.csv"), index=False, float_format="%.8g")
        write_json_atomic(staged("characterization.json"), res.to_dict())
        res.curves.to_csv(staged("curves.csv"), index=False, float_format="%.8g")
        write_curves(res, staged("photon_transfer.png"))
        write_datasheet(res, staged("datasheet.html"))
        write_datasheet_pdf(res, staged("datasheet.pdf"))
    op = res.operating
    print(
        f"EMVA 1288 characterisation of {args.input}: {op['bits']}-bit, {op['bright_steps']} bright steps, exposures "
        f"{op['exposure_s'][0]:.4g}-{op['exposure_s'][1]:.4g} s, up to {op['photons_per_pixel'][1]:.4g} photons per "
        f"pixel (standard point estimate | posterior median [95 %]):"
    )
    print(res.table.to_string(index=False, float_format="%.5g"))
    undetermined = (
        "not determinable (no system gain K)" if res.module == "General" else "not determined (one dark exposure time)"
    )
    verdict = {True: "compatible", False: "NOT compatible", None: undetermined}[res.dark_current_compatible]
    print(f"dark current from the mean and from the variance: {verdict} (95 % interval of their difference)")
    for note in res.notes:
        print(f"NOTE: {note}")
    change = res.ptc.get("change", float("nan"))
    if res.module == "General":
        print(
            f"EMVA 1288 RELEASE 4 LINEAR DOES NOT APPLY: the photon transfer curve's slope changes by {change:+.0%} "
            "over its fit range; K, QE and what needs them are not determinable (General module)"
        )
    else:
        print(f"EMVA 1288 Release 4 Linear applies (photon transfer slope change over the fit range {change:+.1%})")
    print(f"wrote {out}/: " + ", ".join(sorted(p.name for p in out.iterdir() if not p.name.startswith("."))))
    if res.problems:
        print("CHARACTERISATION IMPLAUSIBLE:\n  " + "\n  ".join(res.problems), file=sys.stderr)
        return 3
    return 0
