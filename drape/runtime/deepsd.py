"""The shipped DeePSD model on ONNX Runtime, and batched posing (numpy; no torch).

rig:   outfit vertices (N, 3) m + faces (F, 3) -> weights (N, 24), blend_shapes (P, N, 3) m
pose:  weights, blend shapes, pose keys (T, P) and a motion -> vertices (T, N, 3) m,
       V = LBS(T + sum_p keys_p D_p, J, theta, W) for all frames at once.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drape.geometry.lbs import linear_blend_skinning
from drape.geometry.mesh import neighbour_table, vertex_normals
from drape.geometry.skeleton import PARENTS, as_pose_array, forward_kinematics

MODEL_DIR = Path(__file__).resolve().parents[1] / "assets" / "models" / "deepsd"


def network_inputs(vertices: np.ndarray, faces: np.ndarray) -> dict[str, np.ndarray]:
    """The outfit network's inputs: features (N, 6) float32 = rest position (m) + unit normal;
    nbr_idx (N, K) int64 and nbr_w (N, K) float32, the padded one-ring table."""
    v = np.asarray(vertices, dtype=np.float64)
    idx, w = neighbour_table(faces, len(v))
    return {
        "features": np.concatenate([v, vertex_normals(v, faces)], axis=1).astype(np.float32),
        "nbr_idx": idx,
        "nbr_w": w,
    }


@dataclass(frozen=True)
class Rig:
    """weights (N, 24) float32 summing to 1; blend_shapes (P, N, 3) float32 metres."""

    weights: np.ndarray
    blend_shapes: np.ndarray


class DeePSDModel:
    """The two ONNX files of a DeePSD export, checked against their manifest's sha256."""

    def __init__(self, model_dir: str | Path = MODEL_DIR, threads: int = 2):
        import onnxruntime as ort

        model_dir = Path(model_dir)
        self.manifest = json.loads((model_dir / "manifest.json").read_text())
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        self.sessions = {}
        for name in ("outfit", "pose"):
            entry = self.manifest["files"][name]
            blob = (model_dir / entry["file"]).read_bytes()
            digest = hashlib.sha256(blob).hexdigest()
            if digest != entry["sha256"]:
                raise ValueError(f"{entry['file']}: sha256 {digest} does not match the manifest")
            self.sessions[name] = ort.InferenceSession(blob, opts, providers=["CPUExecutionProvider"])
        self.num_keys = int(self.manifest["files"]["pose"]["outputs"][0]["shape"][-1])

    def rig(self, vertices: np.ndarray, faces: np.ndarray) -> Rig:
        """Blend weights and pose-space blend shapes of an outfit in rest pose."""
        w, d = self.sessions["outfit"].run(["weights", "blend_shapes"], network_inputs(vertices, faces))
        return Rig(weights=w, blend_shapes=d)

    def blend_shapes_data(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """D_data alone (P, N, 3): the model without its physics branch Chi (for evaluation)."""
        return self.sessions["outfit"].run(["blend_shapes_data"], network_inputs(vertices, faces))[0]

    def pose_keys(self, poses: np.ndarray) -> np.ndarray:
        """(T, 24, 3) or (T, 72) axis-angle -> (T, P) pose keys."""
        p = as_pose_array(poses).reshape(-1, 72).astype(np.float32)
        return self.sessions["pose"].run(["pose_keys"], {"poses": p})[0]


def pose_outfit(
    rest_vertices: np.ndarray,
    rig: Rig,
    keys: np.ndarray,
    rest_joints: np.ndarray,
    poses: np.ndarray,
    translation: np.ndarray | None = None,
) -> np.ndarray:
    """Pose an outfit for every frame at once -> (T, N, 3) float32 metres.

    rest_vertices (N, 3); keys (T, P) from `DeePSDModel.pose_keys`; rest_joints (24, 3)
    of the body the outfit was rigged on; poses (T, 24, 3); translation (T, 3) or None.
    """
    P, N, _ = rig.blend_shapes.shape
    T = len(keys)
    offsets = (np.asarray(keys, dtype=np.float32) @ rig.blend_shapes.reshape(P, N * 3)).reshape(T, N, 3)
    transforms, _ = forward_kinematics(as_pose_array(poses), rest_joints, PARENTS, translation)
    return linear_blend_skinning(np.asarray(rest_vertices, dtype=np.float32)[None] + offsets, rig.weights, transforms)
