"""`drape eval intrinsic`'s keyframe tables on the session's small random-init model: with every frame a
keyframe, matched keyframes and vertex interpolation reproduce the sequence and the unmatched decoder does
not; two keyframes are met exactly when matched, so the in-between error is what the table reports."""

import numpy as np
import pytest

from drape.assets.motion import load_clip
from drape.runtime.intrinsic import IntrinsicGarment
from drape.training.intrinsic_eval import keyframe_ratio, two_keyframes
from tests.intrinsic_model import intrinsic_model


@pytest.fixture(scope="module")
def seq():
    """A 'simulated' sequence of 40 frames: a sampled design decoded along dance_a, plus a smooth wobble."""
    garment = IntrinsicGarment(intrinsic_model().path)
    clip = load_clip("dance_a")
    poses, trans = clip.poses[:40].astype(np.float64), clip.trans[:40].astype(np.float64)
    z = np.tile(garment.sample(1, 2, 0, poses, trans)[0], (40, 1))
    v = garment.decode(z, poses, trans).astype(np.float64)
    v += 0.01 * np.sin(np.arange(40) / 6.0)[:, None, None] * np.array([1.0, 0.0, 0.5])
    return garment, {"vertices": v, "poses": poses, "trans": trans, "fps": 30.0}


def test_every_frame_a_keyframe_reproduces_the_sequence_when_matched(seq):
    garment, s = seq
    r = keyframe_ratio(garment, s, threshold_mm=1.0, counts=(2, 40))
    assert r["frames"] == 40
    assert r["drape_matched_errors_mm"]["40"] < 1e-2 and r["vertex_interp_errors_mm"]["40"] < 1e-2
    assert r["drape_matched_keyframes"] == 40 and r["vertex_interp_keyframes"] == 40
    assert r["drape_errors_mm"]["40"] > 1.0 and r["drape_keyframes"] is None  # the random decoder alone cannot


def test_two_keyframes_reports_every_method(seq):
    garment, s = seq
    r = two_keyframes(garment, s, length=30)
    assert set(r) == {"drape_mm", "drape_matched_mm", "vertex_interp_mm", "descriptor_interp_mm"}
    assert all(np.isfinite(x) and x > 0 for x in r.values())
    assert r["drape_matched_mm"] != r["drape_mm"]
    with pytest.raises(ValueError, match="shorter"):
        two_keyframes(garment, s, length=41)

