"""A dask.distributed scheduler named by the user: its address checked at the boundary, the connection's
failure said in one line."""

from __future__ import annotations

import re
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from bayescal.errors import SpecError, optional

__all__ = ["scheduler_address", "connect"]

#: the schemes of dask.distributed's transports
SCHEMES = ("tcp", "tls", "inproc", "ucx", "ws", "wss")
_ADDRESS = re.compile(r"^(?:(?P<scheme>[a-z]+)://)?(?P<host>\[[0-9a-fA-F:.]+\]|[A-Za-z0-9._-]+)(?::(?P<port>\d+))?/?$")
#: seconds to wait for the scheduler before saying it cannot be reached
CONNECT_TIMEOUT_S = 20


def scheduler_address(text: str, what: str = "--scheduler") -> str:
    """``text`` if it is a scheduler address (``tcp://host:8786``, ``host:8786``, ``tls://...``), else
    :class:`~bayescal.errors.SpecError` saying what was expected."""
    value = str(text).strip()
    if value.startswith("inproc://") and len(value) > len("inproc://"):  # an address within this process
        return value
    m = _ADDRESS.match(value)
    port = m.group("port") if m else None
    if m is None or (m.group("scheme") or "tcp") not in SCHEMES or (port is not None and not 0 < int(port) < 65536):
        raise SpecError(
            f"{what} '{text}' is not a scheduler address; expected e.g. tcp://host:8786 "
            f"(schemes: {', '.join(SCHEMES)}; the port 1-65535)"
        )
    if port is None:
        raise SpecError(f"{what} '{text}' names no port; expected e.g. tcp://{m.group('host')}:8786")
    return value


@contextmanager
def connect(address: str) -> Iterator[Any]:
    """A ``distributed.Client`` on the scheduler at ``address``, closed afterwards; a scheduler that cannot
    be reached raises :class:`~bayescal.errors.SpecError` naming the address."""
    Client = optional("distributed", "a dask scheduler (--scheduler)").Client

    address = scheduler_address(address)
    try:
        client = Client(address, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError) as exc:
        raise SpecError(
            f"cannot reach the dask scheduler at {address} ({type(exc).__name__}: {exc}); is it running, and is "
            "the address the one `dask scheduler` printed?"
        ) from None
    try:
        yield client
    finally:
        client.close()
