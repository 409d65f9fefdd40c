"""The user body store beside the engine: what a deleted body leaves behind."""

import os
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from drape.assets.body import Body, has_body, load_body
from drape.assets.outfits import generate_outfit
from drape.geometry.lbs import pose_mesh
from drape.runtime.body_store import BodyStore, body_id
from drape.runtime.deepsd import Rig
from drape.runtime.engine import Engine, RefinePool, RefineSettings, RiggedOutfit


@pytest.fixture(scope="module")
def engine():
    return Engine(refine_workers=1, intrinsic_dir=None)


def _user_body() -> Body:
    p = load_body("neutral", proxy=True)
    return Body(body_id(p.vertices, p.faces, p.weights, p.joints), p.vertices, p.faces, p.weights, p.joints,
                p.parents, p.joint_names)


def test_an_outfit_rigged_on_a_deleted_body_is_no_longer_found(engine):
    """An outfit_id rigged on a user body stayed in the rig cache after DELETE /v1/bodies/{id}: animating it
    answered 200 and then failed mid-answer (its body's joints are looked up by name while posing), a truncated
    npz. Its outfit is not found while its body is gone, and is again once the same body is registered again."""
    body = _user_body()
    store = BodyStore(4, 2**30)
    try:
        store.add(body)
        v = np.array([[0, 1, 0.2], [0.1, 1, 0.2], [0, 1.1, 0.2]], dtype=np.float32)
        f = np.array([[0, 1, 2]], dtype=np.int32)
        rig = Rig(np.full((3, 24), 1 / 24, np.float32), np.zeros((engine.model.num_keys, 3, 3), np.float32))
        oid = engine.outfit_id(v, f, body.name)
        engine.cache.put(oid, RiggedOutfit(oid, body.name, v, f, rig))
        outfit = engine.lookup(oid)
        assert outfit is not None
        assert next(engine.pose_chunks(outfit, np.zeros((2, 24, 3)), np.zeros((2, 3)))).shape == (2, 3, 3)
        store.delete(body.name)
        assert engine.lookup(oid) is None
        store.add(body)
        assert engine.lookup(oid) is outfit
    finally:
        store.close()


def _shirt_on_the_chest(body: Body, frames: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A shirt following the chest alone while the arms come down through its sleeves (refinement moves it):
    (rest vertices (N, 3), faces, poses (T, 24, 3), the posed shirt (T, N, 3))."""
    o = generate_outfit("tshirt", vertices=400, seed=5, body="neutral")
    poses = np.zeros((frames, 24, 3))
    poses[:, 16, 2] = poses[:, 17, 2] = np.linspace(-0.2, -0.9, frames)
    rigid = np.zeros((len(o.vertices), 24), np.float32)
    rigid[:, 9] = 1.0
    return o.vertices, o.faces, poses, pose_mesh(o.vertices, rigid, body.joints, poses).astype(np.float32)


def _whole_and_deleted_after_the_first_chunk(body: Body, chunks_of: Callable[[], Iterator[np.ndarray]],
                                             ) -> tuple[np.ndarray, np.ndarray]:
    """With `body` registered: every chunk of chunks_of() as one array, then again with the body deleted (as
    DELETE /v1/bodies/{id} does) after the first chunk -> (whole, got)."""
    store = BodyStore(4, 2**30)
    try:
        store.add(body)
        whole = np.concatenate(list(chunks_of()))
        chunks = chunks_of()
        first = next(chunks)
        store.delete(body.name)
        assert not has_body(body.name)
        return whole, np.concatenate([first, *chunks])
    finally:
        store.close()


def test_an_animation_started_on_a_user_body_finishes_on_it_after_a_delete(engine):
    """DELETE /v1/bodies/{id} while an animate answer with refinement streamed: each chunk's refinement looked the
    body up by name again, so the chunks after the delete failed (KeyError) and the answer was cut mid-stream.
    A started answer finishes on the body it started on, the same frames as without the delete."""
    body = _user_body()
    v, f, poses, _ = _shirt_on_the_chest(body, 4)
    trans = np.zeros((4, 3))
    rigid = np.zeros((len(v), 24), np.float32)
    rigid[:, 9] = 1.0
    outfit = RiggedOutfit("chest", body.name, v, f, Rig(rigid, np.zeros((engine.model.num_keys, len(v), 3),
                                                                           np.float32)))
    settings = RefineSettings()
    whole, got = _whole_and_deleted_after_the_first_chunk(
        body, lambda: engine.pose_chunks(outfit, poses, trans, chunk=2, refine=settings))
    assert np.array_equal(got, whole)


def test_a_refine_stream_started_on_a_user_body_finishes_on_it_after_a_delete(engine):
    """/v1/refine's chunks, split over two worker processes: a worker got a user body's faces only while it was
    registered, else its name, which a worker cannot load (KeyError mid-stream once the body was deleted)."""
    body = _user_body()
    _, f, poses, frames = _shirt_on_the_chest(body, 8)
    trans = np.zeros((8, 3))
    settings = RefineSettings()
    serving, engine.refine_pool = engine.refine_pool, RefinePool(2)
    try:
        whole, got = _whole_and_deleted_after_the_first_chunk(
            body, lambda: engine.refine_chunks(frames, f, body.name, poses, trans, settings, chunk=4))
    finally:
        engine.refine_pool.close()
        engine.refine_pool = serving
    assert np.abs(whole - frames).max() > 1e-3  # refinement moved the shirt
    assert np.array_equal(got, whole)


class _Store:
    """The OutfitStore deployment's handle as SharedOutfitEngine calls it: get.remote(id).result(timeout_s=)."""

    def __init__(self, outfits):
        self.get = self
        self.outfits = outfits

    def remote(self, outfit_id):
        self.asked = outfit_id
        return self

    def result(self, timeout_s):
        return self.outfits.get(self.asked)


def test_a_replica_does_not_take_an_outfit_of_a_body_it_does_not_hold_from_the_store(engine):
    """On Ray Serve the replica's lookup asked the shared store after Engine.lookup's None and answered the
    store's outfit whatever its body: an outfit rigged on a user body deleted since (or registered on another
    replica only) was found again, and posing it failed mid-answer. Now the store's copy passes the same check."""
    from drape.service.ray_serve import SharedOutfitEngine

    body = _user_body()
    v = np.array([[0, 1, 0.2], [0.1, 1, 0.2], [0, 1.1, 0.2]], dtype=np.float32)
    f = np.array([[0, 1, 2]], dtype=np.int32)
    rig = Rig(np.full((3, 24), 1 / 24, np.float32), np.zeros((engine.model.num_keys, 3, 3), np.float32))
    oid = engine.outfit_id(v, f, body.name)
    replica = SharedOutfitEngine(engine, _Store({oid: RiggedOutfit(oid, body.name, v, f, rig)}))
    assert replica.lookup(oid) is None  # the body is not registered here
    store = BodyStore(4, 2**30)
    try:
        store.add(body)
        assert replica.lookup(oid) is not None
    finally:
        store.close()
    assert replica.lookup(oid) is None


def test_a_registered_body_reaches_the_disk_before_the_answer(tmp_path, monkeypatch):
    """The body's bytes and its rename are fsynced (a 201 then a power cut must not leave an empty or missing
    file): the file's descriptor before the rename, the folder's after it."""
    synced: list[str] = []
    real_fsync = os.fsync

    def fsync(fd: int) -> None:
        synced.append("dir" if os.path.isdir(f"/proc/self/fd/{fd}") else "file")
        real_fsync(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    store = BodyStore(4, 2**30, directory=tmp_path)
    try:
        assert store.add(_user_body())
    finally:
        store.close()  # the body stays registered in this process otherwise
    assert synced == ["file", "dir"]
    assert len(list(tmp_path.glob("body-*.npz"))) == 1 and not list(tmp_path.glob("*.tmp"))


def test_a_body_registered_twice_is_held_until_both_registrations_are_deleted(tmp_path, monkeypatch):
    """Two clients that register the same body get the same name; one DELETE used to forget it for both (the
    other's outfits then answered 404). Each registration is counted, on disk too (fsynced, as the body's file:
    a count lost in a power cut would let one DELETE forget it), and the last DELETE forgets it."""
    body = _user_body()
    synced: list[int] = []
    real_fsync = os.fsync
    monkeypatch.setattr(os, "fsync", lambda fd: synced.append(fd) or real_fsync(fd))
    store = BodyStore(4, 2**30, directory=tmp_path)
    try:
        assert store.add(body) == 1 and store.add(body) == 2
        assert store.registrations(body.name) == 2 and (tmp_path / f"{body.name}.refs").read_text().strip() == "2"
        assert len(synced) == 4  # the body's file and folder, then the count's file and folder
        assert store.delete(body.name) and has_body(body.name) and store.registrations(body.name) == 1
        assert not (tmp_path / f"{body.name}.refs").exists()
        store.add(body)
    finally:
        store.close()
    again = BodyStore(4, 2**30, directory=tmp_path)  # a restart keeps the count
    try:
        assert again.registrations(body.name) == 2
        assert again.delete(body.name) and has_body(body.name)
        assert again.delete(body.name) and not has_body(body.name) and again.registrations(body.name) == 0
        assert not again.delete(body.name)
        assert not list(tmp_path.iterdir())
    finally:
        again.close()
