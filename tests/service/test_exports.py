"""GLB (`model/gltf-binary`) and PC2 (`application/x-pc2`) answers of rig, animate and refine: each GLB
passes the Khronos validator with 0 errors and plays back (an independent reading of the spec) as the
npz answer of the same request; each PC2 equals it; the OpenAPI schema offers both."""

import io
import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "schemas"))
from glb_player import GlbPlayer  # noqa: E402
from gltf_validator import validate  # noqa: E402
from svc_env import problem  # noqa: E402

from drape.assets.motion import load_clip  # noqa: E402
from drape.assets.outfits import generate_outfit  # noqa: E402
from drape.schemas.binary import NPZ, decode_npz, encode_npz  # noqa: E402
from drape.schemas.gltf import GLB  # noqa: E402
from drape.schemas.pc2 import PC2, read_pc2  # noqa: E402


@pytest.fixture(scope="module")
def outfit():
    o = generate_outfit("tshirt", vertices=1200, seed=5)
    return o.vertices, o.faces


def post(http, path, body, accept):
    r = http.post(path, content=encode_npz(body), headers={"content-type": NPZ, "accept": accept})
    assert r.status_code == 200, r.text[:500]
    assert r.headers["content-type"].startswith(accept)
    return r.content


def animate_body(outfit, refine):
    return {"vertices": outfit[0], "faces": outfit[1], "clip": np.array("dance_a"), "refine": np.array(refine)}


def test_the_rig_as_glb(http, outfit):
    glb = post(http, "/v1/outfits/rig", {"vertices": outfit[0], "faces": outfit[1]}, GLB)
    report = validate(glb)
    assert report["errors"] == 0, report["messages"]
    rig = decode_npz(post(http, "/v1/outfits/rig", {"vertices": outfit[0], "faces": outfit[1]}, NPZ))
    player = GlbPlayer(glb)
    assert np.abs(player.positions("outfit") - outfit[0]).max() < 1e-6
    names = player.doc.meshes[0].extras["targetNames"]
    assert len(names) == len(rig["blend_shapes"]) and names[0] == "psd_0"
    assert [n.name for n in player.doc.nodes[:24]] == [str(n) for n in rig["joint_names"]]
    drape_extras = player.doc.asset.extras["drape"]
    assert drape_extras["outfit_id"] == str(rig["outfit_id"]) and drape_extras["influences"] == 4
    diagnostics = json.loads(str(rig["diagnostics"]))
    assert drape_extras["diagnostics"] == {k: v for k, v in diagnostics.items() if v != []}  # pygltflib drops []


@pytest.mark.parametrize("refine", [False, True])
def test_animate_as_glb_plays_as_the_npz_answer(http, outfit, refine):
    body = animate_body(outfit, refine)
    glb = post(http, "/v1/outfits/animate", body, GLB)
    report = validate(glb)
    assert report["errors"] == 0, report["messages"]
    want = decode_npz(post(http, "/v1/outfits/animate", body, NPZ))["vertices"]
    player = GlbPlayer(glb)
    moved = np.abs(want - decode_npz(post(http, "/v1/outfits/animate", animate_body(outfit, False), NPZ))[
        "vertices"]).max()
    assert (moved > 1e-4) == refine  # refinement moved something (the test model penetrates the body)
    for t in (0, len(want) // 2, len(want) - 1):
        err = np.linalg.norm(player.positions("outfit", t) - want[t], axis=1)
        assert err.max() < 1e-4, (t, err.max())  # 0.1 mm: skin weights under 1e-5 are dropped


def test_refine_as_glb_and_pc2(http, outfit):
    posed = decode_npz(post(http, "/v1/outfits/animate", animate_body(outfit, False), NPZ))["vertices"]
    clip = load_clip("dance_a")
    body = {"vertices": posed[:30], "faces": outfit[1], "poses": clip.poses[:30], "translation": clip.trans[:30],
            "fps": np.array(clip.fps)}
    want = decode_npz(post(http, "/v1/refine", body, NPZ))["vertices"]
    glb = post(http, "/v1/refine", body, GLB)
    report = validate(glb)
    assert report["errors"] == 0, report["messages"]
    player = GlbPlayer(glb)
    for t in (0, 11, 29):
        assert np.abs(player.positions("garment", t) - want[t]).max() < 1e-6
    frames, start, rate = read_pc2(post(http, "/v1/refine", body, PC2))
    assert (start, rate) == (0.0, 1.0) and np.array_equal(frames, want)


def test_glb_answers_refuse_a_frame_rate_their_key_times_cannot_hold(http, outfit):
    """animate and refine: a frame rate so low that frame t / fps seconds overflows (or rounds to 0 in) glTF's
    float32 key times is a 422 naming the fps for a GLB answer, not a 500 (the skinned GLB animates one frame too)."""
    still = {"vertices": outfit[0], "faces": outfit[1], "fps": np.array(1e-300)}
    for frames in (1, 2):
        r = http.post("/v1/outfits/animate", content=encode_npz({**still, "poses": np.zeros((frames, 72))}),
                      headers={"content-type": NPZ, "accept": GLB})
        problem(r, 422, "motion.fps", "glTF")
    stream = {**still, "vertices": np.stack([outfit[0]] * 2), "poses": np.zeros((2, 72))}
    r = http.post("/v1/refine", content=encode_npz(stream), headers={"content-type": NPZ, "accept": GLB})
    problem(r, 422, "motion.fps", "glTF")


@pytest.fixture
def long_frames(app):
    """The app's settings with room for 1,000 frames and 400,000 values an answer, for one test (starlette's
    State is no plain object: monkeypatch's undo deleted the attribute)."""
    served = app.state.settings
    app.state.settings = served.model_copy(update={"max_frames": 1000, "max_posed_values": 400_000})
    yield
    app.state.settings = served


def test_glb_answers_bound_their_per_frame_target_weights(http, long_frames):
    """A GLB that plays one morph target a frame animates frames x (frames - 1) weights: quadratic in the frames,
    so it is bounded by DRAPE_MAX_POSED_VALUES as well (a 413 before the work, not hundreds of MB); the npz
    answer of the same request, linear in the frames, still answers. Refine and an intrinsic garment."""
    from tests.intrinsic_model import LATENT, NAME

    T = 700  # 700 x 699 = 489,300 weights > 400,000; 700 x 300 vertices = 210,000 values <= 400,000
    tri = {"vertices": np.zeros((T, 3, 3)), "faces": np.array([[0, 1, 2]]), "poses": np.zeros((T, 72)),
           "fps": np.array(30.0)}
    tri["vertices"][:, 1, 0] = tri["vertices"][:, 2, 1] = 0.1
    r = http.post("/v1/refine", content=encode_npz(tri), headers={"content-type": NPZ, "accept": GLB})
    problem(r, 413, "vertices", "700 x 699 morph-target weights", "400000")
    keyed = {"motion": {"poses": [[0.0] * 72] * T, "fps": 30.0}, "keyframes": [{"frame": 0, "latent": [0.0] * LATENT}]}
    problem(http.post(f"/v1/garments/{NAME}/animate", json=keyed, headers={"accept": GLB}), 413, "motion",
            "morph-target weights")
    assert http.post(f"/v1/garments/{NAME}/animate", json=keyed, headers={"accept": NPZ}).status_code == 200


def test_layers_as_glb_and_pc2(http):
    """/v1/layers/animate's GLB (the two layers as one mesh, inner first) passes the validator and plays the npz
    answer's frames; its PC2 equals them."""
    clip = load_clip("kick")
    body = {"inner": "tshirt", "outer": "jacket", "motion": {"poses": clip.poses[:12].reshape(12, 72).tolist(),
                                                              "translation": clip.trans[:12].tolist()}}

    def ask(accept):
        r = http.post("/v1/layers/animate", json=body, headers={"accept": accept})
        assert r.status_code == 200, r.text[:500]
        return r.content

    z = decode_npz(ask(NPZ))
    want = np.concatenate([z["inner_vertices"], z["outer_vertices"]], axis=1)
    glb = ask(GLB)
    report = validate(glb)
    assert report["errors"] == 0, report["messages"]
    player = GlbPlayer(glb)
    for t in (0, 5, len(want) - 1):
        assert np.abs(player.positions("layers", t) - want[t]).max() < 1e-6
    frames, _, _ = read_pc2(ask(PC2))
    assert np.array_equal(frames, want)


def test_animate_as_pc2_equals_npz(http, outfit):
    body = animate_body(outfit, False)
    data = post(http, "/v1/outfits/animate", body, PC2)
    assert data[:12] == b"POINTCACHE2\0"
    frames, _, _ = read_pc2(data)
    assert np.array_equal(frames, decode_npz(post(http, "/v1/outfits/animate", body, NPZ))["vertices"])


def test_the_schema_offers_glb_and_pc2(http):
    paths = http.get("/openapi.json").json()["paths"]
    for path in ("/v1/outfits/animate", "/v1/refine", "/v1/layers/animate"):
        content = paths[path]["post"]["responses"]["200"]["content"]
        assert GLB in content and PC2 in content
    assert GLB in paths["/v1/outfits/rig"]["post"]["responses"]["200"]["content"]


def test_read_pc2_refuses_what_is_not_one():
    with pytest.raises(ValueError, match="PC2"):
        read_pc2(b"POINTCACHE3\0" + bytes(20))
    with pytest.raises(ValueError, match="declares"):
        read_pc2(io.BytesIO(b"POINTCACHE2\0" + np.array([1, 5], "<i4").tobytes() +
                            np.array([0, 1], "<f4").tobytes() + np.array([2], "<i4").tobytes()).getvalue())


@pytest.fixture
def spent_budget(app):
    """The served settings with a request budget (DRAPE_REQUEST_BUDGET_S) that has run out by the first check."""
    served = app.state.settings
    app.state.settings = served.model_copy(update={"request_budget_s": 1e-9})
    yield
    app.state.settings = served


def test_the_request_budget_stops_glb_answers_with_a_problem(http, outfit, spent_budget):
    """A GLB is made whole before it is sent, so past DRAPE_REQUEST_BUDGET_S it stops with a 413 naming the frames'
    field and saying what to do (it held its computing slot for as long as the work took: a refined GLB of ~4,400
    frames for minutes); a streamed answer of the same request is cut instead (its client sees an incomplete
    answer), and the cut is counted."""
    refined = http.post("/v1/outfits/animate", content=encode_npz(animate_body(outfit, True)),
                        headers={"content-type": NPZ, "accept": GLB})
    problem(refined, 413, "motion", "time budget", "streamed format")
    layers = {"inner": "tshirt", "outer": "jacket", "motion": {"poses": [[0.0] * 72] * 60}}
    problem(http.post("/v1/layers/animate", json=layers, headers={"accept": GLB}), 413, "motion", "time budget",
            "32 of 60 frames")
    cut = 'drape_answers_cut_total{reason="time_budget"}'
    before = next((line for line in http.get("/metrics").text.splitlines() if line.startswith(cut)), f"{cut} 0.0")
    streamed = http.post("/v1/layers/animate", json=layers, headers={"accept": NPZ})
    assert streamed.status_code == 200
    with pytest.raises(Exception):  # noqa: B017 - cut: not a whole npz
        decode_npz(streamed.content)
    after = next(line for line in http.get("/metrics").text.splitlines() if line.startswith(cut))
    assert float(after.split()[-1]) == float(before.split()[-1]) + 1
