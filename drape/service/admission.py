"""Admission control for heavy requests (rig, animate, refine): a bounded number compute at once, a
bounded queue waits for a turn, and anything past that is refused at once with a 503 + Retry-After.

Knows nothing of HTTP beyond raising `Overloaded`; one instance per app, used on the event loop.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from drape.service.errors import Overloaded


class Slot:
    """A turn to compute; `release()` hands it back (idempotent: streams release it when they end)."""

    def __init__(self, admission: Admission) -> None:
        self._admission: Admission | None = admission

    def release(self) -> None:
        if self._admission is not None:
            self._admission._release()
            self._admission = None


class Admission:
    """max_active computations at once, max_queue waiting (each at most queue_timeout_s)."""

    def __init__(self, max_active: int, max_queue: int, queue_timeout_s: float, retry_after_s: int,
                 on_change: Callable[[int, int], None] = lambda active, waiting: None,
                 on_reject: Callable[[str], None] = lambda reason: None) -> None:
        self.max_active, self.max_queue = max_active, max_queue
        self.queue_timeout_s, self.retry_after_s = queue_timeout_s, retry_after_s
        self.active = 0
        self.waiting = 0
        self._free = asyncio.Semaphore(max_active)
        self._on_change, self._on_reject = on_change, on_reject

    def _refuse(self, reason: str, detail: str) -> Overloaded:
        self._on_reject(reason)
        return Overloaded(f"{detail}; retry in {self.retry_after_s} s", self.retry_after_s)

    async def enter(self) -> Slot:
        """A slot now, or after waiting in the queue; Overloaded when the queue is full or the wait too long.

        Counted before the first await: a request taking a free slot is `waiting` until its turn is handed over
        (the semaphore's acquire yields to the event loop first), so `active` alone would let every request that
        arrives in that moment into the queue."""
        if self.active + self.waiting >= self.max_active + self.max_queue:
            raise self._refuse("queue_full", f"{self.active} requests computing and {self.waiting} waiting "
                                             "(the limits)")
        self.waiting += 1
        self._on_change(self.active, self.waiting)
        try:
            await asyncio.wait_for(self._free.acquire(), self.queue_timeout_s)
        except TimeoutError:
            raise self._refuse("queue_timeout", f"no computing slot came free within {self.queue_timeout_s:g} s"
                               ) from None
        finally:
            self.waiting -= 1
        self.active += 1
        self._on_change(self.active, self.waiting)
        return Slot(self)

    def _release(self) -> None:
        self.active -= 1
        self._free.release()
        self._on_change(self.active, self.waiting)
