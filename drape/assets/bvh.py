"""Import BVH motion capture with CMU joint names onto drape's 24-joint skeleton.

Parsing is upc-pymotion's (MIT). Retargeting carries each mapped bone's global
rotation over, bridged from the BVH's own rest pose to drape's T-pose: for a
joint j with a child c, the bridge is the smallest rotation taking drape's rest
bone direction (c - j) to the BVH's. The 7 extra CMU bones (hip joints, Neck1,
thumbs, finger tips) are absorbed into the chain. The BVH must be Y-up; any
unit works (root motion is scaled by the leg-length ratio).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drape.assets.body import Body
from drape.assets.motion import Motion
from drape.geometry.rotations import matrix_to_axis_angle, quaternion_to_matrix, rotation_between
from drape.geometry.skeleton import CMU_TO_SMPL, JOINT_INDEX, JOINT_NAMES, PARENTS

# the child whose direction defines each joint's bone (leaf joints borrow their parent's bridge)
_BONE_CHILD = {
    "left_hip": "left_knee", "right_hip": "right_knee", "left_knee": "left_ankle",
    "right_knee": "right_ankle", "left_ankle": "left_foot", "right_ankle": "right_foot",
    "spine1": "spine2", "spine2": "spine3", "spine3": "neck", "neck": "head",
    "left_collar": "left_shoulder", "right_collar": "right_shoulder",
    "left_shoulder": "left_elbow", "right_shoulder": "right_elbow",
    "left_elbow": "left_wrist", "right_elbow": "right_wrist",
    "left_wrist": "left_hand", "right_wrist": "right_hand",
}


def _global_fk(local: np.ndarray, offsets: np.ndarray, parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """BVH FK: local rotations (T, J, 3, 3), offsets (J, 3), parents (root = itself or -1).

    Returns global rotations (T, J, 3, 3) and rest joint positions (J, 3) relative to the root.
    """
    T, J = local.shape[:2]
    glob = np.empty_like(local)
    rest = np.zeros((J, 3))
    for j in range(J):
        p = int(parents[j])
        if p < 0 or p == j:
            glob[:, j] = local[:, j]
        else:
            glob[:, j] = glob[:, p] @ local[:, j]
            rest[j] = rest[p] + offsets[j]
    return glob, rest


def import_bvh(path: str | Path, body: Body, name: str | None = None) -> Motion:
    """Read a CMU-named, Y-up BVH file and retarget it onto `body` (fps from the file)."""
    from pymotion.io.bvh import BVH

    bvh = BVH()
    bvh.load(str(path))
    rots, pos, parents, offsets, _, _ = bvh.get_data()
    names = [str(n) for n in bvh.data["names"]]
    frame_time = float(bvh.data.get("frame_time", 1.0 / 30.0))
    missing = [n for n in CMU_TO_SMPL if n not in names]
    if missing:
        raise ValueError(f"{path}: BVH lacks CMU joints {missing}")
    col = {n: i for i, n in enumerate(names)}
    local = quaternion_to_matrix(rots)  # pymotion quaternions are (w, x, y, z)
    glob, rest = _global_fk(local, offsets, np.asarray(parents))
    bvh_of = {smpl: col[cmu] for cmu, smpl in CMU_TO_SMPL.items()}

    bridge = np.repeat(np.eye(3)[None], 24, axis=0)
    ours = body.joints.astype(np.float64)
    hips_ours = ours[JOINT_INDEX["left_hip"]] - ours[JOINT_INDEX["right_hip"]]
    hips_bvh = rest[bvh_of["left_hip"]] - rest[bvh_of["right_hip"]]
    bridge[0] = rotation_between(hips_ours, hips_bvh)
    for j, jname in enumerate(JOINT_NAMES):
        child = _BONE_CHILD.get(jname)
        if child is None:
            if j > 0:
                bridge[j] = bridge[PARENTS[j]]
            continue
        d_ours = ours[JOINT_INDEX[child]] - ours[j]
        d_bvh = rest[bvh_of[child]] - rest[bvh_of[jname]]
        bridge[j] = rotation_between(d_ours, d_bvh)
    g = np.stack([glob[:, bvh_of[n]] for n in JOINT_NAMES], axis=1) @ bridge[None]
    loc = g.copy()
    for j in range(1, 24):
        loc[:, j] = np.swapaxes(g[:, PARENTS[j]], -1, -2) @ g[:, j]
    poses = matrix_to_axis_angle(loc)
    leg_ours = float(np.linalg.norm(ours[JOINT_INDEX["left_knee"]] - ours[JOINT_INDEX["left_hip"]])
                     + np.linalg.norm(ours[JOINT_INDEX["left_ankle"]] - ours[JOINT_INDEX["left_knee"]]))
    leg_bvh = float(np.linalg.norm(rest[bvh_of["left_knee"]] - rest[bvh_of["left_hip"]])
                    + np.linalg.norm(rest[bvh_of["left_ankle"]] - rest[bvh_of["left_knee"]]))
    scale = leg_ours / leg_bvh
    root = pos[:, col["Hips"]] * scale  # root channel = hips position in the BVH's world
    trans = root - ours[0]  # pelvis world position = rest pelvis + trans
    return Motion(poses, trans, 1.0 / frame_time, name or Path(path).stem)
