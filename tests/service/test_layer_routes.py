"""The layer routes: GET /v1/layers, the layer templates in /v1/garments, POST /v1/layers/animate through the
client and the frame stream, bad inputs."""

import asyncio
import io
import json
import time

import httpx
import numpy as np
import pytest
from svc_env import assert_a_disconnect_stops_the_work, live_server, problem

import drape
from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.assets.outfits import split_outfit
from drape.geometry.layers import refine_layers
from drape.runtime.deepsd import pose_outfit
from drape.runtime.engine import Engine
from drape.runtime.layers import LayerCatalog
from drape.schemas.binary import FRAMES, NPZ, FrameDecoder, decode_npz

CLIP = load_clip("dance_b")
MOTION = {"poses": CLIP.poses[:40:8].reshape(5, 72), "translation": CLIP.trans[:40:8], "fps": 30.0}
MOTION_JSON = {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in MOTION.items()}


def test_layers_are_listed_and_their_templates_served(http):
    layers = http.get("/v1/layers").json()["layers"]
    assert [(x["inner"], x["outer"]) for x in layers] == [("tshirt", "jacket"), ("tanktop", "longsleeve")]
    served = LayerCatalog()  # what poses each layer: the networks where they ship and measured better
    for x in layers:
        c = served.find(x["inner"], x["outer"])
        assert (x["inner_model"], x["outer_model"], x["model"]) == (c.inner.model, c.outer.model, c.model)
        assert x["inner_model"] in ("mgn_inner", "deepsd") and x["outer_model"] in ("mgn_outer", "deepsd")
        models = {x["inner_model"], x["outer_model"]}
        assert x["model"] == ("deepsd" if models == {"deepsd"} else f"{x['inner_model']}+{x['outer_model']}")
        # an outer network serves the thicknesses it was trained on; DeePSD's rig the post step's range
        assert x["thickness"] == list(c.thickness) and x["body"] == "neutral"
        assert x["thickness"] == ([0.002, 0.02] if x["outer_model"] == "deepsd" else
                                  list(c.outer.network.manifest["config"]["thickness"]))
    (vi, fi), (vo, fo) = split_outfit("tshirt,jacket", 4000, seed=7)
    js = http.get("/v1/garments/jacket").json()
    assert np.allclose(js["vertices"], vo) and js["faces"] == fo.tolist() and js["body"] == "neutral"
    listed = {g["name"]: g for g in http.get("/v1/garments").json()["garments"]}
    assert listed["tshirt"]["num_vertices"] == len(vi) and listed["tshirt"]["models"] == [served.template("tshirt").model]
    assert listed["jacket"]["models"] == [served.template("jacket").model]
    problem(http.post("/v1/garments/jacket/encode", json={"vertices": [[0, 0, 0]], "frame": 0,
                                                          "motion": {"clip": "kick"}}), 404, "layer template")


def test_models_lists_the_served_layer_networks(http):
    """GET /v1/models named DeePSD and the intrinsic spaces but not the layer networks /v1/layers/animate runs:
    each served one is listed ('mgn_inner-<inner>', 'mgn_outer-<inner>_<outer>') with its manifest's version
    and ONNX files, and GET /v1/models/{name} answers it."""
    listed = {m["name"]: m for m in http.get("/v1/models").json()["models"]}
    served = LayerCatalog()
    expected = {}
    for c in served.combinations():
        if c.inner.network is not None:
            expected[f"mgn_inner-{c.inner.name}"] = c.inner.network
        if c.outer.network is not None:
            expected[f"mgn_outer-{c.inner.name}_{c.outer.name}"] = c.outer.network
    assert expected, "no layer network is served"
    assert {n for n in listed if n.startswith("mgn_")} == set(expected)
    for name, network in expected.items():
        info = http.get(f"/v1/models/{name}").json()
        assert info == listed[name] and info["version"] == network.manifest["version"]
        onnx = {k: f for k, f in network.manifest["files"].items() if f["file"].endswith(".onnx")}
        assert set(info["files"]) == set(onnx) and info["trained"] is True
        assert all(info["files"][k]["sha256"] == f["sha256"] for k, f in onnx.items())


def test_animate_layers_through_the_client(server_url):
    """Both layers' frames from the client (sync and async), the refined ones equal to the library's post step on
    the unrefined ones; GLB and PC2 of the two as one mesh; the frame stream names the layer ranges."""
    with drape.Client(server_url) as client:
        assert [x.outer for x in client.layers().layers] == ["jacket", "longsleeve"]
        raw = client.animate_layers(inner="tshirt", outer="jacket", motion=MOTION, thickness=0.004)
        fixed = client.animate_layers(inner="tshirt", outer="jacket", motion=MOTION, thickness=0.004, refine=True)
        pc2 = client.animate_layers(inner="tshirt", outer="jacket", motion=MOTION, format="pc2")
    (vi, fi), (vo, fo) = split_outfit("tshirt,jacket", 4000, seed=7)
    assert raw.inner_vertices.shape == (5, len(vi), 3) and raw.outer_vertices.shape == (5, len(vo), 3)
    assert np.array_equal(raw.inner_faces, fi) and np.array_equal(fixed.outer_faces, fo) and raw.fps == 30.0
    body = load_body("neutral")
    posed = body.pose(MOTION["poses"].reshape(-1, 24, 3).astype(float), MOTION["translation"].astype(float))
    net = LayerCatalog().find("tshirt", "jacket").inner.network
    if net is not None:  # the shipped inner network poses the inner layer: its stream is that network's
        ref = pose_outfit(vi, net.rig, net.pose_keys(MOTION["poses"]), body.joints, MOTION["poses"],
                          MOTION["translation"])
        assert np.abs(raw.inner_vertices - ref).max() < 1e-5
    top = LayerCatalog().find("tshirt", "jacket").outer.network
    if top is not None:  # the shipped outer network poses the outer layer, reading the inner network and H_in
        poses = MOTION["poses"].reshape(-1, 24, 3)
        keys = top.pose_keys(poses, MOTION["translation"], 30.0, 0.004, net.pose_keys(poses), body.joints)
        ref = pose_outfit(vo, top.rig, keys, body.joints, poses, MOTION["translation"])
        assert np.abs(raw.outer_vertices - ref).max() < 1e-5
    ri, ro, report = refine_layers(raw.inner_vertices, fi, raw.outer_vertices, fo, posed, body.faces, thickness=0.004)
    assert np.abs(fixed.inner_vertices - ri).max() < 1e-5 and np.abs(fixed.outer_vertices - ro).max() < 1e-5
    assert sum(report.outer_in_inner_after) < sum(report.outer_in_inner_before)
    assert pc2[:12] == b"POINTCACHE2\0" and len(pc2) == 32 + 5 * (len(vi) + len(vo)) * 12

    async def go():
        async with drape.AsyncClient(server_url) as client:
            listed = await client.layers()
            return listed, await client.animate_layers(inner="tshirt", outer="jacket", motion=MOTION, thickness=0.004)

    listed, frames = asyncio.run(go())
    assert [(x.inner, x.outer) for x in listed.layers] == [("tshirt", "jacket"), ("tanktop", "longsleeve")]
    assert np.array_equal(frames.outer_vertices, raw.outer_vertices)


def test_the_frame_stream_names_the_layer_ranges(http):
    body = {"inner": "tanktop", "outer": "longsleeve", "motion": {"clip": "kick"}}
    r = http.post("/v1/layers/animate", json=body, headers={"accept": FRAMES})
    assert r.status_code == 200
    dec = FrameDecoder()
    frames = np.stack(list(dec.feed(r.content)))
    ranges = dec.header["layers"]
    assert [x["name"] for x in ranges] == ["tanktop", "longsleeve"] and ranges[1]["stop"] == frames.shape[1]
    js = http.post("/v1/layers/animate", json=body).json()
    assert np.allclose(frames[:, : ranges[0]["stop"]], js["inner_vertices"], atol=1e-6)
    assert np.allclose(frames[:, ranges[1]["start"]:], js["outer_vertices"], atol=1e-6)


def test_drape_export_reads_a_saved_layers_answer_as_the_service_writes_its_files(http, tmp_path):
    """`drape export pc2|glb` of a saved layers npz answer refused it ('an npz stream needs vertices'); it is read
    as the one mesh the service's own files hold, inner layer first: the PC2 and the GLB are the service's, byte
    for byte."""
    from drape import cli

    body = {"inner": "tanktop", "outer": "longsleeve", "motion": MOTION_JSON}
    answer = http.post("/v1/layers/animate", json=body, headers={"accept": NPZ})
    (tmp_path / "layers.npz").write_bytes(answer.content)
    for fmt, accept in (("pc2", "application/x-pc2"), ("glb", "model/gltf-binary")):
        served = http.post("/v1/layers/animate", json=body, headers={"accept": accept})
        assert answer.status_code == served.status_code == 200
        cli.main(["export", fmt, str(tmp_path / "layers.npz"), "--out", str(tmp_path / f"layers.{fmt}")])
        assert (tmp_path / f"layers.{fmt}").read_bytes() == served.content, fmt


@pytest.mark.parametrize("accept", [NPZ, "application/json"])
def test_a_layers_answer_streams_and_stops_when_the_client_goes_away(settings, monkeypatch, accept):
    """The npz and JSON answers are written as the frames are computed, as animate's are: the first bytes come
    after the first chunk (not after every frame), and a client that goes away stops the work within a chunk and
    gives the computing slot back (they were made whole first: every frame computed, the slot held, whoever
    waited; past DRAPE_REQUEST_BUDGET_S too)."""
    made = []
    layer_chunks = Engine.layer_chunks

    def slow(self, *args, **kwargs):
        for pair in layer_chunks(self, *args, **kwargs):
            time.sleep(0.15)
            made.append(len(pair[0]))
            yield pair

    monkeypatch.setattr(Engine, "layer_chunks", slow)
    small = settings.model_copy(update={"stream_chunk_frames": 4, "refine_workers": 1})
    body = {"inner": "tanktop", "outer": "longsleeve", "motion": {"poses": np.zeros((48, 72)).tolist()}}
    with live_server(small) as url:
        whole = httpx.post(f"{url}/v1/layers/animate", json={**body, "motion": {"poses": [[0.0] * 72] * 6}},
                           headers={"accept": accept}, timeout=60)
        assert whole.status_code == 200 and whole.headers["content-type"].startswith(accept)
        got = decode_npz(whole.content) if accept == NPZ else whole.json()
        assert np.shape(got["inner_vertices"])[:2] == (6, 1466) and np.shape(got["outer_vertices"])[:2] == (6, 2546)
        assert np.array_equal(got["outer_faces"], LayerCatalog().template("longsleeve").faces)
        assert_a_disconnect_stops_the_work(url, "/v1/layers/animate", body, accept, made)  # 12 chunks asked


def test_layers_bad_inputs(http):
    ok = {"inner": "tshirt", "outer": "jacket", "motion": {"clip": "kick"}}

    def post(**change):
        return http.post("/v1/layers/animate", json={**ok, **change})

    problem(post(inner="cardigan"), 404, "cardigan", "tshirt")
    problem(post(inner="tanktop"), 422, "tanktop", "not served")
    problem(post(thickness=0.5), 422, "thickness", str(LayerCatalog().find("tshirt", "jacket").thickness[1]))
    just_over = LayerCatalog().find("tshirt", "jacket").thickness[1] + 1e-9  # said "0.012 m is outside [.., 0.012]"
    problem(post(thickness=just_over), 422, f"{just_over!r} m is outside")
    problem(post(motion={"poses": [[0.0] * 72] * 201}), 413, "frames")
    nan = json.dumps({**ok, "motion": {"poses": [[float("nan")] * 72]}})  # NaN literals: not JSON
    problem(http.post("/v1/layers/animate", content=nan, headers={"content-type": "application/json"}), 422,
            "motion", "NaN")
    problem(post(refine={"eps": -1.0}), 422, "eps")
    problem(post(colour="red"), 422, "colour")
    problem(http.post("/v1/layers/animate", content=b"x", headers={"content-type": "application/x-npz"}), 415)
    # the outer network reads the motion at 30 fps: a slow motion is many frames there (and at 1e-300 fps, whose
    # glTF key times would overflow float32, infinitely many): a 413 naming the frame rate, not a 500
    slow = {**ok, "motion": {"poses": [[0.0] * 72] * 2, "fps": 1e-300}}
    for accept in ("model/gltf-binary", "application/json"):
        problem(http.post("/v1/layers/animate", json=slow, headers={"accept": accept}), 413, "motion.fps",
                "reads at 30 fps")
    # 2 frames at 0.15 fps span 6.67 s: 201 frames at 30 fps, one over this server's limit; at 0.16 fps they fit
    problem(post(motion={"poses": [[0.0] * 72] * 2, "fps": 0.15}), 413, "motion.fps", "limit of 200")
    assert post(motion={"poses": [[0.0] * 72] * 2, "fps": 0.16}).status_code == 200


def test_a_motion_file_animates_the_layers_as_its_imported_poses_would(server_url, tmp_path):
    """A BVH upload (multipart motion_file + the rest of the request as JSON text in `request`) is the clip the
    importer makes of it on the combination's body: both layers equal the JSON request with those poses; through
    the client's Path too."""
    from drape.assets.motion import import_motion
    from tests.cmu_bvh import cmu_bvh

    bvh = tmp_path / "jump.bvh"
    bvh.write_bytes(cmu_bvh(frames=24, fps=120.0))  # 6 frames at 30 fps
    clip = import_motion(bvh.read_bytes(), load_body("neutral"), fps=30.0, name="jump").motion
    fields = {"inner": "tshirt", "outer": "jacket", "thickness": 0.005}
    with drape.Client(server_url) as client:
        uploaded = client.animate_layers(motion=bvh, **fields)
        sent = client.animate_layers(motion={"poses": clip.poses, "translation": clip.trans, "fps": 30.0}, **fields)
        glb = client.animate_layers(motion=bvh, format="glb", **fields)
    assert uploaded.inner_vertices.shape[0] == clip.num_frames == 6
    assert np.abs(uploaded.inner_vertices - sent.inner_vertices).max() < 1e-5
    assert np.abs(uploaded.outer_vertices - sent.outer_vertices).max() < 1e-5
    assert glb[:4] == b"glTF"


def test_layers_motion_file_bad_inputs(http, tmp_path):
    from tests.cmu_bvh import cmu_bvh

    bvh = cmu_bvh(frames=8, fps=30.0)
    ok = {"inner": "tshirt", "outer": "jacket"}
    ok_text = json.dumps(ok)

    def post(request=ok_text, files=None, **data):
        form = {"request": request, **data} if request is not None else data
        return http.post("/v1/layers/animate", data=form,
                         files=files if files is not None else {"motion_file": ("a.bvh", bvh)})

    assert post().status_code == 200
    # the smallest positive fps resamples the file to its first frame (not NaN poses and a 500)
    slow = post(fps="5e-324")
    assert slow.status_code == 200, slow.text[:300]
    assert len(slow.json()["inner_vertices"]) == 1
    problem(post(files={"other": ("a.bvh", bvh)}), 422, "other")  # an unknown field, named
    problem(post(files={"request": (None, json.dumps(ok))}, request=None), 422, "motion_file")
    problem(post(request=None), 422, "request")
    problem(post(request=json.dumps({**ok, "inner": "cardigan"})), 404, "cardigan")  # before the file is read
    problem(post(request=json.dumps({**ok, "motion": {"clip": "kick"}})), 422, "motion")  # the file is the motion
    problem(post(files={"motion_file": ("a.bvh", b"HIERARCHY nonsense")}), 422, "motion_file")
    # an npz's frame rate below a BVH's 0.1 fps: 30 fps of it overflowed the frame count (a 500)
    slow = io.BytesIO()
    np.savez(slow, poses=np.zeros((5, 72)), mocap_framerate=np.array(1e-320))
    problem(post(files={"motion_file": ("a.npz", slow.getvalue())}), 422, "motion_file", "mocap_framerate", "0.1")
    problem(post(request="{not json"), 400, "request: not valid JSON")
    problem(post(request="[1, 2]"), 422, "request: expected a JSON object")
