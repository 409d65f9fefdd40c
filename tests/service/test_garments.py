"""The garment routes (intrinsic garment space) on the session's small random-init model: through the real
client (sync and async) on a real server the answers equal the library's, a keyframe given as vertices equals
its encoded latent, every answer format agrees, refinement pushes the garment out of the body, the routes take
a computing slot, and every bad input is a 4xx problem naming its field."""

import asyncio
import io
import json
import sys
from pathlib import Path

import numpy as np
import pytest

import drape
from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.geometry.metrics import collision_share
from drape.runtime.intrinsic import IntrinsicGarment
from drape.runtime.layers import LayerCatalog
from drape.schemas.binary import NPZ, decode_npz, encode_npz
from drape.schemas.gltf import GLB
from drape.schemas.pc2 import read_pc2
from drape.service.admission import Admission
from drape.service.uploads import motion_from_file
from tests.cmu_bvh import cmu_bvh
from tests.intrinsic_model import NAME, intrinsic_model

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "schemas"))
from glb_player import GlbPlayer  # noqa: E402
from gltf_validator import validate  # noqa: E402
from svc_env import problem

ROUTES = ["encode", "animate", "sample"]




@pytest.fixture(scope="module")
def garment():
    return IntrinsicGarment(intrinsic_model().path)


@pytest.fixture(scope="module")
def motion():
    """40 frames of a clip as the client sends a motion: poses (T, 72), translation (T, 3), fps."""
    clip = load_clip("dance_a")
    return {"poses": clip.poses[:40].reshape(40, 72).astype(np.float64),
            "translation": clip.trans[:40].astype(np.float64), "fps": 30.0}


@pytest.fixture(scope="module")
def shape(garment, motion):
    """A keyframe shape at frame 12 of the motion, world space: a sampled design, perturbed."""
    _, shapes = garment.sample(1, 3, 12, motion["poses"], motion["translation"])
    return shapes[0] + np.random.default_rng(1).normal(scale=0.002, size=shapes[0].shape).astype(np.float32)


def json_motion(motion):
    return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in motion.items()}


def test_list_and_template(server_url, http, garment):
    with drape.Client(server_url) as client:
        listed = client.garments().garments
        tpl = client.garment(NAME)
        with pytest.raises(drape.DrapeAPIError) as info:
            client.garment("no such skirt")
    assert [g.model_dump() for g in listed if g.models == ["intrinsic"]] == [garment.info()]
    layers = {t.name: [t.model] for t in LayerCatalog().templates()}  # the layer network where one serves
    assert {g.name: g.models for g in listed if g.name in layers} == layers
    assert set(layers) == {"tshirt", "jacket", "tanktop", "longsleeve"} and layers["longsleeve"] == ["mgn_outer"]
    assert all(m in (["mgn_inner"], ["mgn_outer"], ["deepsd"]) for m in layers.values())
    assert listed[0].latent_size == 100 and listed[0].window == 8 and listed[0].models == ["intrinsic"]
    assert (tpl.name, tpl.body) == (NAME, "neutral")
    assert np.array_equal(tpl.vertices, intrinsic_model().vertices) and np.array_equal(tpl.faces, garment.faces)
    assert info.value.status == 404 and "no such skirt" in info.value.detail and NAME in info.value.detail
    js = http.get(f"/v1/garments/{NAME}").json()
    assert np.array_equal(np.asarray(js["vertices"], np.float32), tpl.vertices) and js["faces"] == tpl.faces.tolist()
    problem(http.get(f"/v1/garments/{NAME}", headers={"accept": "text/csv"}), 406, "Accept")


def test_models_lists_each_intrinsic_space(http, garment):
    """/v1/models names each garment's intrinsic space; a random-init test model says it is not trained."""
    info = http.get(f"/v1/models/intrinsic-{NAME}").json()
    assert info["trained"] is False and info["version"] == garment.version
    assert set(info["files"]) == {"encode", "decode", "shape_encode", "shape_decode"}
    assert info["files"]["decode"]["sha256"] == garment.manifest["files"]["decode"]["sha256"]
    assert info["files"]["decode"]["inputs"][0]["shape"][0] == -1
    assert f"intrinsic-{NAME}" in [m["name"] for m in http.get("/v1/models").json()["models"]]


def test_a_keyframe_as_vertices_equals_its_encoded_latent(server_url, garment, motion, shape):
    with drape.Client(server_url) as client:
        z = client.encode_keyframe(NAME, vertices=shape, motion=motion, frame=12)
        by_vertices = client.animate_keyframes(NAME, motion=motion, keyframes=[{"frame": 12, "vertices": shape}],
                                               match_keyframes=False)
        by_latent = client.animate_keyframes(NAME, motion=motion, keyframes=[(12, z)])
        matched = client.animate_keyframes(NAME, motion=motion, keyframes=[{"frame": 12, "vertices": shape}])
    assert z.shape == (100,) and z.dtype == np.float32
    assert np.abs(z - garment.encode(shape, motion["poses"], motion["translation"], 12)).max() <= 1e-6
    assert by_vertices.shape == (40, garment.num_vertices, 3) and by_vertices.dtype == np.float32
    assert np.abs(by_vertices - by_latent).max() <= 1e-6
    # by default the stream meets the shape keyframe (the random model's decoding does not)
    assert np.abs(matched[12] - shape).max() <= 1e-5 < np.abs(by_vertices[12] - shape).max()
    library = garment.keyframed(shape[None], [12], motion["poses"], motion["translation"], motion["fps"])
    assert np.abs(matched - library).max() <= 1e-5
    ref = garment.decode(np.tile(z, (40, 1)), motion["poses"], motion["translation"])
    assert np.abs(by_latent - ref).max() <= 1e-5
    # one keyframe reproduces its own shape only roughly (the model is random), but drives every frame
    assert np.abs(by_latent[12] - by_latent[30]).max() > 1e-3


def test_every_route_reads_the_motion_at_its_fps(server_url, garment, motion, shape):
    """encode, animate and sample read the motion window over the model's seconds at the motion's fps (the same
    poses labelled 24 or 60 fps answered the same vertices: the window was read frame by frame)."""
    at60 = {**motion, "fps": 60.0}
    z0 = garment.latent_mean.astype(np.float32)
    with drape.Client(server_url) as client:
        frames = client.animate_keyframes(NAME, motion=at60, keyframes=[{"frame": 0, "latent": z0}])
        latent = client.encode_keyframe(NAME, vertices=shape, motion=at60, frame=12)
        designs = client.sample_designs(NAME, count=1, seed=3, motion=at60, frame=12)
    library = garment.decode(np.tile(z0, (40, 1)), motion["poses"], motion["translation"], fps=60.0)
    assert np.abs(frames - library).max() <= 1e-5
    assert np.abs(frames - garment.decode(np.tile(z0, (40, 1)), motion["poses"], motion["translation"])).max() > 1e-3
    assert np.abs(latent - garment.encode(shape, motion["poses"], motion["translation"], 12, fps=60.0)).max() <= 1e-6
    _, shapes = garment.sample(1, 3, 12, motion["poses"], motion["translation"], fps=60.0)
    assert np.abs(designs.vertices - shapes).max() <= 1e-5


def test_every_answer_format_agrees(server_url, http, garment, motion, shape):
    z0 = garment.latent_mean.astype(np.float32)
    keyframes = [{"frame": 30, "latent": z0}, {"frame": 12, "vertices": shape}]
    with drape.Client(server_url) as client:
        frames = client.animate_keyframes(NAME, motion=motion, keyframes=keyframes)
        pc2 = client.animate_keyframes(NAME, motion=motion, keyframes=keyframes, format="pc2")
        glb = client.animate_keyframes(NAME, motion=motion, keyframes=keyframes, format="glb")
    npz_body = encode_npz({**{k: np.asarray(v) for k, v in motion.items()}, "vertex_frames": np.array([12]),
                           "vertices": shape[None], "latent_frames": np.array([30]), "latents": z0[None]})
    npz = decode_npz(http.post(f"/v1/garments/{NAME}/animate", content=npz_body,
                               headers={"content-type": NPZ, "accept": NPZ}).content)
    js = http.post(f"/v1/garments/{NAME}/animate", json={
        "motion": json_motion(motion), "keyframes": [{"frame": 12, "vertices": shape.tolist()},
                                                     {"frame": 30, "latent": z0.tolist()}]}).json()
    assert np.array_equal(npz["vertices"], frames) and np.array_equal(npz["faces"], garment.faces)
    assert np.array_equal(np.asarray(js["vertices"], np.float32), frames) and js["fps"] == 30.0
    assert np.array_equal(read_pc2(pc2)[0], frames)
    report = validate(glb)
    assert report["errors"] == 0, report["messages"]
    player = GlbPlayer(glb)
    for t in (0, 21, 39):
        assert np.abs(player.positions(NAME, t) - frames[t]).max() < 1e-5
    # the latents are interpolated: frame 21 is decoded from the mean of the two keyframes' latents, plus the
    # shape keyframe's residual faded; the latent keyframe's frame is its latent decoded, no residual
    poses, trans = motion["poses"], motion["translation"]
    z12 = garment.encode(shape, poses, trans, 12)
    latents = garment.interpolate([(12, z12), (30, z0)], 40)
    assert np.allclose(latents[21], (z12 + z0) / 2, atol=1e-6)
    residual = garment.keyframe_residual(shape[None], [12], [30], latents, garment.motion_frames(poses, trans), 30.0)
    assert np.abs(frames - garment.decode(latents, poses, trans, residual=residual)).max() <= 1e-5
    assert np.abs(frames[30] - garment.decode(latents, poses, trans)[30]).max() <= 1e-5
    assert np.abs(frames[12] - shape).max() <= 1e-5
    plain_npz = encode_npz({**{k: np.asarray(v) for k, v in motion.items()}, "vertex_frames": np.array([12]),
                            "vertices": shape[None], "latent_frames": np.array([30]), "latents": z0[None],
                            "match_keyframes": np.array(False)})
    plain = decode_npz(http.post(f"/v1/garments/{NAME}/animate", content=plain_npz,
                                 headers={"content-type": NPZ, "accept": NPZ}).content)["vertices"]
    plain_js = http.post(f"/v1/garments/{NAME}/animate", json={
        "motion": json_motion(motion), "match_keyframes": False,
        "keyframes": [{"frame": 12, "vertices": shape.tolist()}, {"frame": 30, "latent": z0.tolist()}]}).json()
    assert np.abs(plain - garment.decode(latents, poses, trans)).max() <= 1e-5
    assert np.array_equal(np.asarray(plain_js["vertices"], np.float32), plain)


def test_refinement_pushes_the_garment_out_of_its_body(server_url, garment, motion):
    body = load_body("neutral")
    keyframes = [{"frame": 0, "latent": garment.latent_mean}]
    with drape.Client(server_url) as client:
        raw = client.animate_keyframes(NAME, motion=motion, keyframes=keyframes)
        refined = client.animate_keyframes(NAME, motion=motion, keyframes=keyframes, refine=True)
    assert refined.shape == raw.shape
    every = slice(0, 40, 8)
    bodies = body.pose(motion["poses"][every].reshape(-1, 24, 3), motion["translation"][every])
    before = collision_share(raw[every], bodies, body.faces)
    after = collision_share(refined[every], bodies, body.faces)
    print(f"inside the body: {before:.2%} unrefined, {after:.2%} refined")
    assert before > 0.01 and after < before / 4, (before, after)


def test_sample_designs(server_url, http, garment, motion):
    with drape.Client(server_url) as client:
        samples = client.sample_designs(NAME, count=3, seed=5, motion=motion, frame=7)
        again = client.sample_designs(NAME, count=3, seed=5, motion=motion, frame=7)
    latents, shapes = garment.sample(3, 5, 7, motion["poses"], motion["translation"])
    assert np.array_equal(samples.latents, latents) and np.abs(samples.vertices - shapes).max() <= 1e-6
    assert np.array_equal(again.vertices, samples.vertices)
    js = http.post(f"/v1/garments/{NAME}/sample", json={"count": 3, "seed": 5, "motion": json_motion(motion),
                                                         "frame": 7}).json()
    assert np.array_equal(np.asarray(js["latents"], np.float32), samples.latents)
    assert np.array_equal(np.asarray(js["vertices"], np.float32), samples.vertices)


def test_async_client(server_url, garment, motion, shape):
    async def go():
        async with drape.AsyncClient(server_url) as client:
            listed = await client.garments()
            tpl = await client.garment(NAME)
            z = await client.encode_keyframe(NAME, vertices=shape, motion=motion, frame=12)
            frames = await client.animate_keyframes(NAME, motion=motion, keyframes=[(12, shape)],
                                                    match_keyframes=False)
            matched = await client.animate_keyframes(NAME, motion=motion, keyframes=[(12, shape)])
            pc2 = await client.animate_keyframes(NAME, motion=motion, keyframes=[(12, z)], format="pc2")
            samples = await client.sample_designs(NAME, count=2, seed=1, motion="kick", frame=3)
            return listed, tpl, z, frames, matched, pc2, samples

    listed, tpl, z, frames, matched, pc2, samples = asyncio.run(go())
    assert listed.garments[0].name == NAME and tpl.vertices.shape == (garment.num_vertices, 3)
    assert np.abs(z - garment.encode(shape, motion["poses"], motion["translation"], 12)).max() <= 1e-6
    assert np.abs(read_pc2(pc2)[0] - frames).max() <= 1e-6
    assert np.abs(matched[12] - shape).max() <= 1e-5
    assert samples.latents.shape == (2, 100) and samples.vertices.shape == (2, garment.num_vertices, 3)


def test_a_motion_file_upload(http, garment, shape):
    """A multipart form: the motion as a BVH (motion_file), the rest of the request as JSON text (request)."""
    bvh = cmu_bvh(60)
    poses, trans, _ = motion_from_file(bvh, "neutral", fps=30.0, up=None, max_frames=200,
                                       max_decoded_bytes=2**26)
    frame = len(poses) - 1
    shape = garment.sample(1, 3, frame, poses, trans)[1][0]  # the garment where the file's body is at that frame
    r = http.post(f"/v1/garments/{NAME}/encode", files={"motion_file": ("clip.bvh", bvh)},
                  data={"request": json.dumps({"vertices": shape.tolist(), "frame": frame})})
    assert r.status_code == 200, r.text[:300]
    assert np.abs(np.asarray(r.json()["latent"]) - garment.encode(shape, poses, trans, frame)).max() <= 1e-6
    r = http.post(f"/v1/garments/{NAME}/animate", headers={"accept": NPZ}, files={"motion_file": ("c.bvh", bvh)},
                  data={"request": json.dumps({"keyframes": [{"frame": 0, "latent": [0.1] * 100}]})})
    assert r.status_code == 200 and decode_npz(r.content)["vertices"].shape == (len(poses), garment.num_vertices, 3)
    r = http.post(f"/v1/garments/{NAME}/animate", headers={"accept": NPZ}, files={"motion_file": ("c.bvh", bvh)},
                  data={"fps": "5e-324", "request": json.dumps({"keyframes": [{"frame": 0, "latent": [0.1] * 100}]})})
    assert r.status_code == 200, r.text[:300]  # the smallest positive fps: the file's first frame, not NaN poses
    assert decode_npz(r.content)["vertices"].shape == (1, garment.num_vertices, 3)
    problem(http.post(f"/v1/garments/{NAME}/sample", files={"motion_file": ("c.bvh", bvh)},
                      data={"request": json.dumps({"count": 0})}), 422, "count")
    problem(http.post(f"/v1/garments/{NAME}/sample", files={"motion_file": ("c.bvh", b"junk")},
                      data={"request": json.dumps({"count": 1})}), 422, "motion_file")
    problem(http.post(f"/v1/garments/{NAME}/sample", files={"motion_file": ("c.bvh", bvh)},
                      data={"request": "[1]"}), 422, "request: expected a JSON object")


def test_the_client_sends_a_motion_file_path(server_url, garment, shape, tmp_path):
    """Client.encode_keyframe / animate_keyframes / sample_designs with motion=Path: the file uploaded (multipart),
    the answers those of the imported poses sent as arrays."""
    path = tmp_path / "clip.bvh"
    path.write_bytes(cmu_bvh(60))
    poses, trans, _ = motion_from_file(path.read_bytes(), "neutral", fps=30.0, up=None, max_frames=200,
                                       max_decoded_bytes=2**26)
    arrays = {"poses": poses, "trans": trans, "fps": 30.0}
    shape = garment.sample(1, 3, 2, poses, trans)[1][0]  # the garment where the file's body is at frames 2-3
    keyframes = [{"frame": 2, "vertices": shape}, {"frame": 10, "latent": np.full(100, 0.1, np.float32)}]
    with drape.Client(server_url) as client:
        z = client.encode_keyframe(NAME, vertices=shape, motion=path, frame=3)
        assert np.abs(z - client.encode_keyframe(NAME, vertices=shape, motion=arrays, frame=3)).max() <= 1e-6
        frames = client.animate_keyframes(NAME, motion=path, keyframes=keyframes, refine=True)
        same = client.animate_keyframes(NAME, motion=arrays, keyframes=keyframes, refine=True)
        assert frames.shape == (len(poses), garment.num_vertices, 3) and np.abs(frames - same).max() <= 1e-5
        designs = client.sample_designs(NAME, count=2, seed=4, motion=path, frame=5)
        again = client.sample_designs(NAME, count=2, seed=4, motion=arrays, frame=5)
        assert np.array_equal(designs.latents, again.latents)
        assert np.abs(designs.vertices - again.vertices).max() <= 1e-5


def test_the_client_names_keyframes_as_its_caller_wrote_them(server_url, garment, motion, shape, tmp_path):
    """The client sends keyframes as npz members (latent_frames[j], vertices[j], ...) or, with a motion file, as a
    JSON list with the shapes first; the service's errors named those, which the caller never wrote (a probe got
    `latent_frames[1]` for its keyframes[1]). The errors name the caller's keyframes[i] now."""
    z = np.zeros(100, np.float32)
    path = tmp_path / "clip.bvh"
    path.write_bytes(cmu_bvh(60))
    poses, trans, _ = motion_from_file(path.read_bytes(), "neutral", fps=30.0, up=None, max_frames=200,
                                       max_decoded_bytes=2**26)
    on_file = garment.sample(1, 3, 12, poses, trans)[1][0]  # a shape on the file's body at frame 12
    with drape.Client(server_url) as client:
        for m, key_shape in ((motion, shape), (path, on_file)):
            # keyframes[2] (a latent) on keyframes[0]'s frame; the shape keyframe [1] comes first in the request
            bad = [{"frame": 5, "latent": z}, {"frame": 12, "vertices": key_shape}, {"frame": 5, "latent": z}]
            with pytest.raises(drape.DrapeAPIError) as info:
                client.animate_keyframes(NAME, motion=m, keyframes=bad)
            assert info.value.status == 422 and info.value.field == "keyframes[2].frame", info.value
            assert "frame 5 is also the frame of keyframes[0].frame" in info.value.detail, info.value.detail
            with pytest.raises(drape.DrapeAPIError) as info:
                client.animate_keyframes(NAME, motion=m, keyframes=[{"frame": 2, "latent": z},
                                                                    {"frame": 100000, "latent": z}])
            assert info.value.field == "keyframes[1].frame", info.value
            with pytest.raises(drape.DrapeAPIError) as info:
                client.animate_keyframes(NAME, motion=m, keyframes=[(3, np.zeros(7, np.float32)), (12, key_shape)])
            assert info.value.field == "keyframes[0].latent", info.value


def test_the_routes_take_a_computing_slot(app, http, motion):
    """With no computing slot free, every POST route answers 503 + Retry-After; the GET routes still answer."""
    admission = app.state.admission
    app.state.admission = Admission(0, 0, 1.0, 9)
    try:
        for route in ROUTES:
            r = http.post(f"/v1/garments/{NAME}/{route}", json={"motion": {"clip": "kick"}})
            problem(r, 503, "retry")
            assert r.headers["retry-after"] == "9"
        assert http.get(f"/v1/garments/{NAME}").status_code == 200 and http.get("/v1/garments").status_code == 200
    finally:
        app.state.admission = admission


def test_bad_inputs_name_their_field(http, garment, shape):
    N = garment.num_vertices
    z = [0.0] * 100
    kick = {"clip": "kick"}  # 47 frames
    v = shape.tolist()

    def post(route, **body):
        return http.post(f"/v1/garments/{NAME}/{route}", json=body)

    # unknown garment: a 404 naming it and listing the served ones, on every route
    for route in ROUTES:
        problem(http.post(f"/v1/garments/nope/{route}", json={"motion": kick}), 404, "name", "'nope'", NAME)
    problem(http.get("/v1/garments/nope"), 404, "name", NAME, "tshirt", "longsleeve")  # the layer templates too
    # wrong vertex count
    problem(post("encode", vertices=v[:-1], motion=kick, frame=0), 422, "vertices", f"({N}, 3)", f"({N - 1}, 3)")
    problem(post("animate", motion=kick, keyframes=[{"frame": 0, "vertices": v[:10]}]), 422,
            "keyframes[0].vertices", f"({N}, 3)")
    problem(post("encode", vertices=[[0.0, 0.0]] * N, motion=kick, frame=0), 422, "vertices")
    # frame out of the motion's range
    problem(post("encode", vertices=v, motion=kick, frame=47), 422, "frame", "47 frames")
    problem(post("encode", vertices=v, motion=kick, frame=-1), 422, "frame")
    problem(post("animate", motion=kick, keyframes=[{"frame": 3, "latent": z}, {"frame": 99, "latent": z}]), 422,
            "keyframes[1].frame", "99")
    problem(post("sample", count=2, motion=kick, frame=100), 422, "frame", "47 frames")
    # latent of the wrong size
    problem(post("animate", motion=kick, keyframes=[{"frame": 0, "latent": z[:7]}]), 422, "keyframes[0].latent",
            "100 values", "got 7")
    # NaN / inf
    nan_latent = '{"motion": {"clip": "kick"}, "keyframes": [{"frame": 0, "latent": [NaN' + ", 0" * 99 + "]}]}"
    problem(http.post(f"/v1/garments/{NAME}/animate", content=nan_latent.encode(),
                      headers={"content-type": "application/json"}), 422, "keyframes[0].latent", "NaN")
    inf_vertices = json.dumps({"vertices": v, "motion": kick, "frame": 0}).replace(str(v[5][1]), "Infinity", 1)
    problem(http.post(f"/v1/garments/{NAME}/encode", content=inf_vertices.encode(),
                      headers={"content-type": "application/json"}), 422, "vertices", "NaN or infinite")
    problem(post("animate", motion=kick, keyframes=[{"frame": 0, "latent": [1e9] * 100}]), 422, "keyframes[0].latent")
    # a shape that is not the garment in world space at its frame: 99 m off (it encoded to a junk latent, 200),
    # 10 km off, collapsed to one point or blown up: refused naming the shape
    for bad, words in (((shape + [99.0, 0, 0]).tolist(), ("centre lies", "world space")),
                       ((shape + 1e4).tolist(), ("centre lies",)),
                       (np.repeat(shape.mean(0, keepdims=True), len(shape), 0).tolist(), ("spreads 0.00x",)),
                       ((shape.mean(0) + 5 * (shape - shape.mean(0))).tolist(), ("not this garment",))):
        problem(post("encode", vertices=bad, motion=kick, frame=0), 422, "vertices", *words)
        problem(post("animate", motion=kick, keyframes=[{"frame": 0, "latent": z}, {"frame": 9, "vertices": bad}]),
                422, "keyframes[1].vertices", *words)
    # keyframes: none, twice on one frame, neither or both of vertices and latent
    problem(post("animate", motion=kick, keyframes=[]), 422, "keyframes")
    problem(post("animate", motion=kick), 422, "keyframes")
    problem(post("animate", motion=kick, keyframes=[{"frame": 5, "latent": z}, {"frame": 5, "vertices": v}]), 422,
            "keyframes[1].frame", "frame 5", "keyframes[0]")
    problem(post("animate", motion=kick, keyframes=[{"frame": 5}]), 422, "keyframes[0]", "exactly one")
    problem(post("animate", motion=kick, keyframes=[{"frame": 5, "latent": z, "vertices": v}]), 422, "exactly one")
    # count out of range
    problem(post("sample", count=0, motion=kick), 422, "count")
    problem(post("sample", count=65, motion=kick), 422, "count", "64")
    problem(post("sample", count=2, seed=-1, motion=kick), 422, "seed")
    # the motion, the refine options, formats
    problem(post("sample", count=2, motion={"clip": "moonwalk"}), 404, "motion.clip")
    problem(post("animate", motion=kick, keyframes=[{"frame": 0, "latent": z}], refine={"eps": -1.0}), 422, "eps")
    problem(post("animate", motion=kick, keyframes=[{"frame": 0, "latent": z}], match_keyframes="yes"), 422,
            "match_keyframes")
    problem(http.post(f"/v1/garments/{NAME}/encode", content=b"x", headers={"content-type": "text/plain"}), 415,
            "Content-Type")
    problem(http.post(f"/v1/garments/{NAME}/sample", json={"count": 1, "motion": kick}, headers={"accept": GLB}),
            406, "Accept")


def test_a_glb_answer_refuses_a_frame_rate_its_key_times_cannot_hold(http):
    """A frame rate so low that frame t / fps seconds overflows (or rounds to 0 in) glTF's float32 key times is a
    422 naming the fps for a GLB answer, not a 500; the other formats still answer."""
    body = {"motion": {"poses": [[0.0] * 72] * 3, "fps": 1e-300}, "keyframes": [{"frame": 0, "latent": [0.0] * 100}]}
    for fps, field in ((1e-300, "motion.fps"), (1e-40, "motion.fps")):
        body["motion"]["fps"] = fps
        problem(http.post(f"/v1/garments/{NAME}/animate", json=body, headers={"accept": GLB}), 422, field, "glTF")
    assert http.post(f"/v1/garments/{NAME}/animate", json=body, headers={"accept": NPZ}).status_code == 200
    body["motion"]["fps"] = 1e-3  # slow, but its key times are finite
    assert http.post(f"/v1/garments/{NAME}/animate", json=body, headers={"accept": GLB}).status_code == 200


def test_bad_npz_inputs_name_their_field(http, garment, shape):
    kick = {"clip": np.array("kick")}

    def post(route, **arrays):
        return http.post(f"/v1/garments/{NAME}/{route}", content=encode_npz({**kick, **arrays}),
                         headers={"content-type": NPZ})

    problem(post("encode", vertices=shape[:5], frame=np.array(0)), 422, "vertices")
    problem(post("encode", vertices=shape, frame=np.array(1.5)), 422, "frame", "integer")
    problem(post("encode", vertices=np.full_like(shape, np.inf), frame=np.array(0)), 422, "vertices", "NaN")
    problem(post("encode", vertices=shape), 422, "frame")
    problem(post("animate"), 422, "keyframes", "at least one")
    # named by the members the client wrote (they were the JSON request's keyframes[1].frame, keyframes[0].latent)
    p = problem(post("animate", latent_frames=np.array([1, 1]), latents=np.zeros((2, 100), np.float32)), 422,
                "latent_frames[1]: frame 1 is also the frame of latent_frames[0]")
    assert p["field"] == "latent_frames[1]"
    p = problem(post("animate", latent_frames=np.array([1]), latents=np.zeros((1, 9), np.float32)), 422,
                "latents[0]", "100 values")
    assert p["field"] == "latents[0]"
    p = problem(post("animate", vertex_frames=np.array([0]), vertices=shape[None],
                     latent_frames=np.array([2**40]), latents=np.zeros((1, 100), np.float32)), 422, "latent_frames[0]")
    assert p["field"] == "latent_frames[0]"
    problem(post("animate", latent_frames=np.array([1, 2]), latents=np.zeros((1, 100), np.float32)), 422, "latents")
    problem(post("animate", vertex_frames=np.array([1])), 422, "vertices")
    problem(post("animate", latent_frames=np.array([1]), latents=np.zeros((1, 100), np.float32),
                 match_keyframes=np.array([True, False])), 422, "match_keyframes", "boolean scalar")
    problem(post("sample", count=np.array(65)), 422, "count")
    problem(post("sample", count=np.array(2), frame=np.array(500)), 422, "frame")
    buf = io.BytesIO()
    np.savez(buf, clip=np.array("kick"), count=np.array([object()], dtype=object))
    problem(http.post(f"/v1/garments/{NAME}/sample", content=buf.getvalue(), headers={"content-type": NPZ}), 400,
            "npz")
    ok = post("sample", count=np.array(2), seed=np.array(4), frame=np.array(3))
    assert ok.status_code == 200 and ok.headers["content-type"].startswith("application/json")


def test_the_schema_offers_the_garment_routes(http):
    schema = http.get("/openapi.json").json()
    paths = schema["paths"]
    for route in ("encode", "animate", "sample"):
        op = paths[f"/v1/garments/{{name}}/{route}"]["post"]
        assert {"application/json", NPZ, "multipart/form-data"} <= set(op["requestBody"]["content"])
        assert "503" in op["responses"] and op["parameters"][0]["example"] == NAME
    content = paths["/v1/garments/{name}/animate"]["post"]["responses"]["200"]["content"]
    assert {"application/json", NPZ, "application/x-drape-frames", "application/x-pc2", GLB} <= set(content)
    assert "GarmentList" in schema["components"]["schemas"] and "KeyframeAnimateRequest" in schema["components"][
        "schemas"]


def test_intrinsic_eval_deepsd_baseline_is_what_animate_answers(settings, http):
    """`drape eval intrinsic`'s DeePSD re-targeting row is the animation a user of POST /v1/outfits/animate gets
    for the template (served rig: 4 influences, collision fit), not the network's dense rig."""
    from drape.training.intrinsic_eval import _deepsd_poser

    garment = IntrinsicGarment(intrinsic_model().path)
    clip = load_clip("dance_a")
    poses, trans = clip.poses[:12].astype(np.float64), clip.trans[:12].astype(np.float64)
    ours = _deepsd_poser(garment, settings.model_dir)(poses, trans)
    body = {"outfit": {"vertices": garment.template_vertices.tolist(), "faces": garment.faces.tolist()},
            "motion": {"poses": poses.reshape(len(poses), 72).tolist(), "translation": trans.tolist(), "fps": 30.0}}
    r = http.post("/v1/outfits/animate", json=body)
    assert r.status_code == 200, r.text[:300]
    served = np.asarray(r.json()["vertices"], np.float32)
    assert ours.shape == served.shape == (12, len(garment.template_vertices), 3)
    assert np.abs(ours - served).max() < 1e-5
