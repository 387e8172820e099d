"""One owner of the gateway's live state (issue 12): a command queue drained by the ingest task between batches.

The pipeline (devices, filters, settings, auto-reel), the alarm engine and the ingest counters are changed by the
ingest task only. Everything else that wants a change (REST handlers, presence, the diagnostics and reel timers)
sends it a command, a plain callable, and awaits its result with `Commands.call`; `post` sends one without
waiting (e.g. from a liveliness callback handed to the loop). A batch never yields, so a command always runs
between two batches, never inside one, and commands run in the order they were sent.
"""

from __future__ import annotations

import asyncio
import collections
import logging
from collections.abc import Callable
from typing import Any, TypeVar

log = logging.getLogger("gateway.owner")
T = TypeVar("T")


class Commands:
    """FIFO of callables for the owner task. `call`/`post` on the event loop; `run_pending` on the owner task."""

    def __init__(self) -> None:
        self._items: collections.deque[tuple[Callable[[], Any], asyncio.Future[Any] | None]] = collections.deque()
        self.owner: asyncio.Task[Any] | None = None  # set by the owner task when it starts; None: run inline
        self.on_post: Callable[[], None] = lambda: None  # wakes the owner (the inbox's wake-up)
        self.pending = asyncio.Event()
        self.ran = 0
        self.failed = 0

    def _owner_running(self) -> bool:
        return self.owner is not None and not self.owner.done() and asyncio.current_task() is not self.owner

    async def call(self, fn: Callable[[], T]) -> T:
        """Run `fn` on the owner task and return its result (or raise its exception). Inline when called by the owner
        itself or when no owner runs (before start, after stop: nothing else could change the state then)."""
        if not self._owner_running():
            return fn()
        fut: asyncio.Future[T] = asyncio.get_running_loop().create_future()
        self._items.append((fn, fut))
        self._wake()
        return await fut

    def post(self, fn: Callable[[], object]) -> None:
        """Queue `fn` without waiting for it (event loop thread); its exceptions are logged."""
        if not self._owner_running():
            self._run(fn, None)
            return
        self._items.append((fn, None))
        self._wake()

    def _wake(self) -> None:
        self.pending.set()
        self.on_post()

    def run_pending(self) -> int:
        """Run every queued command (owner task); returns how many ran."""
        self.pending.clear()
        n = 0
        while self._items:
            fn, fut = self._items.popleft()
            if fut is not None and fut.done():  # the caller gave up (request cancelled): do not act for it
                continue
            self._run(fn, fut)
            n += 1
        return n

    def _run(self, fn: Callable[[], Any], fut: asyncio.Future[Any] | None) -> None:
        self.ran += 1
        try:
            result = fn()
        except Exception as exc:
            self.failed += 1
            if fut is None:
                log.exception("owner command failed")
            else:
                fut.set_exception(exc)
            return
        if fut is not None:
            fut.set_result(result)

    def cancel_pending(self) -> None:
        """Stop: callers still waiting get CancelledError; nothing queued runs any more."""
        while self._items:
            _, fut = self._items.popleft()
            if fut is not None and not fut.done():
                fut.cancel()
        self.owner = None

    def __len__(self) -> int:
        return len(self._items)
