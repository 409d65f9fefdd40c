"""Bring your own body (issue 20, item 5): POST /v1/bodies registers a GLB or npz body; its body_id rigs,
fits, animates and refines like a preset (refinement in the worker processes included), GET answers its
arrays, DELETE forgets it; bad bodies answer 4xx problems naming the field; the store is bounded and survives
a restart only with DRAPE_BODY_DIR.

The uploaded body is the neutral preset's collision proxy (1.2k vertices, the neutral skeleton): small enough
for the test limits, and different from every preset's full mesh, so a wrong body would show."""

import asyncio
import dataclasses
import io
import json

import numpy as np
import pytest
from fastapi.testclient import TestClient
from svc_env import problem

import drape
from drape.assets.body import load_body
from drape.assets.outfits import generate_outfit
from drape.geometry.fitting import a_pose
from drape.geometry.lbs import pose_mesh
from drape.geometry.refine import FAR_K, BodySurface
from drape.geometry.skeleton import forward_kinematics
from drape.runtime.engine import RefineSettings, refine_against
from drape.service.app import create_app
from tests.cmu_bvh import cmu_bvh

NPZ = "application/x-npz"


def npz(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


@pytest.fixture(scope="module")
def proxy():
    return load_body("neutral", proxy=True)


@pytest.fixture(scope="module")
def shirt():
    o = generate_outfit("tshirt", vertices=400, seed=5, body="neutral")
    return o.vertices, o.faces


@pytest.fixture
def registered(http, proxy):
    """The proxy registered as an npz request body; deleted after the test."""
    r = http.post("/v1/bodies", content=npz(vertices=proxy.vertices, faces=proxy.faces, weights=proxy.weights,
                                            joints=proxy.joints), headers={"Content-Type": NPZ})
    assert r.status_code == 201, r.text[:300]
    body_id = r.json()["body_id"]
    yield body_id
    http.delete(f"/v1/bodies/{body_id}")


def test_an_npz_body_registers_lists_and_answers_its_arrays(http, registered, proxy):
    assert registered.startswith("body-")
    listed = {b["name"]: b for b in http.get("/v1/bodies").json()["bodies"]}
    assert listed[registered]["preset"] is False and listed["neutral"]["preset"] is True
    assert listed[registered]["num_vertices"] == len(proxy.vertices)
    doc = http.get(f"/v1/bodies/{registered}").json()
    np.testing.assert_allclose(doc["vertices"], proxy.vertices, atol=1e-6)
    np.testing.assert_allclose(doc["weights"], proxy.weights, atol=1e-6)
    assert doc["faces"] == proxy.faces.tolist() and doc["joint_names"] == list(proxy.joint_names)
    z = np.load(io.BytesIO(http.get(f"/v1/bodies/{registered}", headers={"Accept": NPZ}).content))
    np.testing.assert_allclose(z["joints"], proxy.joints, atol=1e-6)
    # a preset's mesh too; the same upload again gives the same id
    assert len(http.get("/v1/bodies/male", headers={"Accept": NPZ}).content) > 100_000
    again = http.post("/v1/bodies", files={"body_file": ("b.npz", npz(vertices=proxy.vertices, faces=proxy.faces,
                                                                       weights=proxy.weights, joints=proxy.joints))})
    assert again.status_code == 201 and again.json()["body_id"] == registered
    # and counts once more: one DELETE takes that registration back, the fixture's first still holds the body
    # (one client's DELETE forgot it for every other that had registered it)
    assert again.json()["registrations"] == 2
    assert http.delete(f"/v1/bodies/{registered}").status_code == 204
    assert http.get(f"/v1/bodies/{registered}", headers={"Accept": NPZ}).status_code == 200


def test_a_user_body_rigs_fits_animates_and_refines(http, registered, proxy, shirt):
    v, f = shirt
    r = http.post("/v1/outfits/rig", json={"vertices": v.tolist(), "faces": f.tolist(), "body": registered})
    assert r.status_code == 200, r.text[:300]
    np.testing.assert_allclose(r.json()["skeleton"]["rest_joints"], proxy.joints, atol=1e-6)
    fit = http.post("/v1/outfits/fit", json={"vertices": v.tolist(), "faces": f.tolist(), "body": registered})
    assert fit.status_code == 200 and fit.json()["report"]["inside_after"] <= 0.001, fit.text[:300]
    a = http.post("/v1/outfits/animate", json={"outfit_id": r.json()["outfit_id"], "motion": {"clip": "walk"},
                                               "refine": True}, headers={"Accept": NPZ})
    assert a.status_code == 200, a.text[:300]
    assert np.isfinite(np.load(io.BytesIO(a.content))["vertices"]).all()
    # /v1/refine on the user body (frames split over the worker processes) = the library against that body
    poses = np.zeros((4, 24, 3))
    poses[:, 16, 2] = poses[:, 17, 2] = np.linspace(-0.2, -0.9, 4)  # arms down into the shirt's sleeves
    rigid = np.zeros((len(v), 24))
    rigid[:, 9] = 1.0  # the shirt follows the chest alone: the lowered arms go through its sleeves
    frames = pose_mesh(v, rigid, proxy.joints, poses)
    req = {"vertices": frames.tolist(), "faces": f.tolist(), "motion": {"poses": poses.reshape(4, 72).tolist()},
           "body": registered}
    out = http.post("/v1/refine", json=req, headers={"Accept": NPZ})
    assert out.status_code == 200, out.text[:300]
    got = np.load(io.BytesIO(out.content))["vertices"]
    settings = RefineSettings()
    expected = refine_against(frames, BodySurface(proxy.faces, len(proxy.vertices), far_k=FAR_K), proxy.pose(poses).astype(
        np.float64), settings.refiner(f, len(v)))
    np.testing.assert_allclose(got, expected, atol=1e-5)
    on_neutral = http.post("/v1/refine", json={**req, "body": "neutral"}, headers={"Accept": NPZ})
    assert np.abs(np.load(io.BytesIO(on_neutral.content))["vertices"] - got).max() > 1e-4  # another body


def test_deleting_forgets_the_body_and_presets_stay(http, registered, shirt):
    v, f = shirt
    rig = http.post("/v1/outfits/rig", json={"vertices": v.tolist(), "faces": f.tolist(), "body": registered})
    assert rig.status_code == 200, rig.text[:300]
    assert http.delete(f"/v1/bodies/{registered}").status_code == 204
    # an outfit rigged on it: the 404 says the body went (it said "rig the outfit again", which fails too)
    for request in ({"json": {"outfit_id": rig.json()["outfit_id"], "motion": {"clip": "walk"}}},
                    {"files": {"motion_file": ("m.bvh", cmu_bvh(frames=4))},
                     "data": {"outfit_id": rig.json()["outfit_id"]}}):
        problem(http.post("/v1/outfits/animate", **request), 404, "outfit_id", registered, "deleted",
                "register the body again")
    problem(http.post("/v1/outfits/rig", json={"vertices": v.tolist(), "faces": f.tolist(), "body": registered}),
            404, "body", "POST /v1/bodies")
    problem(http.get(f"/v1/bodies/{registered}"), 404, "name")
    problem(http.delete(f"/v1/bodies/{registered}"), 404, "name")
    problem(http.delete("/v1/bodies/neutral"), 409, "preset")


def test_a_body_deleted_while_its_refine_answer_streams_finishes_the_answer(http, app, registered, proxy, shirt,
                                                                           monkeypatch):
    """DELETE /v1/bodies/{id} while a /v1/refine answer on that body streamed: every chunk looked the body up by
    name, so the answer was cut after its 200 (a truncated npz). The answer finishes on the body it started on;
    a request after the delete answers 404."""
    from drape.runtime.engine import Engine

    v, f = shirt
    poses = np.zeros((8, 24, 3))
    poses[:, 16, 2] = poses[:, 17, 2] = np.linspace(-0.2, -0.9, 8)
    rigid = np.zeros((len(v), 24))
    rigid[:, 9] = 1.0
    req = {"vertices": pose_mesh(v, rigid, proxy.joints, poses).tolist(), "faces": f.tolist(),
           "motion": {"poses": poses.reshape(8, 72).tolist()}, "body": registered}
    real = Engine.refine_chunks

    def deleted_after_the_first_chunk(self, *args, **kwargs):
        args = (*args[:6], 4, *args[7:])  # 4-frame chunks (two, each split over the two workers)
        chunks = real(self, *args, **kwargs)
        yield next(chunks)
        assert app.state.bodies.delete(registered)  # what DELETE /v1/bodies/{id} does
        yield from chunks

    want = http.post("/v1/refine", json=req, headers={"Accept": NPZ})
    assert want.status_code == 200, want.text[:300]
    monkeypatch.setattr(Engine, "refine_chunks", deleted_after_the_first_chunk)
    got = http.post("/v1/refine", json=req, headers={"Accept": NPZ})
    assert got.status_code == 200, got.text[:300]
    np.testing.assert_array_equal(np.load(io.BytesIO(got.content))["vertices"],
                                  np.load(io.BytesIO(want.content))["vertices"])
    problem(http.post("/v1/refine", json=req, headers={"Accept": NPZ}), 404, "body", "POST /v1/bodies")


@pytest.mark.parametrize("accept", ["application/json", "model/gltf-binary"])
@pytest.mark.parametrize("deleted", ["before the rig", "after the rig"])
def test_a_body_deleted_while_a_rig_is_computed_on_it_answers_404(http, app, registered, shirt, monkeypatch,
                                                                   deleted, accept):
    """DELETE /v1/bodies/{id} while POST /v1/outfits/rig worked on that body: the placement, the rig and the answer's
    skeleton each looked the body up by name, and the one after the delete raised a KeyError: a 500. It is the 404
    the request would have had a moment earlier, naming the body."""
    from drape.runtime.engine import Engine
    from drape.service import handlers

    v, f = shirt
    if deleted == "before the rig":  # between the placement check and the rig
        real_warnings = handlers.body_scale_warnings

        def warnings_then_delete(engine, body):
            out = real_warnings(engine, body)
            assert app.state.bodies.delete(registered)
            return out

        monkeypatch.setattr(handlers, "body_scale_warnings", warnings_then_delete)
    else:  # between the rig and its answer (the skeleton, the GLB's body)
        real_rig = Engine.rig

        def rig_then_delete(self, *args, **kwargs):
            out = real_rig(self, *args, **kwargs)
            assert app.state.bodies.delete(registered)
            return out

        monkeypatch.setattr(Engine, "rig", rig_then_delete)
    r = http.post("/v1/outfits/rig", json={"vertices": v.tolist(), "faces": f.tolist(), "body": registered},
                  headers={"Accept": accept})
    problem(r, 404, "body", registered)


def test_an_a_pose_body_needs_its_rest_pose_and_is_un_posed_with_it(http, proxy):
    pose = a_pose()
    posed = pose_mesh(proxy.vertices, proxy.weights, proxy.joints, pose[None])[0]
    joints = forward_kinematics(pose[None], proxy.joints, proxy.parents)[1][0]
    arrays = npz(vertices=posed, faces=proxy.faces, weights=proxy.weights, joints=joints)
    problem(http.post("/v1/bodies", files={"body_file": ("a.npz", arrays)}), 422, "T-pose", "rest_pose")
    r = http.post("/v1/bodies", files={"body_file": ("a.npz", arrays)},
                  data={"rest_pose": json.dumps(pose.tolist())})
    assert r.status_code == 201, r.text[:300]
    z = np.load(io.BytesIO(http.get(f"/v1/bodies/{r.json()['body_id']}", headers={"Accept": NPZ}).content))
    np.testing.assert_allclose(z["vertices"], proxy.vertices, atol=1e-4)
    np.testing.assert_allclose(z["joints"], proxy.joints, atol=1e-5)
    http.delete(f"/v1/bodies/{r.json()['body_id']}")


def _cancelling(proxy) -> tuple[np.ndarray, np.ndarray]:
    """The proxy's weights with every torso vertex split 0.5 / 0.5 between the hips, and a pose turning one hip
    half a turn about x and the other about y: those vertices' blended skinning rotation is singular
    (diag(0, 0, -1)) -> (weights (V, 24), pose (24, 3))."""
    w = proxy.weights.copy()
    torso = np.isin(w.argmax(axis=1), [3, 6, 9])  # spine1..3
    w[torso] = 0.0
    w[torso, 1] = w[torso, 2] = 0.5
    pose = np.zeros((24, 3))
    pose[1], pose[2] = [np.pi, 0, 0], [0, np.pi, 0]
    return w, pose


def test_a_pose_the_skinning_cannot_undo_is_a_422_naming_it(http, proxy, shirt):
    """Weights that mix joint rotations cancelling in a pose: un-posing by them was a 500 (LinAlgError), or
    vertices 1e15 m away; a rest_pose (POST /v1/bodies) and a fit's pose (POST /v1/outfits/fit) say so."""
    w, pose = _cancelling(proxy)
    arrays = npz(vertices=proxy.vertices, faces=proxy.faces, weights=w, joints=proxy.joints)
    problem(http.post("/v1/bodies", files={"body_file": ("c.npz", arrays)}, data={"rest_pose": json.dumps(pose.tolist())}),
            422, "rest_pose", "cannot be undone")
    nearly = pose.copy()
    nearly[2] = 0.0  # one hip alone half a turn: 0.5 (I + R) is singular too, up to rounding
    problem(http.post("/v1/bodies", files={"body_file": ("c.npz", arrays)}, data={"rest_pose": json.dumps(nearly.tolist())}),
            422, "rest_pose", "cannot be undone")
    r = http.post("/v1/bodies", content=arrays, headers={"Content-Type": NPZ})
    assert r.status_code == 201, r.text[:300]
    v, f = shirt
    problem(http.post("/v1/outfits/fit", json={"vertices": v.tolist(), "faces": f.tolist(), "body": r.json()["body_id"],
                                               "pose": pose.tolist()}), 422, "pose", "cannot be undone")
    http.delete(f"/v1/bodies/{r.json()['body_id']}")


@pytest.mark.parametrize("value", [[["0", "0", "0"]] * 24, [[False] * 3] * 24, [[0.0, True, "0"]] * 24,
                                   [[None] * 3] * 24])
def test_a_rest_pose_of_strings_booleans_or_nulls_is_refused(http, proxy, value):
    """The form's rest_pose is JSON numbers, strictly (as the JSON models): strings and booleans were read as
    numbers by numpy (a T-pose of "0"s or falses registered), nulls as NaN ("contains NaN")."""
    arrays = npz(vertices=proxy.vertices, faces=proxy.faces, weights=proxy.weights, joints=proxy.joints)
    problem(http.post("/v1/bodies", files={"body_file": ("b.npz", arrays)}, data={"rest_pose": json.dumps(value)}),
            422, "rest_pose", "strings, booleans or nulls")


def test_joint_names_in_another_order_are_reordered(http, proxy):
    order = np.random.default_rng(0).permutation(24)
    r = http.post("/v1/bodies", content=npz(vertices=proxy.vertices, faces=proxy.faces,
                                            weights=proxy.weights[:, order], joints=proxy.joints[order],
                                            joint_names=np.array(proxy.joint_names)[order]),
                  headers={"Content-Type": NPZ})
    assert r.status_code == 201, r.text[:300]
    z = np.load(io.BytesIO(http.get(f"/v1/bodies/{r.json()['body_id']}", headers={"Accept": NPZ}).content))
    np.testing.assert_allclose(z["joints"], proxy.joints, atol=1e-6)
    http.delete(f"/v1/bodies/{r.json()['body_id']}")
    # 24 names stored as bytes: the message names the dtype (it said "got shape (24,)", the right shape)
    as_bytes = np.array([n.encode() for n in proxy.joint_names])
    r = http.post("/v1/bodies", content=npz(vertices=proxy.vertices, faces=proxy.faces, weights=proxy.weights,
                                            joints=proxy.joints, joint_names=as_bytes), headers={"Content-Type": NPZ})
    problem(r, 422, "joint_names", "unicode", "|S")


def _bad(proxy, **change):
    arrays = {"vertices": proxy.vertices, "faces": proxy.faces, "weights": proxy.weights, "joints": proxy.joints}
    arrays.update(change)
    return npz(**arrays)


@pytest.mark.parametrize(("change", "status", "words"), [
    ("weights52", 422, ("weights", "24 joints", "52")),
    ("joints52", 422, ("joints", "24 joints")),
    ("weights_half", 422, ("weights", "do not sum to 1", "0.5")),
    ("nan", 422, ("vertices", "NaN")),
    ("centimetres", 422, ("vertices", "metres", "centimetres")),
    ("z_up", 422, ("joints", "+Y up")),
    ("facing_back", 422, ("joints", "face +Z")),
    ("parents", 422, ("parents", "SMPL")),
    ("missing", 422, ("lacks", "weights")),
    ("faces_out", 422, ("faces", "indices")),
])
def test_bad_bodies_answer_4xx_naming_the_field(http, proxy, change, status, words):
    rot_z_up = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    flip = np.diag([-1.0, 1.0, -1.0])
    w52 = np.concatenate([proxy.weights, np.zeros((len(proxy.weights), 28))], axis=1)
    data = {
        "weights52": lambda: _bad(proxy, weights=w52),
        "joints52": lambda: _bad(proxy, joints=np.zeros((52, 3))),
        "weights_half": lambda: _bad(proxy, weights=proxy.weights * np.where(np.arange(len(proxy.weights)) < 9, 0.5,
                                                                             1.0)[:, None]),
        "nan": lambda: _bad(proxy, vertices=np.where(np.arange(len(proxy.vertices))[:, None] == 3, np.nan,
                                                     proxy.vertices)),
        "centimetres": lambda: _bad(proxy, vertices=proxy.vertices * 100, joints=proxy.joints * 100),
        "z_up": lambda: _bad(proxy, vertices=proxy.vertices @ rot_z_up.T, joints=proxy.joints @ rot_z_up.T),
        "facing_back": lambda: _bad(proxy, vertices=proxy.vertices @ flip, joints=proxy.joints @ flip),
        "parents": lambda: _bad(proxy, parents=np.r_[-1, np.zeros(23, int)]),
        "missing": lambda: npz(vertices=proxy.vertices, faces=proxy.faces),
        "faces_out": lambda: _bad(proxy, faces=proxy.faces + len(proxy.vertices)),
    }[change]()
    p = problem(http.post("/v1/bodies", content=data, headers={"Content-Type": NPZ}), status, *words)
    assert len(p["detail"]) < 400


def test_huge_and_wrong_uploads_answer_4xx(http, settings, proxy):
    problem(http.post("/v1/bodies", content=b"\0" * (settings.max_body_bytes + 1),
                      headers={"Content-Type": NPZ}), 413)
    problem(http.post("/v1/bodies", files={"body_file": ("b.obj", b"v 0 0 0\n")}), 422, "body_file", "GLB")
    problem(http.post("/v1/bodies", json={"vertices": []}), 415, "multipart")
    problem(http.post("/v1/bodies", files={"body_file": ("b.npz", _bad(proxy))}, data={"joint_map": "{"}), 422,
            "joint_map")
    problem(http.post("/v1/bodies", files={"mesh": ("b.npz", _bad(proxy))}), 422, "body_file")


def test_the_store_is_bounded_and_kept_only_in_body_dir(settings, proxy, tmp_path):
    one = settings.model_copy(update={"max_bodies": 1, "body_dir": tmp_path, "refine_workers": 1})
    shifted = _bad(proxy, vertices=proxy.vertices + [0, 0.01, 0], joints=proxy.joints + [0, 0.01, 0])
    with TestClient(create_app(one)) as http:
        first = http.post("/v1/bodies", content=_bad(proxy), headers={"Content-Type": NPZ})
        assert first.status_code == 201
        problem(http.post("/v1/bodies", content=shifted, headers={"Content-Type": NPZ}), 507, "DELETE")
    assert [p.name for p in tmp_path.glob("*.npz")] == [f"{first.json()['body_id']}.npz"]
    with TestClient(create_app(one)) as http:  # a restart with the same DRAPE_BODY_DIR keeps it
        assert http.get(f"/v1/bodies/{first.json()['body_id']}").status_code == 200
        assert http.delete(f"/v1/bodies/{first.json()['body_id']}").status_code == 204
    assert not list(tmp_path.glob("*.npz"))
    without = settings.model_copy(update={"refine_workers": 1})
    with TestClient(create_app(without)) as http:
        assert http.post("/v1/bodies", content=_bad(proxy), headers={"Content-Type": NPZ}).status_code == 201
    with TestClient(create_app(without)) as http:  # no DRAPE_BODY_DIR: gone after a restart
        problem(http.get(f"/v1/bodies/{first.json()['body_id']}"), 404)


def test_the_async_client_reads_a_preset_body_as_the_library_holds_it(server_url):
    async def go():
        async with drape.AsyncClient(server_url) as client:
            return await client.body("neutral")

    arrays, body = asyncio.run(go()), load_body("neutral")
    assert isinstance(arrays, drape.client.BodyArrays) and arrays.name == "neutral"
    np.testing.assert_allclose(arrays.vertices, body.vertices, atol=1e-6)
    np.testing.assert_array_equal(arrays.parents, body.parents)
    assert tuple(arrays.joint_names) == tuple(body.joint_names)


def test_the_client_registers_reads_and_deletes_a_body(server_url, proxy, shirt, tmp_path):
    path = tmp_path / "me.npz"
    path.write_bytes(_bad(proxy))
    with drape.Client(server_url) as client:
        reg = client.register_body(path)
        assert reg.body_id.startswith("body-") and reg.num_vertices == len(proxy.vertices)
        assert client.register_body({"vertices": proxy.vertices, "faces": proxy.faces, "weights": proxy.weights,
                                     "joints": proxy.joints}).body_id == reg.body_id
        arrays = client.body(reg.body_id)
        assert isinstance(arrays, drape.client.BodyArrays) and arrays.name == reg.body_id
        np.testing.assert_allclose(arrays.vertices, proxy.vertices, atol=1e-6)
        np.testing.assert_allclose(arrays.weights, proxy.weights, atol=1e-6)
        assert arrays.faces.shape == proxy.faces.shape and len(arrays.joint_names) == 24
        rig = client.rig(shirt, body=reg.body_id)
        np.testing.assert_allclose(rig.rest_joints, proxy.joints, atol=1e-6)
        frames = client.animate(outfit_id=rig.outfit_id, motion="walk", refine=True)
        assert np.isfinite(frames).all() and frames.shape[1] == len(shirt[0])
        client.delete_body(reg.body_id)  # registered twice: held until both are taken back
        assert client.body(reg.body_id).name == reg.body_id
        client.delete_body(reg.body_id)
        with pytest.raises(drape.DrapeAPIError) as err:
            client.rig(shirt, body=reg.body_id)
        assert err.value.status == 404


def _glb(body, names) -> bytes:
    from drape.schemas.gltf import Skeleton, SkinnedMesh, skinned_glb

    return skinned_glb(Skeleton(tuple(names), body.parents, body.joints),
                       [SkinnedMesh("body", body.vertices, body.faces, body.weights)])


def test_a_glb_body_registers_with_smpl_or_mapped_joint_names(http, proxy, shirt):
    fbx = [f"m_avg_{n[0].upper()}_{n.split('_', 1)[1].capitalize()}" if n.startswith(("left_", "right_"))
           else f"m_avg_{n.capitalize()}" for n in proxy.joint_names]
    r = http.post("/v1/bodies", files={"body_file": ("me.glb", _glb(proxy, fbx))})
    assert r.status_code == 201, r.text[:300]
    z = np.load(io.BytesIO(http.get(f"/v1/bodies/{r.json()['body_id']}", headers={"Accept": NPZ}).content))
    np.testing.assert_allclose(z["vertices"], proxy.vertices, atol=1e-5)
    np.testing.assert_allclose(z["joints"], proxy.joints, atol=1e-5)
    np.testing.assert_allclose(z["weights"], proxy.weights, atol=1e-4)
    v, f = shirt
    rig = http.post("/v1/outfits/rig", json={"vertices": v.tolist(), "faces": f.tolist(),
                                             "body": r.json()["body_id"]})
    assert rig.status_code == 200, rig.text[:300]
    # other names: refused without a joint_map (naming the missing joints), accepted with one
    bones = [f"bone{i}" for i in range(24)]
    problem(http.post("/v1/bodies", files={"body_file": ("me.glb", _glb(proxy, bones))}), 422, "body_file",
            "joint_map", "pelvis")
    mapped = http.post("/v1/bodies", files={"body_file": ("me.glb", _glb(proxy, bones))},
                       data={"joint_map": json.dumps(dict(zip(bones, proxy.joint_names, strict=True)))})
    assert mapped.status_code == 201 and mapped.json()["body_id"] == r.json()["body_id"], mapped.text[:300]
    assert mapped.json()["registrations"] == r.json()["registrations"] + 1  # the same body, registered again
    for _ in range(2):  # one DELETE a registration
        assert http.delete(f"/v1/bodies/{r.json()['body_id']}").status_code == 204


def test_the_client_animates_a_user_body_with_a_mocap_file(server_url, proxy, shirt, tmp_path):
    """A BVH path as the motion: uploaded as motion_file, retargeted by the server onto the outfit's body."""
    path = tmp_path / "walk.bvh"
    path.write_bytes(cmu_bvh(frames=20))
    with drape.Client(server_url) as client:
        me = client.register_body(_bad(proxy)).body_id
        rig = client.rig(shirt, body=me)
        frames = client.animate(outfit_id=rig.outfit_id, motion=path, refine=True)
        assert frames.shape[1:] == (len(shirt[0]), 3) and len(frames) >= 1 and np.isfinite(frames).all()
        again = client.animate(outfit=shirt, motion=path, body=me)  # an in-memory outfit is rigged first
        assert again.shape == frames.shape
        client.delete_body(me)


def test_the_command_line_fits_and_imports_onto_a_body_file(proxy, shirt, tmp_path, capsys):
    """`drape outfits fit --body me.glb` and `drape motions import --body me.npz` read the file as POST /v1/bodies
    does (the README's bring-your-own-data steps on the command line; both took presets only); a bad body file is
    one line naming --body and the problem."""
    from drape.cli import main
    from drape.geometry.mesh_io import save_mesh

    tall = {"vertices": proxy.vertices * 1.05, "faces": proxy.faces, "weights": proxy.weights,
            "joints": proxy.joints * 1.05}
    glb, body_npz = tmp_path / "me.glb", tmp_path / "me.npz"
    glb.write_bytes(_glb(dataclasses.replace(proxy, vertices=tall["vertices"], joints=tall["joints"]),
                         proxy.joint_names))
    body_npz.write_bytes(npz(**tall))
    mesh = tmp_path / "shirt.obj"
    save_mesh(mesh, *shirt)
    main(["outfits", "fit", str(mesh), "--body", str(glb), "--out", str(tmp_path / "fit.obj"),
          "--report", str(tmp_path / "fit.json")])
    assert json.loads((tmp_path / "fit.json").read_text())["report"]["inside_after"] <= 0.001
    bvh = tmp_path / "walk.bvh"
    bvh.write_bytes(cmu_bvh(frames=12))
    main(["motions", "import", str(bvh), "--body", str(body_npz), "--out", str(tmp_path / "walk.npz")])
    on_preset = tmp_path / "preset.npz"
    main(["motions", "import", str(bvh), "--out", str(on_preset)])
    with np.load(tmp_path / "walk.npz") as mine, np.load(on_preset) as preset:  # the floor step sees the taller legs
        assert mine["poses"].shape == preset["poses"].shape and not np.allclose(mine["trans"], preset["trans"])
    capsys.readouterr()
    bad = tmp_path / "bad.npz"
    bad.write_bytes(_bad(proxy, weights=proxy.weights * 2))
    with pytest.raises(SystemExit) as exc:
        main(["outfits", "fit", str(mesh), "--body", str(bad), "--out", str(tmp_path / "x.obj")])
    assert str(exc.value.code).startswith(f"drape: error: --body {bad}: weights: "), exc.value
    broken = tmp_path / "broken.glb"  # the GLB reader's errors named the upload's form field, body_file
    broken.write_bytes(b"glTF junk")
    with pytest.raises(SystemExit) as exc:
        main(["outfits", "fit", str(mesh), "--body", str(broken), "--out", str(tmp_path / "x.obj")])
    assert str(exc.value.code) == f"drape: error: --body {broken}: 9 bytes are too few for a GLB (a 12-byte " \
        "header and a chunk)", exc.value
    assert not (tmp_path / "x.obj").exists()
