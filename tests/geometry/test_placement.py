"""The rig answer's placement check (drape.geometry.placement) on a garment turned Z-up."""

import numpy as np

from drape.assets.body import load_body
from drape.assets.outfits import generate_outfit
from drape.geometry.fitting import Z_UP_TO_Y_UP
from drape.geometry.placement import _fits_better_y_up, body_distance, placement


def test_the_z_up_check_turns_the_mesh_as_its_warning_says():
    """A Y-up t-shirt authored Z-up ((x, y, z) -> (x, -z, y): its up is +Z), turned back as the warning tells the user
    (-90 degrees about x: (x, y, z) -> (x, z, -y), fitting's Z_UP_TO_Y_UP) lies where the Y-up one does. The check
    turned it the other way (+90 degrees: upside down) and measured that instead."""
    body = load_body("neutral")
    v = generate_outfit("tshirt", vertices=600, seed=8).vertices.astype(np.float64)
    centre = v.mean(axis=0)
    z_up = (v - centre) @ np.linalg.inv(Z_UP_TO_Y_UP).T + centre
    assert np.allclose((z_up - centre) @ Z_UP_TO_Y_UP.T + centre, v)
    distance = body_distance(body.vertices, body.faces)
    y_up_median = float(np.median(np.abs(distance.signed_distance(v)))) * 1e3
    # turned back it is the Y-up t-shirt: its median distance, not more than 10% over it
    assert _fits_better_y_up(z_up, distance, 2 * 1.1 * y_up_median)
    assert placement(v, body.vertices, body.faces, distance)["warnings"] == []
    assert any("looks Z-up" in w for w in placement(z_up, body.vertices, body.faces, distance)["warnings"])
