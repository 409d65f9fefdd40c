"""A motion file (BVH with CMU names, or an AMASS-style npz) uploaded as the multipart field `motion_file` to
POST /v1/outfits/animate and /v1/refine: imported as `drape motions import` does, resampled to the form's fps
(default 30), bounded by the service's limits; bad files are a 4xx naming `motion_file` (issue 20, item 1).

The service tests run with max_frames=200 and a 4 MiB body limit (svc_env.py).
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from svc_env import problem

from drape.assets.motion import resampled_count
from drape.assets.outfits import generate_outfit
from drape.schemas.binary import NPZ, decode_npz, encode_npz
from tests.cmu_bvh import cmu_bvh as make_cmu_bvh

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "mocap"



def cmu_bvh(frames: int, fps: float = 120.0, first: str = "Hips") -> bytes:
    """A CMU-named BVH (tests/cmu_bvh.py); `first` renames the root."""
    return make_cmu_bvh(frames, fps, rename={"Hips": first})




@pytest.fixture(scope="module")
def outfit_id(app):
    from fastapi.testclient import TestClient

    o = generate_outfit("tshirt", vertices=600, seed=5)
    r = TestClient(app).post("/v1/outfits/rig", json={"vertices": o.vertices.tolist(), "faces": o.faces.tolist()},
                             headers={"accept": NPZ})
    assert r.status_code == 200, r.text
    return str(decode_npz(r.content)["outfit_id"])


def animate(http, motion: bytes, name: str = "take.bvh", accept: str = NPZ, **fields):
    return http.post("/v1/outfits/animate", files={"motion_file": (name, motion)}, data=fields,
                     headers={"accept": accept})


def test_a_bvh_upload_animates_at_the_forms_fps(http, outfit_id):
    r = animate(http, cmu_bvh(481), outfit_id=outfit_id)  # 4 s at 120 fps -> 121 frames at 30 (the default)
    assert r.status_code == 200, r.text
    z = decode_npz(r.content)
    assert z["vertices"].shape[0] == resampled_count(481, 120, 30) == 121 and float(z["fps"]) == 30.0
    assert np.isfinite(z["vertices"]).all()
    r24 = animate(http, cmu_bvh(481), outfit_id=outfit_id, fps="24", refine="true")
    assert r24.status_code == 200, r24.text
    assert decode_npz(r24.content)["vertices"].shape[0] == 97


@pytest.mark.skipif(not (DATA / "05_01_walk.bvh").exists(), reason=f"the real CMU clips are not at {DATA}")
def test_a_real_cmu_clip_uploads(http, outfit_id):
    """A raw CMU walk (599 frames at 120 fps, a T-pose frame 0): 598 frames -> 150 at 30 fps, feet near the
    floor (the lowest vertex of the body's feet is not computed here: the outfit's lowest point is near 0)."""
    r = animate(http, (DATA / "05_01_walk.bvh").read_bytes(), "05_01_walk.bvh", outfit_id=outfit_id)
    assert r.status_code == 200, r.text
    v = decode_npz(r.content)["vertices"]
    assert v.shape[0] == resampled_count(598, 120, 30) == 150
    assert 0.3 < float(np.median(v[..., 1].min(axis=1))) < 1.2  # a t-shirt on a body standing on the floor


def test_an_amass_npz_uploads(http, outfit_id):
    T = 90
    poses = np.zeros((T, 156))
    poses[:, 0] = np.pi / 2  # standing in AMASS's Z-up world
    poses[:, 3 * 16 + 2] = np.linspace(0, -1.0, T)  # left shoulder down
    buf = io.BytesIO()
    np.savez(buf, poses=poses, trans=np.zeros((T, 3)), mocap_framerate=np.array(60.0), betas=np.zeros(16),
             gender=np.array("male"))
    r = animate(http, buf.getvalue(), "clip.npz", outfit_id=outfit_id)
    assert r.status_code == 200, r.text
    assert decode_npz(r.content)["vertices"].shape[0] == resampled_count(T, 60, 30) == 45


def test_refine_takes_a_motion_file(http, outfit_id):
    first = animate(http, cmu_bvh(121), outfit_id=outfit_id)  # 31 frames at 30 fps
    frames = decode_npz(first.content)
    garment = encode_npz({"vertices": frames["vertices"], "faces": frames["faces"]})
    r = http.post("/v1/refine", files={"garment": ("g.npz", garment), "motion_file": ("m.bvh", cmu_bvh(121))},
                  data={"relief_iterations": "0"}, headers={"accept": NPZ})
    assert r.status_code == 200, r.text
    assert decode_npz(r.content)["vertices"].shape == frames["vertices"].shape
    short = http.post("/v1/refine", files={"garment": ("g.npz", garment), "motion_file": ("m.bvh", cmu_bvh(61))})
    problem(short, 422, "motion_file:", "16 frames (at 30 fps)")  # the form's field: it has no `motion`
    problem(http.post("/v1/refine", files={"motion_file": ("m.bvh", cmu_bvh(61))}), 422, "garment")
    # the garment npz's members are named as the form's: garment.<member> (they said vertices, faces, ...)
    bad = frames["vertices"].copy()
    bad[3, 0, 0] = np.nan

    def refine(**members):
        return http.post("/v1/refine", files={"garment": ("g.npz", encode_npz(members)),
                                              "motion_file": ("m.bvh", cmu_bvh(121))})

    problem(refine(vertices=bad, faces=frames["faces"]), 422, "garment.vertices:")
    problem(refine(vertices=frames["vertices"], faces=frames["faces"] + 10**6), 422, "garment.faces:")
    problem(refine(vertices=frames["vertices"], faces=frames["faces"], inner_vertices=bad,
                   inner_faces=frames["faces"], thickness=np.array(0.004)), 422, "garment.inner_vertices:")
    problem(refine(vertices=frames["vertices"], faces=frames["faces"], rest_vertices=frames["vertices"][0, :5]),
            422, "garment.rest_vertices:")


def test_refine_with_the_rest_shape_is_animates_refinement(http, outfit_id):
    """A form whose garment npz carries rest_vertices (the outfit at rest) refines the unrefined stream into what
    animate's own `refine: true` answers (it refines with the rigged outfit's rest shape); without it, the relief
    pass gives something else."""
    bvh = cmu_bvh(121)
    raw = decode_npz(animate(http, bvh, outfit_id=outfit_id).content)
    refined = decode_npz(animate(http, bvh, outfit_id=outfit_id, refine="true").content)["vertices"]
    rest = generate_outfit("tshirt", vertices=600, seed=5).vertices.astype(np.float32)  # the fixture's outfit

    def refine(**extra) -> np.ndarray:
        garment = encode_npz({"vertices": raw["vertices"], "faces": raw["faces"], **extra})
        r = http.post("/v1/refine", files={"garment": ("g.npz", garment), "motion_file": ("m.bvh", bvh)},
                      headers={"accept": NPZ})
        assert r.status_code == 200, r.text
        return decode_npz(r.content)["vertices"]

    assert np.abs(refine(rest_vertices=rest) - refined).max() < 1e-6
    assert np.abs(refine() - refined).max() > 1e-4


def _npz(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


BAD = [
    (cmu_bvh(40, first="mixamorig:Hips"), 422, "expected a CMU-named skeleton"),
    (cmu_bvh(40).replace(b"Frames: 40", b"Frames: 41"), 422, "need"),
    (b"HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\n", 422, "'HIERARCHY' ... 'MOTION'"),
    (b"this is not a motion", 422, "expected a BVH file"),
    (_npz(poses=np.zeros((10, 24, 4))), 422, "quaternions"),
    (_npz(poses=np.zeros((10, 50))), 422, "expected axis-angle poses"),
    (b"PK\x03\x04broken zip", 422, "not a readable npz"),
    (_npz(poses=np.full((10, 72), 1e200)), 422, "beyond 10000 radians"),  # posed to NaN: was a 500
    (cmu_bvh(1601), 413, "1601 frames in the file exceed the limit of 1600"),  # 8 x max_frames
    (cmu_bvh(1000), 413, "250 frames at 30 fps exceed the limit of 200"),
    (cmu_bvh(6).replace(b"Frames: 6", b"Frames: " + b"9" * 19), 413, "a 19-digit number of frames"),
    (_npz(poses=np.zeros((201, 72))), 413, "201 frames at 30 fps exceed the limit of 200"),
]


@pytest.mark.parametrize("data,status,words", BAD, ids=[w for _, _, w in BAD])
def test_bad_motion_files_are_a_4xx_naming_motion_file(http, outfit_id, data, status, words):
    p = problem(animate(http, data, outfit_id=outfit_id), status, "motion_file", words)
    assert p["detail"].startswith("motion_file: ")


def test_bad_form_fields(http, outfit_id):
    ok = cmu_bvh(41)
    problem(http.post("/v1/outfits/animate", data={"outfit_id": outfit_id}, files={"other": ("x", b"1")}), 422,
            "unknown form field")
    problem(http.post("/v1/outfits/animate", data={"outfit_id": outfit_id}, files={"mesh": ("a.obj", b"v 0 0 0")}),
            422, "'mesh'")
    problem(animate(http, ok), 422, "outfit_id", "required")
    problem(animate(http, ok, outfit_id="nope"), 404, "outfit_id")
    problem(animate(http, ok, outfit_id=outfit_id, fps="fast"), 422, "fps")
    problem(animate(http, ok, outfit_id=outfit_id, fps="0"), 422, "fps")
    problem(animate(http, ok, outfit_id=outfit_id, up="x"), 422, "up")
    problem(animate(http, ok, outfit_id=outfit_id, body="female"), 422, "body")
    problem(animate(http, ok, outfit_id=outfit_id, refine="maybe"), 422, "refine")
    problem(animate(http, ok, outfit_id=outfit_id, eps="-1"), 422, "eps")
    problem(http.post("/v1/outfits/animate", data={"outfit_id": outfit_id}, files={"x": ("a", b"")}), 422)
    missing = http.post("/v1/outfits/animate", files={"outfit_id": (None, outfit_id)})
    problem(missing, 422, "motion_file", "required")


def test_the_body_limit_bounds_the_upload(http, settings, outfit_id):
    big = cmu_bvh(40) + b" " * settings.max_body_bytes
    problem(animate(http, big, outfit_id=outfit_id), 413, str(settings.max_body_bytes))


def test_openapi_documents_the_form(http):
    spec = http.get("/openapi.json").json()
    for path, required in (("/v1/outfits/animate", ["motion_file", "outfit_id"]),
                           ("/v1/refine", ["garment", "motion_file"])):
        form = spec["paths"][path]["post"]["requestBody"]["content"]["multipart/form-data"]["schema"]
        assert form["required"] == required and form["properties"]["motion_file"]["format"] == "binary"
        assert "fps" in form["properties"]


def test_a_body_gone_before_the_motion_file_is_read_is_a_404():
    """The route checks the body, then reads the file; a DELETE in between was a KeyError (500)."""
    from drape.service.errors import NotFound
    from drape.service.uploads import motion_from_file

    with pytest.raises(NotFound) as info:
        motion_from_file(b"HIERARCHY\n", "user-0123456789abcdef", fps=30.0, up=None, max_frames=100,
                         max_decoded_bytes=10**6)
    assert info.value.field == "body" and "deleted" in info.value.detail


def _jumping_without_return(frames: int) -> np.ndarray:
    """(frames, 3) axis-angle rotations, each a 72-degree turn from the one before (a jump at 50 fps) that does not
    come back within 0.5 s: a walk over the icosahedral rotation group, each step to the least recently visited of
    the rotations 72 degrees away (a rotation comes back only 41 or more steps later)."""
    from drape.geometry.rotations import axis_angle_to_matrix, matrix_to_axis_angle

    phi = (1 + 5**0.5) / 2
    turns = [axis_angle_to_matrix(np.array(axis) / np.linalg.norm(axis) * angle)
             for axis, angle in (([0.0, 1.0, phi], 2 * np.pi / 5), ([1.0, 1.0, 1.0], 2 * np.pi / 3))]
    group = [np.eye(3)]
    for g in group:  # grows while it is walked: the closure of the two turns, 60 rotations
        for turn in turns:
            if not any(np.allclose(g @ turn, h) for h in group):
                group.append(g @ turn)
    cos72 = 1 + 2 * np.cos(2 * np.pi / 5)  # the trace of a 72-degree turn
    near = [[k for k, h in enumerate(group) if abs(np.trace(g.T @ h) - cos72) < 1e-6] for g in group]
    visited = {0: 0}
    walk = [0]
    for t in range(1, frames):
        walk.append(min(near[walk[-1]], key=lambda k: visited.get(k, -frames)))
        visited[walk[-1]] = t
    return matrix_to_axis_angle(np.stack([group[k] for k in walk]))


def test_a_motion_file_jumping_every_frame_imports_in_linear_time(http, outfit_id, settings):
    """Every joint turning 72 degrees a frame at 50 fps, never back: each jump is a possible flip that does not return.
    Finding flips compared every jump with every later one (T^2 / 2 Python steps a joint): the 1,600 frames the test
    limits allow took 14 s here; the 80,000 the default limits allow (23 MB), hours, holding a computing slot."""
    import time

    frames = 8 * settings.max_frames  # the most a file may hold (MOTION_SOURCE_FACTOR x max_frames)
    poses = np.zeros((frames, 24, 3), np.float32)
    poses[:, 1:] = _jumping_without_return(frames)[:, None]
    data = _npz(poses=poses.reshape(frames, 72), mocap_framerate=np.array(50.0))
    start = time.perf_counter()
    r = animate(http, data, "jumps.npz", outfit_id=outfit_id, fps="1", up="y")
    assert r.status_code == 200, r.text[:300]
    assert time.perf_counter() - start < 5.0


def test_an_uploads_import_warnings_travel_in_the_answer(http, outfit_id, server_url, tmp_path):
    """A Y-up BVH sent with up=z is done as asked (the body lies on its side) and said: the answer's
    Drape-Warnings header (a JSON array) carries what `drape motions import` prints, in every answer format and
    on refine too; the client raises each as a DrapeWarning. The same file with its own up axis has no header
    (a probe's Y-up 141_16_wave with up=z was a silent 200)."""
    import json
    import warnings

    import drape
    from drape.schemas import WARNINGS_HEADER

    bvh = cmu_bvh(121)
    plain = animate(http, bvh, outfit_id=outfit_id)
    assert plain.status_code == 200 and WARNINGS_HEADER not in plain.headers
    for accept in (NPZ, "application/json", "application/x-drape-frames", "model/gltf-binary"):
        r = animate(http, bvh, accept=accept, outfit_id=outfit_id, up="z")
        assert r.status_code == 200, (accept, r.text[:300])
        said = json.loads(r.headers[WARNINGS_HEADER])
        assert said and all(s.startswith("motion_file: ") for s in said), said
        assert "looks Y-up, not Z-up as asked" in said[0], said
    garment = encode_npz({k: v for k, v in decode_npz(plain.content).items() if k in ("vertices", "faces")})
    r = http.post("/v1/refine", files={"garment": ("g.npz", garment), "motion_file": ("m.bvh", bvh)},
                  data={"up": "z", "relief_iterations": "0"}, headers={"accept": NPZ})
    assert r.status_code == 200 and "not Z-up as asked" in r.headers[WARNINGS_HEADER]
    bad = animate(http, bvh, outfit_id=outfit_id, up="z", fps="0")  # an error answer: its problem says it all
    assert bad.status_code == 422 and WARNINGS_HEADER not in bad.headers

    take = tmp_path / "take.bvh"  # the client's MotionFile over a real server (uvicorn, answers streamed)
    take.write_bytes(bvh)
    with drape.Client(server_url) as client, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        o = generate_outfit("tshirt", vertices=600, seed=5)
        served_id = client.rig((o.vertices, o.faces)).outfit_id  # that server's own cache
        client.animate(outfit_id=served_id, motion=drape.client.MotionFile(take, up="z"))
        assert not [w for w in caught if w.category is not drape.DrapeWarning]
        told = [str(w.message) for w in caught if w.category is drape.DrapeWarning]
        assert told and "not Z-up as asked" in told[0] and told[0].startswith("drape: motion_file: ")
        caught.clear()
        client.animate(outfit_id=served_id, motion=drape.client.MotionFile(take))
        assert not [w for w in caught if w.category is drape.DrapeWarning]
        # an outfit with a motion file is rigged through rig first: what its diagnostics say is raised too (a
        # probe's outfit 39% inside the body warned with a poses array, not with a motion file)
        centre = o.vertices.mean(0)
        client.animate(outfit=((o.vertices - centre) * 0.8 + centre, o.faces), motion=drape.client.MotionFile(take))
        told = [str(w.message) for w in caught if w.category is drape.DrapeWarning]
        assert [t for t in told if t.startswith("drape: vertices: ") and "inside the body at rest" in t], told
