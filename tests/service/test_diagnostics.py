"""Every rig answer says where the mesh sits on the body at rest (inside share, distances, boxes, warnings
in sentences); a mesh nowhere near the body is a 422 that says so (rig, and animate with an inline outfit)."""

import json

import numpy as np
import pytest

import drape
from drape.assets.body import load_body
from drape.assets.outfits import generate_outfit
from drape.geometry.mesh import vertex_normals
from drape.geometry.placement import placement
from drape.schemas.binary import NPZ, decode_npz


@pytest.fixture(scope="module")
def shirt():
    o = generate_outfit("tshirt", vertices=600, seed=8)  # a JSON rig within the test limits
    return o.vertices.astype(np.float64), o.faces


def rig(http, v, f, accept="application/json"):
    return http.post("/v1/outfits/rig", json={"vertices": v.tolist(), "faces": f.tolist()}, headers={"accept": accept})


def test_a_garment_on_the_body_has_no_warnings(http, shirt):
    r = rig(http, *shirt)
    assert r.status_code == 200
    d = r.json()["diagnostics"]
    assert d["inside_share"] < 0.02 and d["warnings"] == []
    assert 0 <= d["distance_mm"]["min"] <= d["distance_mm"]["median"] <= d["distance_mm"]["max"] < 300
    npz = decode_npz(rig(http, *shirt, accept=NPZ).content)
    assert json.loads(str(npz["diagnostics"])) == d


def test_a_shrunk_garment_is_reported_inside(http, shirt):
    v, f = shirt
    centre = v.mean(axis=0)
    r = rig(http, centre + 0.8 * (v - centre), f)
    d = r.json()["diagnostics"]
    assert d["inside_share"] > 0.1
    assert any(f"{100 * d['inside_share']:.0f}% of the vertices are inside the body" in w for w in d["warnings"])


def test_a_z_up_garment_is_named(http, shirt):
    v, f = shirt
    centre = v.mean(axis=0)
    z_up = (v - centre) @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]]).T + centre  # (x, -z, y): its up (+y) now +z
    d = rig(http, z_up, f).json()["diagnostics"]
    assert any("looks Z-up" in w for w in d["warnings"]), d["warnings"]


def test_a_garment_away_from_the_body_is_a_422(http, shirt):
    v, f = shirt
    far = v + [0, 0, 2.0]
    r = rig(http, far, f)
    assert r.status_code == 422 and "30 cm" in r.text and "vertices" in r.text, r.text
    r = http.post("/v1/outfits/animate", json={"outfit": {"vertices": far.tolist(), "faces": f.tolist()},
                                               "motion": {"clip": "kick"}})
    assert r.status_code == 422 and "outfit.vertices" in r.text, r.text


def test_the_client_carries_the_diagnostics(server_url, shirt):
    with drape.Client(server_url) as client:
        result = client.rig(shirt)
    assert result.diagnostics["warnings"] == [] and "inside_share" in result.diagnostics


def test_placement_against_an_independent_count():
    body = load_body("neutral")
    normals = vertex_normals(body.vertices, body.faces)
    inner = body.vertices - 0.01 * normals  # 1 cm inside everywhere
    assert placement(inner, body.vertices, body.faces)["inside_share"] > 0.8  # thin parts: 1 cm crosses them
    outer = body.vertices + 0.01 * normals  # 1 cm outside everywhere
    d = placement(outer, body.vertices, body.faces)
    assert d["inside_share"] < 0.1 and abs(d["distance_mm"]["median"] - 10) < 1.5  # concave parts cross back


def test_a_garment_centred_on_the_origin_is_named():
    body = load_body("neutral")
    o = generate_outfit("tshirt", vertices=600, seed=8)
    at_origin = o.vertices - o.vertices.mean(axis=0)  # as garments made for other tools often come
    d = placement(at_origin, body.vertices, body.faces)
    assert any("below the body's feet" in w and "centred on the origin" in w for w in d["warnings"]), d



def test_a_body_taller_than_every_trained_body_is_named():
    """The shipped model (the service tests' own is untrained and knows no trained bodies): the rig handler adds
    this sentence to the diagnostics' warnings."""
    from types import SimpleNamespace

    from drape.runtime.deepsd import DeePSDModel
    from drape.service.handlers import body_scale_warnings

    engine = SimpleNamespace(model=DeePSDModel())  # all body_scale_warnings reads of an Engine
    (sentence,) = body_scale_warnings(engine, "heavy")  # heavy: 1.95 m; trained 1.66-1.80 m
    # three decimals: a body 3 mm shorter than the shortest trained one reads 1.661 against 1.664, not "1.66 m
    # tall, outside the 1.66-1.80 m"
    assert "1.949 m tall, outside the 1.664-1.796 m" in sentence and "scaled to 1.796 m" in sentence, sentence
    assert body_scale_warnings(engine, "male") == []
