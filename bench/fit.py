"""`fit` on garments made for another body: what it infers, how much was inside, how far it moves them.

Inputs: the real garments of ../shared/data/external (ArcSim tops, made for no body of ours; skipped where
absent) onto the neutral body, and generated garments made for one preset, then scaled, moved, turned Z-up
and put in centimetres, fitted onto another preset. Prints per garment: units and up (as inferred), the
share of vertices inside the body at rest before and after the push-out (the after share checked again by
an independent exact distance query), the push-out's mean and largest move and largest edge lengthening,
and the seconds the fit takes; beside it, the seconds of the same fit with the placement search ranked by
exact distances (`exact_search`, the search before 2026-11-27), their ratio, and how far apart the two
fitted meshes are (mm).
Run: .venv/bin/python -m bench.fit
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from drape.assets.body import load_body
from drape.assets.outfits import generate_outfit
from drape.geometry.fitting import fit_garment
from drape.geometry.mesh_io import load_mesh
from drape.geometry.queries import signed_distance_to_mesh

EXTERNAL = Path("..") / "shared" / "data" / "external"
Z_UP_CM = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]) * 100.0


def cases() -> list[tuple[str, np.ndarray, np.ndarray, str]]:
    out = [(p.name, *load_mesh(p), "neutral") for p in sorted(EXTERNAL.glob("*.obj"))]
    for i, (kind, made_on, scale, onto) in enumerate([("tshirt", "female", 1.1, "male"), ("trousers", "male", 0.9, "neutral"),
                                                      ("dress", "neutral", 1.0, "female"), ("longsleeve", "male", 1.0, "female")]):
        o = generate_outfit(kind, vertices=2000, seed=50 + i, body=made_on)
        v = o.vertices.astype(np.float64) * scale + [0.4, -0.3, 0.2]
        out.append((f"{kind} of {made_on} x{scale} moved -> {onto}", v, o.faces, onto))
        if i < 2:
            out.append((f"{kind} of {made_on}, Z-up cm -> {onto}", o.vertices.astype(np.float64) @ Z_UP_CM.T,
                        o.faces, onto))
    return out


def main() -> None:
    print(f"{'garment':44s} {'N':>5s} {'units':>5s} {'up':>2s} {'inside before':>13s} {'after':>6s} {'checked':>7s} "
          f"{'move mean/max mm':>16s} {'stretch mm':>10s} {'s':>5s} {'exact s':>7s} {'ratio':>5s} {'apart mm':>8s}")
    for name, v, f, onto in cases():
        body = load_body(onto)
        t = time.perf_counter()
        r = fit_garment(v, f, body)
        dt = time.perf_counter() - t
        t = time.perf_counter()
        ref = fit_garment(v, f, body, exact_search=True)
        dt_ref = time.perf_counter() - t
        apart = 1e3 * float(np.abs(ref.vertices - r.vertices).max())
        rep = r.report
        check = float(np.mean(signed_distance_to_mesh(r.vertices, body.vertices, body.faces) < 0))
        print(f"{name:44s} {len(v):5d} {rep['units']:>5s} {rep['up']:>2s} {100 * rep['inside_before']:12.2f}% "
              f"{100 * rep['inside_after']:5.2f}% {100 * check:6.2f}% {rep['mean_move_mm']:7.1f} / {rep['max_move_mm']:5.1f}"
              f" {rep['max_stretch_mm']:10.1f} {dt:5.1f} {dt_ref:7.1f} {dt_ref / dt:5.1f} {apart:8.3f}")


if __name__ == "__main__":
    main()
