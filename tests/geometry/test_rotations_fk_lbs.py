"""Rotations, forward kinematics and LBS against hand-composed matrices and invariants."""

import numpy as np
import pytest

from drape.assets.body import load_body
from drape.geometry.lbs import linear_blend_skinning, pose_mesh
from drape.geometry.rotations import (
    axis_angle_to_matrix,
    axis_angle_to_quaternion,
    matrix_to_axis_angle,
    quaternion_to_matrix,
    rotation_between,
)
from drape.geometry.skeleton import JOINT_INDEX, PARENTS, as_pose_array, forward_kinematics


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_axis_angle_matches_elementary_rotations():
    assert np.allclose(axis_angle_to_matrix(np.array([0.7, 0, 0])), rot_x(0.7))
    assert np.allclose(axis_angle_to_matrix(np.array([0, 0, -1.2])), rot_z(-1.2))
    assert np.allclose(axis_angle_to_matrix(np.zeros(3)), np.eye(3))


def test_round_trips():
    rng = np.random.default_rng(0)
    aa = rng.normal(size=(500, 3))
    aa *= (rng.uniform(0, np.pi - 1e-3, 500) / np.linalg.norm(aa, axis=1))[:, None]
    assert np.allclose(matrix_to_axis_angle(axis_angle_to_matrix(aa)), aa, atol=1e-8)
    assert np.allclose(quaternion_to_matrix(axis_angle_to_quaternion(aa)), axis_angle_to_matrix(aa), atol=1e-12)
    r = axis_angle_to_matrix(aa)
    assert np.allclose(r @ np.swapaxes(r, -1, -2), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(r), 1.0)


def test_rotation_between():
    a, b = np.array([1.0, 2.0, 0.5]), np.array([-0.3, 0.1, 1.0])
    r = rotation_between(a, b)
    assert np.allclose(r @ (a / np.linalg.norm(a)), b / np.linalg.norm(b))


def test_pose_array_forms():
    p = np.random.default_rng(1).normal(size=(4, 156))
    assert np.array_equal(as_pose_array(p), p[:, :72].reshape(4, 24, 3))
    with pytest.raises(ValueError):
        as_pose_array(np.zeros((4, 70)))


def test_fk_equals_hand_composed_matrices():
    body = load_body("neutral")
    j = body.joints.astype(np.float64)
    poses = np.zeros((1, 24, 3))
    poses[0, 0] = [0.0, 0.3, 0.0]
    poses[0, JOINT_INDEX["spine1"]] = [0.2, 0.0, 0.0]
    poses[0, JOINT_INDEX["spine2"]] = [0.0, 0.0, -0.4]
    poses[0, JOINT_INDEX["spine3"]] = [0.1, 0.2, 0.0]
    poses[0, JOINT_INDEX["left_collar"]] = [0.0, 0.0, 0.5]
    trans = np.array([[0.1, -0.2, 0.3]])
    _, joints = forward_kinematics(poses, j, PARENTS, trans)
    # compose 4x4 rigid transforms by hand along pelvis -> spine1 -> spine2 -> spine3 -> left_collar
    def rigid(r, t):
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = r, t
        return m

    chain = ["pelvis", "spine1", "spine2", "spine3", "left_collar"]
    m = np.eye(4)
    m[:3, 3] = trans[0]
    prev = np.zeros(3)
    for name in chain:
        k = JOINT_INDEX[name]
        m = m @ rigid(axis_angle_to_matrix(poses[0, k]), j[k] - prev)
        prev = j[k]
        assert np.allclose(joints[0, k], m[:3, 3], atol=1e-10), name
    # a child with zero local rotation sits at the parent's transform of its rest offset
    lsh = JOINT_INDEX["left_shoulder"]
    assert np.allclose(joints[0, lsh], (m @ np.append(j[lsh] - j[JOINT_INDEX["left_collar"]], 1))[:3])


def test_zero_pose_gives_rest_mesh():
    body = load_body("female")
    v = body.pose(np.zeros((2, 24, 3)))
    assert v.shape == (2, len(body.vertices), 3)
    assert np.abs(v - body.vertices).max() < 1e-5


def test_single_joint_rotation_moves_exactly_its_weighted_vertices():
    body = load_body("neutral")
    k = JOINT_INDEX["left_elbow"]
    # the descendants of the elbow move with it; everything else must stay put
    desc = {k}
    for j in range(24):
        if PARENTS[j] in desc:
            desc.add(j)
    influence = body.weights[:, sorted(desc)].sum(axis=1)
    poses = np.zeros((1, 24, 3))
    poses[0, k] = [0.0, -1.0, 0.0]
    moved = np.linalg.norm(body.pose(poses)[0] - body.vertices, axis=1) > 1e-6
    assert np.array_equal(moved, influence > 1e-7)
    assert moved.sum() > 100


def test_lbs_translation_and_batching():
    body = load_body("male", proxy=True)
    rng = np.random.default_rng(3)
    poses = rng.normal(scale=0.3, size=(5, 24, 3))
    trans = rng.normal(size=(5, 3))
    batched = pose_mesh(body.vertices, body.weights, body.joints, poses, trans)
    for t in range(5):
        single = pose_mesh(body.vertices, body.weights, body.joints, poses[t : t + 1], trans[t : t + 1])
        assert np.allclose(batched[t], single[0], atol=1e-5)
    shifted = pose_mesh(body.vertices, body.weights, body.joints, poses, np.zeros((5, 3)))
    assert np.allclose(batched - shifted, trans[:, None, :].astype(np.float32), atol=1e-5)
    # per-frame rest shapes (pose-space offsets) are accepted as (T, N, 3)
    transforms, _ = forward_kinematics(poses, body.joints)
    offsets = np.broadcast_to(body.vertices, (5,) + body.vertices.shape)
    assert np.allclose(linear_blend_skinning(offsets, body.weights, transforms), shifted, atol=1e-5)


def test_unskin_inverts_skinning_and_refuses_cancelling_blends():
    """unskin(blended transforms, posed points) gives the rest points back (an independent check: re-posing by
    linear_blend_skinning); weights mixing rotations half a turn apart raise SingularSkinning, not a 1e15 m
    answer or LinAlgError."""
    from drape.geometry.lbs import SingularSkinning, unskin

    body = load_body("neutral", proxy=True)
    rng = np.random.default_rng(3)
    pose = rng.normal(scale=0.4, size=(1, 24, 3))
    transforms = forward_kinematics(pose, body.joints, PARENTS)[0][0]
    blended = np.einsum("vk,kij->vij", body.weights.astype(np.float64), transforms)
    posed = linear_blend_skinning(body.vertices[None], body.weights, transforms[None])[0]
    np.testing.assert_allclose(unskin(blended, posed), body.vertices, atol=1e-5)  # posed: float32
    half_x, half_y = np.eye(4), np.eye(4)
    half_x[:3, :3], half_y[:3, :3] = np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1])
    for other in (half_y, np.eye(4)):  # det 0 exactly; 0.5 (I + R_x(pi)) = diag(1, 0, 0)
        with pytest.raises(SingularSkinning, match="cannot be undone"):
            unskin(np.stack([np.eye(4), 0.5 * (half_x + other)]), np.zeros((2, 3)))


def test_rest_space_offsets_survive_a_singular_blend():
    """A vertex weighted half and half on two joints half a turn apart (an elbow bent all the way): the exact
    inverse does not exist (it was a LinAlgError); the least-squares offset is answered, the others exactly."""
    from drape.geometry.lbs import rest_space_offsets

    rotations = np.stack([np.eye(3), np.diag([1.0, -1, -1])])
    weights = np.array([[0.5, 0.5], [1.0, 0.0], [0.2, 0.8]])
    offsets = np.array([[0.01, 0.02, 0.0], [0.0, 0.0, 0.03], [0.01, 0.01, 0.01]])
    d = rest_space_offsets(offsets, weights, rotations)
    assert np.isfinite(d).all()
    np.testing.assert_allclose(d[0], [0.01, 0.0, 0.0], atol=1e-7)  # diag(1, 0, 0): only x can be reproduced
    np.testing.assert_allclose(d[1], offsets[1], atol=1e-7)
    np.testing.assert_allclose((0.2 * rotations[0] + 0.8 * rotations[1]) @ d[2], offsets[2], atol=1e-6)
