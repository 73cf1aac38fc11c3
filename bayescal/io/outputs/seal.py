"""Records that a plain text edit cannot forge: each entry of a record carries a keyed digest.

bayescal replaces a file or a folder only when its record says bayescal wrote it (:mod:`.ledger`,
:mod:`.folders`).  A record is a JSON file beside the outputs, so anyone can write one by hand; the
digest makes a hand-written entry worthless.  Each entry is sealed with HMAC-SHA256 (RFC 2104) under a
key that lives outside every output folder, in the user's state folder (``$BAYESCAL_KEY_FILE``, else
``$XDG_STATE_HOME/bayescal/record.key``, else ``~/.local/state/bayescal/record.key``), readable by the
user alone and made on the first write.

What a seal protects against: a record written or edited by hand or by a script (a name listed, a
size and time, the file's true SHA-256), a record copied from another folder onto a different file,
an entry added to a real record.  What it does not: a person or program that reads the key file (the
same account can), and a record made on another machine or account, which is never taken as
bayescal's (its outputs are read as before; they are not replaced without ``--force`` or by hand).
Reading an output never needs the key: a seal decides only whether bayescal may *replace* something.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import secrets
import tempfile
from pathlib import Path

__all__ = ["key_file", "seal", "sealed"]

_KEY_BYTES = 32
_cached: dict[Path, bytes | None] = {}


def key_file() -> Path:
    """Where this account's key is (``$BAYESCAL_KEY_FILE``, then the XDG state folder)."""
    env = os.environ.get("BAYESCAL_KEY_FILE")
    if env:
        return Path(env)
    state = os.environ.get("XDG_STATE_HOME")
    base = Path(state) if state else Path.home() / ".local" / "state"
    return base / "bayescal" / "record.key"


def _key(create: bool) -> bytes | None:
    """The key's bytes; with ``create`` a new key is made when there is none (``None``: none can be)."""
    path = key_file()
    if _cached.get(path) is not None:
        return _cached[path]
    try:
        key = path.read_bytes()
    except OSError:
        key = b""
    if len(key) != _KEY_BYTES and create:
        key = _make(path)
    found = key if len(key) == _KEY_BYTES else None
    _cached[path] = found
    return found


def _make(path: Path) -> bytes:
    """A new key written beside its place and linked in (two processes making one at once agree on the
    first); the folder and the file are the user's alone."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        fd, tmp = tempfile.mkstemp(prefix=".record.key.", dir=path.parent)  # 0600
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(secrets.token_bytes(_KEY_BYTES))
            try:
                os.link(tmp, path)
            except FileExistsError:
                pass
        finally:
            os.unlink(tmp)
        return path.read_bytes()
    except OSError:
        return b""


def _message(context: str, name: str, entry: dict) -> bytes:
    body = {k: v for k, v in entry.items() if k != "mac"}
    return json.dumps([context, name, body], sort_keys=True, separators=(",", ":")).encode()


def seal(context: str, name: str, entry: dict) -> dict:
    """``entry`` with its keyed digest (``"mac"``) over ``context`` (the run or record it belongs to),
    ``name`` and every other field; without a key (an unwritable home) the entry goes unsealed and will
    never authorise a replacement."""
    key = _key(create=True)
    body = {k: v for k, v in entry.items() if k != "mac"}
    if key is None:
        return body
    return body | {"mac": hmac.new(key, _message(context, name, body), hashlib.sha256).hexdigest()}


def sealed(context: str, name: str, entry: dict) -> bool:
    """``entry`` was sealed by this account's key for ``context`` and ``name``, and is unchanged since."""
    mac = entry.get("mac")
    key = _key(create=False)
    if not isinstance(mac, str) or key is None:
        return False
    return hmac.compare_digest(mac, hmac.new(key, _message(context, name, entry), hashlib.sha256).hexdigest())
