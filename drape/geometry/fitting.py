"""Fitting a garment made for another body onto a drape body at rest (what `POST /v1/outfits/fit` and
`drape outfits fit` do).

Steps, each reported:
1. units: `m`, `cm` or `mm`; inferred from the garment's largest extent when not given (a garment is
   0.05-3 m across: up to 3 units is metres, up to 300 centimetres, beyond that millimetres).
2. up axis: `y` (drape's) or `z` (turned a quarter turn about +X, as motion import turns Z-up clips);
   inferred when not given (`infer_up`): the axis the garment's upper half clearly wraps around, else the
   thinner of Y and Z is its depth (a garment is thinnest front to back).
3. placement, rigid (a garment keeps its size: one made for a larger body stays loose): the garment's
   centre is searched along the body's height, facing +Z or -Z (a garment may face either way), its
   horizontal centre on the body's centre at that height, scored on a subsample by how closely it hugs
   the body (mean distance to the body surface, capped at 10 cm, inside vertices counted three times);
   then its height and depth are refined from the best start by Powell's method on the same score (left
   to right it stays centred on the body, as garments are worn).
4. un-posing: a garment authored in another pose than the T-pose (`pose`: "a", or (24, 3) axis-angle
   radians) is placed against the body in that pose, then carried to the rest pose by the inverse of the
   body's own skinning (each vertex with the skinning weights of its nearest posed-body vertex).
5. push-out: the refinement's solver at the rest pose (drape.geometry.refine, zero pose): vertices
   inside the body go out by eps keeping the garment's local shape.

Shapes: vertices (N, 3), faces (F, 3); the result in metres, Y-up, on the body's rest pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from drape.assets.body import Body
from drape.geometry.lbs import SingularSkinning, unskin
from drape.geometry.mesh import unique_edges
from drape.geometry.placement import FAR_M, Z_UP_TO_Y_UP
from drape.geometry.queries import MeshDistance, nearest_vertex_weights
from drape.geometry.refine import EPS, refine
from drape.geometry.skeleton import forward_kinematics

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
CAP_M = 0.10  # a vertex farther than this from the body counts as this far in the placement score
INSIDE_COST = 1.0  # an inside vertex costs this many times its depth
SAMPLE = 400  # vertices scored during the placement search
HEIGHT_STEP_M = 0.03
A_POSE_DEG = 45.0  # the "a" pose: both shoulders lowered this far from the T-pose
UP_WRAP_MARGIN = 0.15  # infer_up: the wrap coverages of Y and Z further apart than this decide
UP_FLAT_RATIO = 0.3  # infer_up: Y or Z under this share of the other is the depth of a flat piece, whatever wraps
LEFT_SHOULDER, RIGHT_SHOULDER = 16, 17  # SMPL joint order


class FitError(ValueError):
    """The garment cannot be fitted (e.g. it sits nowhere on the body); the message says why, `argument`
    which input is at fault ("vertices", or "pose")."""

    def __init__(self, message: str, argument: str = "vertices"):
        super().__init__(message)
        self.argument = argument


@dataclass(frozen=True)
class FitResult:
    """vertices (N, 3) float32 m, Y-up, on the body at rest; transform (4, 4): the similarity applied before
    the un-posing and the push-out (units, up axis, facing, translation); report: what was done."""

    vertices: np.ndarray
    transform: np.ndarray
    report: dict


def infer_units(vertices: np.ndarray) -> str:
    """'m', 'cm' or 'mm' from the largest bounding-box extent (a garment is 0.05-3 m across)."""
    size = float(np.ptp(vertices, axis=0).max())
    return "m" if size <= 3.0 else "cm" if size <= 300.0 else "mm"


def infer_up(vertices: np.ndarray) -> str:
    """'y' or 'z': which axis of a garment (N, 3) is up (X is left to right either way).

    A piece far thinner along one of Y and Z than the other (under UP_FLAT_RATIO: one flat panel, which fills
    every direction of a slice across its depth) is deep along it. Otherwise, first the axis the garment's upper
    half wraps around (`wrap_coverage`), where one of Y and Z clearly wins (by more than UP_WRAP_MARGIN): slices across the true up axis go round the body, slices across the depth
    axis cut a front and a back strip. Otherwise (unsewn panels, tops whose sleeves fill the slices both ways)
    the thinner of the two is the depth (a garment is thinnest front to back). The thinnest-axis rule alone
    took a flared skirt, deeper than it is tall, for Z-up."""
    v = np.asarray(vertices, dtype=np.float64)
    extent = np.ptp(v, axis=0)
    thin = min(extent[1], extent[2]) < UP_FLAT_RATIO * max(extent[1], extent[2])
    if not thin:  # a flat or nearly flat piece (one panel) fills every direction of a slice across its depth
        wrap_y, wrap_z = wrap_coverage(v, 1), wrap_coverage(v, 2)
        if abs(wrap_y - wrap_z) > UP_WRAP_MARGIN:
            return "y" if wrap_y > wrap_z else "z"
    return "z" if extent[1] < extent[2] else "y"


def wrap_coverage(vertices: np.ndarray, axis: int, slices: int = 9, bins: int = 24) -> float:
    """How far a garment's upper half (N, 3) goes round `axis` (1: Y, 2: Z), in [0, 1]: over `slices` thin
    slices across the axis, from 50% to 90% of its extent (the hips of trousers, not their two legs), the share
    of `bins` directions about the slice's centre that hold a vertex, averaged."""
    v = np.asarray(vertices, dtype=np.float64)
    across = [a for a in range(3) if a != axis]
    h = v[:, axis]
    lo, hi = float(h.min()), float(h.max())
    covered = []
    for s in np.linspace(0.5, 0.9, slices):
        p = v[np.abs(h - (lo + s * (hi - lo))) < 0.03 * (hi - lo) + 0.005][:, across]
        if len(p) < 3:
            continue
        c = (p.min(0) + p.max(0)) / 2
        angle = np.arctan2(p[:, 1] - c[1], p[:, 0] - c[0])
        covered.append(len(np.unique(((angle + np.pi) / (2 * np.pi) * bins).astype(int) % bins)) / bins)
    return float(np.mean(covered)) if covered else 0.0


def a_pose(degrees: float = A_POSE_DEG) -> np.ndarray:
    """(24, 3) axis-angle radians: the T-pose with both arms lowered by `degrees` (about Z)."""
    pose = np.zeros((24, 3))
    pose[LEFT_SHOULDER, 2] = -np.radians(degrees)  # the left arm lies along +X: lowering it turns it about -Z
    pose[RIGHT_SHOULDER, 2] = np.radians(degrees)
    return pose


def _scores(points: np.ndarray, distance: MeshDistance, exact: bool = True) -> np.ndarray:
    """(C, S, 3) candidate placements of S points -> (C,) placement scores, m (lower hugs the body better).
    exact=False: MeshDistance's k-nearest-centroid answer, what the search ranks by (~3x faster; the same best
    placement and scores within 0.05 mm: tests/geometry/test_fitting.py)."""
    sd = distance.signed_distance(points.reshape(-1, 3), exact=exact).reshape(points.shape[:2])
    return np.mean(np.where(sd < 0, -INSIDE_COST * sd, np.minimum(sd, CAP_M)), axis=1)


def _centre_at(body_vertices: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """(x, z) centre of the body's vertices between heights lo and hi (the whole body's if none)."""
    band = body_vertices[(body_vertices[:, 1] >= lo) & (body_vertices[:, 1] <= hi)]
    band = band if len(band) else body_vertices
    return (band.min(0) + band.max(0))[[0, 2]] / 2


def place(vertices: np.ndarray, body_vertices: np.ndarray, distance: MeshDistance,
          seed: int = 0, exact_search: bool = False) -> tuple[np.ndarray, float]:
    """A Y-up garment in metres (N, 3) -> (rigid transform (4, 4) putting it on the body, its exact score in m).
    distance: the body's queries, exact within at least CAP_M (no more is needed: the score caps there);
    exact_search: rank the placements by exact distances too (the slower reference bench.fit compares with)."""
    v = np.asarray(vertices, dtype=np.float64)
    rng = np.random.default_rng(seed)
    sample = v[rng.choice(len(v), SAMPLE, replace=False)] if len(v) > SAMPLE else v
    centre = (v.min(0) + v.max(0)) / 2
    half = np.ptp(v[:, 1]) / 2
    b_lo, b_hi = float(body_vertices[:, 1].min()), float(body_vertices[:, 1].max())
    if 2 * half > b_hi - b_lo:
        raise FitError(f"the garment is {2 * half:.2f} m tall, taller than the body ({b_hi - b_lo:.2f} m): "
                       "check its units")
    starts = []
    for yaw in (0.0, np.pi):
        rot = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
        for y in np.arange(b_lo + half * 0.5, b_hi - half * 0.5 + 1e-9, HEIGHT_STEP_M):
            xz = _centre_at(body_vertices, y - half, y + half)
            starts.append((rot, np.array([xz[0], y, xz[1]])))
    candidates = np.stack([(sample - centre) @ rot.T + t for rot, t in starts])  # (C, S, 3)
    rot, t0 = starts[int(np.argmin(_scores(candidates, distance, exact=exact_search)))]
    local = (sample - centre) @ rot.T
    # height and depth only: a garment is worn centred left to right
    res = minimize(lambda p: float(_scores((local + t0 + [0.0, p[0], p[1]])[None], distance, exact=exact_search)[0]),
                   np.zeros(2), method="Powell", options={"xtol": 2e-3, "ftol": 1e-6, "maxfev": 100})
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = t0 + [0.0, res.x[0], res.x[1]] - rot @ centre
    return m, float(_scores((local + t0 + [0.0, res.x[0], res.x[1]])[None], distance)[0])  # the exact score


def unpose(vertices: np.ndarray, body: Body, pose: np.ndarray) -> np.ndarray:
    """Garment vertices (N, 3) m placed on the body in `pose` (24, 3) rad -> (N, 3) m on the body at rest:
    the inverse of the body's skinning, with the weights of each vertex's nearest posed-body vertex."""
    pose = np.asarray(pose, dtype=np.float64).reshape(1, 24, 3)
    transforms = forward_kinematics(pose, body.joints.astype(np.float64), body.parents)[0][0]  # (24, 4, 4)
    posed_body = body.pose(pose)[0].astype(np.float64)
    w = nearest_vertex_weights(vertices, posed_body, body.weights).astype(np.float64)  # (N, 24)
    blended = np.einsum("nk,kij->nij", w, transforms)  # (N, 4, 4)
    try:
        return unskin(blended, vertices)
    except SingularSkinning as exc:
        raise FitError(str(exc), "pose") from None


INSIDE_AFTER_WARNING = 0.001  # a share of vertices left inside the body at rest worth a warning (the bar: 0.1%)


def fit_garment(vertices: np.ndarray, faces: np.ndarray, body: Body, *, units: str | None = None,
                up: str | None = None, pose: str | np.ndarray | None = None, eps: float = EPS,
                exact_search: bool = False) -> FitResult:
    """Fit a garment (vertices (N, 3) in `units`, `up`-up; faces (F, 3)) onto `body` at rest.

    units: 'm' | 'cm' | 'mm' | None (inferred); up: 'y' | 'z' | None (inferred); pose: the pose the garment
    was authored in: None or 't' (the T-pose), 'a' (`a_pose()`), or (24, 3) axis-angle radians.
    Raises FitError when the garment sits nowhere on the body. -> FitResult (report: units, up, whether
    each was inferred, pose, inside_before / inside_after (shares of vertices inside the body at rest,
    before and after the push-out), max_move_mm / mean_move_mm (the push-out's moves), max_stretch_mm (its
    largest edge lengthening), warnings (sentences: units or up given against what the mesh's size or shape
    says; more than INSIDE_AFTER_WARNING of the vertices left inside)). exact_search: `place`'s.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    report: dict = {"units_inferred": units is None, "up_inferred": up is None}
    warnings = []
    size = float(np.ptp(v, axis=0).max())
    if units is not None and units in UNITS and units != infer_units(v):
        warnings.append(f"the mesh is {size:.4g} units across: in {units} that is {size * UNITS[units]:.3g} m, "
                        f"where a garment is 0.05-3 m; its size says {infer_units(v)}")
    if up is not None and up in ("y", "z") and up != infer_up(v):
        warnings.append(f"its shape says {infer_up(v).upper()}-up, not {up.upper()}-up as given")
    units = units or infer_units(v)
    up = up or infer_up(v)
    if units not in UNITS:
        raise FitError(f"units must be one of {sorted(UNITS)}, not {units!r}")
    if up not in ("y", "z"):
        raise FitError(f"up must be 'y' or 'z', not {up!r}")
    pre = np.eye(4)
    pre[:3, :3] = UNITS[units] * (Z_UP_TO_Y_UP if up == "z" else np.eye(3))
    v_m = v @ pre[:3, :3].T
    area = np.linalg.norm(np.cross(v_m[f[:, 1]] - v_m[f[:, 0]], v_m[f[:, 2]] - v_m[f[:, 0]]), axis=1)
    if not np.any(area > 1e-12):  # every vertex at one point (or on one line): nothing to fit
        raise FitError("every face has zero area (its vertices coincide or lie on one line): not a garment", "faces")

    if pose is None or (isinstance(pose, str) and pose == "t"):
        pose_arr, pose_name = np.zeros((24, 3)), "t"
    elif isinstance(pose, str) and pose == "a":
        pose_arr, pose_name = a_pose(), "a"
    elif isinstance(pose, str):
        raise FitError(f"pose must be 't', 'a' or (24, 3) axis-angle radians, not {pose!r}", "pose")
    else:
        pose_arr, pose_name = np.asarray(pose, dtype=np.float64).reshape(24, 3), "given"
    posed = pose_name != "t"
    target = body.pose(pose_arr[None])[0].astype(np.float64) if posed else body.vertices.astype(np.float64)
    distance = MeshDistance(target, body.faces, exact_within=FAR_M)
    placing, score = place(v_m, target, MeshDistance(target, body.faces, exact_within=CAP_M), exact_search=exact_search)
    transform = placing @ pre
    placed = v_m @ placing[:3, :3].T + placing[:3, 3]
    near = float(np.abs(distance.signed_distance(placed)).min())
    if near > FAR_M:
        raise FitError(f"no vertex comes within {FAR_M * 100:.0f} cm of the body wherever the garment is put: "
                       "is it a garment?")
    rest = unpose(placed, body, pose_arr) if posed else placed

    rest_body = body.vertices.astype(np.float64)
    rest_distance = MeshDistance(rest_body, body.faces, exact_within=FAR_M) if posed else distance
    inside_before = float(np.mean(rest_distance.signed_distance(rest) < 0))
    fitted, _ = refine(rest.astype(np.float32), f, rest_body.astype(np.float32), body.faces, eps=eps)
    fitted = fitted[0].astype(np.float64)
    inside_after = float(np.mean(rest_distance.signed_distance(fitted) < 0))
    if inside_after > INSIDE_AFTER_WARNING:
        warnings.append(f"{inside_after:.2%} of the vertices are still inside the body after the push-out: does the "
                        "file hold more than the garment (a body, a second layer)?")
    move = np.linalg.norm(fitted - rest, axis=1)
    e = unique_edges(f)
    before_len = np.linalg.norm(rest[e[:, 1]] - rest[e[:, 0]], axis=1)
    after_len = np.linalg.norm(fitted[e[:, 1]] - fitted[e[:, 0]], axis=1)
    report.update({
        "units": units, "up": up, "pose": pose_name,
        "placement_score_mm": 1e3 * score,
        "inside_before": inside_before, "inside_after": inside_after,
        "max_move_mm": 1e3 * float(move.max()), "mean_move_mm": 1e3 * float(move.mean()),
        "max_stretch_mm": 1e3 * float(max(0.0, (after_len - before_len).max())),
        "warnings": warnings,
    })
    return FitResult(fitted.astype(np.float32), transform, report)
