"""The body collider: slab hulls cover the body and stay close to its skin."""

import numpy as np

from drape.assets.body import load_body
from drape.geometry.mesh import vertex_normals
from drape.sim.collider import fit_hulls, garment_bones, inside_hulls

LOWER = [0, 1, 2, 3, 4, 5, 6, 9]  # pelvis, thighs, spine, shins: what a skirt meets


def _capsule_contains(points, body, bones):
    """Best single capsule per bone (PCA axis, radius covering 99% of its vertices): inside any?"""
    V = body.vertices.astype(np.float64)
    inside = np.zeros(len(points), bool)
    for k in bones:
        P = V[body.weights[:, k] >= 0.3]
        c = P.mean(0)
        a = np.linalg.svd(P - c, full_matrices=False)[2][0]
        t = (P - c) @ a
        p0, p1 = c + t.min() * a, c + t.max() * a

        def dist(X, p0=p0, p1=p1):
            s = np.clip(((X - p0) @ (p1 - p0)) / ((p1 - p0) @ (p1 - p0)), 0, 1)
            return np.linalg.norm(X - (p0 + s[:, None] * (p1 - p0)), axis=1)

        r = np.percentile(dist(P), 99)
        inside |= dist(points) <= r
    return inside


def test_hulls_cover_the_body_and_hug_it():
    body = load_body("neutral")
    hulls = fit_hulls(body, LOWER)
    region = np.isin(body.weights.argmax(axis=1), LOWER)
    V = body.vertices[region].astype(np.float64)
    N = vertex_normals(body.vertices, body.faces)[region].astype(np.float64)
    assert inside_hulls(V, hulls, tol=1e-3).mean() > 0.99  # the cloth cannot reach the skin
    off5 = V + 0.005 * N
    hull_share = inside_hulls(off5, hulls).mean()
    capsule_share = _capsule_contains(off5, body, LOWER).mean()
    print(f"points 5 mm outside the skin inside the collider: hulls {hull_share:.3f}, capsules {capsule_share:.3f}")
    assert hull_share < 0.15
    assert capsule_share > 3 * hull_share  # why capsules were not chosen


def test_garment_bones_picks_the_bones_near_the_garment():
    body = load_body("neutral")
    waist = body.vertices[np.abs(body.vertices[:, 1] - 0.9) < 0.02] * 1.05
    bones = garment_bones(body, waist, reach=0.05)
    assert 0 in bones or 3 in bones
    assert 15 not in bones  # not the head
