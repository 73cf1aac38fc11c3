"""The verb that plans a campaign: design."""

from __future__ import annotations

from pathlib import Path


def cmd_design(args) -> int:
    from bayescal.campaign.design import design
    from bayescal.cli.progress import stage_reporter
    from bayescal.io.outputs import check_output_dir

    if args.out is not None:
        check_output_dir(args.out, "design")
    goals = dict(args.goal or [])
    plan = design(
        args.protocol,
        args.model,
        goals=goals,
        goal_scale=1.0 if args.goal_scale is None else args.goal_scale,
        budget_rows=args.budget_rows,
        setting_cost=args.setting_cost,
        draws=args.draws,
        keep_checks=args.keep_checks,
        after=args.after,
        block_rows=args.block_rows,
        seed=args.seed,
        progress=stage_reporter(args.quiet),
    )
    print(plan.summary())
    from bayescal.cli.results import emit

    emit(summary=plan.summary(), met=bool(plan.met), over_budget=bool(plan.over_budget))
    if args.out is not None:
        out = plan.save(Path(args.out))
        print(f"wrote {out / 'design.toml'} (read by `bayescal simulate --design`), groups.csv and widths.csv")
    # goals asked for and not reached: loud (exit 3); a budget alone asks for the narrowest design it buys
    asked = args.budget_rows is None or bool(args.goal) or args.goal_scale is not None
    if plan.over_budget:
        return 3
    return 3 if asked and not (plan.met or plan.done or args.after is not None) else 0
