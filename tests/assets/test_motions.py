"""Embedded clips, motion time operations, procedural motions and the importers."""

import numpy as np
import pytest

from drape.assets.body import load_body
from drape.assets.motion import (
    MOTIONS_DIR,
    Motion,
    heading,
    list_clips,
    load_clip,
    load_motion_npz,
    resample,
    tile_cycle,
)
from drape.assets.procedural import LIMITS, generate_motion
from drape.geometry.skeleton import JOINT_INDEX, forward_kinematics


def test_at_least_15_clips_with_contract():
    clips = list_clips()
    assert len(clips) >= 15 and "walk" in clips
    for name in clips:
        with np.load(MOTIONS_DIR / f"{name}.npz", allow_pickle=False) as z:
            assert z["poses"].dtype == np.float32 and z["poses"].shape[1:] == (24, 3)
            assert z["trans"].dtype == np.float32 and z["trans"].shape == (len(z["poses"]), 3)
            assert z["fps"].shape == () and float(z["fps"]) == 30.0
            assert np.isfinite(z["poses"]).all() and np.isfinite(z["trans"]).all()
    assert (MOTIONS_DIR / "ATTRIBUTION.md").exists()


def test_walk_keeps_a_foot_on_the_floor_and_moves_forward():
    from drape.assets.deepmimic import foot_heights

    body = load_body("neutral")
    walk = load_clip("walk")
    assert walk.num_frames >= 90
    assert np.median(np.abs(foot_heights(walk, body))) < 0.02
    forward = walk.trans[-1] - walk.trans[0]
    assert np.linalg.norm(forward[[0, 2]]) > 2.0  # several metres over the clip
    # the body faces the way it walks (+-45 degrees)
    yaw = heading(walk.poses.astype(np.float64))
    travel = np.arctan2(forward[0], forward[2])
    assert abs(np.angle(np.exp(1j * (np.median(yaw) - travel)))) < np.pi / 4


def test_resample_keeps_endpoints_and_duration():
    m = load_clip("kick")
    r = resample(m, 60.0)
    assert r.num_frames == 2 * (m.num_frames - 1) + 1
    assert np.allclose(r.poses[0], m.poses[0], atol=1e-5) and np.allclose(r.poses[-1], m.poses[-1], atol=1e-5)
    assert np.allclose(r.poses[::2], m.poses, atol=1e-4)


def test_tile_cycle_continues_root_motion():
    rng = np.random.default_rng(0)
    n = 11
    poses = np.zeros((n, 24, 3))
    poses[:, 0, 1] = np.linspace(0, 0.5, n)  # turns 0.5 rad per cycle
    poses[:, 3] = rng.normal(scale=0.1, size=3)
    trans = np.zeros((n, 3))
    trans[:, 2] = np.linspace(0, 1.0, n)
    m = tile_cycle(Motion(poses, trans, 30.0), 35)
    assert m.num_frames >= 35
    assert np.allclose(heading(m.poses[10:11].astype(float)), 0.5, atol=1e-5)  # cycle 2 starts turned
    step = np.linalg.norm(np.diff(m.trans, axis=0), axis=1)
    assert step.max() < 0.11  # no jump at the seams


def test_a_motion_npz_is_a_drape_clip_and_an_amass_file_points_at_the_importer(tmp_path):
    """`sim run --clip`, `sim dataset --motions` and `render --motion` read drape clips. An AMASS file was read
    as its first 72 values, Z-up (the body simulated lying on its side) and with SMPL-H's left-hand finger joints
    as SMPL's two hands: now refused, naming `drape motions import`, which converts it."""
    rng = np.random.default_rng(1)
    poses = rng.normal(scale=0.2, size=(20, 72))
    np.savez(tmp_path / "clip.npz", poses=poses, trans=np.zeros((20, 3)), fps=np.float32(60.0))
    m = load_motion_npz(tmp_path / "clip.npz")
    assert m.fps == 60.0 and np.allclose(m.poses, poses.reshape(20, 24, 3), atol=1e-6)
    np.savez(tmp_path / "amass.npz", poses=rng.normal(scale=0.2, size=(20, 156)), trans=np.zeros((20, 3)),
             mocap_framerate=np.array(120.0))
    np.savez(tmp_path / "smplh.npz", poses=rng.normal(scale=0.2, size=(20, 156)), trans=np.zeros((20, 3)))
    np.savez(tmp_path / "amass72.npz", poses=poses, trans=np.zeros((20, 3)), mocap_framerate=np.array(120.0))
    for name in ("amass", "smplh", "amass72"):
        with pytest.raises(ValueError, match="drape motions import"):
            load_motion_npz(tmp_path / f"{name}.npz")
    np.savez(tmp_path / "bad.npz", poses=np.array([{"a": 1}], dtype=object))
    with pytest.raises(ValueError):
        load_motion_npz(tmp_path / "bad.npz")  # object arrays are never unpickled


def test_procedural_motion_smooth_limited_seeded():
    a = generate_motion(240, seed=5)
    b = generate_motion(240, seed=5)
    c = generate_motion(240, seed=6)
    assert np.array_equal(a.poses, b.poses) and not np.allclose(a.poses, c.poses)
    body = load_body("neutral")
    _, joints = forward_kinematics(a.poses, body.joints, translation=a.trans)
    vel = np.linalg.norm(np.diff(joints, axis=0), axis=2) * a.fps  # m/s
    acc = np.linalg.norm(np.diff(joints, 2, axis=0), axis=2) * a.fps**2
    assert vel.max() < 6.0 and acc.max() < 120.0  # no pops
    # knees only bend forward, elbows only flex, within the table
    from drape.geometry.rotations import axis_angle_to_matrix

    knee = axis_angle_to_matrix(a.poses[:, JOINT_INDEX["left_knee"]])
    angle = np.arctan2(knee[:, 2, 1], knee[:, 1, 1])
    assert angle.min() >= -1e-5 and angle.max() <= LIMITS["left_knee"][0][1] + 1e-5
    ankles = joints[:, [JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"]], 1].min(1)
    assert np.allclose(ankles, body.joints[JOINT_INDEX["left_ankle"], 1], atol=1e-4)
    long = generate_motion(3000, seed=1)
    assert long.num_frames == 3000 and np.isfinite(long.poses).all()


def _ankle_separation(motion, body):
    _, joints = forward_kinematics(motion.poses, body.joints)
    return np.linalg.norm(joints[:, JOINT_INDEX["left_ankle"]] - joints[:, JOINT_INDEX["right_ankle"]], axis=1)


def test_spread_motions_part_the_legs_like_the_kick_and_leave_spread_zero_unchanged():
    body = load_body("neutral")
    plain, zero = generate_motion(300, seed=7), generate_motion(300, seed=7, spread=0.0)
    assert np.array_equal(plain.poses, zero.poses) and np.array_equal(plain.trans, zero.trans)
    wide = generate_motion(300, seed=7, spread=1.0)
    kick = _ankle_separation(load_clip("kick"), body)
    # the plain generator never parts the legs as far as the held-out kick; spread does
    assert np.percentile(_ankle_separation(plain, body), 95) < 0.8 < np.percentile(kick, 95)
    assert np.percentile(_ankle_separation(wide, body), 95) > 0.8 * np.percentile(kick, 95)
    # still smooth (no pops), a foot on the floor
    _, joints = forward_kinematics(wide.poses, body.joints, translation=wide.trans)
    assert (np.linalg.norm(np.diff(joints, 2, axis=0), axis=2) * wide.fps**2).max() < 120.0
    ankles = joints[:, [JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"]], 1].min(1)
    assert np.allclose(ankles, body.joints[JOINT_INDEX["left_ankle"], 1], atol=1e-4)


def test_posture_motions_carry_real_mocaps_upper_back_and_clavicles_and_leave_posture_zero_unchanged():
    """posture=1 gives spine3 and the collars the local rotations real CMU mocap has there (POSTURE's means,
    which the plain generator never makes: it keeps the collars at zero, spine3 near it); every other joint's local rotation, the
    smoothness and the foot on the floor are those of the plain motion."""
    from drape.assets.procedural import POSTURE

    body = load_body("neutral")
    plain, zero = generate_motion(300, seed=11), generate_motion(300, seed=11, posture=0.0)
    assert np.array_equal(plain.poses, zero.poses) and np.array_equal(plain.trans, zero.trans)
    moved = [JOINT_INDEX[j] for j in POSTURE]
    collars = [JOINT_INDEX["left_collar"], JOINT_INDEX["right_collar"]]
    assert np.abs(plain.poses[:, collars]).max() < 1e-9 and abs(plain.poses[:, JOINT_INDEX["spine3"], 0].mean()) < 0.1
    motions = [generate_motion(300, seed=20 + i, posture=1.0) for i in range(8)]
    for name, (mean, _std) in POSTURE.items():
        got = np.concatenate([m.poses[:, JOINT_INDEX[name]] for m in motions]).mean(0)
        assert np.abs(got - np.asarray(mean)).max() < 0.12, (name, got)
    postured = generate_motion(300, seed=11, posture=1.0)
    rest = [j for j in range(24) if j not in moved]
    assert np.allclose(postured.poses[:, rest], plain.poses[:, rest])
    _, joints = forward_kinematics(postured.poses, body.joints, translation=postured.trans)
    assert (np.linalg.norm(np.diff(joints, 2, axis=0), axis=2) * postured.fps**2).max() < 120.0
    ankles = joints[:, [JOINT_INDEX["left_ankle"], JOINT_INDEX["right_ankle"]], 1].min(1)
    assert np.allclose(ankles, body.joints[JOINT_INDEX["left_ankle"], 1], atol=1e-4)


def _write_bvh(path, body, frames):
    """A CMU-named BVH whose rest skeleton is `body`'s, in centimetres, with Euler ZXY channels."""
    from drape.geometry.skeleton import CMU_EXTRAS, CMU_TO_SMPL

    j = body.joints.astype(float) * 100.0
    # CMU hierarchy, with the extras in place (zero-length joints at their child's position)
    tree = [
        ("Hips", None), ("LHipJoint", "Hips"), ("LeftUpLeg", "LHipJoint"), ("LeftLeg", "LeftUpLeg"),
        ("LeftFoot", "LeftLeg"), ("LeftToeBase", "LeftFoot"), ("RHipJoint", "Hips"),
        ("RightUpLeg", "RHipJoint"), ("RightLeg", "RightUpLeg"), ("RightFoot", "RightLeg"),
        ("RightToeBase", "RightFoot"), ("LowerBack", "Hips"), ("Spine", "LowerBack"), ("Spine1", "Spine"),
        ("Neck", "Spine1"), ("Neck1", "Neck"), ("Head", "Neck1"), ("LeftShoulder", "Spine1"),
        ("LeftArm", "LeftShoulder"), ("LeftForeArm", "LeftArm"), ("LeftHand", "LeftForeArm"),
        ("LeftFingerBase", "LeftHand"), ("LeftHandFinger1", "LeftFingerBase"), ("LThumb", "LeftHand"),
        ("RightShoulder", "Spine1"), ("RightArm", "RightShoulder"), ("RightForeArm", "RightArm"),
        ("RightHand", "RightForeArm"), ("RightFingerBase", "RightHand"),
        ("RightHandFinger1", "RightFingerBase"), ("RThumb", "RightHand"),
    ]

    def pos(name):
        if name in CMU_TO_SMPL:
            return j[JOINT_INDEX[CMU_TO_SMPL[name]]]
        if name in ("LHipJoint", "RHipJoint"):
            return j[0] + 0.5 * (j[JOINT_INDEX["left_hip" if name[0] == "L" else "right_hip"]] - j[0])
        return pos(CMU_EXTRAS[name]) + np.array([0.0, 2.0, 0.0]) if name == "Neck1" else pos(CMU_EXTRAS[name]) + np.array([1.0, 0.0, 1.0])

    children = {}
    for name, parent in tree:
        children.setdefault(parent, []).append(name)
    lines = ["HIERARCHY"]

    def emit(name, depth):
        parent = dict(tree)[name]
        off = pos(name) - (pos(parent) if parent else 0)
        pad = "  " * depth
        lines.append(f"{pad}{'ROOT' if parent is None else 'JOINT'} {name}")
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET {off[0]:.6f} {off[1]:.6f} {off[2]:.6f}")
        if parent is None:
            lines.append(f"{pad}  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation")
        else:
            lines.append(f"{pad}  CHANNELS 3 Zrotation Xrotation Yrotation")
        for c in children.get(name, []):
            emit(c, depth + 1)
        if name not in children:
            lines.append(f"{pad}  End Site\n{pad}  {{\n{pad}    OFFSET 0 1 0\n{pad}  }}")
        lines.append(pad + "}")

    emit("Hips", 0)
    names = [n for n, _ in tree]
    order = []

    def walk(name):
        order.append(name)
        for c in children.get(name, []):
            walk(c)

    walk("Hips")
    rng = np.random.default_rng(3)
    lines += ["MOTION", f"Frames: {frames}", "Frame Time: 0.033333"]
    for _ in range(frames):
        vals = list(rng.normal(scale=5.0, size=3) + j[0])
        for name in order:
            vals += list(rng.normal(scale=20.0, size=3) if name not in CMU_EXTRAS else np.zeros(3))
        lines.append(" ".join(f"{v:.5f}" for v in vals))
    path.write_text("\n".join(lines) + "\n")
    assert set(names) == set(order)


def test_bvh_import_reproduces_joint_positions(tmp_path):
    """Retargeted poses, posed with drape's FK, put every joint where pymotion's FK puts it."""
    from pymotion.io.bvh import BVH
    from pymotion.ops.skeleton import fk

    from drape.assets.bvh import import_bvh
    from drape.geometry.skeleton import CMU_TO_SMPL

    body = load_body("neutral")
    path = tmp_path / "take.bvh"
    _write_bvh(path, body, 12)
    m = import_bvh(path, body)
    assert m.num_frames == 12 and abs(m.fps - 30.0) < 0.01
    bvh = BVH()
    bvh.load(str(path))
    rots, pos, parents, offsets, _, _ = bvh.get_data()
    ref, _ = fk(rots, pos[:, 0], offsets, parents)
    names = [str(n) for n in bvh.data["names"]]
    _, ours = forward_kinematics(m.poses.astype(float), body.joints, translation=m.trans.astype(float))
    for cmu, smpl in CMU_TO_SMPL.items():
        assert np.allclose(ours[:, JOINT_INDEX[smpl]], ref[:, names.index(cmu)] / 100.0, atol=2e-3), cmu


@pytest.mark.parametrize("bad", [{"walk": 1.5}, {"walk": -0.1}, {"walk": float("nan")}, {"spread": 2.0},
                                 {"posture": -0.5}])
def test_generate_motion_refuses_shares_outside_0_1(bad):
    """walk and spread are shares (0..1): outside it (or NaN) a ValueError naming the argument, which the CLI
    prints as one line (`drape motions generate --walk 1.5`), not a motion that silently saturates."""
    name = next(iter(bad))
    with pytest.raises(ValueError, match=f"{name} must be within"):
        generate_motion(10, **bad)
