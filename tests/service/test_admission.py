"""Admission control and the streamed answers on the event loop, without HTTP: the bounds hold however the
requests interleave; a failure before the first frame is raised while a problem document can still answer."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from drape.service.admission import Admission, Slot
from drape.service.answers import ENCODERS, FrameSource, first_chunk_ahead, stream_frames
from drape.service.errors import Overloaded
from drape.service.metrics import Metrics


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


@pytest.mark.parametrize("answer", sorted(ENCODERS))
def test_an_error_in_the_first_chunk_is_raised_before_the_answer_starts(answer):
    """Every encoder's first piece is a header: the first chunk is computed before the answer starts, so its
    error reaches the route (a problem document), not a 200 cut short; the slot is handed back."""
    def chunks():
        raise ValueError("the first chunk failed")
        yield  # a generator, as the routes' chunks are

    src = FrameSource(chunks, np.zeros((1, 3), np.int32), 4, 3, 30.0, "")

    async def scenario() -> None:
        admission = Admission(1, 0, 1.0, 1)
        slot = await admission.enter()
        with pytest.raises(ValueError, match="first chunk failed"):
            await stream_frames(answer, src, slot, 60.0, Metrics())
        assert admission.active == 0

    asyncio.run(scenario())


def test_the_first_chunk_ahead_keeps_every_frame_in_order():
    frames = np.arange(5 * 2 * 3, dtype=np.float32).reshape(5, 2, 3)
    calls = []

    def chunks():
        for i in range(0, 5, 2):
            calls.append(i)
            yield frames[i:i + 2]

    ahead = first_chunk_ahead(FrameSource(chunks, np.zeros((1, 3), np.int32), 5, 2, 30.0, ""))
    assert calls == [0]  # computed now, the rest when asked
    np.testing.assert_array_equal(np.concatenate(list(ahead.chunks())), frames)
