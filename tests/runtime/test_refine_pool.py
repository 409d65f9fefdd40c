"""Refinement split over worker processes gives exactly the in-process result."""

import os
import signal
import time

import numpy as np
import pytest

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.geometry.lbs import pose_mesh
from drape.geometry.queries import nearest_vertex_weights
from drape.runtime.engine import RefinePool, RefineSettings
from drape.sim.layers import split_outfit


@pytest.fixture(scope="module")
def stream():
    """The nearest-body-weights LBS baseline on 7 frames of a held-out clip: it penetrates."""
    body = load_body("neutral")
    o = generate_outfit("longsleeve", vertices=1500, seed=77)
    w = nearest_vertex_weights(o.vertices, body.vertices, body.weights)
    clip = load_clip("dance_b")
    frames = np.arange(0, clip.num_frames, 20)[:7]
    p, t = clip.poses[frames].astype(float), clip.trans[frames].astype(float)
    return pose_mesh(o.vertices, w, body.joints, p, t).astype(np.float32), o.faces, p, t


@pytest.mark.parametrize("relief_iterations", [0, 10])
def test_two_workers_equal_one_process(stream, relief_iterations):
    g, faces, p, t = stream
    settings = RefineSettings(relief_iterations=relief_iterations)
    alone = RefinePool(1).refine(g, faces, "neutral", p, t, settings)
    assert np.abs(alone - g).max() > 1e-3, "the test input should need refining"
    pool = RefinePool(2)
    try:
        split = pool.refine(g, faces, "neutral", p, t, settings)
        assert pool._pool is not None, "7 frames over 2 workers should go to the worker processes"
    finally:
        pool.close()
    assert split.dtype == np.float32 and np.array_equal(split, alone)


def test_two_layers_over_two_workers_equal_one_process():
    """The post step between layers (a t-shirt under a jacket, the nearest-weights baseline on 6 frames) gives
    the same inner and outer split over two workers as in the serving process."""
    body = load_body("neutral")
    (vi, fi), (vo, fo) = split_outfit("tshirt,jacket", 1500, seed=3)
    clip = load_clip("dance_b")
    frames = np.arange(0, clip.num_frames, 25)[:6]
    p, t = clip.poses[frames].astype(float), clip.trans[frames].astype(float)
    inner, outer = (pose_mesh(x, nearest_vertex_weights(x, body.vertices, body.weights), body.joints, p, t
                              ).astype(np.float32) for x in (vi, vo))
    settings = RefineSettings()
    alone = RefinePool(1).refine_layers(inner, fi, outer, fo, 0.006, "neutral", p, t, settings)
    assert np.abs(alone[1] - outer).max() > 1e-3, "the test input should need refining"
    pool = RefinePool(2)
    try:
        split = pool.refine_layers(inner, fi, outer, fo, 0.006, "neutral", p, t, settings)
        assert pool._pool is not None, "6 frames over 2 workers should go to the worker processes"
    finally:
        pool.close()
    assert all(x.dtype == np.float32 and np.array_equal(x, y) for x, y in zip(split, alone, strict=True))


def test_a_short_chunk_stays_in_process(stream):
    g, faces, p, t = stream
    settings = RefineSettings()
    pool = RefinePool(2)
    out = pool.refine(g[:3], faces, "neutral", p[:3], t[:3], settings)
    assert pool._pool is None
    assert np.array_equal(out, RefinePool(1).refine(g[:3], faces, "neutral", p[:3], t[:3], settings))


def test_a_dead_worker_falls_back_to_the_serving_process(stream):
    g, faces, p, t = stream
    settings = RefineSettings()
    pool = RefinePool(2)
    try:
        for pid in list(pool.start()._processes):  # type: ignore[attr-defined]
            os.kill(pid, signal.SIGKILL)
        time.sleep(0.5)
        out = pool.refine(g, faces, "neutral", p, t, settings)
        assert pool._pool is None, "the broken pool is dropped; the next chunk starts new workers"
        assert np.array_equal(out, RefinePool(1).refine(g, faces, "neutral", p, t, settings))
        assert np.array_equal(pool.refine(g, faces, "neutral", p, t, settings), out)
        assert pool._pool is not None
    finally:
        pool.close()


def test_two_layer_streams_refined_at_once_in_process_equal_each_alone():
    """The serving process refines layers in its own threads (one worker, or a chunk too short to split), two
    requests at once with the same templates and thickness; the LayerRefiner they share keeps per-frame state (the
    posed inner layer its surfaces query), so one request's frame must not be measured against the other's."""
    import sys
    import threading

    body = load_body("neutral")
    (vi, fi), (vo, fo) = split_outfit("tshirt,jacket", 800, seed=3)
    clip = load_clip("dance_b")
    settings = RefineSettings(relief_iterations=0)
    streams = []
    for offset in (0, 13):
        frames = np.arange(offset, clip.num_frames, 25)[:3]
        p, t = clip.poses[frames].astype(float), clip.trans[frames].astype(float)
        inner, outer = (pose_mesh(x, nearest_vertex_weights(x, body.vertices, body.weights), body.joints, p, t
                                  ).astype(np.float32) for x in (vi, vo))
        streams.append((inner, outer, p, t))
    pool = RefinePool(1)
    alone = [pool.refine_layers(i, fi, o, fo, 0.006, "neutral", p, t, settings) for i, o, p, t in streams]
    got: list[list] = [[], []]
    start = threading.Barrier(2)

    def run(k: int) -> None:
        i, o, p, t = streams[k]
        start.wait()
        for _ in range(3):
            got[k].append(pool.refine_layers(i, fi, o, fo, 0.006, "neutral", p, t, settings))

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-5)
    try:
        threads = [threading.Thread(target=run, args=(k,)) for k in range(2)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
    finally:
        sys.setswitchinterval(interval)
    for k in range(2):
        for inner, outer in got[k]:
            assert np.array_equal(inner, alone[k][0]) and np.array_equal(outer, alone[k][1])


def test_a_request_that_saw_a_broken_pool_leaves_the_new_one_alone(stream):
    """Two requests in flight when a worker dies both see the pool broken; the first to fall back drops it and its
    next chunk starts new workers. The other falling back later must not shut those down (it closed whatever pool
    was current: the new one, cancelling the first request's queued chunks mid-answer)."""
    g, faces, p, t = stream
    settings = RefineSettings()
    pool = RefinePool(2)
    try:
        broken = pool.start()
        for pid in list(broken._processes):  # type: ignore[attr-defined]
            os.kill(pid, signal.SIGKILL)
        time.sleep(0.5)
        pool.close()  # the first request fell back ...
        fresh = pool.start()  # ... and its next chunk started new workers
        pool.start = lambda: broken  # type: ignore[method-assign]  # the second request still holds the broken pool
        out = pool.refine(g, faces, "neutral", p, t, settings)
        del pool.start
        assert np.array_equal(out, RefinePool(1).refine(g, faces, "neutral", p, t, settings))
        assert pool._pool is fresh
        assert fresh.submit(int, 7).result() == 7
    finally:
        pool.close()
