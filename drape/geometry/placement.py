"""Where a garment sits on a body at rest: what the rig answer reports so a user sees a misplaced garment.

`placement(vertices, body_vertices, body_faces)` measures, for a garment (N, 3) m against a body in its
rest pose: the share of garment vertices inside the body (signed distance to the closest body
triangle < 0), the unsigned distance to the body surface (min, median, max; mm), both bounding boxes,
and plain-sentence warnings (much of the garment inside the body; a garment that looks Z-up, i.e. sits
far closer to the body turned Y-up; one that looks like centimetres or millimetres). Distances beyond `MeshDistance`'s exact
range are upper bounds, which is all a report needs.
"""

from __future__ import annotations

import numpy as np

from drape.geometry.queries import MeshDistance

INSIDE_WARNING = 0.02  # share of vertices inside the body at rest past which the rig warns
FAR_M = 0.30  # a garment with no vertex this close to the body is not on it
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # (x, y, z) -> (x, z, -y), column vectors


def body_distance(body_vertices: np.ndarray, body_faces: np.ndarray) -> MeshDistance:
    """The distance queries `placement` makes against a body at rest (build once per body, reuse)."""
    return MeshDistance(np.asarray(body_vertices, dtype=np.float64), body_faces, exact_within=FAR_M)


def placement(vertices: np.ndarray, body_vertices: np.ndarray, body_faces: np.ndarray,
              distance: MeshDistance | None = None) -> dict:
    """-> {"inside_share", "distance_mm": {"min", "median", "max"}, "bbox": {"garment", "body"} as
    [[min x, y, z], [max x, y, z]] m, "warnings": [sentences]}. distance: `body_distance` of this body,
    when the caller keeps one."""
    v = np.asarray(vertices, dtype=np.float64)
    body = np.asarray(body_vertices, dtype=np.float64)
    distance = distance or body_distance(body, body_faces)
    sd = distance.signed_distance(v)
    dist_mm = np.abs(sd) * 1e3
    inside = float(np.mean(sd < 0))
    g_lo, g_hi, b_lo, b_hi = v.min(0), v.max(0), body.min(0), body.max(0)
    warnings = []
    if inside > INSIDE_WARNING:
        warnings.append(f"{100 * inside:.0f}% of the vertices are inside the body at rest: the garment is not "
                        "placed on this body (move or scale it onto the body, or it will animate inside it)")
    extent, body_extent = g_hi - g_lo, b_hi - b_lo
    if _fits_better_y_up(v, distance, float(np.median(dist_mm))):
        warnings.append("the mesh looks Z-up (turned by -90 degrees about x about its centre it sits on the "
                        "body far closer); drape is Y-up")
    height = float(body_extent[1])
    if g_lo[1] < b_lo[1] - 0.05:
        warnings.append(f"the mesh reaches {100 * (b_lo[1] - g_lo[1]):.0f} cm below the body's feet (the floor): "
                        f"it spans y {g_lo[1]:.2f} to {g_hi[1]:.2f} m where the body spans {b_lo[1]:.2f} to "
                        f"{b_hi[1]:.2f} m; it looks centred on the origin, not placed on the body")
    elif g_hi[1] < b_lo[1] + 0.3 * height:
        warnings.append(f"the whole mesh lies below the body's knees (y up to {g_hi[1]:.2f} m of the body's "
                        f"{b_hi[1]:.2f} m): it is not placed on the body")
    size = float(np.linalg.norm(extent))
    if size > 5 * float(np.linalg.norm(body_extent)):
        warnings.append(f"the mesh is {size:.1f} m across, far larger than the body: it looks like centimetres "
                        "or millimetres; drape expects metres")
    elif size < 0.05 * float(np.linalg.norm(body_extent)):
        warnings.append(f"the mesh is {100 * size:.1f} cm across: it looks scaled down (drape expects metres)")
    return {
        "inside_share": inside,
        "distance_mm": {"min": float(dist_mm.min()), "median": float(np.median(dist_mm)),
                        "max": float(dist_mm.max())},
        "bbox": {"garment": [g_lo.tolist(), g_hi.tolist()], "body": [b_lo.tolist(), b_hi.tolist()]},
        "warnings": warnings,
    }


def _fits_better_y_up(v: np.ndarray, distance: MeshDistance, median_mm: float) -> bool:
    """Whether the mesh turned from Z-up to Y-up (-90 degrees about x, about its centre) lies at under half
    its median distance from the body surface: then it was authored Z-up."""
    centre = v.mean(axis=0)
    turned = (v - centre) @ Z_UP_TO_Y_UP.T + centre
    d = np.abs(distance.signed_distance(turned)) * 1e3
    return bool(np.median(d) < 0.5 * median_mm)
