"""The command line's entry point: parse, run the verb inside bayescal's numerics, map errors to exit codes.

Exit codes: 0 success, 2 bad input (the message names the row/column or
key), 3 a fit that failed its diagnostics (outputs are still written, marked
FAILED).
"""

from __future__ import annotations

import os
import signal
import sys
from typing import NoReturn

from bayescal.cli.parser import build, input_paths, output_files

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``bayescal`` command (exit codes in the module docstring)."""
    parser = build()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # a command line not understood: a script asking for JSON still gets a document
        if exc.code not in (0, None) and "--json" in (sys.argv[1:] if argv is None else argv):
            from bayescal.cli.results import dump

            error = "the command line was not understood (the usage message is on stderr)"
            dump({"verb": None, "exit": exc.code, "error": error}, [])
        raise
    if getattr(args, "json", False):
        from bayescal.cli.results import dump, json_document
        from bayescal.io.outputs import committed

        before = len(committed())  # the folders this command puts in place, not an earlier one's in this process
        with json_document(args.verb) as doc:
            code = _run(args)
        doc["exit"] = code
        doc.setdefault("error", None)
        dump(doc, list(dict.fromkeys(committed()[before:])))
        return code
    return _run(args)


def _run(args) -> int:
    """The verb inside bayescal's numerics, its errors mapped to exit codes (the message also goes into a
    ``--json`` document)."""
    from bayescal._config import numerics
    from bayescal.cli.results import emit
    from bayescal.errors import BayescalError
    from bayescal.io.outputs import check_output_file, overwrite_allowed, reading, writing_as

    previous = _catch_interrupts()
    try:
        with numerics(), overwrite_allowed(getattr(args, "force", False)), reading(input_paths(args)):
            with writing_as(args.verb):
                check_output_file(*output_files(args))  # before any work: a file of the user's is never replaced
                return args.func(args)
    except BayescalError as exc:
        message = _as_given(str(exc))
        print(f"bayescal: error: {message}", file=sys.stderr)
        emit(error=message)
        return 2
    except (OSError, UnicodeError) as exc:  # unreadable or unwritable paths, wrong encodings
        message = _as_given(_os_message(exc))
        print(f"bayescal: error: {message}", file=sys.stderr)
        emit(error=message)
        return 2
    except KeyboardInterrupt:
        _interrupted()
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def _interrupted(*_) -> NoReturn:
    """Ctrl-C: remove staged outputs and leave at once with status 130.

    Installed as the SIGINT handler rather than left to ``KeyboardInterrupt``,
    which JAX's garbage-collection callback can swallow (the run then went on
    to finish with status 0); chains still running in worker threads cannot be
    stopped from Python, so the process does not wait for them.
    """
    from bayescal.io.outputs import committed, discard_staging

    discard_staging()
    print(f"\nbayescal: {_interrupt_message(committed())}", file=sys.stderr)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(130)


def _interrupt_message(done) -> str:
    """What an interrupt left: the outputs put in place before it came, or none."""
    if not done:
        return "interrupted; no output was written or replaced (an earlier output there is as it was)"
    where = ", ".join(f"{p}/" for p in done)
    return (
        f"interrupted after the output was put in place, whole: {where} (it replaced any earlier output "
        "there); what the command does after writing (a report, the printed summary) may be missing"
    )


def _catch_interrupts():
    """Install :func:`_interrupted` for SIGINT (main thread only); returns the previous handler."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGINT, _interrupted)


def _as_given(message: str) -> str:
    """A message with paths as the user gave them: a shipped example by its name, a path under the current
    folder relative to it (a message names no folder of the installed package or of the machine)."""
    import re

    from bayescal.io.resources import models_dir

    shipped = re.escape(str(models_dir()) + os.sep)
    message = re.sub(shipped + r"([\w.-]+)", r"\1 (a shipped example)", message)
    here = os.getcwd()
    return message.replace(here + os.sep, "") if here != os.sep else message


def _os_message(exc: BaseException) -> str:
    if isinstance(exc, UnicodeDecodeError):
        return f"cannot decode the input as {exc.encoding} text ({exc.reason} at byte {exc.start}); save it as UTF-8"
    if isinstance(exc, OSError) and exc.filename is not None:
        what = {
            IsADirectoryError: "is a directory; expected a file",
            NotADirectoryError: "is not a directory",
            FileNotFoundError: "no such file or directory",
            PermissionError: "permission denied",
        }.get(type(exc), exc.strerror or str(exc))
        return f"{exc.filename}: {what}"
    return str(exc)
