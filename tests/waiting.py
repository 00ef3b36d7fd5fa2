"""Waiting on a condition in tests, never on the wall clock for a result."""

from __future__ import annotations

import time
from collections.abc import Callable


def wait_until(condition: Callable[[], bool], limit_s: float = 60.0) -> bool:
    """Polls a condition every 10 ms; False when `limit_s` passes first (the limit only keeps a
    broken receiver from hanging the test, it measures nothing)."""
    end = time.monotonic() + limit_s
    while not condition():
        if time.monotonic() > end:
            return False
        time.sleep(0.01)
    return True
