"""What the gateway's single-purpose worker threads (store writer, blocking publisher) share."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


def wait_until_idle(cond: threading.Condition, pending: Callable[[], bool], thread: threading.Thread,
                    timeout_s: float) -> bool:  # fmt: skip
    """Wait on `cond` until `pending()` is false (the worker notifies after each item); False on timeout or when the
    worker thread has died (nothing would ever drain the queue)."""
    deadline = time.monotonic() + timeout_s
    with cond:
        while pending():
            left = deadline - time.monotonic()
            if left <= 0 or not thread.is_alive():
                return False
            cond.wait(left)
    return True
