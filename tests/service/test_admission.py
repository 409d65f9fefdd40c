"""Admission control on the event loop, without HTTP: the bounds hold however the requests interleave."""

from __future__ import annotations

import asyncio

from drape.service.admission import Admission, Slot
from drape.service.errors import Overloaded


def test_requests_arriving_together_get_one_slot_and_one_queue_place():
    """Six requests in one moment (before the first has its turn handed over): 1 computes, 1 waits, 4 are
    refused at once; a release hands the turn to the waiting one, and a queue place is free again."""
    async def scenario() -> None:
        refused: list[str] = []
        admission = Admission(1, 1, 30.0, 7, on_reject=refused.append)
        tasks = [asyncio.ensure_future(admission.enter()) for _ in range(6)]
        for _ in range(5):
            await asyncio.sleep(0)
        done = [t for t in tasks if t.done()]
        slots = [t.result() for t in done if t.exception() is None]
        assert len(slots) == 1 and isinstance(slots[0], Slot)
        assert sum(isinstance(t.exception(), Overloaded) for t in done) == 4 and refused == ["queue_full"] * 4
        waiting = [t for t in tasks if not t.done()]
        assert len(waiting) == 1 and (admission.active, admission.waiting) == (1, 1)
        slots[0].release()
        second = await asyncio.wait_for(waiting[0], 5.0)
        assert (admission.active, admission.waiting) == (1, 0)
        third = asyncio.ensure_future(admission.enter())  # the queue place is free again: it waits
        await asyncio.sleep(0)
        try:
            await admission.enter()
            raise AssertionError("a third request was let in with one computing and one waiting")
        except Overloaded:
            pass
        second.release()
        (await asyncio.wait_for(third, 5.0)).release()
        assert (admission.active, admission.waiting) == (0, 0)

    asyncio.run(scenario())


def test_no_slots_refuses_everything():
    async def scenario() -> None:
        admission = Admission(0, 0, 1.0, 9)
        for _ in range(3):
            try:
                await admission.enter()
                raise AssertionError("admitted with no slots")
            except Overloaded:
                pass
        assert (admission.active, admission.waiting) == (0, 0)

    asyncio.run(scenario())
