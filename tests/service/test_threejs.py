"""three.js plays drape's animate GLB as drape poses: GLTFLoader + AnimationMixer in headless Chromium
(tests/schemas/threejs_player.py) against the npz answer of the same request, for two outfits, two clips, with
and without refinement (each pair of the three met once), and the body against drape's own body posing; 3 frames
each.

three.js reads one skin weight set (JOINTS_0/WEIGHTS_0, normalised to sum 1); drape's GLB carries every
influence in sets of 4. The served rig has 4 influences by default, so three.js must match drape; a rig
asked for with 8, and the body (491 of its vertices have 5 or 6), cannot: those are strict xfails with
the measured figures, and two checks pin the gap on the 4-influence limit alone: three.js does exactly
the specification's arithmetic on the first set (tests/schemas/glb_player.py restricted to it), and the
specification's arithmetic on every set is drape's answer.
"""

import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "schemas"))
from glb_player import GlbPlayer  # noqa: E402
from threejs_player import threejs_play  # noqa: E402

from drape.assets.body import load_body  # noqa: E402
from drape.assets.motion import load_clip  # noqa: E402
from drape.assets.outfits import generate_outfit  # noqa: E402
from drape.schemas.binary import NPZ, decode_npz, encode_npz  # noqa: E402
from drape.schemas.gltf import GLB  # noqa: E402

# type, vertices, seed: under 1,973 vertices, so 152 frames stay within the test service's 300,000 posed values
OUTFITS = {"tshirt": ("tshirt", 1200, 5), "dress": ("dress", 1200, 7)}
CLIPS = ("walk", "dance_a")
MEAN_MM, MAX_MM = 1.0, 5.0
# outfit, clip, refine, influences (None: the service's default, 4)
# each pair of outfit, clip and refine met once (4 of the 8 combinations: every browser run costs ~20 s)
CASES: list[tuple[str, str, bool, int | None]] = [("tshirt", "walk", False, None), ("tshirt", "dance_a", True, None),
                                                  ("dress", "walk", True, None), ("dress", "dance_a", False, None),
                                                  ("tshirt", "dance_a", False, 8)]
SPEC_MM = 0.01  # three.js against the specification's arithmetic on the same weight set

# three.js against drape at 8 influences per vertex (worst of the 3 frames), on the test model
EIGHT = pytest.mark.xfail(strict=True, raises=AssertionError, reason=(
    "three.js reads 4 influences (JOINTS_0/WEIGHTS_0) and the rig asked for has 8; measured: mean up to "
    "136.7 mm, max up to 257.3 mm from drape (the untrained test model spreads its weights over every joint)"))
BODY_FOUR_INFLUENCES = pytest.mark.xfail(strict=True, raises=AssertionError, reason=(
    "three.js reads 4 influences; 491 of the neutral body's 13,718 vertices have 5 or 6 (the first 4 hold "
    ">= 90.2% of their weight); measured: body mean 0.018-0.027 mm, max 9.3-16.9 mm from drape"))


@dataclass
class Played:
    glb: bytes
    want: np.ndarray  # (T, N, 3): drape's npz answer
    frames: list[int]
    fps: float
    three: dict[str, dict[int, np.ndarray]]  # mesh -> frame -> (N, 3)


@pytest.fixture(scope="module")
def played(app):
    """(outfit, clip, refine, influences) -> Played: the GLB and npz answers, three.js's outfit and body at
    frames 0, T/2 and T - 1; each case requested and played once for the module."""
    client, cache = TestClient(app), {}

    def get(outfit: str, clip: str, refine: bool, influences: int | None = None) -> Played:
        key = (outfit, clip, refine, influences)
        if key not in cache:
            kind, n, seed = OUTFITS[outfit]
            o = generate_outfit(kind, vertices=n, seed=seed)
            body = {"vertices": o.vertices, "faces": o.faces, "clip": np.array(clip), "refine": np.array(refine)}
            if influences is not None:
                body["influences"] = np.array(influences)

            def post(accept: str) -> bytes:
                r = client.post("/v1/outfits/animate", content=encode_npz(body),
                                headers={"content-type": NPZ, "accept": accept})
                assert r.status_code == 200, r.text[:500]
                return r.content

            motion = load_clip(clip)
            glb, fps, frames = post(GLB), motion.fps, [0, motion.num_frames // 2, motion.num_frames - 1]
            with ThreadPoolExecutor(1) as pool:  # the browser plays while the service computes the npz answer
                three = pool.submit(threejs_play, glb, ["outfit", "body"], frames, fps)
                want = decode_npz(post(NPZ))["vertices"]
                cache[key] = Played(glb, want, frames, fps, three.result())
        return cache[key]

    return get


def mm(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    e = np.linalg.norm(np.asarray(a, np.float64) - b, axis=1) * 1000
    return float(e.mean()), float(e.max())


@pytest.mark.parametrize(("outfit", "clip", "refine", "influences"),
                         [pytest.param(*c, marks=EIGHT if c[3] == 8 else ()) for c in CASES])
def test_threejs_plays_the_outfit_as_drape(played, outfit, clip, refine, influences):
    p = played(outfit, clip, refine, influences)
    worst = []
    for f in p.frames:
        mean, top = mm(p.three["outfit"][f], p.want[f])
        print(f"three.js vs drape, {outfit} {clip} refine={refine} influences={influences or 4} frame {f}: "
              f"mean {mean:.3f} mm, max {top:.3f} mm")
        worst.append((mean, top, f))
    assert max(w[0] for w in worst) <= MEAN_MM and max(w[1] for w in worst) <= MAX_MM, (
        outfit, clip, refine, influences, worst)


@pytest.mark.parametrize(("outfit", "clip", "refine", "influences"), CASES)
def test_threejs_is_the_spec_on_the_first_weight_set(played, outfit, clip, refine, influences):
    """three.js = the glTF arithmetic (node TRS, joint matrices, morph weights, sparse targets) on
    JOINTS_0/WEIGHTS_0 normalised: for the outfit (pose keys, refinement targets) and the body."""
    p = played(outfit, clip, refine, influences)
    player = GlbPlayer(p.glb)
    for mesh in ("outfit", "body"):
        for f in p.frames:
            mean, top = mm(p.three[mesh][f], player.positions(mesh, f, max_sets=1))
            assert top <= SPEC_MM, (mesh, f, mean, top)


@pytest.mark.parametrize(("outfit", "clip", "refine", "influences"), CASES)
def test_the_glb_with_every_weight_set_is_drape(played, outfit, clip, refine, influences):
    """What an engine reading every JOINTS_n/WEIGHTS_n set shows is drape's outfit and body: the gap above
    is the first set alone."""
    p = played(outfit, clip, refine, influences)
    player = GlbPlayer(p.glb)
    motion = load_clip(clip)
    body = load_body("neutral").pose(motion.poses[p.frames], motion.trans[p.frames])
    for k, f in enumerate(p.frames):
        assert mm(player.positions("outfit", f), p.want[f])[1] <= 0.1, f
        assert mm(player.positions("body", f), body[k])[1] <= 0.1, f


@pytest.mark.parametrize("clip", [pytest.param(c, marks=BODY_FOUR_INFLUENCES) for c in CLIPS])
def test_threejs_plays_the_body_as_drape(played, clip):
    p = played(*next(c for c in CASES if c[1] == clip))  # the body does not depend on the outfit or refinement
    motion = load_clip(clip)
    want = load_body("neutral").pose(motion.poses[p.frames], motion.trans[p.frames])
    worst = []
    for k, f in enumerate(p.frames):
        mean, top = mm(p.three["body"][f], want[k])
        print(f"three.js vs drape, body {clip} frame {f}: mean {mean:.4f} mm, max {top:.4f} mm")
        worst.append((mean, top, f))
    assert max(w[0] for w in worst) <= MEAN_MM and max(w[1] for w in worst) <= MAX_MM, (clip, worst)
