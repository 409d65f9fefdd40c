"""The 24-joint SMPL-layout skeleton and forward kinematics.

A pose is axis-angle local rotations `(T, 24, 3)` relative to the rest pose
(T-pose), plus root translation `(T, 3)` in metres. Every joint's rest frame is
the world frame, as in SMPL, so a zero pose reproduces the rest mesh.
"""

from __future__ import annotations

import numpy as np

from drape.geometry.rotations import axis_angle_to_matrix

JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee",
    "spine2", "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot",
    "neck", "left_collar", "right_collar", "head", "left_shoulder", "right_shoulder",
    "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hand", "right_hand",
)
PARENTS: np.ndarray = np.array(
    [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21],
    dtype=np.int32,
)
NUM_JOINTS = 24
JOINT_INDEX: dict[str, int] = {name: i for i, name in enumerate(JOINT_NAMES)}

# CMU bone -> SMPL joint; the 7 extras are merged into the joint of their parent bone
CMU_TO_SMPL: dict[str, str] = {
    "Hips": "pelvis", "LeftUpLeg": "left_hip", "RightUpLeg": "right_hip", "LowerBack": "spine1",
    "LeftLeg": "left_knee", "RightLeg": "right_knee", "Spine": "spine2", "LeftFoot": "left_ankle",
    "RightFoot": "right_ankle", "Spine1": "spine3", "LeftToeBase": "left_foot",
    "RightToeBase": "right_foot", "Neck": "neck", "LeftShoulder": "left_collar",
    "RightShoulder": "right_collar", "Head": "head", "LeftArm": "left_shoulder",
    "RightArm": "right_shoulder", "LeftForeArm": "left_elbow", "RightForeArm": "right_elbow",
    "LeftHand": "left_wrist", "RightHand": "right_wrist", "LeftFingerBase": "left_hand",
    "RightFingerBase": "right_hand",
}
CMU_EXTRAS: dict[str, str] = {
    "LHipJoint": "Hips", "RHipJoint": "Hips", "Neck1": "Neck", "LThumb": "LeftHand",
    "RThumb": "RightHand", "LeftHandFinger1": "LeftFingerBase", "RightHandFinger1": "RightFingerBase",
}



def as_pose_array(poses: np.ndarray) -> np.ndarray:
    """Accept (T, 24, 3), (T, 72) or SMPL-H/X-wide (T, 156) pose arrays -> (T, 24, 3) float64.

    Wider arrays keep their first 72 values (the 24 body joints), as DESIGN.md says.
    """
    p = np.asarray(poses, dtype=np.float64)
    if p.ndim == 3 and p.shape[1:] == (NUM_JOINTS, 3):
        return p
    if p.ndim == 2 and p.shape[1] >= 3 * NUM_JOINTS and p.shape[1] % 3 == 0:
        return p[:, : 3 * NUM_JOINTS].reshape(-1, NUM_JOINTS, 3)
    raise ValueError(f"poses must be (T, 24, 3) or (T, 72+) wide, got shape {p.shape}")


def forward_kinematics(
    poses: np.ndarray,
    rest_joints: np.ndarray,
    parents: np.ndarray = PARENTS,
    translation: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Posed joint frames from local rotations.

    poses: (T, K, 3) axis-angle radians; rest_joints: (K, 3) metres;
    parents: (K,) with -1 for the root, every parent index lower than its child;
    translation: (T, 3) metres added to every joint, or None.
    Returns (skinning transforms (T, K, 4, 4) that map rest-pose points to posed
    points, posed joint positions (T, K, 3) metres), both float64.
    """
    rot = axis_angle_to_matrix(poses)  # (T, K, 3, 3)
    T, K = rot.shape[:2]
    rest_joints = np.asarray(rest_joints, dtype=np.float64)
    glob_rot = np.empty_like(rot)
    glob_pos = np.empty((T, K, 3))
    for k in range(K):
        p = int(parents[k])
        if p < 0:
            glob_rot[:, k] = rot[:, k]
            glob_pos[:, k] = rest_joints[k]
        else:
            glob_rot[:, k] = glob_rot[:, p] @ rot[:, k]
            offset = rest_joints[k] - rest_joints[p]
            glob_pos[:, k] = glob_pos[:, p] + glob_rot[:, p] @ offset
    if translation is not None:
        glob_pos = glob_pos + np.asarray(translation, dtype=np.float64)[:, None, :]
    transforms = np.zeros((T, K, 4, 4))
    transforms[..., :3, :3] = glob_rot
    # x_posed = R_k (x_rest - j_k) + g_k
    transforms[..., :3, 3] = glob_pos - np.einsum("tkij,kj->tki", glob_rot, rest_joints)
    transforms[..., 3, 3] = 1.0
    return transforms, glob_pos
