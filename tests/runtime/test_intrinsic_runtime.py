"""The served intrinsic garment space (numpy + ONNX Runtime) against the torch model it was exported from:
decode and encode agree to 1e-4 m on a real motion, a keyframe's latent depends on the motion up to its frame
only, interpolation is linear between keyframes and held outside them, sampling is the manifest's statistics,
and the registry loads every model folder (checked by sha256) and nothing else."""

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest
import torch

from drape.assets.body import load_body
from drape.assets.motion import load_clip
from drape.export.intrinsic import VERSION as INTRINSIC_VERSION
from drape.geometry.character_space import motion_windows, root_frames
from drape.models.intrinsic import character_space, world_space
from drape.runtime.engine import Engine
from drape.runtime.intrinsic import (
    KEYFRAME_FADE_S,
    GarmentRegistry,
    IntrinsicGarment,
    KeyframeResidual,
    garment_names,
    interpolate,
    residual_weights,
)
from tests.intrinsic_model import NAME, WINDOW, intrinsic_model


@pytest.fixture(scope="module")
def tg():
    return intrinsic_model()


@pytest.fixture(scope="module")
def garment(tg):
    return IntrinsicGarment(tg.path)


@pytest.fixture(scope="module")
def motion():
    clip = load_clip("dance_a")
    return clip.poses[:70].astype(np.float64), clip.trans[:70].astype(np.float64)


def torch_frames(poses, trans):
    """The torch side's inputs: windows (T, W + 1, 24, 3), root position (T, 3), rotation (T, 3, 3) as tensors."""
    body = load_body("neutral")
    joints, rp, rr = root_frames(poses, trans, body.joints.astype(np.float64), body.parents)
    return (torch.as_tensor(motion_windows(joints, rp, rr, WINDOW)), torch.as_tensor(rp, dtype=torch.float32),
            torch.as_tensor(rr, dtype=torch.float32))


def test_decode_equals_the_torch_model(tg, garment, motion):
    poses, trans = motion
    rng = np.random.default_rng(0)
    z = (garment.latent_mean + garment.latent_std * rng.standard_normal((len(poses), garment.latent_size)))
    z = z.astype(np.float32)
    windows, rp, rr = torch_frames(poses, trans)
    with torch.no_grad():
        ref = world_space(tg.model.decode(torch.as_tensor(z), windows), rp, rr).numpy()
    out = garment.decode(z, poses, trans)
    assert out.shape == (len(poses), garment.num_vertices, 3) and out.dtype == np.float32
    assert np.abs(out - ref).max() <= 1e-4
    chunked = garment.decode(z, poses, trans, chunk=16)  # windows reaching back over a chunk's start
    assert np.abs(chunked - ref).max() <= 1e-4
    # the tolerance discriminates: a window one frame off, or another latent, moves the shapes by millimetres
    shifted = windows.clone()
    shifted[:, 0] = windows[:, 1]
    with torch.no_grad():
        off = world_space(tg.model.decode(torch.as_tensor(z), shifted), rp, rr).numpy()
    assert np.abs(off - ref).max() > 1e-3
    assert np.abs(garment.decode(z + 0.1 * garment.latent_std.astype(np.float32), poses, trans) - ref).max() > 1e-3
    assert garment.decode(z[:0], poses[:0], trans[:0]).shape == (0, garment.num_vertices, 3)


def test_encode_equals_the_torch_model_and_sees_the_motion_up_to_its_frame(tg, garment, motion):
    poses, trans = motion
    windows, rp, rr = torch_frames(poses, trans)
    frame = 37
    shape = garment.decode(np.tile(garment.latent_mean.astype(np.float32), (len(poses), 1)), poses, trans)[frame]
    with torch.no_grad():
        local = character_space(torch.as_tensor(shape)[None], rp[frame:frame + 1], rr[frame:frame + 1])
        ref = tg.model.encode(local, windows[frame:frame + 1])[0].numpy()
    z = garment.encode(shape, poses, trans, frame)
    assert z.shape == (garment.latent_size,) and z.dtype == np.float32
    assert np.abs(z - ref).max() <= 1e-4
    # frames after the keyframe do not matter; frames before it do
    later = poses.copy()
    later[frame + 1:] += 0.3
    assert np.array_equal(garment.encode(shape, later, trans, frame), z)
    assert np.array_equal(garment.encode(shape, poses[:frame + 1], trans[:frame + 1], frame), z)
    earlier = poses.copy()
    earlier[frame - 2] += 0.3
    assert np.abs(garment.encode(shape, earlier, trans, frame) - z).max() > 1e-4
    # every frame at once equals one at a time
    seq = garment.decode(np.tile(z, (12, 1)), poses[:12], trans[:12])
    every = garment.encode_frames(seq, poses[:12], trans[:12], chunk=5)
    assert np.abs(every[9] - garment.encode(seq[9], poses[:12], trans[:12], 9)).max() <= 1e-5
    with pytest.raises(ValueError, match="outside"):
        garment.encode(shape, poses, trans, len(poses))


def test_interpolation_is_linear_between_keyframes_and_held_outside():
    a, b, c = np.array([0.0, 1.0]), np.array([2.0, -1.0]), np.array([5.0, 5.0])
    z = interpolate([(14, c), (4, a), (8, b)], 20)  # any order
    assert z.shape == (20, 2) and z.dtype == np.float32
    assert np.array_equal(z[:5], np.tile(a, (5, 1)))  # held before the first keyframe, exact at it
    assert np.array_equal(z[14:], np.tile(c, (6, 1)))  # exact at the last one and held after it
    assert np.array_equal(z[8], b)
    assert np.allclose(z[6], (a + b) / 2) and np.allclose(z[5], 0.75 * a + 0.25 * b)
    assert np.allclose(z[11], (b + c) / 2)
    assert np.array_equal(interpolate([(3, a)], 5), np.tile(a, (5, 1)).astype(np.float32))
    assert np.array_equal(IntrinsicGarment.interpolate([(0, a), (2, c)], 3)[1], ((a + c) / 2).astype(np.float32))
    with pytest.raises(ValueError, match="frame 4"):
        interpolate([(4, a), (4, b)], 10)
    with pytest.raises(ValueError, match="at least one"):
        interpolate([], 10)


def test_residual_weights_are_the_interpolation_weights_faded_by_distance():
    keys = np.array([4, 8, 14])
    w = residual_weights(keys, np.arange(20), 5.0)
    assert w.shape == (20, 3)
    assert np.array_equal(w[keys], np.eye(3))  # a keyframe's own frame: itself alone, weight 1
    assert np.allclose(w[6], [0.5 * np.exp(-2 / 5), 0.5 * np.exp(-2 / 5), 0])
    assert np.allclose(w[9], [0, 5 / 6 * np.exp(-1 / 5), 1 / 6 * np.exp(-5 / 5)])
    assert np.allclose(w[:4, 0], np.exp(-np.arange(4, 0, -1) / 5)) and not w[:4, 1:].any()  # before the first
    assert np.allclose(w[15:, 2], np.exp(-np.arange(1, 6) / 5)) and not w[15:, :2].any()  # after the last
    assert np.allclose(residual_weights(keys, np.arange(20), 1e12).sum(axis=1), 1.0)  # no fading: a partition
    r = np.random.default_rng(0).normal(size=(3, 7, 3)).astype(np.float32)
    dense = np.einsum("tk,knc->tnc", residual_weights(keys, np.arange(2, 17), 5.0), r)
    assert np.allclose(KeyframeResidual(keys, r, 5.0).at(2, 17), dense, atol=1e-6)


def test_matched_keyframes_are_met_exactly_and_the_correction_fades(garment, motion):
    poses, trans = motion
    rng = np.random.default_rng(3)
    keys = [10, 50]
    shapes = garment.decode(np.tile(garment.latent_mean, (len(poses), 1)).astype(np.float32), poses, trans)[keys]
    shapes = shapes + rng.normal(0, 0.01, shapes.shape).astype(np.float32)  # not a decoded shape
    plain = garment.keyframed(shapes, keys, poses, trans, 30.0, match_keyframes=False)
    matched = garment.keyframed(shapes, keys, poses, trans, 30.0)
    assert np.abs(matched[keys] - shapes).max() <= 1e-5  # met exactly
    assert np.abs(plain[keys] - shapes).max() > 5e-3  # the decoder alone does not meet them
    fade = 30.0 * KEYFRAME_FADE_S
    for t, k in ((0, 10), (5, 10), (60, 50), (69, 50)):  # before the first / after the last keyframe: its
        # residual alone (a rigid move of it: same length per vertex), faded by the distance
        gap = np.linalg.norm(matched[t] - plain[t], axis=1)
        own = np.linalg.norm(shapes[keys.index(k)] - plain[k], axis=1)
        assert np.allclose(gap, np.exp(-abs(t - k) / fade) * own, atol=1e-5)


def test_many_keyframes_are_encoded_and_matched_in_blocks_as_one_by_one(garment, motion, monkeypatch):
    """encode_at and keyframe_residual run DECODE_BLOCK keyframes per ONNX Runtime call (10,000 keyframes in one
    call took 4-5 GB): with a block of 4, 11 shape keyframes in shuffled frame order, among latent keyframes, give
    the latents and residuals of encoding and decoding each keyframe alone, in frame order."""
    import drape.runtime.intrinsic as intrinsic

    poses, trans = motion
    mf = garment.motion_frames(poses, trans)
    rng = np.random.default_rng(5)
    frames = rng.permutation(np.arange(3, 69, 6))  # 11 shape keyframes
    latent_frames = [0, 4, 69]
    shapes = garment.decode(np.tile(garment.latent_mean, (len(poses), 1)).astype(np.float32), poses, trans)[frames]
    shapes = shapes + rng.normal(0, 0.01, shapes.shape).astype(np.float32)
    alone_z = np.concatenate([garment.encode_at(shapes[i:i + 1], frames[i:i + 1], mf) for i in range(len(frames))])
    latents = np.tile(garment.latent_mean, (len(poses), 1)).astype(np.float32)
    latents[frames] = alone_z
    alone = [garment.keyframe_residual(shapes[i:i + 1], frames[i:i + 1], [], latents, mf, 30.0).residuals[0]
             for i in range(len(frames))]
    monkeypatch.setattr(intrinsic, "DECODE_BLOCK", 4)
    calls: list[int] = []
    for name in ("_encode_local", "_decode_local"):
        run = getattr(garment, name)
        monkeypatch.setattr(garment, name, lambda a, w, run=run: (calls.append(len(a)), run(a, w))[1])
    assert np.allclose(garment.encode_at(shapes, frames, mf), alone_z, atol=1e-6)
    together = garment.keyframe_residual(shapes, frames, latent_frames, latents, mf, 30.0)
    assert calls == [4, 4, 3, 4, 4, 3], calls  # two passes of 11 keyframes, 4 per ONNX Runtime call
    assert together.frames.tolist() == sorted([*frames.tolist(), *latent_frames])
    expected = {int(f): r for f, r in zip(frames, alone, strict=True)} | {f: 0 * alone[0] for f in latent_frames}
    assert np.allclose(together.residuals, np.stack([expected[int(f)] for f in together.frames]), atol=1e-6)


def test_a_motion_at_twice_the_models_fps_is_read_over_the_same_seconds(garment, motion):
    """The motion window spans the model's seconds whatever the motion's fps: the clip at 60 fps (its frames
    and, between them, the mean of each pair) gives at its even frames the garment the 30 fps clip gives at every
    frame. The window read frame by frame saw half the time at 60 fps (the same poses labelled 24 or 60 fps
    answered the same vertices; 60 against 30 fps differed by up to 10 cm)."""
    poses, trans = motion
    T = 40
    p30, t30 = poses[:T], trans[:T]
    p60 = np.empty((2 * T - 1, 24, 3))
    t60 = np.empty((2 * T - 1, 3))
    p60[::2], t60[::2] = p30, t30
    p60[1::2], t60[1::2] = 0.5 * (p30[1:] + p30[:-1]), 0.5 * (t30[1:] + t30[:-1])
    z = np.repeat(garment.latent_mean[None], T, axis=0)
    at30 = garment.decode(z, p30, t30, fps=30.0)
    at60 = garment.decode(np.repeat(garment.latent_mean[None], 2 * T - 1, axis=0), p60, t60, fps=60.0)
    np.testing.assert_allclose(at60[::2], at30, atol=2e-5)
    relabelled = garment.decode(z, p30, t30, fps=60.0)  # the same frames read as 60 fps: a slower motion
    assert np.abs(relabelled - at30)[garment.window:].max() > 1e-3
    assert np.array_equal(garment.decode(z, p30, t30), at30)  # None: the model's own fps


def test_sample_draws_from_the_latent_statistics(garment, motion):
    poses, trans = motion
    latents, shapes = garment.sample(5, 11, 20, poses, trans)
    expected = garment.latent_mean + garment.latent_std * np.random.default_rng(11).standard_normal((5, 100))
    assert np.allclose(latents, expected.astype(np.float32))
    assert shapes.shape == (5, garment.num_vertices, 3)
    again, same = garment.sample(5, 11, 20, poses, trans)
    assert np.array_equal(again, latents) and np.array_equal(same, shapes)
    for i in (0, 4):  # each is its latent decoded at that frame
        decoded = garment.decode(np.tile(latents[i], (len(poses), 1)), poses, trans)[20]
        assert np.abs(decoded - shapes[i]).max() <= 1e-5
    assert not np.array_equal(garment.sample(5, 12, 20, poses, trans)[0], latents)


def test_the_registry_loads_every_model_folder_and_checks_sha256(tg, tmp_path):
    assert len(GarmentRegistry(tmp_path / "missing")) == 0 and len(GarmentRegistry(tmp_path)) == 0
    assert garment_names(tmp_path / "missing") == [] and garment_names(tg.root) == [NAME]
    reg = GarmentRegistry(tg.root)
    assert reg.names() == [NAME] and NAME in reg and reg.get("nope") is None
    g = reg.get(NAME)
    assert g.info() == {"name": NAME, "num_vertices": len(tg.vertices), "num_faces": len(tg.faces),
                        "body": "neutral", "models": ["intrinsic"], "fps": 30.0, "window": WINDOW,
                        "version": INTRINSIC_VERSION, "latent_size": 100}
    assert np.array_equal(g.vertices, tg.vertices) and np.array_equal(g.faces, tg.faces)
    (tmp_path / "notes").mkdir()  # a folder without a manifest is not a model
    shutil.copytree(tg.path, tmp_path / "a")
    assert GarmentRegistry(tmp_path).names() == [NAME]
    shutil.copytree(tg.path, tmp_path / "b")
    with pytest.raises(ValueError, match="already served"):
        GarmentRegistry(tmp_path)
    shutil.rmtree(tmp_path / "b")
    with open(tmp_path / "a" / "decode.onnx", "ab") as f:
        f.write(b"\0")
    with pytest.raises(ValueError, match="sha256"):
        GarmentRegistry(tmp_path)
    manifest = json.loads((tg.path / "manifest.json").read_text())
    assert "evaluation" not in manifest and manifest["files"]["template"]["file"] == "template.npz"


def test_the_engine_streams_a_garment_in_chunks(tg, garment, motion):
    poses, trans = motion
    engine = Engine(intrinsic_dir=tg.root)  # the shipped DeePSD model beside it
    try:
        g = engine.garments.get(NAME)
        z = interpolate([(0, g.latent_mean), (60, g.latent_mean + g.latent_std)], len(poses))
        chunks = list(engine.garment_chunks(g, z, poses, trans, chunk=32))
        assert [len(c) for c in chunks] == [32, 32, 6]
        assert np.abs(np.concatenate(chunks) - garment.decode(z, poses, trans)).max() <= 1e-5
    finally:
        engine.close()


def test_serving_a_garment_imports_no_torch(tg):
    code = (
        "import sys, numpy as np; from drape.runtime.intrinsic import GarmentRegistry;"
        f"g = GarmentRegistry({str(tg.root)!r}).get({NAME!r});"
        "v = g.decode(np.tile(g.latent_mean, (3, 1)), np.zeros((3, 24, 3)), np.zeros((3, 3)));"
        "z = g.encode(v[2], np.zeros((3, 24, 3)), np.zeros((3, 3)), 2);"
        "bad = [m for m in sys.modules if m == 'torch' or m.startswith('torch.')];"
        "print(bad); sys.exit(1 if bad or v.shape != (3, g.num_vertices, 3) else 0)"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
