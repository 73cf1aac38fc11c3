"""``python -m bayescal``: the command-line tool, as the ``bayescal`` command."""

from bayescal.cli.app import main

raise SystemExit(main())
