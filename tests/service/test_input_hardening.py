"""Multipart forms and npz archives the parser or a route once mishandled: each is a 4xx problem naming the field,
never a 500 and never a silent guess (a long boundary was a 500; a repeated or misspelt field, a member stored twice,
or a fit pose of strings, was quietly taken or dropped)."""

import io
import zipfile

import numpy as np
import pytest
from svc_env import problem

from drape.schemas.binary import NPZ

OBJ = b"v 0 1 0.2\nv 0.1 1 0.2\nv 0 1.1 0.2\nv 0.1 1.1 0.25\nf 1 2 3\nf 2 4 3\n"


@pytest.mark.parametrize("path", ["/v1/outfits/rig", "/v1/outfits/animate", "/v1/refine", "/v1/bodies"])
def test_a_boundary_longer_than_the_parser_takes_is_a_400_naming_content_type(http, path):
    boundary = "b" * 300  # python-multipart refuses over 256 (RFC 2046: at most 70): was a 500 FormParserError
    body = f"--{boundary}\r\nContent-Disposition: form-data; name=\"x\"\r\n\r\n1\r\n--{boundary}--\r\n".encode()
    r = http.post(path, content=body, headers={"content-type": f"multipart/form-data; boundary={boundary}"})
    problem(r, 400, "Content-Type", "boundary")


@pytest.mark.parametrize("path", ["/v1/outfits/rig", "/v1/bodies"])
def test_a_form_cut_before_its_closing_boundary_is_a_400_not_a_form_without_its_last_field(http, path):
    """The parser drops a last part it never sees end: a rig form cut after `body=female` rigged on neutral (a
    200 with neutral's outfit_id), an animate form cut after `refine=true` answered unrefined frames."""
    b = "xyz"
    head = (f"--{b}\r\nContent-Disposition: form-data; name=\"mesh\"; filename=\"a.obj\"\r\n\r\n").encode() + OBJ
    cut = head + f"\r\n--{b}\r\nContent-Disposition: form-data; name=\"body\"\r\n\r\nfemale\r\n".encode()
    r = http.post(path, content=cut, headers={"content-type": f"multipart/form-data; boundary={b}"})
    problem(r, 400, "body", "closing boundary")
    if path == "/v1/outfits/rig":  # the same form whole is read
        whole = http.post(path, content=cut + f"--{b}--\r\n".encode(),
                          headers={"content-type": f"multipart/form-data; boundary={b}"})
        female = http.post(path, files={"mesh": ("a.obj", OBJ)}, data={"body": "female"})
        assert whole.status_code == 200 and whole.json()["outfit_id"] == female.json()["outfit_id"], whole.text[:300]


def test_a_field_given_twice_is_refused_not_last_wins(http):
    files = [("mesh", ("a.obj", OBJ)), ("mesh", ("b.obj", OBJ))]
    problem(http.post("/v1/outfits/rig", files=files), 422, "mesh", "more than once")
    files = [("motion_file", ("m.bvh", b"HIERARCHY")), ("outfit_id", (None, b"a")), ("outfit_id", (None, b"b"))]
    p = problem(http.post("/v1/outfits/animate", files=files), 422, "outfit_id", "more than once")
    assert p["field"] == "outfit_id"  # the field's name, not its repr ("'outfit_id'")


def test_the_rig_form_refuses_an_unknown_field_as_the_other_forms_do(http):
    """`influence=8` (for influences) was dropped without a word: the rig answered 4 influences."""
    r = http.post("/v1/outfits/rig", files={"mesh": ("a.obj", OBJ)}, data={"influence": "8"})
    p = problem(r, 422, "influence: unknown form field 'influence'", "influences")
    assert p["field"] == "influence"


@pytest.mark.parametrize("cell", ['"0"', "true", "null"])
def test_a_fit_form_pose_of_strings_booleans_or_nulls_is_refused(http, cell):
    """Strings were read as numbers (a 200), booleans as 0/1 and nulls as NaN ('must be finite ... within 2 pi')."""
    pose = "[" + ",".join([f"[{cell}, 0, 0]"] * 24) + "]"
    r = http.post("/v1/outfits/fit", files={"mesh": ("a.obj", OBJ)}, data={"pose": pose})
    problem(r, 422, "pose", "numbers")


def _npy(a: np.ndarray) -> bytes:
    f = io.BytesIO()
    np.save(f, a)
    return f.getvalue()


def test_an_npz_member_stored_twice_is_refused_not_last_wins(http):
    """A zip may hold one name twice; the later entry was read (here: an outfit_id that answered 404)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("poses.npy", _npy(np.zeros((3, 72))))
        z.writestr("outfit_id.npy", _npy(np.array("first")))
        z.writestr("outfit_id.npy", _npy(np.array("second")))
    r = http.post("/v1/outfits/animate", content=buf.getvalue(), headers={"content-type": NPZ})
    problem(r, 400, "body", "'outfit_id'", "more than once")


@pytest.mark.parametrize("fps", [29.97, 1e-300])
def test_the_npz_answer_gives_the_frame_rate_it_was_asked_for(http, fps):
    """The npz answer stored fps as float32: 29.97 came back 29.969999 and 1e-300 (in range: (0, 1000]) as 0."""
    req = {"outfit": {"vertices": [[0, 1, 0.2], [0.1, 1, 0.2], [0, 1.1, 0.2]], "faces": [[0, 1, 2]]},
           "motion": {"poses": np.zeros((2, 72)).tolist(), "fps": fps}}
    r = http.post("/v1/outfits/animate", json=req, headers={"accept": NPZ})
    assert r.status_code == 200, r.text
    assert float(np.load(io.BytesIO(r.content))["fps"]) == fps


TINY = {"vertices": [[0, 1, 0.2], [0.1, 1, 0.2], [0, 1.1, 0.2]], "faces": [[0, 1, 2]]}


def _npz(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def test_refine_false_beside_refine_options_is_refused_not_the_options_dropped(http):
    """The options turn refinement on; `refine` false beside them answered 200 unrefined, the options dropped without
    a word (npz and form animate, the garment's npz animate)."""
    off = {"refine": np.array(False), "eps": np.array(0.01)}
    r = http.post("/v1/outfits/animate", content=_npz(vertices=np.array(TINY["vertices"], float),
                                                      faces=np.array(TINY["faces"]), poses=np.zeros((2, 72)), **off),
                  headers={"content-type": NPZ, "accept": NPZ})
    problem(r, 422, "refine", "eps")
    r = http.post("/v1/garments/testskirt/animate", headers={"content-type": NPZ}, content=_npz(
        poses=np.zeros((3, 72)), latent_frames=np.array([0]), latents=np.zeros((1, 100)), **off))
    problem(r, 422, "refine", "eps")
    rig = http.post("/v1/outfits/rig", json=TINY)
    assert rig.status_code == 200, rig.text[:300]
    motion = b"HIERARCHY\n"  # never read: the fields are checked first
    r = http.post("/v1/outfits/animate", files={"motion_file": ("m.bvh", motion)},
                  data={"outfit_id": rig.json()["outfit_id"], "refine": "false", "max_iterations": "5"})
    problem(r, 422, "refine", "max_iterations")


def test_errors_in_an_uploaded_mesh_name_the_mesh_field(http):
    """A bad OBJ's faces or vertices were named 'faces' / 'vertices', fields the form does not have."""
    bad = b"v 0 1 0.2\nv 0.1 1 0.2\nv 0 1.1 0.2\nf 1 1 2\n"  # a face repeating a vertex
    problem(http.post("/v1/outfits/rig", files={"mesh": ("a.obj", bad)}), 422, "mesh.faces: ", "repeats")
    problem(http.post("/v1/outfits/fit", files={"mesh": ("a.obj", bad)}), 422, "mesh.faces: ", "repeats")
    far = b"v 50 1 0.2\nv 50.1 1 0.2\nv 50 1.1 0.2\nf 1 2 3\n"  # 50 m from the body
    problem(http.post("/v1/outfits/rig", files={"mesh": ("a.obj", far)}), 422, "mesh.vertices: ", "within")



@pytest.mark.parametrize(("field", "text"), [("fps", "2_0"), ("fps", "infinity"), ("eps", "nan"), ("eps", "1_0e-3"),
                                             ("max_iterations", "1_0"), ("max_iterations", "5.0"),
                                             ("max_iterations", "9" * 5000), ("relief_iterations", "1" * 4301),
                                             ("fps", "3" * 400)])
def test_form_numbers_are_json_numbers_not_what_python_reads(http, field, text):
    """float() and int() read "2_0" as 20 and "nan" as a number: fps=2_0 animated at 20 fps. int() refuses a
    number of over 4,300 digits with a ValueError: max_iterations of 5,000 nines was a 500."""
    rig = http.post("/v1/outfits/rig", json=TINY)
    assert rig.status_code == 200, rig.text[:300]
    r = http.post("/v1/outfits/animate", files={"motion_file": ("m.bvh", b"HIERARCHY\n")},
                  data={"outfit_id": rig.json()["outfit_id"], field: text})
    problem(r, 422, field, "expected")


def test_a_body_whose_faces_leave_its_vertices_off_the_surface_is_refused(http):
    """The proxy's 1,229 vertices with one triangle registered (201), and rig, refine and export then ran against
    that one triangle."""
    from drape.assets.body import load_body

    proxy = load_body("neutral", proxy=True)
    arrays = {"vertices": proxy.vertices, "faces": proxy.faces[:1], "weights": proxy.weights, "joints": proxy.joints}
    r = http.post("/v1/bodies", content=_npz(**arrays), headers={"content-type": NPZ})
    problem(r, 422, "faces", "0.2% of the 1229 vertices")
    r = http.post("/v1/bodies", files={"body_file": ("b.npz", _npz(**arrays))})
    problem(r, 422, "body_file.faces", "lie on a face")


@pytest.mark.parametrize(("path", "body"), [
    ("/v1/layers/animate", {"inner": "tshirt", "outer": "jacket"}),
    ("/v1/garments/testskirt/animate", {"keyframes": [{"frame": 0, "latent": [0.0] * 100}]}),
    ("/v1/outfits/animate", {"outfit": {"vertices": [[0, 1, 0.2], [0.1, 1, 0.2], [0, 1.1, 0.2]], "faces": [[0, 1, 2]]}}),
])
def test_wrong_refine_options_name_the_option_not_the_union_member(http, path, body):
    """`refine` is true/false or options; a wrong option was named `refine.bool` (the problem's field) beside
    `refine.RefineOptions.eps`, pydantic's names for the union's members."""
    p = problem(http.post(path, json={**body, "motion": {"clip": "kick"}, "refine": {"eps": 0.5}}), 422,
                "refine.eps: Input should be less than or equal to 0.05")
    assert p["field"] == "refine.eps" and "bool" not in p["detail"] and "RefineOptions" not in p["detail"], p
    p = problem(http.post(path, json={**body, "motion": {"clip": "kick"}, "refine": {"epz": 0.01}}), 422, "refine.epz")
    assert p["field"] == "refine.epz", p
    p = problem(http.post(path, json={**body, "motion": {"clip": "kick"}, "refine": "yes"}), 422,
                "refine: Input should be a valid boolean")
    assert p["field"] == "refine", p


def test_poses_with_one_wrong_value_name_that_value_not_the_other_union_member(http):
    """poses are (T, 72) or (T, 24, 3): one string among (T, 24, 3) poses was reported as `motion.poses.0.N: Input
    should be a valid number` five times (the (T, 72) member's complaints about valid rows), the string itself not
    at all; a (T, 72) row with one string also listed 'Input should be a valid list' for each of its numbers."""
    rig = http.post("/v1/outfits/rig", json={"vertices": [[0, 1, 0.2], [0.1, 1, 0.2], [0, 1.1, 0.2]],
                                              "faces": [[0, 1, 2]]})
    outfit_id = rig.json()["outfit_id"]
    nested = [[[0, 0, 0]] * 24, [[0, 0, 0]] * 3 + [[0, 0, "a"]] + [[0, 0, 0]] * 20]
    p = problem(http.post("/v1/outfits/animate", json={"outfit_id": outfit_id, "motion": {"poses": nested}}), 422,
                "motion.poses[1][3][2]: Input should be a valid number")
    assert p["field"] == "motion.poses[1][3][2]" and "poses[0]" not in p["detail"], p
    flat = [[0.0] * 71 + ["a"]]
    p = problem(http.post("/v1/outfits/animate", json={"outfit_id": outfit_id, "motion": {"poses": flat}}), 422)
    assert p["field"] == "motion.poses[0][71]" and "valid list" not in p["detail"], p


def test_a_json_object_that_names_a_key_twice_is_refused_not_last_wins(http):
    """`{"outfit_id": "nope", "outfit_id": "<valid>"}` answered 200 (the reverse a 404) and `"refine": true,
    "refine": false` unrefined frames: json.loads keeps the last. A form field or npz member given twice was
    refused already."""
    body = b'{"motion": {"clip": "kick"}, "refine": true, "refine": false, "outfit_id": "x"}'
    p = problem(http.post("/v1/outfits/animate", content=body, headers={"content-type": "application/json"}), 422,
                "'refine' more than once")
    assert p["field"] == "refine"
    nested = b'{"outfit_id": "x", "motion": {"clip": "kick", "clip": "walk"}}'
    p = problem(http.post("/v1/outfits/animate", content=nested, headers={"content-type": "application/json"}), 422,
                "'clip' more than once")
    assert p["field"] == "motion.clip"  # its path in the document (was "clip")
    listed = b'{"motion": {"clip": "kick"}, "keyframes": [{"frame": 0}, {"frame": 1, "frame": 2}]}'
    p = problem(http.post("/v1/outfits/animate", content=listed, headers={"content-type": "application/json"}), 422,
                "'frame' more than once")
    assert p["field"] == "keyframes[1].frame"
    form = {"motion_file": ("m.bvh", b"HIERARCHY"), "request": (None, b'{"inner": "tshirt", "inner": "tanktop"}')}
    p = problem(http.post("/v1/layers/animate", files=form), 422, "'inner' more than once")
    assert p["field"] == "request"  # the form field that holds the JSON text
    pose = '{"pelvis": [0, 0, 0], "pelvis": [1, 0, 0]}'
    r = http.post("/v1/bodies", files={"body_file": ("b.glb", b"glTF")}, data={"joint_map": pose})
    assert problem(r, 422, "'pelvis' more than once")["field"] == "joint_map"


def test_a_body_file_npz_is_named_body_file_and_a_rest_pose_given_twice_is_refused(http):
    """An unreadable npz in the body_file form field was named `body`; a form rest_pose beside the archive's own
    rest_pose member was taken and the member dropped without a word."""
    from drape.assets.body import load_body

    buf = io.BytesIO()
    np.savez(buf, vertices=np.array([1, None], dtype=object))
    r = http.post("/v1/bodies", files={"body_file": ("b.npz", buf.getvalue())})
    assert problem(r, 400, "pickled or object arrays are refused")["field"] == "body_file"
    r = http.post("/v1/bodies", files={"body_file": ("b.npz", b"PK\x03\x04")})
    assert problem(r, 400)["field"] == "body_file"
    proxy = load_body("neutral", proxy=True)
    arrays = {"vertices": proxy.vertices, "faces": proxy.faces, "weights": proxy.weights, "joints": proxy.joints,
              "rest_pose": np.zeros((24, 3))}
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    r = http.post("/v1/bodies", files={"body_file": ("b.npz", buf.getvalue())},
                  data={"rest_pose": "[" + ",".join(["[0, 0, 0]"] * 24) + "]"})
    assert problem(r, 422, "given twice")["field"] == "rest_pose"


def test_an_npz_scalar_of_long_double_reads_as_a_python_float():
    """np.array(0.01, np.longdouble).item() is numpy's own long double: the range checks then refused 0.01
    ("expected ... in (0, 0.05], got 0.0100...")."""
    from drape.service.decode import npz_scalar

    value = npz_scalar({"thickness": np.array(0.01, np.longdouble)}, "thickness")
    assert type(value) is float and value == 0.01
    assert type(npz_scalar({"n": np.array(3, np.uint8)}, "n")) is int
