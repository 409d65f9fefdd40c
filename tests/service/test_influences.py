"""The served rig has at most 4 skin influences a vertex by default, 8 when asked (JSON, npz, multipart);
anything else is a 422 naming `influences`; an outfit_id keeps the influences it was rigged with."""

import numpy as np
import pytest

from drape.assets.outfits import generate_outfit
from drape.schemas.binary import NPZ, decode_npz, encode_npz


@pytest.fixture(scope="module")
def mesh():
    o = generate_outfit("tshirt", vertices=900, seed=3)
    return o.vertices, o.faces


def influences_of(answer: bytes) -> int:
    return int((decode_npz(answer)["skinning_weights"] > 0).sum(axis=1).max())


def test_four_by_default_eight_when_asked_in_every_request_form(http, mesh):
    v, f = mesh
    json_body = {"vertices": v.tolist(), "faces": f.tolist()}
    r4 = http.post("/v1/outfits/rig", json=json_body, headers={"accept": NPZ})
    r8 = http.post("/v1/outfits/rig", json={**json_body, "influences": 8}, headers={"accept": NPZ})
    assert influences_of(r4.content) <= 4 and 4 < influences_of(r8.content) <= 8
    assert decode_npz(r4.content)["outfit_id"] != decode_npz(r8.content)["outfit_id"]
    npz8 = http.post("/v1/outfits/rig", content=encode_npz({"vertices": v, "faces": f, "influences": np.array(8)}),
                     headers={"content-type": NPZ, "accept": NPZ})
    assert str(decode_npz(npz8.content)["outfit_id"]) == str(decode_npz(r8.content)["outfit_id"])
    obj = "".join(f"v {x} {y} {z}\n" for x, y, z in v) + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f)
    form = http.post("/v1/outfits/rig", files={"mesh": ("shirt.obj", obj.encode())}, data={"influences": "8"},
                     headers={"accept": NPZ})
    assert form.status_code == 200 and influences_of(form.content) <= 8


@pytest.mark.parametrize("value", [5, "8", 0, True])
def test_other_values_are_a_422_naming_the_field(http, mesh, value):
    v, f = mesh
    r = http.post("/v1/outfits/rig", json={"vertices": v.tolist(), "faces": f.tolist(), "influences": value})
    assert r.status_code == 422 and "influences" in r.text, r.text


def test_an_outfit_id_keeps_its_influences(http, mesh):
    v, f = mesh
    oid = http.post("/v1/outfits/rig", json={"vertices": v.tolist(), "faces": f.tolist(), "influences": 8}).json()[
        "outfit_id"]
    ok = http.post("/v1/outfits/animate", json={"outfit_id": oid, "motion": {"clip": "kick"}, "influences": 8},
                   headers={"accept": NPZ})
    assert ok.status_code == 200
    r = http.post("/v1/outfits/animate", json={"outfit_id": oid, "motion": {"clip": "kick"}, "influences": 4})
    assert r.status_code == 422 and "influences" in r.text, r.text
