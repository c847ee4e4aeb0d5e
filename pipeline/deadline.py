"""The ingest time bound: a deadline that format readers check between units of work.

`load_scene` opens one with `within(seconds, path)`; readers call `check()` inside their
loops (per node, per primitive, per prim, per texture). What this bounds: everything done in
Python between those checks. What it does not: a single native call already running (one
`json.loads`, one `Usd.Stage.Open`, one image decode) cannot be interrupted from Python; those
are bounded by the size limits on their input instead (Limits.max_file_bytes, pixel counts).
"""
from __future__ import annotations

import contextlib
import contextvars
import time
from collections.abc import Iterator

from core.errors import IngestTimeout

_current: contextvars.ContextVar[tuple[float, str, float] | None] = contextvars.ContextVar(
    "ingest_deadline", default=None)


@contextlib.contextmanager
def within(seconds: float, path: str) -> Iterator[None]:
    """Run the body under a deadline `seconds` from now; `check()` raises IngestTimeout after."""
    token = _current.set((time.monotonic() + seconds, str(path), seconds))
    try:
        yield
    finally:
        _current.reset(token)


def check() -> None:
    """Raise IngestTimeout (naming the file) when the current deadline has passed."""
    current = _current.get()
    if current is not None and time.monotonic() > current[0]:
        raise IngestTimeout(current[1], f"parsing took longer than the {current[2]:g} s "
                                        "ingest time bound (ASSET_PREVIEW_INGEST_SECONDS)")
