"""Every file bayescal writes, from the bottom up, with no import circle:

- :mod:`.disk`: a file's digest, permissions, a write the disk refused, NetCDF by a plain write;
- :mod:`.seal`: the keyed digest that makes a record's entries unforgeable by a text edit;
- :mod:`.interrupts`: Ctrl-C held back while files are put in place; what a run has put in place;
- :mod:`.claims`: what the running command says: ``--force``, its inputs, its product;
- :mod:`.folders`: output folders (the run's marker, staging, additions, verification on read);
- :mod:`.ledger`: single files in a folder of the user's, and the checks every single file passes;
- :mod:`.atomic`: the atomic write of a single file, entered in the right record.
"""

from bayescal.io.outputs.atomic import atomic_path, write_json_atomic, write_text_atomic
from bayescal.io.outputs.claims import overwrite_allowed, reading, writing_as
from bayescal.io.outputs.disk import sha256, write_errors, write_netcdf
from bayescal.io.outputs.folders import (
    FORMAT,
    HASHED_BYTES,
    MARKER,
    RunInfo,
    Stage,
    check_output_dir,
    read_marker,
    record_file,
    scratch_directory,
    staged_directory,
    verify_output,
)
from bayescal.io.outputs.interrupts import committed, discard_staging, interrupts_held
from bayescal.io.outputs.ledger import LEDGER, check_output_file, commit_file, refusal
from bayescal.io.outputs.seal import key_file

__all__ = [
    "FORMAT",
    "HASHED_BYTES",
    "LEDGER",
    "MARKER",
    "RunInfo",
    "Stage",
    "atomic_path",
    "check_output_dir",
    "check_output_file",
    "commit_file",
    "committed",
    "discard_staging",
    "interrupts_held",
    "key_file",
    "overwrite_allowed",
    "read_marker",
    "reading",
    "record_file",
    "refusal",
    "scratch_directory",
    "sha256",
    "staged_directory",
    "verify_output",
    "write_errors",
    "write_json_atomic",
    "write_netcdf",
    "write_text_atomic",
    "writing_as",
]
