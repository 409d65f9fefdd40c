"""The `drape` command line, end to end on small inputs."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from drape.geometry.mesh_io import load_mesh

EXTERNAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "external"


def drape(*args):
    r = subprocess.run([sys.executable, "-m", "drape.cli", *args], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_outfits_generate_writes_a_mesh(tmp_path):
    out = tmp_path / "outfit.obj"
    drape("outfits", "generate", "--type", "tshirt,trousers", "--vertices", "1500", "--seed", "3",
          "--body", "female", "--out", str(out))
    v, f = load_mesh(out)
    assert abs(len(v) - 1500) <= 150 and f.max() < len(v)
    # one named object a garment, each garment's vertices together: the service reads them as the rig's parts
    from drape.assets.outfits import generate_outfit
    from drape.geometry.mesh_io import obj_parts

    outfit = generate_outfit("tshirt,trousers", vertices=1500, seed=3, body="female")
    parts = obj_parts(out.read_bytes(), out.name, len(v))
    assert [p["name"] for p in parts] == outfit.garments
    for g, p in enumerate(parts):
        mine = outfit.vertices[outfit.garment == g]
        assert p["stop"] - p["start"] == len(mine)
        np.testing.assert_allclose(v[p["start"]:p["stop"]], mine, atol=1e-6)
    def triangles(vertices, faces):  # each face as its corners' coordinates, same winding, any order
        return sorted(map(tuple, vertices[faces].reshape(len(faces), 9).round(5).tolist()))

    assert triangles(v, f) == triangles(outfit.vertices, outfit.faces)


def test_outfits_fit_puts_a_z_up_centimetre_garment_on_the_body(tmp_path):
    from drape.geometry.mesh_io import save_mesh

    made = tmp_path / "made.obj"
    drape("outfits", "generate", "--type", "trousers", "--vertices", "500", "--seed", "2", "--body", "male",
          "--out", str(made))
    v, f = load_mesh(made)
    foreign = tmp_path / "foreign.obj"
    save_mesh(foreign, v @ np.array([[100.0, 0, 0], [0, 0, -100.0], [0, 100.0, 0]]).T, f)  # Z-up, cm
    out, report = tmp_path / "fitted.obj", tmp_path / "new" / "fit.json"  # a folder to make, as for the mesh
    text = drape("outfits", "fit", str(foreign), "--body", "neutral", "--out", str(out), "--report", str(report))
    assert "units cm (inferred), up z (inferred)" in text, text
    import json

    rep = json.loads(report.read_text())["report"]
    assert rep["inside_after"] <= 0.001 and len(load_mesh(out)[0]) == len(v)


def test_outfits_fit_keeps_an_objs_garments_as_objects(tmp_path):
    """The fit keeps the vertex order, so an OBJ's objects are written back as they came, and the rig answers
    the fitted file with the same parts (they were dropped: one unnamed mesh)."""
    from drape.geometry.mesh_io import obj_parts

    made, out = tmp_path / "two.obj", tmp_path / "fitted.obj"
    drape("outfits", "generate", "--type", "tshirt,trousers", "--vertices", "800", "--seed", "2", "--out", str(made))
    drape("outfits", "fit", str(made), "--body", "male", "--out", str(out))
    before = obj_parts(made.read_bytes(), made.name, len(load_mesh(made)[0]))
    assert [p["name"] for p in before] == ["trousers", "tshirt"]
    assert obj_parts(out.read_bytes(), out.name, len(load_mesh(out)[0])) == before


@pytest.mark.skipif(not (EXTERNAL / "ncsim_arcsim_tshirt_no_sleeves.obj").exists(), reason="../shared/data absent")
def test_outfits_fit_writes_an_obj_back_with_its_uvs_materials_and_normals(tmp_path):
    """A real garment OBJ made elsewhere (ArcSim, Meshlab's export: mtllib, one vn per v) fitted to an OBJ: the
    same file with its vertices moved (it was written as bare v/f lines, its material and normals gone); its
    normals turned with the fit (Z-up to Y-up, faced front) and still on the outer side of the fitted cloth."""
    mesh = EXTERNAL / "ncsim_arcsim_tshirt_no_sleeves.obj"
    out = tmp_path / "fitted.obj"
    text = drape("outfits", "fit", str(mesh), "--body", "neutral", "--out", str(out))
    assert "normals: turned" in text, text
    old, new = mesh.read_text().splitlines(), out.read_text().splitlines()
    assert [a for a in old if not a.startswith(("v ", "vn "))] == [b for b in new if not b.startswith(("v ", "vn "))]
    assert "mtllib ./tshirt.obj.mtl" in new
    v, f = load_mesh(out)
    normals = np.array([[float(c) for c in line.split()[1:]] for line in new if line.startswith("vn ")])
    assert normals.shape == v.shape  # this file has one normal per vertex, in order
    import trimesh

    smooth = trimesh.Trimesh(v, f, process=False).vertex_normals  # the fitted geometry's own
    used = np.unique(f)  # 100 of its 330 vertices are in no face: no normal of their own to compare with
    agree = np.einsum("ij,ij->i", normals[used], smooth[used])
    assert np.median(agree) > 0.9 and (agree > 0).mean() > 0.95, np.percentile(agree, [5, 50])


def test_motions_generate_and_render(tmp_path):
    motion = tmp_path / "m.npz"
    drape("motions", "generate", "--frames", "40", "--seed", "2", "--out", str(motion))
    with np.load(motion, allow_pickle=False) as z:
        assert z["poses"].shape == (40, 24, 3)
    # a body file as --body, as outfits fit and motions import take one; an --out that would become x.obj.npz refused
    from drape.assets.body import BODIES_DIR

    drape("motions", "generate", "--frames", "5", "--body", str(BODIES_DIR / "male.npz"), "--out", str(tmp_path / "b"))
    assert (tmp_path / "b.npz").exists()
    r = subprocess.run([sys.executable, "-m", "drape.cli", "motions", "generate", "--frames", "5", "--out",
                        str(tmp_path / "x.obj")], capture_output=True, text=True)
    assert r.returncode != 0 and "expected a file ending in .npz" in r.stderr and not (tmp_path / "x.obj.npz").exists()
    # --out me beside --body me.npz would write me.npz: the body is not replaced (it was)
    import shutil

    shutil.copy(BODIES_DIR / "male.npz", tmp_path / "me.npz")
    r = subprocess.run([sys.executable, "-m", "drape.cli", "motions", "generate", "--frames", "5", "--body",
                        str(tmp_path / "me.npz"), "--out", str(tmp_path / "me")], capture_output=True, text=True)
    assert r.returncode != 0 and "is the input" in r.stderr, r.stderr
    assert (tmp_path / "me.npz").read_bytes() == (BODIES_DIR / "male.npz").read_bytes()
    drape("motions", "generate", "--frames", "5", "--out", str(tmp_path / "upper.NPZ"))
    assert [p.name for p in tmp_path.glob("upper*")] == ["upper.NPZ"]  # not upper.NPZ.npz
    mesh = tmp_path / "skirt.ply"
    drape("outfits", "generate", "--type", "skirt", "--vertices", "800", "--out", str(mesh))
    png = tmp_path / "look.png"
    drape("render", "--body", "male", "--outfit", str(mesh), "--motion", str(motion), "--frames", "0,39",
          "--out", str(png))
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_errors_are_reported_not_raised(tmp_path):
    r = subprocess.run([sys.executable, "-m", "drape.cli", "outfits", "generate", "--type", "cape",
                        "--out", str(tmp_path / "x.obj")], capture_output=True, text=True)
    assert r.returncode == 2 and "unknown garment type" in r.stderr
    r = subprocess.run([sys.executable, "-m", "drape.cli", "render", "--clip", "nope", "--out",
                        str(tmp_path / "x.png")], capture_output=True, text=True)
    assert r.returncode == 2 and "unknown clip" in r.stderr


def test_files_that_cannot_be_read_or_written_are_one_line_errors(tmp_path):
    """A missing or unreadable input, or an --out that cannot be made (its folder is a file): the path and the
    OS's reason, exit 1, no traceback; a KeyError's message is printed as it is, not as its repr."""
    def fails(*args):
        r = subprocess.run([sys.executable, "-m", "drape.cli", *args], capture_output=True, text=True)
        assert r.returncode in (1, 2) and "Traceback" not in r.stderr, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1, r.stderr
        return r.stderr.strip()

    missing = tmp_path / "missing.npz"
    assert fails("export", "pc2", str(missing), "--out", str(tmp_path / "x.pc2")) == \
        f"drape: error: {missing}: No such file or directory"
    assert fails("export", "glb", str(tmp_path), "--out", str(tmp_path / "x.glb")) == \
        f"drape: error: {tmp_path}: Is a directory"
    assert fails("render", "--motion", str(missing), "--out", str(tmp_path / "x.png")).endswith(
        f"{missing}: No such file or directory")
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    assert fails("motions", "generate", "--frames", "3", "--out", str(blocker / "m.npz")).startswith(
        f"drape: error: {blocker}: ")
    assert fails("render", "--clip", "nope", "--out", str(tmp_path / "x.png")).startswith(
        "drape: error: unknown clip 'nope'; embedded clips: ")


def test_export_pc2_and_glb_from_an_npz_stream(tmp_path):
    from drape.schemas.binary import encode_npz
    from drape.schemas.pc2 import read_pc2

    rng = np.random.default_rng(0)
    frames = rng.normal(size=(7, 30, 3)).astype(np.float32)
    faces = np.stack([np.arange(28), np.arange(1, 29), np.arange(2, 30)], 1).astype(np.int32)
    stream = tmp_path / "s.npz"
    stream.write_bytes(encode_npz({"vertices": frames, "faces": faces, "fps": np.float32(24)}))
    drape("export", "pc2", str(stream), "--out", str(tmp_path / "s.pc2"), "--start-frame", "1")
    got, start, rate = read_pc2((tmp_path / "s.pc2").read_bytes())
    assert np.array_equal(got, frames) and (start, rate) == (1.0, 1.0)
    drape("export", "glb", str(stream), "--out", str(tmp_path / "s.glb"))
    import pygltflib

    doc = pygltflib.GLTF2.load_from_bytes((tmp_path / "s.glb").read_bytes())
    assert len(doc.meshes[0].primitives[0].targets) == 6
    times = doc.accessors[doc.animations[0].samplers[0].input]
    assert abs(times.max[0] - 6 / 24) < 1e-6


def test_export_refuses_a_malformed_stream_naming_the_member(tmp_path, monkeypatch, capsys):
    """Every malformed npz stream is a one-line refusal naming the file and the member, before anything is
    written: not a traceback, a pygltflib JSON error, or a PC2 / GLB of NaNs, dangling faces or a broken clock."""
    from drape import cli
    from drape.schemas.binary import encode_npz

    rng = np.random.default_rng(1)
    v = rng.normal(size=(4, 10, 3)).astype(np.float32)
    f = np.array([[0, 1, 2], [2, 3, 9]], np.int32)

    def refused(kind, arrays, *extra):
        stream, out = tmp_path / "s.npz", tmp_path / f"out.{kind}"
        stream.write_bytes(encode_npz(arrays))
        with pytest.raises(SystemExit) as exc:
            cli.main(["export", kind, str(stream), "--out", str(out), *extra])
        assert not out.exists()
        text = exc.value.code if isinstance(exc.value.code, str) else capsys.readouterr().err
        assert exc.value.code != 0 and "\n" not in text.strip(), text
        return text

    for kind in ("pc2", "glb"):
        assert "'vertices' must be (T, N, 3) numbers" in refused(kind, {"vertices": v.astype(complex), "faces": f})
        assert "'vertices' must be (T, N, 3) numbers" in refused(kind, {"vertices": np.array([[["a"]]]), "faces": f})
        bad = v.copy()
        bad[2, 3, 1] = np.nan
        assert "'vertices' holds NaN or infinite values" in refused(kind, {"vertices": bad, "faces": f})
        assert "'vertices' holds NaN or infinite values" in refused(kind, {"vertices": v * 1e300, "faces": f})
        assert "no frames or no vertices" in refused(kind, {"vertices": v[:0], "faces": f})
        assert "no frames or no vertices" in refused(kind, {"vertices": v[:, :0], "faces": f[:0]})
        text = refused(kind, {"vertices": np.array([object()], dtype=object), "faces": f})
        assert str(tmp_path / "s.npz") in text and "pickled or object arrays are refused" in text
    layers = {"inner_vertices": v, "inner_faces": f[:1], "outer_vertices": v, "outer_faces": f[:1]}
    for change, said in (({"inner_vertices": np.array([[["a", "b", "c"]]])}, "'inner_vertices' must be (T, N, 3) num"),
                         ({"outer_vertices": v > 0}, "'outer_vertices' must be (T, N, 3) numbers, got (4, 10, 3) bool"),
                         ({"outer_vertices": v[:2]}, "must have the same frames"),
                         ({"outer_faces": f + 1}, "'outer_faces' index vertices 1..10; its layer has 10"),
                         ({"inner_faces": f - 1}, "'inner_faces' index vertices -1..8")):
        assert said in refused("pc2", {**layers, **change})
    for faces, said in ((f + 1, "'faces' index vertices 1..10; the stream has 10 (0..9)"),
                        (f - 1, "'faces' index vertices -1..8"), (f[:, :2], "'faces' must be (F, 3) integers"),
                        (f + 0.5, "'faces' must be (F, 3) integers"), (f[:0], "'faces' must be (F, 3) integers")):
        assert said in refused("glb", {"vertices": v, "faces": faces})
    for fps in (0.0, -24.0, np.nan, np.inf, np.array([24.0, 30.0]), np.array("24")):
        assert "'fps' must be one positive number" in refused("glb", {"vertices": v, "faces": f, "fps": fps})
    assert "too low for a glTF animation" in refused("glb", {"vertices": v, "faces": f, "fps": np.float32(1e-44)})
    # a rate beyond float32 would put every key at 0 s (key times must increase)
    assert "too high for a glTF animation" in refused("glb", {"vertices": v, "faces": f, "fps": np.float64(1e39)})
    monkeypatch.setenv("DRAPE_MAX_POSED_VALUES", "11")  # the service's bound, read from the same setting
    assert "4 frames need 4 x 3 morph-target weights" in refused("glb", {"vertices": v, "faces": f})
    for start in ("nan", "inf", "1e39"):
        assert "--start-frame must be a finite float32" in refused("pc2", {"vertices": v, "faces": f}, "--start-frame",
                                                                    start)
    # PC2 stores neither faces nor a frame rate: a stream whose faces or fps would not make a GLB still exports
    stream = tmp_path / "s.npz"
    stream.write_bytes(encode_npz({"vertices": v, "faces": f[:, :2] + 100, "fps": np.array([1.0, 2.0])}))
    cli.main(["export", "pc2", str(stream), "--out", str(tmp_path / "ok.pc2")])
    assert (tmp_path / "ok.pc2").stat().st_size == 32 + v.nbytes
    # nor a stream without faces at all (it was refused: "needs 'vertices' (T, N, 3) and 'faces' (F, 3)")
    stream.write_bytes(encode_npz({"vertices": v}))
    cli.main(["export", "pc2", str(stream), "--out", str(tmp_path / "points.pc2")])
    assert (tmp_path / "points.pc2").read_bytes() == (tmp_path / "ok.pc2").read_bytes()
    assert "needs 'vertices' (T, N, 3) and 'faces' (F, 3)" in refused("glb", {"vertices": v})


def test_sim_dataset_substeps_run_every_parameter_set_finer(tmp_path):
    import json

    garment = tmp_path / "long_skirt.obj"
    drape("outfits", "generate", "--type", "long_skirt", "--vertices", "300", "--seed", "3", "--out", str(garment))
    out = tmp_path / "data"
    drape("sim", "dataset", "--garment", str(garment), "--params", "2", "--seed", "21", "--motions", "walk,run",
          "--frames", "2", "--holdout-params", "1", "--holdout-motions", "1", "--splits", "test", "--substeps", "6",
          "--workers", "1", "--out", str(out))
    manifest = json.loads((out / "manifest.json").read_text())
    assert [p["substeps"] for p in manifest["params"]] == [6, 6]  # the default sets run 4
    (item,) = manifest["items"] + manifest["rejected"]
    assert item["key"].startswith("long_skirt__p01__")
    r = subprocess.run([sys.executable, "-m", "drape.cli", "sim", "dataset", "--garment", str(garment), "--motions",
                        "walk,run", "--substeps", "0", "--out", str(tmp_path / "bad")], capture_output=True, text=True)
    assert r.returncode != 0 and "--substeps must be in [1, 64]" in r.stderr
    # resumed into the same folder with other settings (the default 4 substeps): one line naming the item, no traceback
    r = subprocess.run([sys.executable, "-m", "drape.cli", "sim", "dataset", "--garment", str(garment), "--params", "2",
                        "--seed", "21", "--motions", "walk,run", "--frames", "2", "--holdout-params", "1",
                        "--holdout-motions", "1", "--splits", "test", "--workers", "1", "--out", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "simulated with other parameters" in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_sim_option_files_and_ranges_are_refused_in_one_line(tmp_path, capsys):
    """sim run's --params must be a JSON object of known parameters and sim dataset's --thickness LOW,HIGH: a
    one-line refusal naming the option, before any simulation (a JSON list raised TypeError from SimParams(**...),
    an unknown key printed pydantic's multi-line report, one number 'not enough values to unpack')."""
    from drape import cli
    from drape.geometry.mesh_io import save_mesh

    garment = tmp_path / "g.obj"
    save_mesh(garment, np.array([[0, 1, 0], [0.1, 1, 0], [0, 1.1, 0]], np.float32), np.array([[0, 1, 2]]))

    def refused(*args):
        with pytest.raises(SystemExit) as exc:
            cli.main(list(args))
        text = exc.value.code if isinstance(exc.value.code, str) else capsys.readouterr().err
        assert exc.value.code != 0 and "\n" not in text.strip(), text
        return text

    params = tmp_path / "p.json"
    for given, said in (("[1]", "must be a JSON object of parameters, got list"),
                        ('{"young": ', "is not JSON: Expecting value"),
                        ('{"nope": 1}', "nope: Extra inputs are not permitted"),
                        ('{"young": -1}', "young: Input should be greater than")):
        params.write_text(given)
        text = refused("sim", "run", "--garment", str(garment), "--clip", "walk", "--params", str(params), "--out",
                       str(tmp_path / "s.npz"))
        assert text.startswith(f"--params {params}: ") and said in text, text
    for given in ("0.01", "a,b", "0.01,0.02,0.03"):
        assert refused("sim", "dataset", "--garment", str(garment), "--outer", str(garment), "--thickness", given,
                       "--motions", "walk,run", "--out", str(tmp_path / "d")).startswith(
            f"--thickness takes LOW,HIGH in m, got {given!r}")
    # a split left empty names its option; nothing is made (it said "holdout_motions must be in [1, 0], got 1",
    # after making the dataset's folders)
    text = refused("sim", "dataset", "--garment", str(garment), "--motions", "walk", "--out", str(tmp_path / "d"))
    assert text.startswith("drape: error: --holdout-motions 1: the last ones of the 1 motions (--motions) are held "
                           "out") and "give at least 2 motions" in text, text
    text = refused("sim", "dataset", "--garment", str(garment), "--motions", "walk,run", "--params", "2",
                   "--holdout-params", "2", "--out", str(tmp_path / "d"))
    assert text.startswith("drape: error: --holdout-params 2:") and "must be in [1, 1]" in text, text
    text = refused("sim", "dataset", "--garment", str(garment), "--outer", str(garment), "--motions", "walk,run",
                   "--params", "8", "--holdout-params", "8", "--out", str(tmp_path / "d"))  # two layers too
    assert text.startswith("drape: error: --holdout-params 8:"), text
    assert not (tmp_path / "s.npz").exists() and not (tmp_path / "d").exists()


@pytest.mark.parametrize(("args", "said"), [
    (["motions", "generate", "--frames", "1000000", "--out", "m.npz"], "--frames: must be in [1, 108,000], got 1000000"),
    (["motions", "generate", "--frames", "0", "--out", "m.npz"], "--frames: must be in [1, 108,000], got 0"),
    (["motions", "generate", "--frames", "1e8", "--out", "m.npz"], "--frames: expected an integer, got '1e8'"),
    (["eval", "layers", "--frames", "0"], "--frames: must be >= 1, got 0"),
    (["sim", "dataset", "--garment", "g.obj", "--motions", "walk", "--out", "d", "--workers", "0"],
     "--workers: must be >= 1, got 0"),
    (["sim", "sweep", "--workers", "-1", "--out", "d"], "--workers: must be >= 1, got -1"),
    (["sim", "dataset", "--garment", "g.obj", "--motions", "walk", "--out", "d", "--frames", "-1"],
     "--frames: must be >= 1, got -1"),
    (["sim", "dataset", "--garment", "g.obj", "--motions", "walk", "--out", "d", "--only-params", "36,x"],
     "--only-params: expected a comma list of integers, got '36,x'"),
    (["sim", "dataset", "--garment", "g.obj", "--motions", "walk", "--out", "d", "--only-params", "-1"],
     "--only-params: indices must be >= 0, got '-1'"),
    (["render", "--smooth", "-1", "--out", "r.png"], "--smooth: must be >= 0, got -1"),
])
def test_counts_out_of_range_are_refused_before_any_work(args, said, tmp_path, monkeypatch, capsys):
    """Counts are checked as the command line is read (argparse's one-line error, exit 2): `motions generate
    --frames 100000000` ran for minutes, `eval layers --frames 0` failed only after loading every model,
    `sim dataset --workers 0` simulated on all cores and `--workers -1` on one, `render --smooth -1` drew."""
    from drape import cli

    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        cli.main(args)
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and err[-1].endswith(f"error: argument {said}"), err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("command", [["train", "deepsd"], ["train", "intrinsic", "--template", "skirt"],
                                     ["eval", "deepsd"]])
@pytest.mark.parametrize(("text", "said"), [("not json", "is not JSON: Expecting value"),
                                            ("[1, 2]", "a config is a JSON object of settings, got list"),
                                            (b"\xff\xfe", "is not JSON text (UTF-8)")])
def test_a_config_that_is_not_a_json_object_is_named_in_one_line(command, text, said, tmp_path, capsys):
    """Every trainer and evaluator reads its --config through drape.training.config_file.read_config: a file that is
    not a JSON object is refused naming the file (it printed json's 'Expecting value: line 1 column 1' alone)."""
    from drape import cli

    config = tmp_path / "c.json"
    config.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(SystemExit) as exc:
        cli.main([*command, "--config", str(config), *(["--checkpoints", str(tmp_path / "ck")]
                                                        if command[0] == "train" else [])])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and err.startswith(f"drape: error: {config}: {said}") and "\n" not in err, err


@pytest.mark.parametrize(("command", "committed", "typo", "said"), [
    (["train", "deepsd"], "deepsd", ("loss", "colision"), "loss: unknown setting 'colision' (did you mean 'collision'?)"),
    (["train", "intrinsic", "--template", "skirt"], "intrinsic_skirt", ("shape", "laplacain"),
     "shape: unknown setting 'laplacain' (did you mean 'laplacian'?)"),
    (["train", "mgn-inner", "--inner", "tshirt"], "mgn_inner_tshirt", ("", "batch_frame"),
     "unknown setting 'batch_frame' (did you mean 'batch_frames'?)"),
    (["train", "mgn-outer", "--outer", "jacket"], "mgn_outer_jacket", ("", "wieght_decay"),
     "unknown setting 'wieght_decay' (did you mean 'weight_decay'?)"),
    (["eval", "deepsd"], "deepsd", ("steps", "physic"), "steps: unknown setting 'physic' (did you mean 'physics'?)"),
])
def test_a_misspelt_setting_is_refused_before_anything_runs(command, committed, typo, said, tmp_path, capsys):
    """A committed config with one setting misspelt (a trainer read it with .get and a default, or not at all, so
    the run trained on the default without a word) is refused naming the file, the setting and the nearest name;
    nothing is written."""
    from drape import cli
    from drape.training.config_file import CONFIGS

    cfg = json.loads((CONFIGS / f"{committed}.json").read_text())
    where, name = typo
    (cfg[where] if where else cfg)[name] = 1
    config = tmp_path / "c.json"
    config.write_text(json.dumps(cfg))
    with pytest.raises(SystemExit) as exc:
        cli.main([*command, "--config", str(config), *(["--checkpoints", str(tmp_path / "ck")]
                                                        if command[0] == "train" else [])])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and err.startswith(f"drape: error: {config}: {said}") and "\n" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.json"]


@pytest.mark.parametrize(("command", "committed", "setting", "said"), [
    (["train", "intrinsic", "--template", "skirt"], "intrinsic_skirt", "dataset",
     "no simulated dataset here (no manifest.json); the Makefile's intrinsic-data targets"),
    (["train", "mgn-outer", "--outer", "jacket"], "mgn_outer_jacket", "data",
     "no two-layer simulations here (no manifest.json); make layers-data simulates them"),
])
def test_training_without_its_simulations_names_the_make_target_and_makes_no_folder(command, committed, setting, said,
                                                                                     tmp_path, capsys):
    """A trainer whose dataset was never simulated said 'data/.../manifest.json: No such file or directory' and
    left an empty checkpoints folder behind."""
    from drape import cli
    from drape.training.config_file import CONFIGS

    cfg = json.loads((CONFIGS / f"{committed}.json").read_text())
    cfg[setting] = str(tmp_path / "never_simulated")
    cfg.pop("extra_datasets", None)
    config = tmp_path / "c.json"
    config.write_text(json.dumps(cfg))
    with pytest.raises(SystemExit) as exc:
        cli.main([*command, "--config", str(config), "--checkpoints", str(tmp_path / "ck")])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 1 and err.startswith(f"drape: error: {tmp_path / 'never_simulated'}: {said}"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.json"]


def _refused(capsys, *args):
    """cli.main(args) -> (exit code, its one line of stderr); no traceback."""
    from drape import cli

    with pytest.raises(SystemExit) as exc:
        cli.main(list(args))
    err = exc.value.code if isinstance(exc.value.code, str) else capsys.readouterr().err
    assert exc.value.code != 0 and len(err.strip().splitlines()) == 1, err
    return (1 if isinstance(exc.value.code, str) else exc.value.code), err.strip().splitlines()[-1]


def test_a_mesh_that_is_not_a_triangle_mesh_is_named_in_one_line(tmp_path, capsys):
    """outfits fit, render --outfit and sim run read meshes through load_mesh: a mesh without faces printed numpy's
    'zero-size array to reduction operation maximum' (and `render --outfit` drew the body alone, exit 0), faces past
    the vertices and a .bvh raised trimesh's IndexError / NotImplementedError as tracebacks, NaN vertices 'arange:
    cannot compute length', a missing file trimesh's 'string is not a file'."""
    files = {"nofaces.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\n", "empty.stl": "solid x\nendsolid x\n",
             "oob.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "nan.obj": "v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
             "bad.ply": "hello\n", "walk.bvh": "HIERARCHY\n"}
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    out = tmp_path / "fitted.obj"
    for name, code, said in (("nofaces.obj", 2, "the file holds no triangle faces (points or lines only?)"),
                             ("empty.stl", 2, "the file holds no triangle faces"),
                             ("oob.obj", 2, "not a readable OBJ mesh (IndexError"),
                             ("nan.obj", 2, "vertices hold NaN or infinite values"),
                             ("bad.ply", 2, "not a readable PLY mesh"),
                             ("walk.bvh", 2, "unsupported mesh suffix '.bvh'"),
                             ("missing.obj", 1, "No such file or directory")):
        got = _refused(capsys, "outfits", "fit", str(tmp_path / name), "--out", str(out))
        assert got[0] == code and got[1].startswith(f"drape: error: {tmp_path / name}: {said}"), got
    (tmp_path / "point.obj").write_text("v 0 1 0\nv 0 1 0\nv 0 1 0\nf 1 2 3\n")  # fitted, exit 0, before
    got = _refused(capsys, "outfits", "fit", str(tmp_path / "point.obj"), "--out", str(out))
    assert got == (1, f"drape: error: {tmp_path / 'point.obj'}: every face has zero area (its vertices coincide or "
                      "lie on one line): not a garment"), got
    assert not out.exists()
    png = tmp_path / "look.png"
    got = _refused(capsys, "render", "--outfit", str(tmp_path / "nofaces.obj"), "--out", str(png))
    assert got == (2, f"drape: error: {tmp_path / 'nofaces.obj'}: the file holds no triangle faces (points or lines only?)")
    assert not png.exists()


@pytest.mark.parametrize(("option", "value", "said"), [
    ("--looseness", "nan", "looseness must be within [0, 3], got nan"),  # printed 'cannot convert float NaN to integer'
    ("--looseness", "-0.5", "looseness must be within [0, 3], got -0.5"),  # negative ease: cloth inside the body
    ("--looseness", "5", "looseness must be within [0, 3], got 5.0"),
    ("--length", "inf", "length must be within [0, 1], got inf"),  # an OverflowError traceback
    ("--length", "-3", "length must be within [0, 1], got -3.0"),  # an extrapolated hem, written as if fine
])
def test_outfit_looseness_and_length_out_of_range_are_refused(option, value, said, tmp_path, capsys):
    out = tmp_path / "o.obj"
    assert _refused(capsys, "outfits", "generate", "--type", "trousers", "--vertices", "300", option, value,
                    "--out", str(out)) == (2, f"drape: error: {said}")
    assert not out.exists()


def test_a_motion_file_that_is_not_a_clip_is_named_in_one_line(tmp_path, capsys):
    """render --motion (and sim run --clip FILE.npz) read clips through load_motion_npz: an empty or truncated file
    raised EOFError / BadZipFile tracebacks, a lone .npy a TypeError, a text file numpy's pickle advice, a clip whose
    members disagree a message without the file."""
    good = np.zeros((5, 24, 3))
    (tmp_path / "empty.npz").write_bytes(b"")
    (tmp_path / "text.npz").write_text("HIERARCHY\n")
    np.save(tmp_path / "one.npy", good)
    (tmp_path / "one.npy").rename(tmp_path / "one.npz")
    np.savez(tmp_path / "clip.npz", poses=good, trans=np.zeros((5, 3)), fps=np.float32(30))
    data = (tmp_path / "clip.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[:len(data) // 2])
    np.savez(tmp_path / "short_trans.npz", poses=good, trans=np.zeros((3, 3)))
    np.savez(tmp_path / "no_frames.npz", poses=good[:0])
    np.savez(tmp_path / "fps_list.npz", poses=good, fps=np.zeros(0))
    png = tmp_path / "look.png"
    for name, said in (("empty.npz", "not a readable npz file"), ("cut.npz", "not a readable npz file"),
                       ("text.npz", "not an npz file"), ("one.npz", "holds one .npy array"),
                       ("short_trans.npz", "trans has 3 frames, poses 5"), ("no_frames.npz", "the clip has no frames"),
                       ("fps_list.npz", "'fps' must be one number")):
        code, line = _refused(capsys, "render", "--motion", str(tmp_path / name), "--frames", "0", "--out", str(png))
        assert code == 2 and line.startswith(f"drape: error: {tmp_path / name}: {said}"), line
    assert not png.exists()


def test_render_options_are_checked_and_the_written_file_is_named(tmp_path, capsys):
    """--azimuth nan drew every panel blank (exit 0); --frames 0,x printed int()'s 'invalid literal'; an --out
    without a suffix printed that path while matplotlib wrote OUT.png."""
    from drape import cli

    png = tmp_path / "look.png"
    with pytest.raises(SystemExit) as exc:  # argparse's usage and its one-line error
        cli.main(["render", "--azimuth", "nan", "--out", str(png)])
    err = capsys.readouterr().err.strip().splitlines()
    assert exc.value.code == 2 and err[-1].endswith("error: argument --azimuth: must be a finite number, got 'nan'")
    motion = tmp_path / "m.npz"
    np.savez(motion, poses=np.zeros((5, 24, 3)))
    assert _refused(capsys, "render", "--motion", str(motion), "--frames", "0,x", "--out", str(png)) == \
        (2, "drape: error: --frames: expected a comma list of frame indices, got '0,x'")
    assert _refused(capsys, "render", "--motion", str(motion), "--frames", "0,5", "--out", str(png)) == \
        (2, "drape: error: --frames: frames [5] outside 0..4")
    # options that would be ignored without a word
    assert _refused(capsys, "render", "--clip", "walk", "--motion", str(motion), "--out", str(png)) == \
        (2, "drape: error: --clip, --motion: give one motion, not both")
    assert _refused(capsys, "render", "--clip", "walk", "--keyframes", "0,5", "--out", str(png)) == \
        (2, "drape: error: --keyframes: not used without --sim")
    assert _refused(capsys, "render", "--sim", str(motion), "--outfit", "x.obj", "--out", str(png)) == \
        (2, "drape: error: --outfit: not used with --sim")
    assert not png.exists()
    cli.main(["render", "--out", str(tmp_path / "rest")])
    assert capsys.readouterr().out.strip() == str(tmp_path / "rest.png")
    assert (tmp_path / "rest.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_an_out_never_replaces_an_input_and_bad_files_are_one_line(tmp_path, capsys, monkeypatch):
    """--out naming an input (by any path, a hard link too) is refused before any work: outfits fit, export
    pc2|glb and sim run replaced their input. render --sim on a 0-byte file, a sequence with no frames, fewer poses
    than frames or faces past the vertices were tracebacks; --frames without a motion and an --outfit far from the
    body drew the rest pose or the body alone with exit 0; serve took --port 99999; Ctrl-C printed a traceback."""
    import os

    from drape import cli
    from drape.geometry.mesh_io import save_mesh

    mesh = tmp_path / "shirt.obj"
    cli.main(["outfits", "generate", "--type", "tshirt", "--vertices", "300", "--out", str(mesh)])
    before = mesh.read_bytes()
    link = tmp_path / "link.obj"
    os.link(mesh, link)
    for out in (mesh, link):
        code, line = _refused(capsys, "outfits", "fit", str(mesh), "--out", str(out))
        assert f"is the input {mesh}" in line, line
    stream = tmp_path / "s.npz"
    np.savez(stream, vertices=np.zeros((2, 3, 3), np.float32), faces=np.array([[0, 1, 2]]), fps=np.array(30.0))
    os.link(stream, tmp_path / "s.glb")  # the same file under a GLB's name
    for kind, out in (("pc2", stream), ("glb", tmp_path / "s.glb")):
        assert "is the input" in _refused(capsys, "export", kind, str(stream), "--out", str(out))[1]
    assert "ending in .glb" in _refused(capsys, "export", "glb", str(stream), "--out", str(tmp_path / "a.obj"))[1]
    assert "is the input" in _refused(capsys, "sim", "run", "--garment", str(mesh), "--clip", "walk", "--frames", "1",
                                      "--out", str(mesh))[1]
    assert mesh.read_bytes() == before
    body = tmp_path / "me.npz"  # a body file is an input too
    body.write_bytes(b"PK")
    assert "is the input" in _refused(capsys, "outfits", "fit", str(mesh), "--body", str(body), "--out", str(body))[1]
    assert "is --out" in _refused(capsys, "outfits", "fit", str(mesh), "--out", str(tmp_path / "f.obj"), "--report",
                                  str(tmp_path / "f.obj"))[1]
    assert body.read_bytes() == b"PK"
    png = tmp_path / "x.png"
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    assert "not a simulated sequence npz" in _refused(capsys, "render", "--sim", str(empty), "--out", str(png))[1]
    one = tmp_path / "one.npz"  # a single .npy array under an .npz name (a TypeError traceback)
    with open(one, "wb") as fh:
        np.save(fh, np.zeros(3))
    assert "a single array" in _refused(capsys, "render", "--sim", str(one), "--out", str(png))[1]
    good = dict(vertices=np.zeros((2, 3, 3)), faces=np.array([[0, 1, 2]]), poses=np.zeros((2, 24, 3)),
                trans=np.zeros((2, 3)), body=np.array("neutral"), params=np.array("{}"), garment=np.array("g"),
                motion=np.array("walk"), fps=np.array(30.0))
    for change, words in (({"vertices": np.zeros((0, 3, 3)), "poses": np.zeros((0, 24, 3)), "trans": np.zeros((0, 3))},
                           "T >= 1"),
                          ({"poses": np.zeros((1, 24, 3)), "trans": np.zeros((1, 3))}, "'poses' and 'trans'"),
                          ({"faces": np.array([[0, 1, 1002]])}, "'faces' must be"),
                          ({"body": None}, "needs body"),
                          ({}, "'params' must be a JSON object with the numbers young, density, thickness"),
                          ({"poses": np.zeros((2,))}, "'poses' and 'trans'")):
        seq = tmp_path / "seq.npz"
        np.savez(seq, **{k: v for k, v in {**good, **change}.items() if v is not None})
        assert words in _refused(capsys, "render", "--sim", str(seq), "--out", str(png))[1], words
    assert "give --clip, --motion or --sim" in _refused(capsys, "render", "--frames", "5,6", "--out", str(png))[1]
    far = tmp_path / "far.obj"
    save_mesh(far, np.array([[100, 1, 0], [100.1, 1, 0], [100, 1.1, 0]]), np.array([[0, 1, 2]]))
    assert "fit it first" in _refused(capsys, "render", "--outfit", str(far), "--out", str(png))[1]
    assert not png.exists()
    with pytest.raises(SystemExit) as exc:  # argparse's usage and its one error line, exit 2
        cli.main(["serve", "--port", "99999"])
    assert exc.value.code == 2 and "--port: must be in [1, 65535], got 99999" in capsys.readouterr().err

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "_motions_generate", interrupted)
    assert _refused(capsys, "motions", "generate", "--frames", "3", "--out", str(tmp_path / "m.npz")) == \
        (130, "drape: interrupted")


@pytest.mark.parametrize("option", ["--real-mocap", "--external", "--ground-truth"])
def test_eval_deepsd_refuses_a_folder_named_on_purpose_that_is_not_there(option, tmp_path, capsys):
    """Its defaults are skipped when absent; a folder given on purpose was skipped the same way, without a word,
    and the evaluation ran on without it."""
    missing = tmp_path / "nope"
    assert _refused(capsys, "eval", "deepsd", option, str(missing)) == (1, f"drape: error: {option} {missing}: no such "
                                                                           "folder")


@pytest.mark.parametrize(("command", "option", "kind"), [(["train", "intrinsic"], "--template", "intrinsic"),
                                                         (["train", "mgn-inner"], "--inner", "mgn_inner"),
                                                         (["train", "mgn-outer"], "--outer", "mgn_outer")])
def test_a_name_with_no_committed_config_lists_the_names_there_are(command, option, kind, capsys):
    """It was an OSError about drape/training/configs/<kind>_<name>.json."""
    code, line = _refused(capsys, *command, option, "nosuch")
    assert code == 2 and line.startswith(f"drape: error: {option} 'nosuch': no committed config {kind}_nosuch.json; "
                                         f"configs of {kind}: "), line


def test_an_unknown_body_names_the_presets_and_the_body_files_body_takes(tmp_path, capsys):
    """--body takes a body file too (a probe read only the presets in the error and in docs/fitting.md)."""
    mesh = tmp_path / "tshirt.obj"
    from drape import cli

    cli.main(["outfits", "generate", "--type", "tshirt", "--vertices", "300", "--out", str(mesh)])
    capsys.readouterr()
    got = _refused(capsys, "outfits", "fit", str(mesh), "--body", "nobody", "--out", str(tmp_path / "f.obj"))
    assert got == (2, "drape: error: --body: unknown body 'nobody'; presets: female, heavy, male, neutral; or a body "
                      "file (.glb, .gltf, .npz)")
