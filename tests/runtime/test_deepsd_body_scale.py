"""DeePSD on a body outside its trained heights reads the garment and body scaled into that range: a body
inside the range is rigged as before, and two bodies past it by different factors get the same weights and
blend shapes in proportion to their size."""

import numpy as np
import pytest

from drape.assets.body import Body, load_body
from drape.assets.outfits import generate_outfit
from drape.runtime.deepsd import DeePSDModel


def scaled(body: Body, k: float) -> Body:
    return Body(f"{body.name}_x{k}", body.vertices * k, body.faces, body.weights, body.joints * k, body.parents,
                body.joint_names)


@pytest.fixture(scope="module")
def outfit():
    return generate_outfit("tshirt,shorts", vertices=1500, seed=3, body="neutral")


def test_trained_heights_come_from_the_manifest_bodies():
    model = DeePSDModel()
    bodies = model.manifest["training"]["config"]["bodies"]
    lo, hi = model.trained_heights
    heights = [float(np.ptp(load_body(b).vertices[:, 1])) for b in bodies]
    assert (lo, hi) == pytest.approx((min(heights), max(heights)))
    assert DeePSDModel(scale_bodies=None).trained_heights is None


def test_a_trained_body_is_rigged_as_it_is(outfit):
    body = load_body("neutral")
    a = DeePSDModel().rig(outfit.vertices, outfit.faces, body)
    b = DeePSDModel(scale_bodies=None).rig(outfit.vertices, outfit.faces, body)
    assert DeePSDModel().body_scale(body) is None
    assert np.array_equal(a.weights, b.weights) and np.array_equal(a.blend_shapes, b.blend_shapes)


def test_bodies_past_the_range_read_the_same_and_answer_in_their_own_size(outfit):
    model, body = DeePSDModel(), load_body("neutral")
    rigs = {k: model.rig(outfit.vertices * k, outfit.faces, scaled(body, k)) for k in (1.2, 1.3)}
    assert np.allclose(rigs[1.2].weights, rigs[1.3].weights, atol=1e-5)
    assert np.allclose(rigs[1.3].blend_shapes, rigs[1.2].blend_shapes * (1.3 / 1.2), atol=1e-6)
    # and not what the model says when it reads the tall body as it is
    as_is = DeePSDModel(scale_bodies=None).rig(outfit.vertices * 1.2, outfit.faces, scaled(body, 1.2))
    assert np.abs(as_is.weights - rigs[1.2].weights).max() > 1e-2
