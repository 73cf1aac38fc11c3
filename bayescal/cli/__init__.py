"""The ``bayescal`` command: every verb parses its arguments, calls the library, prints and exits.

Exit codes: 0 success, 2 bad input (the message names the file, row, column or key), 3 a fit
that failed its diagnostics or does not fit its data, 130 interrupted.
"""

from bayescal.cli.app import main

__all__ = ["main"]
