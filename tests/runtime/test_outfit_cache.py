"""The engine's rig cache, keyed by the content of an outfit."""

import numpy as np

from drape.runtime.engine import Engine


def test_the_outfit_id_tells_apart_meshes_whose_bytes_run_together():
    """The id hashed the vertices' bytes and then the faces', with nothing between: a mesh with one more vertex
    whose float32 bits are a face's int32 indices, and that face fewer, gave the same bytes and so the same id;
    anyone could rig such a twin of a known mesh first and every later rig of that mesh got the twin's rig
    (another vertex count) from the shared cache. The shapes are part of the id now."""
    engine = Engine(refine_workers=1, intrinsic_dir=None)
    v = np.array([[0, 1, 0.2], [0.1, 1, 0.2], [0, 1.1, 0.2], [0.1, 1.1, 0.25]], dtype=np.float32)
    f = np.array([[0, 1, 2], [1, 3, 2]], dtype=np.int32)
    twin_v = np.concatenate([v, f[:1].view(np.float32)])  # the first face's bits as a fifth vertex
    twin_f = f[1:]
    assert twin_v.tobytes() + twin_f.tobytes() == v.tobytes() + f.tobytes()
    assert engine.outfit_id(twin_v, twin_f, "neutral") != engine.outfit_id(v, f, "neutral")
