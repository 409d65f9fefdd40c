"""Where the largest edge stretches left by refinement come from: a diagnostic for bench/refine.py.

Input: the long sleeve + trousers outfit on the held-out clip dance_b (every 5th frame), posed by
the nearest-body-weights LBS baseline (the issue's penetrating input; 6k and 20k vertices) and by
the shipped DeePSD (6k). For each method (refine with its defaults, the stretch relief pass
included; norelief = the same without it, `relief_iterations=0`; naive = each inside vertex to its
closest body point + eps) it lists the 8 most stretched
edges over all frames: the stretch (elongation vs the input, mm), each end's depth in the input
(exact closest-triangle signed distance, mm; negative inside), whether the refined edge passes
through the body (a point at 1/4, 1/2 or 3/4 of it inside by the winding number: its ends sit on
opposite sides of a limb), and the naive push's stretch of the same edge in the same frame.
`gap deg`: for the connected patch of input cloth inside the body that holds the edge's deeper end,
the largest angle around the limb's axis with none of the patch's outside neighbours in it (limb:
the body vertices skinned mostly to the joint of the patch's deepest vertex's closest body face;
axis: their first principal direction). Under 180 degrees the patch's rim goes all round the limb:
the limb pierces the cloth, and no placement of the patch outside the body leaves it unstretched.
A summary line per method counts the listed edges with both ends more than 15 mm inside in the
input, those that pass through the body after, and those whose patch rim goes all round the limb.
A second gives the spike figures over all edges and frames except the edges with an end in such a
pierced patch: the largest stretch, its 99.9th percentile and the edges over 10 mm per frame.

Run: .venv/bin/python -m bench.refine_spikes (about 2 minutes on the 2-core machine)
"""

from __future__ import annotations

import numpy as np
from scipy.sparse.csgraph import connected_components

from bench.refine import baseline_input, posed_body
from drape.assets.body import Body
from drape.assets.motion import load_clip
from drape.assets.outfits import generate_outfit
from drape.geometry.mesh import adjacency_matrix, unique_edges
from drape.geometry.metrics import edge_lengths
from drape.geometry.queries import MeshDistance, winding_number
from drape.geometry.refine import BodySurface, Refiner, RefineReport, naive_push
from drape.runtime.deepsd import DeePSDModel, pose_outfit

TOP = 8
DEEP = 0.015  # m


def passes_through(a: np.ndarray, b: np.ndarray, body: np.ndarray, body_faces: np.ndarray) -> np.ndarray:
    """Edges from a (K, 3) to b (K, 3), metres -> (K,) bool: a point at 1/4, 1/2 or 3/4 of the edge is inside
    the body (M, 3) by the winding number."""
    inner = np.array([0.25, 0.5, 0.75])
    pts = a[:, None] + inner[None, :, None] * (b - a)[:, None]
    inside = winding_number(pts.reshape(-1, 3), body, body_faces) > 0.5
    return np.asarray(inside.reshape(len(a), -1).any(axis=1), dtype=bool)


def rim_gap_deg(garment: np.ndarray, sd: np.ndarray, adjacency, patch: np.ndarray,  # noqa: ANN001
                distance: MeshDistance, body: Body, posed: np.ndarray) -> float:
    """The largest angle (degrees) around the limb's axis free of an inside patch's outside rim.

    garment (N, 3) m, the input frame; sd (N,) its signed distances, m; adjacency (N, N) sparse;
    patch (K,): the vertex indices of one connected patch of inside vertices; posed (M, 3) m, the
    posed body. The limb: the body vertices skinned mostly to the joint of the patch's deepest
    vertex's closest body face; its axis: their first principal direction.
    """
    rim = np.unique(adjacency[patch].indices)
    rim = rim[sd[rim] >= 0]
    if len(rim) == 0:
        return 360.0
    face = distance.closest(garment[patch[[np.argmin(sd[patch])]]])[2][0]
    joint = np.bincount(body.weights[body.faces[face]].argmax(axis=1)).argmax()
    limb = posed[body.weights.argmax(axis=1) == joint]
    centre = limb.mean(axis=0)
    _, _, axes = np.linalg.svd(limb - centre, full_matrices=False)  # axes[0]: the limb's long axis
    rel = garment[rim] - centre
    angle = np.sort(np.degrees(np.arctan2(rel @ np.cross(axes[0], axes[1]), rel @ axes[1])))
    return float(np.max(np.diff(np.append(angle, angle[0] + 360.0))))


def patch_gaps(garment: np.ndarray, sd: np.ndarray, adjacency, distance: MeshDistance,  # noqa: ANN001
               body: Body, posed: np.ndarray) -> np.ndarray:
    """(N,) float: each input vertex's patch rim gap (degrees, `rim_gap_deg`); NaN for vertices outside."""
    gap = np.full(len(garment), np.nan)
    inside = np.nonzero(sd < 0)[0]
    num, label = connected_components(adjacency[inside][:, inside], directed=False)
    for k in range(num):
        patch = inside[label == k]
        gap[patch] = rim_gap_deg(garment, sd, adjacency, patch, distance, body, posed)
    return gap


def main() -> None:
    body, p, t, b = posed_body(np.arange(0, load_clip("dance_b").num_frames, 5))
    surface = BodySurface(body.faces, len(body.vertices))
    model = DeePSDModel()
    cases = [("baseline", 6000), ("deepsd", 6000), ("baseline", 20000)]
    print(f"{'input':8s} {'N':>6s} {'method':8s} {'frame':>5s} {'edge':>12s} {'stretch mm':>10s} "
          f"{'depth in mm':>15s} {'through body':>12s} {'naive mm':>8s} {'gap deg':>7s}")
    for source, n in cases:
        o = generate_outfit("longsleeve,trousers", vertices=n, seed=77)
        if source == "baseline":
            g = baseline_input(o, body, p, t)
        else:
            g = pose_outfit(o.vertices, model.rig(o.vertices, o.faces, body), model.pose_keys(p), body.joints, p, t)
        g = g.astype(np.float64)
        edges, nv = unique_edges(o.faces), len(o.vertices)
        adjacency = adjacency_matrix(o.faces, nv).tocsr()
        methods = {"refine": Refiner(o.faces, nv), "norelief": Refiner(o.faces, nv, relief_iterations=0)}
        naive = np.stack([naive_push(g[i], b[i], surface) for i in range(len(g))])
        naive_stretch = edge_lengths(naive, edges) - edge_lengths(g, edges)  # (T, E) m
        outputs = {name: np.stack([r.refine_frame(g[i], b[i], surface, RefineReport()) for i in range(len(g))])
                   for name, r in methods.items()}
        outputs["naive"] = naive
        distances = [MeshDistance(b[i], body.faces) for i in range(len(g))]
        input_sd = np.stack([d.signed_distance(g[i]) for i, d in enumerate(distances)])  # (T, N) m
        gaps = np.stack([patch_gaps(g[i], input_sd[i], adjacency, distances[i], body, b[i]) for i in range(len(g))])
        pierced_edge = np.any(gaps[:, edges] < 180, axis=2)  # (T, E): an end in a patch the limb pierces
        for name, r in outputs.items():
            stretch = edge_lengths(r, edges) - edge_lengths(g, edges)
            top = np.argsort(-stretch, axis=None)[:TOP]
            deep = through = pierced = 0
            for frame, e in zip(*np.unravel_index(top, stretch.shape), strict=True):
                ends = edges[e]
                depth = input_sd[frame, ends]
                crosses = bool(passes_through(r[frame][ends[:1]], r[frame][ends[1:]], b[frame], body.faces)[0])
                gap = "-"
                if depth.min() < 0:
                    gap_deg = gaps[frame, ends[np.argmin(depth)]]
                    gap = f"{gap_deg:.0f}"
                    pierced += int(gap_deg < 180)
                deep += int(np.all(depth < -DEEP))
                through += int(crosses)
                print(f"{source:8s} {nv:6d} {name:8s} {frame:5d} {ends[0]:6d}-{ends[1]:<5d} {stretch[frame, e] * 1e3:10.2f} "
                      f"{depth[0] * 1e3:7.1f} {depth[1] * 1e3:7.1f} {'yes' if crosses else 'no':>12s} "
                      f"{naive_stretch[frame, e] * 1e3:8.2f} {gap:>7s}")
            print(f"{source:8s} {nv:6d} {name:8s} of the {TOP} largest: both ends over {DEEP * 1e3:.0f} mm deep in "
                  f"the input {deep}, through the body after {through}, patch rim all round the limb {pierced}")
            off = stretch[~pierced_edge]
            print(f"{source:8s} {nv:6d} {name:8s} all edges off pierced patches ({100 * off.size / stretch.size:.2f}% "
                  f"of edge-frames): largest {off.max() * 1e3:.2f} mm, 99.9th percentile "
                  f"{np.percentile(off, 99.9) * 1e3:.2f} mm, over 10 mm {np.count_nonzero(off > 0.01) / len(g):.1f} "
                  f"per frame", flush=True)


if __name__ == "__main__":
    main()
