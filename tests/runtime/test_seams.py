"""UV seams cannot open (issue 20, item 8): coincident vertices are welded for the network and for the
refinement, and every answer restores them (drape.geometry.mesh.weld)."""

import numpy as np
import pytest

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.geometry.lbs import pose_mesh
from drape.geometry.mesh import coincident_groups, weld
from drape.geometry.queries import nearest_vertex_weights
from drape.runtime.deepsd import DeePSDModel
from drape.runtime.engine import Engine, RefinePool, RefineSettings


def seamed(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A seam down the front and back (x = 0), as a UV cut makes: the faces right of it use copies of the
    vertices they share with the left. -> (vertices (N + k, 3), faces, copied (k,) original indices)."""
    centroid_x = vertices[faces].mean(axis=1)[:, 0]
    right = centroid_x > 0
    copied = np.intersect1d(np.unique(faces[right]), np.unique(faces[~right]))
    copy_of = {int(i): len(vertices) + k for k, i in enumerate(copied)}
    f = faces.copy()
    f[right] = np.vectorize(lambda i: copy_of.get(int(i), int(i)))(faces[right])
    return np.concatenate([vertices, vertices[copied]]), f, copied


@pytest.fixture(scope="module")
def outfit():
    o = generate_outfit("tshirt", vertices=1200, seed=21)
    v, f, copied = seamed(o.vertices, o.faces)
    assert len(copied) > 20
    return o, v, f, copied


def test_weld_merges_exactly_the_copies(outfit):
    o, v, f, copied = outfit
    welded, wf, group = weld(v, f)
    np.testing.assert_array_equal(welded, o.vertices)  # first appearance order: the original mesh
    np.testing.assert_array_equal(wf, o.faces)
    np.testing.assert_array_equal(group[len(o.vertices):], copied)
    first, g = coincident_groups(np.array([[0.0, 1.0, 0], [-0.0, 1.0 + 1e-7, 0], [2.0, 0.0, 0], [0, 1, 0.1]]))
    assert first.tolist() == [0, 2, 3] and g.tolist() == [0, 0, 1, 2]


def test_the_network_rigs_a_seamed_mesh_as_the_sewn_one(outfit):
    o, v, f, copied = outfit
    model = DeePSDModel()
    body = load_body("neutral")
    sewn, cut = model.rig(o.vertices, o.faces, body), model.rig(v, f, body)
    np.testing.assert_array_equal(cut.weights[: len(o.vertices)], sewn.weights)
    np.testing.assert_array_equal(cut.weights[len(o.vertices):], sewn.weights[copied])
    np.testing.assert_array_equal(cut.blend_shapes[:, len(o.vertices):], sewn.blend_shapes[:, copied])


def test_animate_and_refine_keep_the_seam_closed(outfit):
    o, v, f, copied = outfit
    engine = Engine()
    rigged = engine.rig(v, f, "neutral")
    clip = load_clip("dance_b")
    p, t = clip.poses[::30].astype(float), clip.trans[::30].astype(float)
    for refine in (None, RefineSettings()):
        frames = np.concatenate(list(engine.pose_chunks(rigged, p, t, refine=refine)))
        assert np.abs(frames[:, len(o.vertices):] - frames[:, copied]).max() == 0.0


def test_refinement_of_a_seamed_stream_equals_the_sewn_one():
    """A stream that penetrates (nearest-body-weights LBS): refined with the seam, the copies move with their
    originals and the rest is what refining the sewn mesh gives."""
    body = load_body("neutral")
    o = generate_outfit("longsleeve", vertices=1200, seed=5)
    v, f, copied = seamed(o.vertices, o.faces)
    clip = load_clip("dance_b")
    p, t = clip.poses[::40].astype(float), clip.trans[::40].astype(float)
    w = nearest_vertex_weights(v, body.vertices, body.weights)
    stream = pose_mesh(v, w, body.joints, p, t).astype(np.float32)
    pool = RefinePool(1)
    cut = pool.refine(stream, f, "neutral", p, t, RefineSettings())
    sewn = pool.refine(stream[:, : len(o.vertices)], o.faces, "neutral", p, t, RefineSettings())
    assert np.abs(sewn - stream[:, : len(o.vertices)]).max() > 1e-3, "the input should need refining"
    np.testing.assert_allclose(cut[:, : len(o.vertices)], sewn, atol=1e-6)  # float32 rounding of a copied array
    np.testing.assert_array_equal(cut[:, len(o.vertices):], cut[:, copied])  # the seam stays closed, exactly
