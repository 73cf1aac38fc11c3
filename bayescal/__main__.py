"""``python -m bayescal``: the ``bayescal`` command."""

from bayescal.cli import main

raise SystemExit(main())
