"""The training's body collider (drape.training.physics.BodyCollider) against the evaluation's exact measure
(drape.geometry.queries: the closest triangle of the whole body, signed by the interpolated normal)."""

import numpy as np
import torch

from drape.assets.body import load_body
from drape.geometry.queries import closest_point_on_triangles as closest_numpy
from drape.geometry.queries import signed_distance_to_mesh
from drape.training import physics


def test_closest_point_on_triangles_in_torch_is_the_numpy_one():
    rng = np.random.default_rng(0)
    a, b, c = (rng.normal(size=(4000, 3)) for _ in range(3))
    p = rng.normal(size=(4000, 3)) * 2  # every region: inside, past each edge, past each corner
    _, want = closest_numpy(p, a, b, c)
    got = physics.closest_point_on_triangles(*(torch.as_tensor(x) for x in (p, a, b, c))).numpy()
    assert np.allclose(got, want, atol=1e-9)


def _posed_points() -> tuple[np.ndarray, np.ndarray, torch.Tensor, np.ndarray]:
    """Points within 1 cm of a posed body (arms down, the elbows bent: cloth between arm and chest) ->
    (points (2, P, 3), body vertices (2, M, 3), transforms, faces)."""
    body = load_body("neutral")
    poses = np.zeros((2, 24, 3), np.float32)
    poses[:, 16, 2], poses[:, 17, 2] = -1.2, 1.2  # shoulders: arms down
    poses[1, 18, 1], poses[1, 19, 1] = -1.5, 1.5  # elbows bent
    transforms = physics.skinning_transforms(torch.as_tensor(poses), torch.as_tensor(body.joints))
    posed = physics.lbs(torch.as_tensor(body.vertices), torch.as_tensor(body.weights), transforms).numpy()
    rng = np.random.default_rng(1)
    pick = rng.choice(len(body.vertices), 3000, replace=False)
    points = posed[:, pick] + rng.uniform(-0.01, 0.01, size=(2, 3000, 3)).astype(np.float32)
    return points, posed, transforms, body.faces


def test_the_triangle_collider_answers_as_the_exact_measure_and_its_gradient_leads_out():
    body = load_body("neutral")
    points, posed, transforms, faces = _posed_points()
    exact = np.stack([signed_distance_to_mesh(p, b, faces) for p, b in zip(points, posed, strict=True)])
    collider = physics.BodyCollider(body, load_body("neutral", proxy=True), body.vertices[:3000], triangles=True)
    g = torch.as_tensor(points, dtype=torch.float32).requires_grad_(True)
    sd = collider.signed_distance(g, transforms)
    got = sd.detach().numpy()
    # measured 0.991 and 0.988; the rest lie where the arms pressed down overlap the chest
    assert np.mean(np.sign(got) == np.sign(exact)) > 0.985
    assert np.mean(np.abs(got - exact) < 1e-4) > 0.98  # the same closest point, up to float32
    physics.collision_loss(sd, 0.005).backward()
    grad = g.grad.numpy()
    inside = exact < -1e-3
    assert np.isfinite(grad).all() and inside.sum() > 500
    step = -grad / np.maximum(np.linalg.norm(grad, axis=-1, keepdims=True), 1e-30)  # 0.5 mm down the gradient
    moved = np.stack([signed_distance_to_mesh(p + 5e-4 * d, b, faces) for p, d, b in zip(points, step, posed,
                                                                                          strict=True)])
    assert np.mean(moved[inside] > exact[inside] + 4e-4) > 0.95


def test_the_sparse_normal_sum_gives_the_scattered_and_the_numpy_normals():
    from drape.geometry.mesh import vertex_normals as normals_numpy

    _, posed, _, faces = _posed_points()
    v, f = torch.as_tensor(posed), torch.as_tensor(faces, dtype=torch.int64)
    sparse = physics.vertex_normals(v, f, physics.face_incidence(faces, posed.shape[1])).numpy()
    scattered = physics.vertex_normals(v, f).numpy()
    want = normals_numpy(posed.astype(np.float64), faces)
    assert sparse.shape == scattered.shape == posed.shape
    assert np.abs(sparse - scattered).max() < 1e-5
    assert np.abs(sparse - want).max() < 1e-5


def test_nearest_points_is_the_brute_force_nearest_on_every_device_path():
    rng = np.random.default_rng(2)
    queries = torch.as_tensor(rng.normal(size=(3, 500, 3)), dtype=torch.float32)
    points = torch.as_tensor(rng.normal(size=(3, 200, 3)), dtype=torch.float32)
    d2 = ((queries.numpy()[:, :, None].astype(np.float64) - points.numpy()[:, None].astype(np.float64)) ** 2).sum(-1)
    want = d2.argmin(-1)
    got = physics.nearest_points(queries, points).numpy()  # the CPU's KD-tree
    assert got.shape == (3, 500) and got.dtype == np.int64
    assert (got == want).all()
    assert (torch.cdist(queries, points).argmin(-1).numpy() == want).all()  # the path other devices take
