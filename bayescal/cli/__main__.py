"""``python -m bayescal.cli``: the ``bayescal`` command."""

from bayescal.cli.app import main

raise SystemExit(main())
