"""The ``examples`` verb: list the shipped specs, designs and data, and copy them out to edit."""

from __future__ import annotations

import shutil
from pathlib import Path


def cmd_examples(args) -> int:
    from bayescal.cli.results import emit
    from bayescal.errors import SpecError
    from bayescal.io.resources import DESCRIPTOR, example_path, examples

    shipped = examples()
    if not args.copy:
        width = max(len(e.name) for e in shipped)
        print("Shipped examples (use a name wherever a spec or design file goes, e.g. --model seed000):")
        for e in shipped:
            print(f"  {e.name:<{width}}  {e.kind:<12}  {e.about}")
        print("Copy one to edit it: bayescal examples --copy NAME [--to DIR]")
        emit(examples=[{"name": e.name, "kind": e.kind, "about": e.about} for e in shipped])
        return 0
    picked = [e for e in shipped if e.name == args.copy]
    if not picked:  # a name's every file: seed003 is the film's spec and its example data
        picked = [e for e in shipped if e.name.split("_")[0] == args.copy]
    if not picked:
        for kind in ("spec", "design"):
            path = example_path(args.copy, kind)
            picked += [e for e in shipped if e.path == path]
    if not picked:
        raise SpecError(f"no shipped example '{args.copy}'; `bayescal examples` lists them")
    # a design names its spec: copy both, so the copy runs as it is
    for e in list(picked):
        if e.kind == "design":
            spec = _design_spec(e.path)
            picked += [s for s in shipped if s.path.name == spec and s not in picked]
    target = Path(args.to)
    clash = [target / _copied(e).name for e in picked if (target / _copied(e).name).exists()]
    if clash:
        raise SpecError(f"{clash[0]} exists; bayescal does not overwrite your files (give another --to)")
    target.mkdir(parents=True, exist_ok=True)
    for e in picked:
        if e.path.name == DESCRIPTOR:  # an image set: its folder, descriptor and images together
            shutil.copytree(e.path.parent, target / e.path.parent.name)
        else:
            shutil.copyfile(e.path, target / e.path.name)
        print(f"copied {e.kind} {e.name} to {target / _copied(e).name}")
    emit(copied=[str(target / _copied(e).name) for e in picked])
    return 0


def _copied(e) -> Path:
    """What copying an example writes: its file, or an image set's folder."""
    from bayescal.io.resources import DESCRIPTOR

    return Path(e.path.parent.name) if e.path.name == DESCRIPTOR else Path(e.path.name)


def _design_spec(path: Path) -> str | None:
    from bayescal.io.toml import read_toml

    return read_toml(path, "design (TOML)").get("spec")
