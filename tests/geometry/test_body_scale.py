"""Bringing a body into a trained range of heights: the identity inside it, the range's nearest height
outside, about the floor point under the pelvis."""

import numpy as np
import pytest

from drape.assets.body import load_body
from drape.geometry.body_scale import body_height, body_scale, torso_size

RANGE = (1.66, 1.80)


def test_a_body_inside_the_range_is_read_as_it_is():
    body = load_body("neutral")
    s = body_scale(body.vertices, body.joints, RANGE)
    assert s.identity
    assert np.array_equal(s.apply(body.vertices), body.vertices.astype(np.float64))


@pytest.mark.parametrize(("factor", "target"), [(1.25, RANGE[1]), (0.8, RANGE[0])])
def test_a_body_outside_is_scaled_to_the_nearest_height_about_its_floor_under_the_pelvis(factor, target):
    body = load_body("neutral")
    shift = np.array([0.3, 0.1, -0.2])  # a body standing elsewhere, its floor 10 cm up
    verts, joints = body.vertices * factor + shift, body.joints * factor + shift
    pelvis = joints[0]
    s = body_scale(verts, joints, RANGE)
    scaled = s.apply(verts)
    assert body_height(scaled) == pytest.approx(target, rel=1e-9)
    assert scaled[:, 1].min() == pytest.approx(0.1, abs=1e-9)  # the floor stays
    assert np.allclose(s.apply(pelvis)[[0, 2]], pelvis[[0, 2]])  # the vertical through the pelvis stays
    # a similarity: every distance scaled by the same factor
    d0, d1 = np.linalg.norm(verts[1:] - verts[:-1], axis=1), np.linalg.norm(scaled[1:] - scaled[:-1], axis=1)
    assert np.allclose(d1, d0 * s.scale[1]) and np.all(s.scale == s.scale[1])


def test_an_empty_or_inverted_range_is_refused():
    body = load_body("neutral")
    with pytest.raises(ValueError, match="heights"):
        body_scale(body.vertices, body.joints, (1.8, 1.6))


def test_torso_size_follows_the_body_and_torso_ranges_scale_x_and_z_only_past_them():
    body = load_body("male")
    w, d = torso_size(body.vertices, body.joints)
    assert 0.2 < w < 0.6 and 0.15 < d < 0.4  # a torso, not an arm span (~1.7 m at rest)
    wide = np.array([1.2, 1.0, 1.1])
    w2, d2 = torso_size(body.vertices * wide, body.joints * wide)
    assert w2 == pytest.approx(1.2 * w, rel=0.02) and d2 == pytest.approx(1.1 * d, rel=1e-6)
    ranges = ((0.5 * w, w), (0.5 * d, d))
    height = body_height(body.vertices)
    s = body_scale(body.vertices * wide, body.joints * wide, (height, height), ranges)
    assert s.scale[1] == 1.0
    w3, d3 = torso_size(s.apply(body.vertices * wide), s.apply(body.joints * wide))
    assert w3 == pytest.approx(w, rel=0.02) and d3 == pytest.approx(d, rel=1e-6)
    assert body_scale(body.vertices, body.joints, (height, height), ranges).identity
