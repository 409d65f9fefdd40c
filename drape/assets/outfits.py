"""A seeded generator of template outfits in rest pose (T-pose) on a body preset.

Every garment has its own topology, built from quad grids split into triangles:

* tops (t-shirt, tank top, long sleeve, jacket, dress): a torso grid whose rows
  run from the hem up to a neck ring; its lower rows wrap the convex hull of the
  body's cross-section in each horizontal slab, its upper rows ("cap") wrap the
  3D convex hull of the shoulders and neck base. Armholes are rectangles cut out
  of the grid; sleeves are lofted from the armhole loop along the arm axis. The
  jacket is open at the front.
* trousers and shorts: a pelvis tube split at the crotch by a bridge chain into
  two leg tubes lofted along the legs (a "pair of pants", manifold by design).
* skirts: one tube around both legs, flaring toward the hem.

After construction, vertices closer than the clearance to the exact body surface
are pushed out along the body normal, alternating with light smoothing.
Vertex order is shuffled with the seed, so no two outfits share an ordering.
Garments listed together are layered inner to outer (bottoms, tops, jacket),
each outer one wrapping the inner ones. Units: metres, +Y up, facing +Z.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

from drape.assets.body import Body, load_body
from drape.geometry.mesh import uniform_laplacian, vertex_normals
from drape.geometry.queries import MeshDistance
from drape.geometry.skeleton import JOINT_INDEX

GARMENT_TYPES = ("tshirt", "tanktop", "longsleeve", "trousers", "shorts", "skirt", "dress", "jacket", "long_skirt")
LAYER = {"trousers": 0, "shorts": 0, "skirt": 0, "long_skirt": 0, "dress": 1, "tanktop": 1, "tshirt": 1,
         "longsleeve": 1, "jacket": 2}
SKIRTS = ("skirt", "long_skirt")  # tubes from the waist down, open at the hem
CLEARANCE = 0.004  # metres; the generator's own target, above the 2 mm promise


@dataclass
class Outfit:
    """vertices (N, 3) float32 m; faces (F, 3) int32; garment (N,) int32 index into `garments`."""

    vertices: np.ndarray
    faces: np.ndarray
    garment: np.ndarray
    garments: list[str]
    params: dict[str, dict[str, float]] = field(default_factory=dict)

    def to_trimesh(self):  # noqa: ANN201 - trimesh is a serve dependency
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)


class _Builder:
    """Accumulates vertices and triangles."""

    def __init__(self) -> None:
        self.points: list[np.ndarray] = []
        self.faces: list[np.ndarray] = []
        self.n = 0

    def add(self, pts: np.ndarray) -> np.ndarray:
        pts = np.asarray(pts, dtype=np.float64)
        idx = np.arange(self.n, self.n + int(np.prod(pts.shape[:-1]))).reshape(pts.shape[:-1])
        self.points.append(pts.reshape(-1, 3))
        self.n += idx.size
        return idx

    def quads(self, a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> None:
        """Quads (a, b, c, d) counter-clockwise seen from outside -> two triangles each."""
        self.faces.append(np.stack([a, b, c], axis=-1).reshape(-1, 3))
        self.faces.append(np.stack([a, c, d], axis=-1).reshape(-1, 3))

    def strip(self, lower: np.ndarray, upper: np.ndarray) -> None:
        """Join two closed loops of equal length, lower -> upper along the tube."""
        nxt = np.roll(np.arange(len(lower)), -1)
        self.quads(lower, lower[nxt], upper[nxt], upper)

    def orient(self, first_face: int, anchor: np.ndarray, axis: np.ndarray) -> None:
        """Flip faces added since `first_face` if most point toward the axis (anchor, unit axis)."""
        faces = np.concatenate(self.faces)
        pts = np.concatenate(self.points)
        part = faces[first_face:]
        tri = pts[part]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        rel = tri.mean(axis=1) - anchor
        radial = rel - (rel @ axis)[:, None] * axis
        if np.einsum("fc,fc->", n, radial) < 0:
            part = part[:, ::-1]
        self.faces = [faces[:first_face], part]

    @property
    def num_faces(self) -> int:
        return sum(len(f) for f in self.faces)

    def mesh(self) -> tuple[np.ndarray, np.ndarray]:
        """(vertices (N, 3), faces (F, 3)) without the vertices no face uses (e.g. inside armholes)."""
        pts, faces = np.concatenate(self.points), np.concatenate(self.faces).astype(np.int64)
        used = np.zeros(len(pts), dtype=bool)
        used[faces] = True
        new_index = np.cumsum(used) - 1
        return pts[used], new_index[faces]


# ----------------------------------------------------------------------------- envelopes


def _hull_radius(points2d: np.ndarray, dirs2d: np.ndarray) -> np.ndarray:
    """Distance from the origin along unit directions (D, 2) to the convex hull of points (P, 2).

    Returns (D,); 0 where the hull is undefined or does not contain the origin in that direction.
    """
    if len(points2d) < 3:
        return np.full(len(dirs2d), np.linalg.norm(points2d, axis=1).max(initial=0.0))
    try:
        hull = ConvexHull(np.vstack([points2d, [[0.0, 0.0]]]))
    except QhullError:
        return np.full(len(dirs2d), np.linalg.norm(points2d, axis=1).max(initial=0.0))
    n, h = hull.equations[:, :-1], -hull.equations[:, -1]  # n . x <= h
    dots = dirs2d @ n.T
    with np.errstate(divide="ignore"):
        r = np.where(dots > 1e-9, h[None] / dots, np.inf)
    return r.min(axis=1)


def _hull_radius_3d(points: np.ndarray, anchor: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Distance from `anchor` along unit directions (D, 3) to the 3D convex hull of points (P, 3)."""
    hull = ConvexHull(np.vstack([points - anchor, [[0.0, 0.0, 0.0]]]))
    n, h = hull.equations[:, :-1], -hull.equations[:, -1]
    dots = dirs @ n.T
    with np.errstate(divide="ignore"):
        r = np.where(dots > 1e-9, h[None] / dots, np.inf)
    return r.min(axis=1)


@dataclass
class _Parts:
    """Body vertices by dominant joint group (all (P, 3) arrays)."""

    torso: np.ndarray
    pelvis: np.ndarray
    legs: dict[str, np.ndarray]
    arms: dict[str, np.ndarray]


def _parts(body: Body, inner: np.ndarray) -> _Parts:
    """Group body vertices, and the inner garments' vertices, by the dominant joint of the nearest body vertex."""
    dom = body.weights.argmax(axis=1)
    pts = body.vertices.astype(np.float64)
    if len(inner):
        _, near = cKDTree(pts).query(inner)
        dom = np.concatenate([dom, dom[near]])
        pts = np.vstack([pts, inner])

    def pick(*names: str) -> np.ndarray:
        return pts[np.isin(dom, [JOINT_INDEX[n] for n in names])]

    return _Parts(
        torso=pick("pelvis", "spine1", "spine2", "spine3", "neck", "left_collar", "right_collar"),
        pelvis=pick("pelvis", "spine1", "spine2", "left_hip", "right_hip", "left_knee", "right_knee"),
        legs={s: pick(f"{s}_hip", f"{s}_knee", f"{s}_ankle") for s in ("left", "right")},
        arms={s: pick(f"{s}_collar", f"{s}_shoulder", f"{s}_elbow", f"{s}_wrist") for s in ("left", "right")},
    )


def _slab(points: np.ndarray, axis: int, value: float, half: float) -> np.ndarray:
    return points[np.abs(points[:, axis] - value) <= half]


# ----------------------------------------------------------------------------- garments


@dataclass
class _Style:
    """Per-garment shape parameters (metres unless noted)."""

    ease: float  # gap added outside the envelope
    flare: float  # extra radius per metre below the waist (skirts)
    hem_y: float  # hem height
    sleeve_end: float  # sleeve length as a fraction of shoulder->wrist (0 = no sleeve)
    open_front: bool = False


class _Generator:
    def __init__(self, body: Body, spacing: float, rng: np.random.Generator):
        self.body = body
        self.h = spacing
        self.rng = rng
        j = body.joints
        J = JOINT_INDEX
        self.j = {name: j[i].astype(np.float64) for name, i in J.items()}
        self.y_crotch = float(self.j["left_hip"][1] - 0.085 * (j[0, 1] / 0.89))
        self.y_waist = float(self.j["pelvis"][1] + 0.06)
        self.y_armpit = float(self.j["left_shoulder"][1] - 0.11)
        self.y_shoulder = float(self.j["left_shoulder"][1] + 0.03)
        self.y_neck = float(self.j["neck"][1] - 0.01)
        self.centre = np.array([0.0, 0.0, float(j[JOINT_INDEX["spine3"], 2])])

    # --- rows and columns
    def _columns(self, perimeter: float, even: bool = True) -> int:
        c = max(12, int(round(perimeter / self.h)))
        return c + (c % 2) if even else c

    def _ring_dirs(self, C: int, phase: float, open_gap: float = 0.0) -> np.ndarray:
        if open_gap > 0:
            th = np.linspace(open_gap, 2 * np.pi - open_gap, C + 1)
        else:
            th = phase + 2 * np.pi * np.arange(C) / C
        return th

    # --- the torso grid of tops and the pelvis tube of bottoms
    def tube(self, parts: np.ndarray, y_lo: float, y_hi: float, style: _Style, thetas: np.ndarray,
             waist_y: float | None = None) -> np.ndarray:
        """Rows of points (R, C, 3) between heights y_lo < y_hi around the vertical body axis."""
        R = max(3, int(round((y_hi - y_lo) / self.h)) + 1)
        ys = np.linspace(y_lo, y_hi, R)
        u = np.stack([np.sin(thetas), np.cos(thetas)], axis=1)  # (C, 2) in (x, z)
        half = max(0.6 * self.h, 0.012)
        radii = []
        for y in ys:
            pts = _slab(parts, 1, y, half)
            r = _hull_radius(pts[:, [0, 2]] - self.centre[[0, 2]], u)
            radii.append(np.where(np.isfinite(r), r, 0.0))
        rad = np.stack(radii)  # (R, C), rows bottom -> top
        if waist_y is not None:
            # hanging cloth never narrows below the hips: running maximum from the waist down
            below = ys < waist_y
            top = int(np.nonzero(below)[0].max()) if below.any() else -1
            for r_ in range(top - 1, -1, -1):
                rad[r_] = np.maximum(rad[r_], rad[r_ + 1])
            rad += style.flare * np.clip(waist_y - ys, 0.0, None)[:, None]
        rad += style.ease
        x = self.centre[0] + rad * u[None, :, 0]
        z = self.centre[2] + rad * u[None, :, 1]
        return np.stack([x, np.broadcast_to(ys[:, None], x.shape), z], axis=-1)

    def cap(self, parts: np.ndarray, top_row: np.ndarray, style: _Style, thetas: np.ndarray, neck_r: float) -> np.ndarray:
        """Rows (K, C, 3) from just above the torso's top row to the neck ring over the shoulders."""
        anchor = np.array([self.centre[0], self.y_armpit, self.centre[2]])
        region = parts[parts[:, 1] > self.y_armpit - 0.03]
        u = np.stack([np.sin(thetas), np.zeros_like(thetas), np.cos(thetas)], axis=1)
        top_dirs = top_row - anchor
        top_dirs /= np.linalg.norm(top_dirs, axis=1, keepdims=True)
        neck = np.array([self.centre[0], self.y_neck, self.centre[2]]) + neck_r * u - anchor
        neck_dirs = neck / np.linalg.norm(neck, axis=1, keepdims=True)
        arc = float(np.mean(np.linalg.norm(neck - (top_row - anchor), axis=1)))
        K = max(2, int(round(arc / self.h)))
        rows = []
        for k in range(1, K + 1):
            t = k / K
            d = (1 - t) * top_dirs + t * neck_dirs
            d /= np.linalg.norm(d, axis=1, keepdims=True)
            r = _hull_radius_3d(region, anchor, d) + style.ease * (1 - 0.5 * t)
            if k == K:
                r = np.maximum(r, np.linalg.norm(neck, axis=1))
            rows.append(anchor + r[:, None] * d)
        return np.stack(rows)

    def loft(self, b: _Builder, loop: np.ndarray, loop_pts: np.ndarray, axis_pts: np.ndarray,
             parts: np.ndarray, ease: float, end: float, blend: int = 3) -> None:
        """Loft a tube from a closed loop of existing vertices along a polyline axis (A, 3).

        Rings sit at arc length steps of h along the axis up to fraction `end` of it;
        each ring point keeps the angle its loop point has around the axis.
        """
        seg = np.linalg.norm(np.diff(axis_pts, axis=0), axis=1)
        total = float(seg.sum()) * end
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        axis_dir = (axis_pts[-1] - axis_pts[0]) / np.linalg.norm(axis_pts[-1] - axis_pts[0])
        e1 = np.cross(axis_dir, [0.0, 0.0, 1.0]) if abs(axis_dir[2]) < 0.9 else np.cross(axis_dir, [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis_dir, e1)

        def centre_at(s: float) -> np.ndarray:
            return np.array([np.interp(s, cum, axis_pts[:, c]) for c in range(3)])

        # where the loop sits along the axis, and each loop point's angle around it
        s0 = float(np.clip(np.mean((loop_pts - axis_pts[0]) @ axis_dir), 0.0, total))
        rel = loop_pts - centre_at(s0)
        ang = np.arctan2(rel @ e2, rel @ e1)
        u = np.stack([np.cos(ang), np.sin(ang)], axis=1)
        n_rings = max(2, int(round((total - s0) / self.h)))
        prev = loop
        first = b.num_faces
        half = max(0.6 * self.h, 0.012)
        proj = (parts - axis_pts[0]) @ axis_dir
        for k in range(1, n_rings + 1):
            s = s0 + (total - s0) * k / n_rings
            c = centre_at(s)
            slab = parts[np.abs(proj - s) <= half] - c
            r = _hull_radius(np.column_stack([slab @ e1, slab @ e2]), u)
            r = np.where(np.isfinite(r), r, 0.02) + ease
            ring = c + r[:, None] * (u[:, :1] * e1 + u[:, 1:] * e2)
            w = min(1.0, k / blend)
            w = w * w * (3 - 2 * w)
            ring = (1 - w) * (loop_pts + (s - s0) * axis_dir) + w * ring
            idx = b.add(ring)
            b.strip(prev, idx)
            prev = idx
        b.orient(first, axis_pts[0], axis_dir)

    # --- garment assemblies
    def top(self, b: _Builder, parts: _Parts, style: _Style, kind: str) -> None:
        torso_pts = parts.torso if style.hem_y > self.y_crotch else np.vstack([parts.torso, parts.pelvis])
        perim = 2 * np.pi * 0.16
        C = self._columns(perim)
        C -= C % 4  # the sides (90 and 270 degrees) fall on columns
        gap = 0.03 if style.open_front else 0.0
        # this draw is unused but kept: removing it would change every seed's outfit, including
        # the cached training and evaluation outfits behind the published DeePSD table
        self.rng.uniform(0, 2 * np.pi / C)
        thetas = self._ring_dirs(C, 0.0, gap)
        hip_flare = self.y_waist if style.hem_y < self.y_crotch else None
        rows = self.tube(torso_pts, style.hem_y, self.y_shoulder, style, thetas, hip_flare)
        neck_r = 0.075 + (0.02 if kind in ("tanktop", "dress") else 0.0) + (0.02 if style.open_front else 0.0)
        rows = np.concatenate([rows, self.cap(parts.torso, rows[-1], style, thetas, neck_r)])
        R, Cn = rows.shape[:2]
        first = b.num_faces
        idx = b.add(rows)
        closed = not style.open_front
        ncol = Cn if closed else Cn - 1
        keep = np.ones((R - 1, ncol), dtype=bool)
        ys = rows[:, 0, 1]
        r_lo = int(np.searchsorted(ys, self.y_armpit - (0.04 if kind in ("tanktop", "dress") else 0.0)))
        r_hi = int(np.searchsorted(ys, self.y_shoulder))  # armhole rows [r_lo, r_hi)
        half_w = max(2, int(round(0.055 / (2 * np.pi * 0.16 / C)))) if style.sleeve_end == 0 else None
        holes = []
        for side, th in (("left", np.pi / 2), ("right", 3 * np.pi / 2)):
            c_mid = int(np.argmin(np.abs(np.angle(np.exp(1j * (thetas[:ncol] - th))))))
            if half_w is None:
                # sleeve holes: loop length close to the sleeve's perimeter
                want = self._columns(2 * np.pi * 0.075 + style.ease * 6, even=True)
                hw = max(1, (want // 2 - (r_hi - r_lo)) // 2)
                hw = min(hw, c_mid, ncol - 1 - c_mid)  # an oversize top's hole stays inside the grid
            else:
                hw = half_w
            c0, c1 = c_mid - hw, c_mid + hw
            keep[r_lo:r_hi, c0:c1] = False
            holes.append((side, c0, c1))
        r_i = np.arange(R - 1)[:, None]
        c_i = np.arange(ncol)[None, :]
        r_i, c_i = np.broadcast_arrays(r_i, c_i)
        r_i, c_i = r_i[keep], c_i[keep]
        c_n = (c_i + 1) % Cn
        b.quads(idx[r_i, c_i], idx[r_i, c_n], idx[r_i + 1, c_n], idx[r_i + 1, c_i])
        b.orient(first, self.centre, np.array([0.0, 1.0, 0.0]))
        if style.sleeve_end <= 0:
            return
        for side, c0, c1 in holes:
            # the hole's boundary loop, counter-clockwise seen from outside the torso
            loop = np.concatenate([
                idx[r_lo, c0:c1], idx[r_lo:r_hi, c1], idx[r_hi, c1:c0:-1], idx[r_hi:r_lo:-1, c0],
            ])
            pts = np.concatenate(b.points)[loop]
            axis_pts = np.stack([self.j[f"{side}_shoulder"], self.j[f"{side}_elbow"], self.j[f"{side}_wrist"]])
            axis_pts[0, 0] = pts[:, 0].mean()
            self.loft(b, loop, pts, axis_pts, parts.arms[side], style.ease + 0.01, style.sleeve_end)

    def bottoms(self, b: _Builder, parts: _Parts, style: _Style, kind: str) -> None:
        C = self._columns(2 * np.pi * 0.17)
        C -= C % 4
        thetas = self._ring_dirs(C, 0.0)
        if kind in SKIRTS:
            rows = self.tube(parts.pelvis, style.hem_y, self.y_waist, style, thetas, self.y_waist)
        else:
            rows = self.tube(parts.pelvis, self.y_crotch, self.y_waist, style, thetas)
        first = b.num_faces
        idx = b.add(rows)
        for r in range(len(rows) - 1):
            b.strip(idx[r], idx[r + 1])
        b.orient(first, self.centre, np.array([0.0, 1.0, 0.0]))
        if kind in SKIRTS:
            return
        bottom = idx[0]
        pts = np.concatenate(b.points)
        front, back = pts[bottom[0]], pts[bottom[C // 2]]
        m = max(1, int(round(np.linalg.norm(front - back) / self.h)) - 1)
        t = np.linspace(0, 1, m + 2)[1:-1]  # back -> front
        chain_pts = back[None] * (1 - t[:, None]) + front[None] * t[:, None]
        chain_pts[:, 0] = 0.0
        chain_pts[:, 1] = self.y_crotch - 0.01
        chain = b.add(chain_pts)
        left = np.concatenate([bottom[: C // 2 + 1], chain])  # front -> +X side -> back -> middle
        right = np.concatenate([bottom[C // 2 :], bottom[:1], chain[::-1]])
        pts = np.concatenate(b.points)
        for side, loop in (("left", left), ("right", right)):
            axis_pts = np.stack([self.j[f"{side}_hip"], self.j[f"{side}_knee"], self.j[f"{side}_ankle"]])
            axis_pts[0, 1] = self.y_crotch + 0.02
            total = float(np.linalg.norm(np.diff(axis_pts, axis=0), axis=1).sum())
            end = float(np.clip((axis_pts[0, 1] - style.hem_y) / total, 0.15, 1.0))
            self.loft(b, loop, pts[loop], axis_pts, parts.legs[side], style.ease, end)


def _style(kind: str, rng: np.random.Generator, gen: _Generator, looseness: float, length: float) -> _Style:
    knee, ankle = float(gen.j["left_knee"][1]), float(gen.j["left_ankle"][1])
    hip = gen.y_crotch
    ease = 0.006 + 0.03 * looseness
    lerp = lambda a, b: a + (b - a) * length  # noqa: E731
    if kind == "tshirt":
        return _Style(ease, 0.0, lerp(hip + 0.12, hip - 0.02), lerp(0.2, 0.4))
    if kind == "longsleeve":
        return _Style(ease, 0.0, lerp(hip + 0.12, hip - 0.02), lerp(0.85, 0.97))
    if kind == "tanktop":
        return _Style(ease, 0.0, lerp(hip + 0.12, hip), 0.0)
    if kind == "jacket":
        return _Style(ease + 0.02, 0.0, lerp(hip - 0.04, knee + 0.1), lerp(0.9, 0.98), open_front=True)
    if kind == "dress":
        return _Style(ease, 0.25 + 0.2 * looseness, lerp(knee + 0.08, ankle + 0.12), 0.0)
    if kind == "skirt":
        return _Style(ease + 0.004, 0.25 + 0.25 * looseness, lerp(hip - 0.1, knee - 0.06), 0.0)
    if kind == "long_skirt":  # mid-calf (length 0) to just above the ankle (1)
        return _Style(ease + 0.004, 0.3 + 0.25 * looseness, lerp(knee - 0.14, ankle + 0.08), 0.0)
    if kind == "shorts":
        return _Style(ease, 0.0, lerp(hip - 0.06, knee + 0.12), 0.0)
    if kind == "trousers":
        return _Style(ease, 0.0, lerp(knee - 0.2, ankle + 0.02), 0.0)
    raise ValueError(f"unknown garment type {kind!r}; choose from {', '.join(GARMENT_TYPES)}")


def _settle(vertices: np.ndarray, faces: np.ndarray, body: MeshDistance, rounds: int = 8) -> np.ndarray:
    """Push vertices closer than CLEARANCE to the body out along its normal, smoothing between rounds.

    The rounds use the fast approximate closest point; a last exact round settles the rest.
    """
    v = vertices.copy()
    lap = uniform_laplacian(faces, len(v))

    def push(exact: bool) -> bool:
        cp, n, _ = body.closest(v, exact=exact)
        diff = v - cp
        sd = np.linalg.norm(diff, axis=1) * np.sign(np.einsum("pc,pc->p", diff, n))
        bad = sd < CLEARANCE
        v[bad] = cp[bad] + n[bad] * (CLEARANCE + 0.0015)
        return bool(bad.any())

    for _ in range(rounds):
        if not push(exact=False):
            break
        v -= 0.3 * (lap @ v)
    push(exact=True)
    return v


def _build(body: Body, kinds: list[str], spacing: float, seed: int, looseness: float | None,
           length: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, dict[str, float]]]:
    rng = np.random.default_rng(seed)
    gen = _Generator(body, spacing, rng)
    inner = np.zeros((0, 3))
    verts, faces, labels, params = [], [], [], {}
    offset = 0
    for g, kind in enumerate(kinds):
        loose = float(rng.uniform(0.0, 1.0)) if looseness is None else float(looseness)
        leng = float(rng.uniform(0.0, 1.0)) if length is None else float(length)
        style = _style(kind, rng, gen, loose, leng)
        if len(inner):
            style.ease += 0.008
        b = _Builder()
        parts = _parts(body, inner)
        if kind in ("trousers", "shorts", *SKIRTS):
            gen.bottoms(b, parts, style, kind)
        else:
            gen.top(b, parts, style, kind)
        v, f = b.mesh()
        verts.append(v)
        faces.append(f + offset)
        labels.append(np.full(len(v), g, dtype=np.int32))
        params[kind] = {"looseness": loose, "length": leng, "ease_m": style.ease, "hem_y_m": style.hem_y}
        offset += len(v)
        inner = np.vstack([inner, v])
    return np.concatenate(verts), np.concatenate(faces), np.concatenate(labels), params


MAX_LOOSENESS = 3.0  # above 1: oversize (docs/deepsd_experiments.md); the generator is tested up to 3


def generate_outfit(
    types: str | list[str],
    vertices: int = 4000,
    seed: int = 0,
    body: str | Body = "neutral",
    looseness: float | None = None,
    length: float | None = None,
) -> Outfit:
    """Generate an outfit of one or more garments on a body preset in rest pose.

    types: a garment type or a list (or comma-separated string) of them;
    vertices: target total vertex count (met within ~10%); seed: drives the
    random choices (looseness, length when not given, vertex order);
    looseness, length: in [0, 1] (tight..loose, short..long), random when None; looseness up to
    MAX_LOOSENESS makes garments for a larger body (DeePSD's oversize outfits). Outside: ValueError (NaN made
    a float-to-int error, infinity an OverflowError, other values extrapolated hems and negative ease).
    """
    kinds = [t.strip() for t in types.split(",")] if isinstance(types, str) else list(types)
    for k in kinds:
        if k not in GARMENT_TYPES:
            raise ValueError(f"unknown garment type {k!r}; choose from {', '.join(GARMENT_TYPES)}")
    if len(set(kinds)) != len(kinds):
        raise ValueError("each garment type may appear once per outfit")
    if not 200 <= vertices <= 60000:
        raise ValueError(f"vertices must be in [200, 60000], got {vertices}")
    for name, value, high in (("looseness", looseness, MAX_LOOSENESS), ("length", length, 1.0)):
        if value is not None and not 0.0 <= value <= high:
            raise ValueError(f"{name} must be within [0, {high:g}], got {value}")
    kinds.sort(key=lambda k: LAYER[k])
    b = load_body(body) if isinstance(body, str) else body
    spacing = 0.05 * np.sqrt(2000 / vertices)
    for _ in range(5):
        v, f, lab, params = _build(b, kinds, spacing, seed, looseness, length)
        ratio = len(v) / vertices
        if abs(ratio - 1) < 0.04:
            break
        spacing *= np.sqrt(ratio)
    v = _settle(v, f, MeshDistance(b.vertices, b.faces, vertex_normals(b.vertices, b.faces)))
    rng = np.random.default_rng([seed, 1])
    perm = rng.permutation(len(v))  # new index of old vertex i is inv[i]
    inv = np.empty_like(perm)
    inv[perm] = np.arange(len(v))
    f = inv[f][rng.permutation(len(f))]
    f = np.roll(f, int(rng.integers(3)), axis=1)  # same winding, another first corner
    return Outfit(v[perm].astype(np.float32), f.astype(np.int32), lab[perm], kinds, params)


def split_outfit(types: str, vertices: int, seed: int = 0, body: str | Body = "neutral",
                 looseness: float | None = None, length: float | None = None,
                 ) -> tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """Two garments ("inner,outer", e.g. "tshirt,jacket") generated as one layered outfit
    (`drape.assets.outfits.generate_outfit`, the outer built around the inner) and split into two meshes:
    ((inner vertices (Ni, 3) float32, faces (Fi, 3) int32), (outer ..)). vertices: the two together."""
    kinds = [t.strip() for t in types.split(",")]
    if len(kinds) != 2:
        raise ValueError(f"give two garment types, inner first: {types!r}")
    outfit = generate_outfit(kinds, vertices=vertices, seed=seed, body=body, looseness=looseness, length=length)
    if outfit.garments != kinds:
        raise ValueError(f"the generator layers {kinds} as {outfit.garments} (inner first): swap them")
    out = []
    for g in range(2):
        keep = outfit.garment == g
        index = np.full(len(keep), -1, dtype=np.int64)
        index[keep] = np.arange(int(keep.sum()))
        faces = outfit.faces[keep[outfit.faces].all(axis=1)]
        out.append((outfit.vertices[keep].astype(np.float32), index[faces].astype(np.int32)))
    return out[0], out[1]
