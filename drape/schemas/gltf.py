"""glTF 2.0 binary (GLB) of drape's results, written with pygltflib: what engines and DCC tools load.

Two kinds of file:

- `skinned_glb`: the outfit as a skinned mesh bound to the 24-joint skeleton (nodes named with the
  SMPL joint names, rest offsets as node translations, inverse bind matrices) with its pose-space
  blend shapes as morph targets (`extras.targetNames`), and the body as a second skinned mesh. With
  an `Animation`: per frame, every joint's rotation, the root's translation and the morph-target
  weights (the pose keys), so an engine's skinning of the morphed mesh is drape's own posing
  (`linear_blend_skinning(rest + keys @ D, W, FK(poses))`); optional per-frame corrections (e.g.
  what refinement moved) ride along as one extra sparse morph target per frame, weight 1 at its frame.
- `vertex_animation_glb`: a stream (T, N, 3) as a mesh whose frame 0 is the base and every later
  frame a morph target (weight 1 at its frame): for streams that come without a rig (refine).

Conventions: metres, +Y up, right-handed (as drape and glTF); frame t plays at t / fps seconds.
Skin weights go in sets of 4 (JOINTS_n/WEIGHTS_n), largest first, so JOINTS_0/WEIGHTS_0 hold the 4
largest; each vertex's weights are renormalised in float32 with the last non-zero one set to 1 minus
the others (the Khronos validator's normalisation check), and padding slots carry weight 0 on joint 0
(the validator warns about a zero weight on another joint) unless the vertex uses joint 0 (a joint
repeated on a vertex is a validator error).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np
import pygltflib as gl

from drape.geometry.rotations import axis_angle_to_quaternion

GLB = "model/gltf-binary"
MIN_WEIGHT = 1e-5  # skin weights below this are dropped (then the rest renormalised)
_F32, _U8, _U16, _U32 = gl.FLOAT, gl.UNSIGNED_BYTE, gl.UNSIGNED_SHORT, gl.UNSIGNED_INT


@dataclass(frozen=True)
class Skeleton:
    """joint_names (K,); parents (K,) int, -1 for the root, parents before children; rest_joints (K, 3) m."""

    joint_names: tuple[str, ...]
    parents: np.ndarray
    rest_joints: np.ndarray


@dataclass(frozen=True)
class SkinnedMesh:
    """A mesh in rest pose: vertices (N, 3) float32 m, faces (F, 3) int, weights (N, K) rows summing to 1,
    morph targets (M, N, 3) float32 m (offsets from the rest vertices) with their names, or none; uv_corners
    (F, 3, 2): the texture coordinates of each face's corners (OBJ's convention, v from the image's bottom), or
    none. With them, a vertex on a UV seam is written once per side (`split_uv_seams`)."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    weights: np.ndarray
    targets: np.ndarray | None = None
    target_names: tuple[str, ...] = ()
    uv_corners: np.ndarray | None = None


def split_uv_seams(faces: np.ndarray, uv_corners: np.ndarray, num_vertices: int,
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """glTF keeps one TEXCOORD_0 per vertex: faces (F, 3) and their corners' texture coordinates (F, 3, 2) ->
    (source (C,) int64: the mesh vertex each written vertex copies, in the mesh's order, every vertex at least
    once (one in no face with uv 0), faces (F, 3) into the written vertices, uv (C, 2) float32). One written
    vertex per distinct (vertex, uv) pair: a vertex on a seam becomes one copy per side, at the same place."""
    vid = np.asarray(faces, np.int64).reshape(-1)
    uv_f32 = np.asarray(uv_corners, np.float32).reshape(-1, 2) + np.float32(0.0)  # -0.0 -> 0.0: one UV, not two
    bits = np.ascontiguousarray(uv_f32).view(np.uint32).astype(np.int64)
    pairs, inverse = np.unique(np.column_stack([vid, bits]), axis=0, return_inverse=True)
    unused = np.setdiff1d(np.arange(num_vertices), pairs[:, 0])
    source = np.concatenate([pairs[:, 0], unused])
    uv_bits = np.concatenate([pairs[:, 1:], np.zeros((len(unused), 2), np.int64)]).astype(np.uint32)
    order = np.argsort(source, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    uv = np.ascontiguousarray(uv_bits[order]).view(np.float32).reshape(-1, 2)
    return source[order], rank[inverse.reshape(-1)].reshape(-1, 3), uv


@dataclass(frozen=True)
class Animation:
    """poses (T, K, 3) axis-angle rad, translation (T, 3) m (of the root), fps; keys (T, M) the first
    mesh's morph-target weights per frame; corrections: per frame, the first mesh's extra offsets in its
    rest space (vertex indices (k,) int, offsets (k, 3) float32 m), or None."""

    poses: np.ndarray
    translation: np.ndarray
    fps: float
    keys: np.ndarray | None = None
    corrections: list[tuple[np.ndarray, np.ndarray]] | None = None


class _Writer:
    """The glTF document and its one binary buffer, grown accessor by accessor."""

    def __init__(self) -> None:
        self.doc = gl.GLTF2(asset=gl.Asset(generator="drape", version="2.0"), scene=0)
        self.blob = bytearray()

    def view(self, data: bytes, target: int | None = None) -> int:
        self.blob += b"\0" * (-len(self.blob) % 4)
        self.doc.bufferViews.append(gl.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=len(data),
                                                  target=target))
        self.blob += data
        return len(self.doc.bufferViews) - 1

    def accessor(self, array: np.ndarray, kind: str, *, target: int | None = None, bounds: bool = False) -> int:
        """array (count, width) or (count,) of float32 / uint8 / uint16 / uint32 -> accessor index."""
        a = np.ascontiguousarray(array)
        component = {np.dtype(np.float32): _F32, np.dtype(np.uint8): _U8, np.dtype(np.uint16): _U16,
                     np.dtype(np.uint32): _U32}[a.dtype]
        acc = gl.Accessor(bufferView=self.view(a.tobytes(), target), componentType=component, count=len(a),
                          type=kind)
        if bounds:
            flat = a.reshape(len(a), -1)
            acc.min, acc.max = flat.min(axis=0).tolist(), flat.max(axis=0).tolist()
        self.doc.accessors.append(acc)
        return len(self.doc.accessors) - 1

    def sparse_vec3(self, count: int, indices: np.ndarray, values: np.ndarray) -> int:
        """A VEC3 float accessor of `count` elements, zero except values (k, 3) at indices (k,)."""
        idx = np.asarray(indices, dtype=np.uint32)
        val = np.ascontiguousarray(values, dtype=np.float32).reshape(-1, 3)
        # the bounds after substitution (indices strictly increasing): the values', and 0 where an element keeps it
        lo, hi = (val.min(axis=0), val.max(axis=0)) if len(val) else (np.zeros(3), np.zeros(3))
        if len(idx) < count:
            lo, hi = np.minimum(lo, 0.0), np.maximum(hi, 0.0)
        acc = gl.Accessor(componentType=_F32, count=count, type=gl.VEC3, min=lo.tolist(), max=hi.tolist(),
                          byteOffset=None)  # no bufferView: zeros, then the sparse values
        if len(idx):
            acc.sparse = gl.Sparse(count=len(idx),
                                   indices=gl.AccessorSparseIndices(bufferView=self.view(idx.tobytes()),
                                                                    componentType=_U32),
                                   values=gl.AccessorSparseValues(bufferView=self.view(val.tobytes())))
        self.doc.accessors.append(acc)
        return len(self.doc.accessors) - 1

    def glb(self) -> bytes:
        """The GLB container written here (pygltflib's save_to_bytes copies the buffer twice more): a 12-byte header,
        the JSON chunk (padded with spaces) and the BIN chunk (the buffer, its views 4-aligned, padded with zeros)."""
        self.blob += b"\0" * (-len(self.blob) % 4)
        self.doc.buffers.append(gl.Buffer(byteLength=len(self.blob)))
        text = self.doc.gltf_to_json(separators=(",", ":"), indent=None).encode("utf-8")
        text += b" " * (-len(text) % 4)
        head = struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(text) + 8 + len(self.blob))
        return b"".join([head, struct.pack("<I4s", len(text), b"JSON"), text,
                         struct.pack("<I4s", len(self.blob), b"BIN\0"), self.blob])


def skin_sets(weights: np.ndarray, min_weight: float = MIN_WEIGHT) -> tuple[np.ndarray, np.ndarray]:
    """weights (N, K) -> (joints (N, 4S) uint8, weights (N, 4S) float32): each vertex's influences of at
    least `min_weight`, largest first, renormalised in float32 (the last non-zero one is 1 minus the
    others); padding slots hold weight 0 on joint 0, or on joints the vertex does not use where it uses
    joint 0 (joint 0 again where the skeleton has no more: only a non-zero weight may not repeat a joint).
    S = ceil(max influences / 4), also where the skeleton has fewer than 4S joints."""
    w = np.asarray(weights, dtype=np.float64)
    N, K = w.shape
    w = np.where(w >= min_weight, w, 0.0)
    empty = w.sum(axis=1) <= 0
    w[empty, np.argmax(np.asarray(weights)[empty], axis=1)] = 1.0  # a vertex keeps at least its top joint
    used = (w > 0).sum(axis=1)
    width = 4 * math.ceil(int(used.max()) / 4)
    w = np.pad(w, ((0, 0), (0, max(width - K, 0))))  # fewer joints than slots: zero columns fill the last set
    order = np.argsort(-w, axis=1, kind="stable")  # (N, max(K, width)): used joints first, by weight
    ws = np.take_along_axis(w, order, axis=1)
    joints, ws = order[:, :width], ws[:, :width].astype(np.float32)
    ws /= ws.sum(axis=1, keepdims=True, dtype=np.float32)
    last = used - 1
    rows = np.arange(N)
    ws[rows, last] = 0.0
    ws[rows, last] = np.float32(1.0) - ws.sum(axis=1, dtype=np.float32)
    # padding: joint 0 where the vertex does not use joint 0 (the validator's advice); where it does,
    # the unused joints the sort put there (joint 0 twice on a vertex would be an error)
    pad = ws == 0
    pad &= ~(joints == 0).any(axis=1, where=~pad, keepdims=True)
    joints = np.where(pad | (joints >= K), 0, joints)  # a filler column is no joint: weight 0 on joint 0 (allowed)
    return joints.astype(np.uint8), ws


def _quat_xyzw(axis_angle: np.ndarray) -> np.ndarray:
    q = axis_angle_to_quaternion(axis_angle)  # (..., 4) w, x, y, z
    return np.ascontiguousarray(np.concatenate([q[..., 1:], q[..., :1]], axis=-1), dtype=np.float32)


def _add_skeleton(w: _Writer, skeleton: Skeleton) -> list[int]:
    """Joint nodes (rest offsets as translations); returns their node indices in joint order."""
    joints = np.asarray(skeleton.rest_joints, dtype=np.float64)
    base = len(w.doc.nodes)
    for k, name in enumerate(skeleton.joint_names):
        p = int(skeleton.parents[k])
        offset = joints[k] - (joints[p] if p >= 0 else 0.0)
        w.doc.nodes.append(gl.Node(name=name, translation=offset.tolist()))
    for k, p in enumerate(skeleton.parents):
        if p >= 0:
            w.doc.nodes[base + int(p)].children.append(base + k)
    return [base + k for k in range(len(skeleton.joint_names))]


def smooth_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (N, 3) float32, unit length, of a mesh at rest; vertices at the same place (a
    UV seam's copies, a file's own seams) share one, so shading is smooth across seams. A vertex in no face (or
    only degenerate ones) gets +Y (glTF asks every NORMAL to be unit length)."""
    v = np.asarray(vertices, np.float32)
    f = np.asarray(faces, np.int64)
    _, place = np.unique(v, axis=0, return_inverse=True)
    place = place.reshape(-1)
    area_normal = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]).astype(np.float64)
    summed = np.zeros((int(place.max(initial=-1)) + 1, 3))
    for k in range(3):
        np.add.at(summed, place[f[:, k]], area_normal)
    n = summed[place]
    length = np.linalg.norm(n, axis=1, keepdims=True)
    out = np.where(length > 1e-20, n / np.maximum(length, 1e-300), [0.0, 1.0, 0.0])
    return out.astype(np.float32)


def _seams_split(mesh: SkinnedMesh) -> tuple[SkinnedMesh, np.ndarray | None, np.ndarray | None]:
    """-> (the mesh as written: with uv_corners, one vertex per (vertex, uv) pair, vertices, weights and targets
    copied; the written vertices' uv (C, 2) or None; their source vertices (C,) or None)."""
    if mesh.uv_corners is None:
        return mesh, None, None
    source, faces, uv = split_uv_seams(mesh.faces, mesh.uv_corners, len(mesh.vertices))
    targets = None if mesh.targets is None else np.asarray(mesh.targets)[:, source]
    return (SkinnedMesh(mesh.name, np.asarray(mesh.vertices)[source], faces, np.asarray(mesh.weights)[source],
                        targets, mesh.target_names), uv, source)


def _add_skinned_mesh(w: _Writer, mesh: SkinnedMesh, skin: int, extra_targets: list[int] | None = None,
                      uv: np.ndarray | None = None) -> int:
    """A mesh node (skinned by `skin`) for `mesh`; extra targets (accessor indices) follow its own; uv (N, 2)
    (OBJ's convention) as TEXCOORD_0 (glTF's: v from the image's top). -> node."""
    v = np.ascontiguousarray(mesh.vertices, dtype=np.float32)
    attrs = gl.Attributes(POSITION=w.accessor(v, gl.VEC3, target=gl.ARRAY_BUFFER, bounds=True))
    # rest normals, skinned by the engine as the positions are (without them a viewer shades the garment flat)
    attrs.NORMAL = w.accessor(smooth_normals(v, mesh.faces), gl.VEC3, target=gl.ARRAY_BUFFER)
    if uv is not None:
        gl_uv = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]]).astype(np.float32)
        attrs.TEXCOORD_0 = w.accessor(gl_uv, gl.VEC2, target=gl.ARRAY_BUFFER)
    joints, weights = skin_sets(mesh.weights)
    for s in range(joints.shape[1] // 4):
        setattr(attrs, f"JOINTS_{s}", w.accessor(joints[:, 4 * s:4 * s + 4], gl.VEC4, target=gl.ARRAY_BUFFER))
        setattr(attrs, f"WEIGHTS_{s}", w.accessor(weights[:, 4 * s:4 * s + 4], gl.VEC4, target=gl.ARRAY_BUFFER))
    indices = w.accessor(np.asarray(mesh.faces, dtype=np.uint32).reshape(-1), gl.SCALAR,
                         target=gl.ELEMENT_ARRAY_BUFFER)
    prim = gl.Primitive(attributes=attrs, indices=indices, mode=gl.TRIANGLES)
    names = list(mesh.target_names)
    targets = []
    if mesh.targets is not None:
        for d in np.asarray(mesh.targets, dtype=np.float32):
            targets.append({"POSITION": w.accessor(d, gl.VEC3, bounds=True)})
    targets += [{"POSITION": a} for a in extra_targets or []]
    gmesh = gl.Mesh(name=mesh.name, primitives=[prim])
    if targets:
        names += [f"frame_{i}" for i in range(len(extra_targets or []))]
        prim.targets = targets
        gmesh.weights = [0.0] * len(targets)
        gmesh.extras = {"targetNames": names}
    w.doc.meshes.append(gmesh)
    w.doc.nodes.append(gl.Node(name=mesh.name, mesh=len(w.doc.meshes) - 1, skin=skin))
    return len(w.doc.nodes) - 1


def _sampler(w: _Writer, anim: gl.Animation, times: int, values: np.ndarray, kind: str, interpolation: str) -> int:
    anim.samplers.append(gl.AnimationSampler(input=times, output=w.accessor(values, kind),
                                             interpolation=interpolation))
    return len(anim.samplers) - 1


def skinned_glb(skeleton: Skeleton, meshes: list[SkinnedMesh], animation: Animation | None = None,
                extras: dict | None = None) -> bytes:
    """The meshes skinned to one skeleton (the first mesh receives the animation's morph weights and
    corrections) -> GLB bytes; `extras` (JSON-able) go to the asset's extras. See the module docstring."""
    w = _Writer()
    if extras:
        w.doc.asset.extras = extras
    joint_nodes = _add_skeleton(w, skeleton)
    rest = np.asarray(skeleton.rest_joints, dtype=np.float64)
    ibm = np.tile(np.eye(4, dtype=np.float32), (len(joint_nodes), 1, 1))
    ibm[:, :3, 3] = -rest  # the joints' rest frames are the world frame translated to each joint
    w.doc.skins.append(gl.Skin(name="skeleton", joints=joint_nodes, skeleton=joint_nodes[0],
                               inverseBindMatrices=w.accessor(ibm.transpose(0, 2, 1).reshape(-1, 16), gl.MAT4)))
    written = [_seams_split(m) for m in meshes]
    meshes = [m for m, _, _ in written]
    extra: list[int] = []
    if animation is not None and animation.corrections is not None:
        n, source = len(meshes[0].vertices), written[0][2]
        extra = [w.sparse_vec3(n, *_corrections_of(idx, off, source)) for idx, off in animation.corrections]
    mesh_nodes = [_add_skinned_mesh(w, m, 0, extra if i == 0 else None, uv) for i, (m, uv, _) in enumerate(written)]
    w.doc.scenes.append(gl.Scene(name="drape", nodes=[joint_nodes[0], *mesh_nodes]))
    if animation is not None:
        _add_animation(w, animation, rest, joint_nodes, mesh_nodes[0], meshes[0], len(extra))
    return w.glb()


def _corrections_of(indices: np.ndarray, offsets: np.ndarray, source: np.ndarray | None,
                    ) -> tuple[np.ndarray, np.ndarray]:
    """A frame's correction (vertex indices (k,), offsets (k, 3)) on the written vertices: each copy of a
    corrected vertex gets its offset (source: the written vertices' source vertices, or None: the same)."""
    if source is None:
        return indices, offsets
    slot = np.full(int(source.max(initial=-1)) + 1, -1, np.int64)
    slot[np.asarray(indices, np.int64)] = np.arange(len(indices))
    at = slot[source]
    written = np.nonzero(at >= 0)[0]
    return written, np.asarray(offsets)[at[written]]


def _add_animation(w: _Writer, a: Animation, rest: np.ndarray, joint_nodes: list[int], mesh_node: int,
                   mesh: SkinnedMesh, n_extra: int) -> None:
    poses = np.asarray(a.poses, dtype=np.float64).reshape(len(a.poses), -1, 3)
    T = len(poses)
    anim = gl.Animation(name="motion")
    times = w.accessor(np.arange(T, dtype=np.float32) / np.float32(a.fps), gl.SCALAR, bounds=True)
    quats = _quat_xyzw(poses)  # (T, K, 4)
    for k, node in enumerate(joint_nodes):
        s = _sampler(w, anim, times, quats[:, k], gl.VEC4, gl.ANIM_LINEAR)
        anim.channels.append(gl.AnimationChannel(sampler=s, target=gl.AnimationChannelTarget(node=node,
                                                                                           path=gl.ROTATION)))
    root = (rest[0] + np.asarray(a.translation, dtype=np.float64)).astype(np.float32)
    s = _sampler(w, anim, times, root, gl.VEC3, gl.ANIM_LINEAR)
    anim.channels.append(gl.AnimationChannel(sampler=s, target=gl.AnimationChannelTarget(node=joint_nodes[0],
                                                                                       path=gl.TRANSLATION)))
    n_own = 0 if mesh.targets is None else len(mesh.targets)
    if n_own + n_extra:
        weights = np.zeros((T, n_own + n_extra), dtype=np.float32)
        if a.keys is not None:
            weights[:, :n_own] = a.keys
        if n_extra:
            weights[np.arange(T), n_own + np.arange(T)] = 1.0
        s = _sampler(w, anim, times, weights.reshape(-1), gl.SCALAR, gl.ANIM_LINEAR)
        anim.channels.append(gl.AnimationChannel(sampler=s, target=gl.AnimationChannelTarget(node=mesh_node,
                                                                                           path="weights")))
    w.doc.animations.append(anim)


def key_times_finite(frames: int, fps: float) -> bool:
    """Whether glTF's float32 key times of `frames` frames at `fps` (frame t at t / fps seconds) are all finite (and
    so increasing): False for a rate that rounds to 0 in float32 or puts the last frame beyond float32's range, or a
    rate beyond float32's range (every key at 0 s)."""
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        rate = np.float32(fps)
        return bool(np.isfinite(rate) and np.isfinite(np.float32(max(frames - 1, 0)) / rate))


def frame_target_weights(frames: int) -> int:
    """The morph-target weights a GLB animates when it plays one target a frame (`vertex_animation_glb`; a skinned
    GLB's per-frame corrections): frames x (frames - 1), quadratic in the frames."""
    return frames * (frames - 1)


def vertex_animation_glb(vertices: np.ndarray, faces: np.ndarray, fps: float, name: str = "garment",
                         min_offset: float = 0.0) -> bytes:
    """A stream vertices (T, N, 3) m as one mesh: frame 0 is the base, frame t >= 1 a morph target
    (its offsets from frame 0, sparse where fewer than half the vertices move by more than
    `min_offset` m), weight 1 at its frame and 0 elsewhere -> GLB bytes."""
    v = np.asarray(vertices, dtype=np.float32)
    T, N, _ = v.shape
    w = _Writer()
    attrs = gl.Attributes(POSITION=w.accessor(v[0], gl.VEC3, target=gl.ARRAY_BUFFER, bounds=True))
    indices = w.accessor(np.asarray(faces, dtype=np.uint32).reshape(-1), gl.SCALAR, target=gl.ELEMENT_ARRAY_BUFFER)
    prim = gl.Primitive(attributes=attrs, indices=indices, mode=gl.TRIANGLES)
    targets = []
    for t in range(1, T):
        d = v[t] - v[0]
        moved = np.flatnonzero(np.abs(d).max(axis=1) > min_offset)
        if len(moved) < N // 2:
            targets.append({"POSITION": w.sparse_vec3(N, moved, d[moved])})
        else:
            targets.append({"POSITION": w.accessor(d, gl.VEC3, bounds=True)})
    mesh = gl.Mesh(name=name, primitives=[prim])
    if targets:
        prim.targets = targets
        mesh.weights = [0.0] * len(targets)
        mesh.extras = {"targetNames": [f"frame_{t}" for t in range(1, T)]}
    w.doc.meshes.append(mesh)
    w.doc.nodes.append(gl.Node(name=name, mesh=0))
    w.doc.scenes.append(gl.Scene(name="drape", nodes=[0]))
    if targets:
        anim = gl.Animation(name="frames")
        times = w.accessor(np.arange(T, dtype=np.float32) / np.float32(fps), gl.SCALAR, bounds=True)
        weights = np.zeros((T, T - 1), dtype=np.float32)
        weights[np.arange(1, T), np.arange(T - 1)] = 1.0
        s = _sampler(w, anim, times, weights.reshape(-1), gl.SCALAR, gl.ANIM_LINEAR)
        anim.channels.append(gl.AnimationChannel(sampler=s, target=gl.AnimationChannelTarget(node=0, path="weights")))
        w.doc.animations.append(anim)
    return w.glb()
