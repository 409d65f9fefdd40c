"""Refinement speed and quality, in one run, against two baselines.

Input: the shipped DeePSD posing a long-sleeve + trousers outfit (2k, 6k, 20k vertices) on the
held-out clip dance_b (every 5th frame), which leaves a few percent of vertices inside the body.
Methods: drape's refinement (affected-region solve, progressive pass, stretch relief pass) with its
defaults (`refine`), and without the relief pass (`norelief`, `relief_iterations=0`); (a) naive: each inside
vertex moved to its closest body point + eps; (b) the same energy solved on the whole mesh with
an unfactorised sparse solve (spsolve) each iteration, relief pass on. Quality: share of vertices inside after
(exact closest-triangle test), mean Laplacian deviation (mm), spikes = largest edge stretch
(largest edge elongation vs the input frame, mm), its 99.9th percentile over all edges and
frames, and spike edges (edges elongated by more than 10 mm, per frame), and the
frame-to-frame jitter refinement adds (mm). Two inputs: the shipped DeePSD and
the nearest-body-weights LBS baseline (the issue's penetrating input).

The posed body intersects itself (the upper arm enters the torso at the armpit, the thighs
overlap); input cloth in that overlap is inside by the winding number but outside by the
closest-triangle sign, so no sign-based method moves it while its neighbours are pushed out
(bench/refine_self_intersection.py). The two `off-ovl` columns repeat the spike figures over the
edges with no such hidden endpoint in the input: the largest stretch and the >10 mm edges per
frame. Winding numbers are brute force, so they are computed only for the endpoints of the edges
those two figures need.
Run: .venv/bin/python -m bench.refine
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from drape.assets.body import Body, load_body
from drape.assets.motion import load_clip
from drape.assets.outfits import Outfit, generate_outfit
from drape.geometry.lbs import pose_mesh
from drape.geometry.mesh import uniform_laplacian, unique_edges
from drape.geometry.metrics import edge_lengths
from drape.geometry.queries import MeshDistance, nearest_vertex_weights, winding_number
from drape.geometry.refine import BodySurface, Refiner, RefineReport, added_jitter_mm, naive_push
from drape.runtime.deepsd import DeePSDModel, pose_outfit


class GlobalSolveRefiner(Refiner):
    """Baseline (b): the whole-mesh system, assembled and solved from scratch every iteration."""

    def _solve(self, v, inside, targets):  # noqa: ANN001, ANN202
        d = np.zeros(self.n)
        d[inside] = self.weight
        rhs = np.zeros((self.n, 3))
        rhs[inside] = self.weight * (targets - v[inside])
        delta = spsolve((self.system + sp.diags(d)).tocsc(), rhs)
        return v + delta, np.arange(self.n)


def inside_pct(x: np.ndarray, distances: list[MeshDistance]) -> float:
    """Share (%) of garment vertices inside the body over frames: x (T, N, 3), one MeshDistance per posed body frame."""
    return float(100 * np.mean([np.mean(d.signed_distance(x[t]) < 0) for t, d in enumerate(distances)]))


class HiddenVertices:
    """Which input vertices lie in the body's own overlap: inside by the winding number, outside by
    the closest-triangle sign. Answered per frame for the vertices asked about, and cached.

    garment (T, N, 3) m, the input; body (T, M, 3) m; distances: one MeshDistance per body frame.
    """

    def __init__(self, garment: np.ndarray, body: np.ndarray, body_faces: np.ndarray, distances: list[MeshDistance]):
        self.garment, self.body, self.body_faces, self.distances = garment, body, body_faces, distances
        self.known = np.zeros(garment.shape[:2], dtype=bool)
        self.hidden = np.zeros(garment.shape[:2], dtype=bool)

    def __call__(self, t: int, idx: np.ndarray) -> np.ndarray:
        """Frame t, vertex indices (K,) -> (K,) bool."""
        new = np.unique(idx[~self.known[t, idx]])
        if len(new):
            outside = new[self.distances[t].signed_distance(self.garment[t][new]) >= 0]
            if len(outside):
                self.hidden[t, outside] = winding_number(self.garment[t][outside], self.body[t], self.body_faces) > 0.5
            self.known[t, new] = True
        return self.hidden[t, idx]


def off_overlap_spikes(stretch: np.ndarray, edges: np.ndarray, hidden: HiddenVertices) -> tuple[float, float]:
    """stretch (T, E) m -> (largest stretch over edges with no hidden endpoint, mm; such edges over 10 mm per frame)."""
    largest, count = 0.0, 0
    for t, s in enumerate(stretch):
        order = np.argsort(-s)
        big = order[s[order] > 0.01]
        count += int(np.count_nonzero(~hidden(t, edges[big].ravel()).reshape(-1, 2).any(1)))
        for start in range(0, len(order), 32):  # down the sorted edges to the first one with no hidden end
            chunk = order[start:start + 32]
            if s[chunk[0]] <= largest:
                break
            clean = chunk[~hidden(t, edges[chunk].ravel()).reshape(-1, 2).any(1)]
            if len(clean):
                largest = max(largest, float(s[clean[0]]))
                break
    return largest * 1e3, count / len(stretch)


def quality(g, r, distances, lap, edges, hidden) -> tuple[float, ...]:
    inside = inside_pct(r, distances)
    lap_dev = float(np.mean([np.linalg.norm(lap @ (r[t] - g[t]), axis=1).mean() for t in range(len(r))]) * 1e3)
    stretch = edge_lengths(r, edges) - edge_lengths(g, edges)
    spike, p999 = float(np.max(stretch) * 1e3), float(np.percentile(stretch, 99.9) * 1e3)
    spikes = float(np.count_nonzero(stretch > 0.01) / len(r))
    return (inside, lap_dev, spike, p999, spikes, *off_overlap_spikes(stretch, edges, hidden), added_jitter_mm(g, r))


def posed_body(frames: np.ndarray) -> tuple[Body, np.ndarray, np.ndarray, np.ndarray]:
    """The neutral body on the held-out clip dance_b at `frames`: (Body, poses (T, 24, 3), trans (T, 3),
    posed body vertices (T, M, 3) float64, metres)."""
    body = load_body("neutral")
    clip = load_clip("dance_b")
    p, t = clip.poses[frames].astype(float), clip.trans[frames].astype(float)
    return body, p, t, body.pose(p, t).astype(np.float64)


def baseline_input(o: Outfit, body: Body, p: np.ndarray, t: np.ndarray) -> np.ndarray:
    """LBS with weights copied from the nearest body vertex: (T, N, 3) metres, the issue's penetrating input."""
    return pose_mesh(o.vertices, nearest_vertex_weights(o.vertices, body.vertices, body.weights), body.joints, p, t)


def penetrating_inputs(model: DeePSDModel, o: Outfit, body: Body, p: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
    """The two inputs refinement is benched on, each (T, N, 3) metres: the shipped DeePSD's output
    and the nearest-weights LBS baseline."""
    return {
        "deepsd": pose_outfit(o.vertices, model.rig(o.vertices, o.faces, body), model.pose_keys(p), body.joints, p, t),
        "baseline": baseline_input(o, body, p, t),
    }


def main() -> None:
    model = DeePSDModel()
    body, p, t, b = posed_body(np.arange(0, load_clip("dance_b").num_frames, 5))
    surface = BodySurface(body.faces, len(body.vertices))
    distances = [MeshDistance(x, body.faces) for x in b]  # one per posed body frame, for every quality figure
    print(f"{'input':8s} {'N':>6s} {'method':8s} {'ms/frame':>9s} {'inside %':>9s} {'lap dev mm':>11s} "
          f"{'spike mm':>9s} {'p99.9 mm':>9s} {'>10mm/fr':>9s} {'off-ovl spike':>13s} {'off-ovl >10/fr':>14s} "
          f"{'jitter mm':>10s}")
    for n in (2000, 6000, 20000):
        o = generate_outfit("longsleeve,trousers", vertices=n, seed=77)
        lap, edges = uniform_laplacian(o.faces, len(o.vertices)), unique_edges(o.faces)
        inputs = penetrating_inputs(model, o, body, p, t)
        fast, slow = Refiner(o.faces, len(o.vertices)), GlobalSolveRefiner(o.faces, len(o.vertices))
        unrelieved = Refiner(o.faces, len(o.vertices), relief_iterations=0)
        methods = {
            "refine": lambda x, y, r=fast: r.refine_frame(x, y, surface, RefineReport()),
            "norelief": lambda x, y, r=unrelieved: r.refine_frame(x, y, surface, RefineReport()),
            "naive": lambda x, y: naive_push(x, y, surface),
            "global": lambda x, y, r=slow: r.refine_frame(x, y, surface, RefineReport()),
        }
        for source, g in inputs.items():
            g = g.astype(np.float64)
            before = inside_pct(g, distances)
            hidden = HiddenVertices(g, b, body.faces, distances)
            print(f"{source:8s} {len(o.vertices):6d} {'input':8s} {'':>9s} {before:9.3f}")
            for name, fn in methods.items():
                t0 = time.perf_counter()
                r = np.stack([fn(g[i], b[i]) for i in range(len(g))])
                ms = (time.perf_counter() - t0) / len(g) * 1e3
                ins, dev, spike, p999, spikes, off_spike, off_spikes, jit = quality(g, r, distances, lap, edges, hidden)
                print(f"{source:8s} {len(o.vertices):6d} {name:8s} {ms:9.1f} {ins:9.3f} {dev:11.3f} "
                      f"{spike:9.2f} {p999:9.2f} {spikes:9.1f} {off_spike:13.2f} {off_spikes:14.1f} {jit:10.3f}",
                      flush=True)


if __name__ == "__main__":
    main()
