"""The embedded body presets: file contract, conventions, proxies, and (slow) anny parity."""

import numpy as np
import pytest

from drape.assets.body import BODIES_DIR, list_bodies, load_body
from drape.geometry.mesh import is_edge_manifold
from drape.geometry.skeleton import JOINT_INDEX, JOINT_NAMES, PARENTS


def test_presets_listed():
    assert {"neutral", "female", "male"} <= set(list_bodies())


@pytest.mark.parametrize("name", ["neutral", "female", "male", "heavy"])
def test_contract_and_conventions(name):
    with np.load(BODIES_DIR / f"{name}.npz", allow_pickle=False) as z:
        assert z["vertices"].dtype == np.float32 and z["vertices"].shape[1] == 3
        assert z["faces"].dtype == np.int32 and z["faces"].shape[1] == 3
        assert z["weights"].dtype == np.float32 and z["weights"].shape == (len(z["vertices"]), 24)
        assert z["joints"].dtype == np.float32 and z["joints"].shape == (24, 3)
        assert z["parents"].dtype == np.int32 and np.array_equal(z["parents"], PARENTS)
        assert z["joint_names"].dtype.kind == "U" and tuple(z["joint_names"]) == JOINT_NAMES
    b = load_body(name)
    assert np.allclose(b.weights.sum(1), 1.0, atol=1e-5) and b.weights.min() >= 0
    assert b.faces.max() < len(b.vertices)
    v, j = b.vertices, b.joints
    assert abs(v[:, 1].min()) < 1e-6 and 1.5 < v[:, 1].max() < 2.0  # feet on the floor, +Y up
    # T-pose: wrists level with the shoulders, left arm along +X
    lw, ls = j[JOINT_INDEX["left_wrist"]], j[JOINT_INDEX["left_shoulder"]]
    assert abs(lw[1] - ls[1]) < 0.01 and lw[0] > ls[0] + 0.4
    assert j[JOINT_INDEX["right_wrist"], 0] < -0.4
    # facing +Z: the toes are in front of the ankles
    assert j[JOINT_INDEX["left_foot"], 2] > j[JOINT_INDEX["left_ankle"], 2] + 0.05


@pytest.mark.parametrize("name", ["neutral", "female", "male", "heavy"])
def test_collision_proxy(name):
    full, proxy = load_body(name), load_body(name, proxy=True)
    assert 1000 <= len(proxy.vertices) <= 2000
    assert np.array_equal(proxy.joints, full.joints)
    assert is_edge_manifold(proxy.faces)
    # proxy vertices lie on the full body and carry (interpolated) weights of the same skeleton
    from drape.geometry.queries import signed_distance_to_mesh

    assert np.abs(signed_distance_to_mesh(proxy.vertices, full.vertices, full.faces)).max() < 1e-4
    assert np.allclose(proxy.weights.sum(1), 1.0, atol=1e-5)


@pytest.mark.slow
def test_lbs_of_baked_body_equals_anny_posing():
    """Plain LBS with the merged 24-joint weights reproduces anny's own posing (needs anny; ~2 min cold).

    The 7 extra CMU bones get identity local deltas, so they move rigidly with
    their parents, which is exactly what merging their weights assumes.
    """
    pytest.importorskip("anny")
    import os

    os.environ.setdefault("ANNY_CACHE_DIR", os.path.abspath("cache/anny"))
    os.environ.setdefault("WARP_CACHE_PATH", os.path.abspath("cache/warp"))
    import anny
    import torch

    from drape.assets import body_bake as bb
    from drape.geometry.lbs import linear_blend_skinning
    from drape.geometry.rotations import axis_angle_to_matrix
    from drape.geometry.skeleton import CMU_EXTRAS, CMU_TO_SMPL

    model = anny.Anny(rig="cmu_mb", topology="anny", pose_parameterization="local-bone")
    labels = list(model.bone_labels)
    col = {n: i for i, n in enumerate(labels)}
    rng = np.random.default_rng(0)
    delta = torch.eye(4, dtype=model.template_vertices.dtype).repeat(1, len(labels), 1, 1)
    rots = axis_angle_to_matrix(rng.normal(scale=0.4, size=(len(labels), 3)))
    for name in CMU_TO_SMPL:
        delta[0, col[name], :3, :3] = torch.as_tensor(rots[col[name]])
    with torch.no_grad():
        out = model(pose_parameters=delta, phenotype_kwargs=bb.PRESETS["neutral"])
    rest = out["rest_vertices"][0].double().numpy()
    posed = out["vertices"][0].double().numpy()
    skin = (out["bone_poses"][0].double() @ torch.linalg.inv(out["rest_bone_poses"][0].double())).numpy()
    w31 = bb._anny_rest(bb.PRESETS["neutral"])["weights"]
    w24, _ = bb.merge_to_smpl(w31, np.zeros((len(labels), 3)), labels)
    tr24 = np.zeros((1, 24, 4, 4))
    for cmu, smpl in CMU_TO_SMPL.items():
        tr24[0, JOINT_INDEX[smpl]] = skin[col[cmu]]
    for extra, parent in CMU_EXTRAS.items():  # rigid with the parent, as the merge assumes
        assert np.allclose(skin[col[extra]], skin[col[parent]], atol=1e-5)
    ours = linear_blend_skinning(rest, w24, tr24)[0]
    assert np.abs(ours - posed).max() < 1e-4
