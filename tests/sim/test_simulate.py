"""MuJoCo cloth on a tiny skirt, a dozen frames: shapes, pins, quality, and parameter effects."""

from functools import cache, lru_cache

import numpy as np
import pytest

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.geometry.lbs import linear_blend_skinning
from drape.geometry.queries import nearest_vertex_weights
from drape.geometry.skeleton import forward_kinematics
from drape.sim.collider import fit_hulls, garment_bones
from drape.sim.params import SimParams
from drape.sim.quality import QualityGate
from drape.sim.simulate import (
    PIN_MASS_SCALE,
    Cloth,
    compile_scene,
    scene_xml,
    simulate,
    top_boundary,
)

FRAMES = 12


@lru_cache(maxsize=1)
def _skirt():
    return generate_outfit("skirt", vertices=300, seed=3, length=0.6)


@cache
def _run(**changes):
    o = _skirt()
    params = SimParams(**{**SimParams().model_dump(), **changes})
    return simulate(o.vertices, o.faces, load_body("neutral"), load_clip("walk"), params,
                    frames=FRAMES, settle_blend=6, settle_hold=6)


def test_sequence_shapes_and_quality():
    r = _run()
    o = _skirt()
    assert r.vertices.shape == (FRAMES, len(o.vertices), 3) and r.vertices.dtype == np.float32
    assert r.poses.shape == (FRAMES, 24, 3) and r.trans.shape == (FRAMES, 3)
    assert np.isfinite(r.vertices).all()
    assert QualityGate().failures(r.stats) == []
    assert r.stats["penetration_p99_m"] <= 0.005
    # the skirt moves with the body: its centre stays within 10 cm of the root horizontally
    root = r.trans[:, [0, 2]]
    centre = r.vertices.mean(axis=1)[:, [0, 2]]
    assert np.linalg.norm(centre - root, axis=1).max() < 0.10


def test_waistband_follows_the_skinned_body():
    r = _run()
    o = _skirt()
    body = load_body("neutral")
    top = top_boundary(o.vertices, o.faces)
    assert 20 < len(top) < len(o.vertices) // 3
    tr, _ = forward_kinematics(r.poses, body.joints, body.parents, r.trans)
    target = linear_blend_skinning(o.vertices[top], nearest_vertex_weights(o.vertices[top], body.vertices,
                                                                           body.weights), tr)
    assert np.abs(r.vertices[:, top] - target).max() < 1e-3


def _mean_height(r):
    return r.stats["mean_height_m"]


def _motion(r):
    """Mean per-frame displacement of the cloth relative to the root, m."""
    rel = r.vertices - r.trans[:, None]
    return float(np.linalg.norm(np.diff(rel, axis=0), axis=2).mean())


@pytest.mark.parametrize(
    ("name", "low", "high"),
    [("young", 1e4, 1e6), ("thickness", 3e-4, 3e-3)],
)
def test_softer_cloth_hangs_lower(name, low, high):
    assert _mean_height(_run(**{name: low})) < _mean_height(_run(**{name: high})) - 1e-3


@pytest.mark.parametrize(("name", "light", "heavy"), [("density", 0.1, 1.0), ("gravity", 3.0, 20.0)])
def test_heavier_cloth_hangs_lower(name, light, heavy):
    assert _mean_height(_run(**{name: heavy})) < _mean_height(_run(**{name: light})) - 1e-3


def test_air_drag_lifts_the_hem_of_a_walking_skirt():
    # walking forward at ~1 m/s through still air: drag pushes the hem back and up
    still, windy = _run(air_drag=0.0), _run(air_drag=20.0)
    assert _mean_height(windy) > _mean_height(still) + 5e-3
    assert _motion(windy) < _motion(still)


@pytest.mark.parametrize(
    ("name", "a", "b"),
    [("poisson", 0.0, 0.45), ("damping", 0.0, 2e-3), ("friction", 0.0, 1.5), ("contact_margin", 0.0, 0.01)],
)
def test_every_parameter_changes_the_result(name, a, b):
    diff = np.abs(_run(**{name: a}).vertices - _run(**{name: b}).vertices).mean()
    print(f"{name}: {a} vs {b}: mean vertex difference {1000 * diff:.2f} mm")
    assert diff > 1e-4


def test_simulation_is_deterministic():
    o = _skirt()
    args = (o.vertices, o.faces, load_body("neutral"), load_clip("walk"), SimParams())
    a = simulate(*args, frames=3, settle_blend=2, settle_hold=1)
    b = simulate(*args, frames=3, settle_blend=2, settle_hold=1)
    assert np.array_equal(a.vertices, b.vertices)


def test_heavy_pins_compiled_equal_the_model_made_heavy_after_compiling():
    """compile_scene sets the pinned vertices' masses in the spec; the model (every array) equals the one the
    simulator made before: compiled light, body_mass scaled, mj_setConst."""
    import mujoco

    o, body = _skirt(), load_body("neutral")
    v = o.vertices.astype(np.float64)
    hulls = fit_hulls(body, garment_bones(body, o.vertices, reach=0.2))
    pinned = top_boundary(v, o.faces)
    assert len(pinned) > 10
    new = compile_scene([Cloth("cloth", v, o.faces)], [v], [pinned], hulls, SimParams(), 30.0)
    old = mujoco.MjModel.from_xml_string(scene_xml([(Cloth("cloth", v, o.faces), v)], hulls, SimParams(), 30.0))
    old.body_mass[[old.body(f"cloth_{i}").id for i in pinned]] *= PIN_MASS_SCALE
    mujoco.mj_setConst(old, mujoco.MjData(old))
    arrays = [k for k in dir(old) if not k.startswith("_") and isinstance(getattr(old, k), np.ndarray)
              and getattr(old, k).dtype != object]
    assert {"body_mass", "body_invweight0", "dof_invweight0", "flex_bending"} <= set(arrays)
    differ = [k for k in arrays if not np.array_equal(getattr(old, k), getattr(new, k), equal_nan=True)]
    assert differ == []
    mass = np.array([new.body_mass[new.body(f"cloth_{i}").id] for i in range(len(v))])
    free = np.setdiff1d(np.arange(len(v)), pinned)
    assert mass[pinned].min() > 1000 * np.median(mass[free])


def test_too_many_frames_is_an_error():
    o = _skirt()
    clip = load_clip("walk")
    with pytest.raises(ValueError, match="frames"):
        simulate(o.vertices, o.faces, load_body("neutral"), clip, frames=clip.num_frames + 1)


def test_sim_run_command_writes_the_contract_and_renders(tmp_path):
    import json
    import subprocess
    import sys

    def drape(*args):
        r = subprocess.run([sys.executable, "-m", "drape.cli", *args], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr

    mesh, seq, png = tmp_path / "skirt.obj", tmp_path / "seq.npz", tmp_path / "seq.png"
    drape("outfits", "generate", "--type", "skirt", "--vertices", "300", "--seed", "3", "--length", "0.6",
          "--out", str(mesh))
    drape("sim", "run", "--garment", str(mesh), "--body", "neutral", "--clip", "walk", "--frames", "4",
          "--out", str(seq))
    with np.load(seq, allow_pickle=False) as z:
        assert z["vertices"].shape[0] == 4 and z["vertices"].dtype == np.float32
        assert z["poses"].shape == (4, 24, 3) and z["trans"].shape == (4, 3)
        assert SimParams.model_validate_json(str(z["params"])) == SimParams()
        assert "penetration_p99_m" in json.loads(str(z["stats"]))
    drape("render", "--sim", str(seq), "--out", str(png))
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


_KINEMATICS = """
import hashlib
from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.sim.simulate import bone_kinematics, settle_motion
clip = load_clip("dance_b")
poses, trans = settle_motion(clip, clip.num_frames, 15, 15)
_, *moving = bone_kinematics(load_body("neutral"), poses, trans, clip.fps)
print(hashlib.sha256(b"".join(x.tobytes() for x in moving)).hexdigest())
"""


def test_what_moves_the_body_in_the_simulation_does_not_depend_on_numpys_simd_paths():
    """numpy picks its loops by CPU; with every dispatched SIMD target turned off (NPY_DISABLE_CPU_FEATURES, as on
    an older CPU) the bones' positions, rotations and velocities MuJoCo is given are the same bytes (without the
    float32 grid, dance_b's angular velocities differed in 12 values by ~1e-15 rad/s, and its two-layer simulation
    by 6 mm RMS), so a cached held-out simulation is the same on every x86 machine (docs/sim.md)."""
    import os
    import subprocess
    import sys

    from numpy._core import _multiarray_umath as m

    found = [f for f in m.__cpu_dispatch__ if m.__cpu_features__.get(f)]
    if not found:
        pytest.skip("this CPU runs numpy's baseline loops only: nothing to turn off")
    runs = []
    for disabled in ("", " ".join(found)):
        env = {**os.environ, "NPY_DISABLE_CPU_FEATURES": disabled}
        out = subprocess.run([sys.executable, "-c", _KINEMATICS], env=env, capture_output=True, text=True, check=True)
        runs.append(out.stdout.strip())
    assert runs[0] == runs[1], f"numpy's SIMD targets {found} changed the bones' kinematics"


_PIN_TARGETS = """
import hashlib
import numpy as np
from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.geometry.queries import nearest_vertex_weights
from drape.runtime.layers import LayerCatalog
from drape.sim.simulate import bone_kinematics, pin_targets, settle_motion, top_boundary
body, clip = load_body("neutral"), load_clip("dance_b")
poses, trans = settle_motion(clip, 60, 15, 15)
tr = bone_kinematics(body, poses, trans, clip.fps)[0]
outer = next(iter(LayerCatalog().combinations())).outer
v0 = np.asarray(outer.vertices, dtype=np.float64)
pinned = top_boundary(v0, outer.faces)
w = nearest_vertex_weights(v0[pinned], body.vertices, body.weights)
print(hashlib.sha256(pin_targets(v0[pinned], w, tr).tobytes()).hexdigest())
"""


def test_the_pinned_targets_do_not_depend_on_the_cpus_kernels():
    """The pinned top boundary's targets are the same bytes under OpenBLAS's AVX2 and AVX512 kernels and with
    numpy's SIMD loops turned off. Skinned in float32 through BLAS (`linear_blend_skinning`) they were not, and the
    held-out two-layer simulations differed between machines (the jacket's simulated H-Coll on dance_b 3.56% under
    `OPENBLAS_CORETYPE=Haswell`, 4.40% under this Sapphire Rapids machine's own kernels, 2026-12-02);
    `pin_targets` skins them in float64 by elementwise products (docs/sim.md)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from numpy._core import _multiarray_umath as m

    flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    if " avx512f" not in flags:
        pytest.skip("OpenBLAS's SkylakeX kernels need AVX512")
    found = " ".join(f for f in m.__cpu_dispatch__ if m.__cpu_features__.get(f))
    runs = []
    for env in ({"OPENBLAS_CORETYPE": "Haswell"}, {"OPENBLAS_CORETYPE": "SkylakeX"},
                {"OPENBLAS_CORETYPE": "Haswell", "NPY_DISABLE_CPU_FEATURES": found}):
        out = subprocess.run([sys.executable, "-c", _PIN_TARGETS], env={**os.environ, **env}, capture_output=True,
                             text=True, check=True)
        runs.append(out.stdout.strip())
    assert runs[0] == runs[1] == runs[2], "the CPU's kernels changed the pinned targets"


def test_pin_targets_are_linear_blend_skinning():
    """`pin_targets` against `linear_blend_skinning` (float32 GEMMs): the same points within float32 rounding, on
    weights mixing up to four joints."""
    from drape.sim.simulate import pin_targets

    body = load_body("neutral")
    rng = np.random.default_rng(3)
    poses = rng.normal(0, 0.4, (5, 24, 3))
    tr, _ = forward_kinematics(poses, body.joints, body.parents, rng.normal(0, 0.2, (5, 3)))
    idx = rng.choice(len(body.vertices), 50, replace=False)
    got = pin_targets(body.vertices[idx], body.weights[idx], tr)
    want = linear_blend_skinning(body.vertices[idx], body.weights[idx], tr)
    assert got.dtype == np.float64 and got.shape == (5, 50, 3)
    assert np.array_equal(got, got.astype(np.float32).astype(np.float64))
    assert np.abs(got - want).max() < 1e-6
    assert (np.count_nonzero(body.weights[idx], axis=1) > 1).sum() > 10
