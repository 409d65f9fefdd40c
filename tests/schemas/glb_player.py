"""An independent reading of a GLB: what a glTF engine computes for a mesh at an animation key.

Straight from the glTF 2.0 specification, with pygltflib only for the container: node TRS local
matrices (the animation's sampled values at key index `frame`), global matrices by walking parents,
joint matrices = global(joint) @ inverseBindMatrix, morph targets added to POSITION with the
animated weights (sparse accessors expanded), then skinning over every JOINTS_n/WEIGHTS_n set.
Uses none of drape's geometry.
"""

from __future__ import annotations

import numpy as np
import pygltflib as gl

_DTYPE = {gl.FLOAT: np.float32, gl.UNSIGNED_BYTE: np.uint8, gl.UNSIGNED_SHORT: np.uint16,
          gl.UNSIGNED_INT: np.uint32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


class GlbPlayer:
    def __init__(self, data: bytes) -> None:
        self.doc = gl.GLTF2.load_from_bytes(data)
        self.blob = self.doc.binary_blob()

    def _view(self, index: int, dtype, count: int, width: int) -> np.ndarray:
        bv = self.doc.bufferViews[index]
        return np.frombuffer(self.blob, dtype, count * width, bv.byteOffset or 0).reshape(count, width)

    def accessor(self, index: int) -> np.ndarray:
        acc = self.doc.accessors[index]
        dtype, width = _DTYPE[acc.componentType], _WIDTH[acc.type]
        if acc.bufferView is None:
            out = np.zeros((acc.count, width), dtype)
        else:
            out = self._view(acc.bufferView, dtype, acc.count, width).copy()
        if acc.sparse is not None:
            sp = acc.sparse
            idx = self._view(sp.indices.bufferView, _DTYPE[sp.indices.componentType], sp.count, 1)[:, 0]
            out[idx] = self._view(sp.values.bufferView, dtype, sp.count, width)
        return out

    def _local(self, frame: int | None) -> list[np.ndarray]:
        trs = [[np.array(n.translation or [0, 0, 0], float), np.array(n.rotation or [0, 0, 0, 1], float),
                np.array(n.scale or [1, 1, 1], float)] for n in self.doc.nodes]
        self.weights: dict[int, np.ndarray] = {}
        if frame is not None:
            anim = self.doc.animations[0]
            for ch in anim.channels:
                out = self.accessor(anim.samplers[ch.sampler].output)
                node, path = ch.target.node, ch.target.path
                if path == "weights":
                    n = len(self.doc.meshes[self.doc.nodes[node].mesh].weights)
                    self.weights[node] = out.reshape(-1, n)[frame]
                else:
                    trs[node][{"translation": 0, "rotation": 1, "scale": 2}[path]] = out[frame].astype(float)
        mats = []
        for t, q, s in trs:
            x, y, z, w = q / np.linalg.norm(q)
            r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                          [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                          [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
            m = np.eye(4)
            m[:3, :3] = r * s
            m[:3, 3] = t
            mats.append(m)
        return mats

    def positions(self, mesh_name: str, frame: int | None = None, max_sets: int | None = None) -> np.ndarray:
        """World positions (N, 3) of the named mesh's node at animation key `frame` (None: rest). With
        `max_sets`, skinning reads only the first max_sets JOINTS_n/WEIGHTS_n sets, their weights scaled
        to sum to 1 per vertex: what an engine that reads fewer sets does (three.js's GLTFLoader reads
        JOINTS_0/WEIGHTS_0 and normalises them)."""
        local = self._local(frame)
        parent = {c: i for i, n in enumerate(self.doc.nodes) for c in n.children}

        def world(i: int) -> np.ndarray:
            return world(parent[i]) @ local[i] if i in parent else local[i]

        node_index = next(i for i, n in enumerate(self.doc.nodes) if n.mesh is not None
                          and self.doc.meshes[n.mesh].name == mesh_name)
        node = self.doc.nodes[node_index]
        mesh = self.doc.meshes[node.mesh]
        prim = mesh.primitives[0]
        pos = self.accessor(prim.attributes.POSITION).astype(np.float64)
        weights = self.weights.get(node_index, np.array(mesh.weights or [], float))
        for wgt, target in zip(weights, prim.targets or [], strict=True):
            if wgt != 0:
                pos = pos + wgt * self.accessor(target["POSITION"])
        if node.skin is None:
            m = world(node_index)
            return pos @ m[:3, :3].T + m[:3, 3]
        skin = self.doc.skins[node.skin]
        ibm = self.accessor(skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
        joint_mats = np.stack([world(j) @ ibm[k] for k, j in enumerate(skin.joints)])
        out = np.zeros_like(pos)
        total = np.zeros((len(pos), 1))
        homo = np.concatenate([pos, np.ones((len(pos), 1))], axis=1)
        s = 0
        while getattr(prim.attributes, f"JOINTS_{s}", None) is not None and (max_sets is None or s < max_sets):
            joints = self.accessor(getattr(prim.attributes, f"JOINTS_{s}")).astype(int)
            w = self.accessor(getattr(prim.attributes, f"WEIGHTS_{s}")).astype(np.float64)
            for c in range(4):
                out += w[:, c:c + 1] * np.einsum("nij,nj->ni", joint_mats[joints[:, c]], homo)[:, :3]
            total += w.sum(axis=1, keepdims=True)
            s += 1
        return out if max_sets is None else out / total
