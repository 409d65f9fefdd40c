"""Every bad input of the contract answers a 4xx problem+json naming the field; never a 500."""

import io
import pickle

import numpy as np
import pytest
from svc_env import problem

from tests.intrinsic_model import NAME

V = [[0.0, 1.0, 0.2], [0.1, 1.0, 0.2], [0.0, 1.1, 0.2], [0.1, 1.1, 0.25]]
F = [[0, 1, 2], [1, 3, 2]]




def rig(http, **body):
    return http.post("/v1/outfits/rig", json={"vertices": V, "faces": F, **body})


def animate(http, **body):
    return http.post("/v1/outfits/animate", json={"outfit": {"vertices": V, "faces": F}, "motion": {"clip": "kick"},
                                                  **body})


def test_nan_and_inf(http):
    r = http.post("/v1/outfits/rig", content=b'{"vertices": [[0,1,0.2],[NaN,1,0.2],[0,1.1,0.2]], "faces": [[0,1,2]]}',
                  headers={"content-type": "application/json"})
    problem(r, 422, "vertices", "NaN")
    poses = "[[" + ",".join(["0"] * 71 + ["Infinity"]) + "]]"
    body = f'{{"outfit": {{"vertices": {V}, "faces": {F}}}, "motion": {{"poses": {poses}}}}}'
    r = http.post("/v1/outfits/animate", content=body.encode(), headers={"content-type": "application/json"})
    problem(r, 422, "motion")
    # a bounded number given as NaN is named as not finite (pydantic said "less than or equal to 1000")
    body = f'{{"outfit": {{"vertices": {V}, "faces": {F}}}, "motion": {{"clip": "kick", "fps": NaN}}}}'
    r = http.post("/v1/outfits/animate", content=body.encode(), headers={"content-type": "application/json"})
    problem(r, 422, "motion.fps", "finite")
    body = f'{{"outfit": {{"vertices": {V}, "faces": {F}}}, "motion": {{"clip": "kick"}}, "refine": {{"eps": NaN}}}}'
    r = http.post("/v1/outfits/animate", content=body.encode(), headers={"content-type": "application/json"})
    problem(r, 422, "eps", "finite")


def test_finite_values_that_overflow_when_posed(http):
    """Poses, or a refined stream's later frames, finite but far out of range: a 422 before the work (they posed
    to NaN: an animate answer of NaN frames with a 200, a refine answer cut after its 200 by the body's KD-tree)."""
    poses = [[0.0] * 72, [0.0] * 5 + [1e200] + [0.0] * 66]
    problem(animate(http, motion={"poses": poses}), 422, "motion.poses", "beyond 10000 radians")
    far = [[x * 1e200 for x in v] for v in V]
    body = {"vertices": [V, far], "faces": F, "motion": {"poses": [[0.0] * 72] * 2}}
    for accept in ("application/json", "application/x-npz"):
        problem(http.post("/v1/refine", json=body, headers={"accept": accept}), 422, "vertices", "beyond 10100 m")
    inner = {"vertices": [V, far], "faces": F, "thickness": 0.004}
    problem(http.post("/v1/refine", json={**body, "vertices": [V, V], "inner": inner}), 422, "inner.vertices",
            "beyond 10100 m")


def test_wrong_shapes(http):
    problem(http.post("/v1/outfits/rig", json={"vertices": [[0, 1], [1, 0], [0, 0]], "faces": F}), 422, "vertices")
    problem(animate(http, motion={"poses": [[0.0] * 70]}), 422, "motion.poses")
    problem(animate(http, motion={"poses": [[0.0] * 72] * 3, "translation": [[0, 0, 0]]}), 422, "motion.translation")


def test_faces_out_of_range(http):
    problem(rig(http, faces=[[0, 1, 7]]), 422, "faces", "[0, 3]")
    problem(rig(http, faces=[[0, 0, 1]]), 422, "faces", "repeats")
    buf = io.BytesIO()  # uint64 indices past int64: named as they are, not as the negative number a cast wraps to
    np.savez(buf, vertices=np.array(V, np.float32), faces=np.array([[2**64 - 1, 1, 2]], np.uint64))
    p = problem(http.post("/v1/outfits/rig", content=buf.getvalue(), headers={"content-type": "application/x-npz"}),
                422, "faces", str(2**64 - 1))
    assert "-1" not in p["detail"]


def test_empty_and_degenerate_mesh(http):
    p = problem(http.post("/v1/outfits/rig", json={"vertices": [], "faces": []}), 422, "vertices")
    assert p["field"] == "vertices"  # a request model's validation names it in the field member too (it was null)
    flat = [[0, 0, 0], [1, 1, 1], [2, 2, 2]]
    problem(http.post("/v1/outfits/rig", json={"vertices": flat, "faces": [[0, 1, 2]]}), 422, "zero area")
    # a real triangle 1e-9 m across: its area is below the zero-area bound, and the message says it is too small
    tiny = [[0, 1e-9, 0], [1e-9, 0, 0], [0, 0, 1e-9]]
    for route in ("/v1/outfits/rig", "/v1/outfits/fit"):
        problem(http.post(route, json={"vertices": tiny, "faces": [[0, 1, 2]]}), 422, "vertices", "far too small")


def test_too_many_vertices_and_frames(http, settings):
    n = settings.max_vertices + 1
    verts = np.random.default_rng(0).normal(size=(n, 3)).round(3).tolist()
    problem(http.post("/v1/outfits/rig", json={"vertices": verts, "faces": [[0, 1, 2]]}), 413,
            str(settings.max_vertices))
    poses = [[0.0] * 72] * (settings.max_frames + 1)
    problem(animate(http, motion={"poses": poses}), 413, str(settings.max_frames))


def test_too_large_body(http, settings):
    r = http.post("/v1/outfits/rig", content=b"0" * (settings.max_body_bytes + 1),
                  headers={"content-type": "application/json"})
    problem(r, 413, str(settings.max_body_bytes))


def test_malformed_json_obj_glb_npz(http):
    problem(http.post("/v1/outfits/rig", content=b"{not json", headers={"content-type": "application/json"}),
            400, "JSON")
    problem(http.post("/v1/outfits/rig", files={"mesh": ("a.obj", b"v 0 0 zzz\nf 1 2 9\n")}), 400, "mesh")
    problem(http.post("/v1/outfits/rig", files={"mesh": ("a.glb", b"glTF\x02\x00\x00\x00garbage")}), 400, "mesh")
    problem(http.post("/v1/outfits/rig", content=b"PK\x03\x04 not a zip",
                      headers={"content-type": "application/x-npz"}), 400, "npz")
    problem(http.post("/v1/outfits/rig", files={"mesh": ("a.stl", b"solid x")}), 422, "mesh")


def test_pickled_npz_is_refused_and_nothing_unpickles(http):
    class Boom:
        def __reduce__(self):
            return (exec, ("raise SystemExit('unpickled!')",))

    buf = io.BytesIO()
    np.savez(buf, vertices=np.array([Boom()], dtype=object), faces=np.array(F))
    problem(http.post("/v1/outfits/rig", content=buf.getvalue(), headers={"content-type": "application/x-npz"}),
            400, "npz")
    raw = pickle.dumps({"vertices": V, "faces": F})
    problem(http.post("/v1/outfits/rig", content=raw, headers={"content-type": "application/x-npz"}), 400)


def test_unknown_outfit_id_clip_body_model(http):
    problem(http.post("/v1/outfits/animate", json={"outfit_id": "deadbeef", "motion": {"clip": "kick"}}), 404,
            "outfit_id")
    problem(animate(http, motion={"clip": "moonwalk"}), 404, "motion.clip")
    problem(rig(http, body="giant"), 422, "body")
    problem(http.get("/v1/models/nope"), 404, "name")


def test_unsupported_accept_and_content_type(http):
    problem(http.post("/v1/outfits/rig", json={"vertices": V, "faces": F}, headers={"accept": "text/csv"}), 406,
            "Accept")
    problem(http.post("/v1/outfits/animate", content=b"x", headers={"content-type": "text/plain"}), 415,
            "Content-Type")
    # a compressed body: a 415 naming the encoding (read as JSON it was "not valid JSON (... byte 0x8b ...)")
    import gzip
    import json

    body = json.dumps({"vertices": V, "faces": F}).encode()
    for url in ("/v1/outfits/rig", "/v1/outfits/animate"):
        p = problem(http.post(url, content=gzip.compress(body), headers={"content-type": "application/json",
                                                                          "content-encoding": "gzip"}), 415, "'gzip'")
        assert p["field"] == "Content-Encoding"
    ok = http.post("/v1/outfits/rig", content=body, headers={"content-type": "application/json",
                                                              "content-encoding": "identity"})
    assert ok.status_code == 200, ok.text[:200]


def test_refine_bad_inputs(http):
    frames = [V] * 2
    body = {"vertices": frames, "faces": F, "motion": {"poses": [[0.0] * 72] * 3}}
    problem(http.post("/v1/refine", json=body), 422, "motion", "3 frames")
    problem(http.post("/v1/refine", json={**body, "vertices": [[[0, 0], [1, 1], [2, 2]]]}), 422, "vertices")
    problem(http.post("/v1/refine", json={**body, "faces": [[0, 1, 9]], "motion": {"poses": [[0.0] * 72] * 2}}),
            422, "faces")
    problem(animate(http, refine={"eps": -1.0}), 422, "eps")
    problem(animate(http, refine={"relief_iterations": -1}), 422, "relief_iterations")


def test_refine_npz_bad_options(http):
    """An npz refine request carries its options as scalars, checked like the JSON request's options."""
    def post(**arrays):
        buf = io.BytesIO()
        np.savez(buf, vertices=np.array([V] * 2, np.float32), faces=np.array(F), poses=np.zeros((2, 72)), **arrays)
        return http.post("/v1/refine", content=buf.getvalue(), headers={"content-type": "application/x-npz"})

    problem(post(relief_iterations=np.array(-1)), 422, "relief_iterations")
    problem(post(eps=np.array(1.0)), 422, "eps")
    problem(post(eps=np.array([0.003, 0.003])), 422, "eps", "scalar")
    problem(post(max_iterations=np.array("three")), 422, "max_iterations")
    assert post(eps=np.array(0.004), relief_iterations=np.array(2)).status_code == 200


def test_refine_rest_shape_bad_inputs(http):
    """/v1/refine's rest_vertices (JSON, npz): (N, 3) with the stream's N, finite, in metres, not with inner."""
    frames = [V] * 2
    body = {"vertices": frames, "faces": F, "motion": {"poses": [[0.0] * 72] * 2}}
    assert http.post("/v1/refine", json={**body, "rest_vertices": V}).status_code == 200
    problem(http.post("/v1/refine", json={**body, "rest_vertices": V[:-1]}), 422, "rest_vertices", f"({len(V)}, 3)")
    problem(http.post("/v1/refine", json={**body, "rest_vertices": [[0, 0]] * len(V)}), 422, "rest_vertices")
    problem(http.post("/v1/refine", json={**body, "rest_vertices": [[1e4, 0, 0]] * len(V)}), 422, "rest_vertices",
            "metres")
    problem(http.post("/v1/refine", json={**body, "rest_vertices": V, "inner": {"vertices": frames, "faces": F}}),
            422, "rest_vertices", "inner")

    def post(**arrays):
        buf = io.BytesIO()
        np.savez(buf, vertices=np.array(frames, np.float32), faces=np.array(F), poses=np.zeros((2, 72)), **arrays)
        return http.post("/v1/refine", content=buf.getvalue(), headers={"content-type": "application/x-npz"})

    assert post(rest_vertices=np.array(V, np.float64)).status_code == 200
    bad = np.array(V, np.float64)
    bad[0, 1] = np.nan
    problem(post(rest_vertices=bad), 422, "rest_vertices", "NaN")
    problem(post(rest_vertices=np.array(frames, np.float64)), 422, "rest_vertices")


def test_exactly_one_outfit_and_one_motion_source(http):
    problem(http.post("/v1/outfits/animate", json={"motion": {"clip": "kick"}}), 422, "outfit")
    problem(animate(http, motion={"clip": "kick", "poses": [[0.0] * 72]}), 422, "motion")


@pytest.mark.parametrize("path", ["/v1/bodies", "/v1/motions", "/v1/models"])
def test_api_key_guards_v1(settings, path):
    from fastapi.testclient import TestClient

    from drape.service.app import create_app

    app = create_app(settings.model_copy(update={"api_key": "s3cret"}))
    with TestClient(app) as c:
        problem(c.get(path), 401, "Authorization")
        problem(c.get(path, headers={"authorization": "Bearer wrong"}), 401)
        assert c.get(path, headers={"authorization": "Bearer s3cret"}).status_code == 200
        assert c.get(path, headers={"authorization": "bearer s3cret"}).status_code == 200  # the scheme: any case
        problem(c.get(path, headers={"authorization": "Basic s3cret"}), 401)
        assert c.get("/healthz").status_code == 200  # liveness stays open


def test_refine_inner_layer_bad_inputs(http):
    """The inner layer of /v1/refine (JSON `inner`, npz inner_vertices / inner_faces / thickness): its frames
    must match the stream's, its faces its vertices, its thickness lie in (0, 5 cm]; NaN refused."""
    frames = [V] * 2
    body = {"vertices": frames, "faces": F, "motion": {"poses": [[0.0] * 72] * 2}}
    inner = {"vertices": frames, "faces": F, "thickness": 0.004}
    assert http.post("/v1/refine", json={**body, "inner": inner}).status_code == 200
    problem(http.post("/v1/refine", json={**body, "inner": {**inner, "vertices": [V] * 3}}), 422, "inner.vertices",
            "(2, Ni, 3)")
    problem(http.post("/v1/refine", json={**body, "inner": {**inner, "faces": [[0, 1, 99]]}}), 422, "inner.faces")
    problem(http.post("/v1/refine", json={**body, "inner": {**inner, "thickness": 0.5}}), 422, "thickness")
    problem(http.post("/v1/refine", json={**body, "inner": {**inner, "vertices": [[[0, 0, 0]] * 3] * 2}}),
            422, "inner")

    def post(**arrays):
        buf = io.BytesIO()
        np.savez(buf, vertices=np.array(frames, np.float32), faces=np.array(F), poses=np.zeros((2, 72)), **arrays)
        return http.post("/v1/refine", content=buf.getvalue(), headers={"content-type": "application/x-npz"})

    bad = np.array(frames, np.float32)
    bad[1, 0, 0] = np.nan
    problem(post(inner_vertices=bad, inner_faces=np.array(F)), 422, "inner_vertices", "NaN")  # the npz member's name
    problem(post(inner_vertices=np.array(frames, np.float32)), 422, "inner_faces")
    problem(post(thickness=np.array(0.004)), 422, "inner_vertices")
    problem(post(inner_vertices=np.array(frames, np.float32), inner_faces=np.array(F), thickness=np.array(-1.0)),
            422, "thickness")
    assert post(inner_vertices=np.array(frames, np.float32), inner_faces=np.array(F)).status_code == 200


@pytest.mark.parametrize("url, members", [
    ("/v1/outfits/animate", {"vertices": np.array(V), "faces": np.array(F)}),
    ("/v1/refine", {"vertices": np.tile(np.array(V), (3, 1, 1)), "faces": np.array(F)}),
    (f"/v1/garments/{NAME}/sample", {"count": np.array(1), "frame": np.array(0)}),
])
def test_an_npz_member_the_request_does_not_read_is_named(http, url, members):
    """A probe sent AMASS's `trans` for `translation`: the npz request dropped it without a word and animated the
    garment in place (200), where JSON answers an unknown field with a 422. Now the npz does too."""
    from drape.schemas.binary import encode_npz

    poses = np.zeros((3, 72))
    p = problem(http.post(url, content=encode_npz({**members, "poses": poses, "trans": np.ones((3, 3))}),
                          headers={"content-type": "application/x-npz"}), 422, "did you mean 'translation'?")
    assert p["field"] == "trans"
    p = problem(http.post(url, content=encode_npz({**members, "poses": poses, "refine_eps": np.array(0.01)}),
                          headers={"content-type": "application/x-npz"}), 422, "not a member this request reads")
    assert p["field"] == "refine_eps"
    ok = http.post(url, content=encode_npz({**members, "poses": poses, "translation": np.ones((3, 3))}),
                   headers={"content-type": "application/x-npz", "accept": "application/x-npz"})
    assert ok.status_code == 200, ok.text[:300]
