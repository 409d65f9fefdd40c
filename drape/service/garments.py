"""Handlers of the garment routes (the intrinsic garment space); they know nothing of HTTP.

Requests arrive as dicts shaped like the wire models of drape.schemas.garments (from JSON, npz or a form: the
arrays may be lists or numpy arrays); every array is checked here against the garment (vertex count, latent
size), the motion (frame range) and for finiteness, and each error names its field.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from drape.runtime.engine import Engine, RefineSettings
from drape.runtime.intrinsic import IntrinsicGarment, KeyframeResidual, interpolate
from drape.schemas.garments import MAX_SAMPLES, MAX_SEED, GarmentInfo, GarmentList
from drape.service.errors import InvalidInput, LimitExceeded, NotFound, quoted
from drape.service.handlers import (
    MAX_WORLD_M,
    _array,
    check_answer_size,
    check_finite_within,
    check_motion,
    check_refine,
)
from drape.service.settings import Settings

MAX_LATENT = 1e4  # |latent value|: far beyond any trained latent, and far from float32's range


def find(engine: Engine, name: str) -> IntrinsicGarment:
    """The garment named `name`, or a 404 naming it and listing the served ones."""
    garment = engine.garments.get(name)
    if garment is None and engine.layers.template(name) is not None:
        raise NotFound(f"garment {quoted(name, 80)} is a layer template with no intrinsic model: it is animated by "
                       "POST /v1/layers/animate", "name")
    if garment is None:
        known = engine.garments.names()
        served = f"the served garments: {', '.join(known)}" if known else "no garments are served"
        raise NotFound(f"unknown garment {quoted(name, 80)}; {served} (GET /v1/garments)", "name")
    return garment


def find_template(engine: Engine, name: str):  # noqa: ANN201 (an IntrinsicGarment or a layer template)
    """The template named `name` (GET /v1/garments/{name}: an intrinsic garment or a layer template), or a 404
    naming it and listing every served template."""
    template = engine.layers.template(name) or engine.garments.get(name)
    if template is None:
        known = [*engine.garments.names(), *(t.name for t in engine.layers.templates())]
        served = f"the served templates: {', '.join(known)}" if known else "no templates are served"
        raise NotFound(f"unknown garment {quoted(name, 80)}; {served} (GET /v1/garments)", "name")
    return template


def garment_list(engine: Engine) -> GarmentList:
    """The intrinsic templates, then the layer templates (GET /v1/layers)."""
    return GarmentList(garments=[*(GarmentInfo(**g.info()) for g in engine.garments),
                                 *(GarmentInfo(**t.info()) for t in engine.layers.templates())])


def check_frame(value: Any, num_frames: int, field: str) -> int:
    """An integer frame index of a motion of `num_frames` frames: 0 <= frame < num_frames."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise InvalidInput(f"expected an integer frame index, got {quoted(value, 40)}", field)
    if not 0 <= int(value) < num_frames:
        raise InvalidInput(f"frame {int(value)} is outside the motion's {num_frames} frames (0 to {num_frames - 1})",
                           field)
    return int(value)


def check_shape(value: Any, garment: IntrinsicGarment, field: str) -> np.ndarray:
    """A garment shape: (N, 3) metres, N the template's vertex count, finite -> float64 array."""
    v = _array(value, field, np.float64, 2)
    if v.shape != (garment.num_vertices, 3):
        raise InvalidInput(f"expected ({garment.num_vertices}, 3), the vertices of garment {garment.name!r} in its "
                           f"template's order, got {v.shape}", field)
    check_finite_within(v, MAX_WORLD_M, f"coordinates beyond {MAX_WORLD_M:g} m: the vertices must be "
                        "in metres", field)
    return v


def check_latent(value: Any, garment: IntrinsicGarment, field: str) -> np.ndarray:
    """A latent (Z,), Z the garment's latent size, finite and within +-MAX_LATENT -> float32 array."""
    z = _array(value, field, np.float64, 1)
    if z.shape != (garment.latent_size,):
        raise InvalidInput(f"expected {garment.latent_size} values (the latent size of garment {garment.name!r}), "
                           f"got {len(z)}", field)
    check_finite_within(z, MAX_LATENT, f"values beyond +-{MAX_LATENT:g}", field)
    return z.astype(np.float32)


def check_encoded(z: np.ndarray, field: str) -> np.ndarray:
    """A latent the encoder gave for the shape in `field`: within the bound a latent keyframe has (+-MAX_LATENT), so
    every latent drape answers can be sent back as a keyframe; beyond it the shape is nothing like what the model
    was trained on (a garment kilometres away, or not world space at its frame) -> 422 naming the shape."""
    if not np.isfinite(z).all() or np.abs(z).max() > MAX_LATENT:
        raise InvalidInput(f"the shape encodes to a latent beyond +-{MAX_LATENT:g} (largest |value| "
                           f"{float(np.abs(z).max()):.3g}): it is far from every shape the model was trained on; give "
                           "the garment in metres, world space at its frame, on the motion's body", field)
    return z


MAX_KEYFRAME_OFFSET_M = 0.5  # a keyframe's centroid from the template's, both in character space
KEYFRAME_SPREAD = (1 / 3, 3.0)  # a keyframe's RMS spread over the template's


def check_on_body(vertices: np.ndarray, garment: IntrinsicGarment, poses: np.ndarray, trans: np.ndarray, frame: int,
                  field: str) -> None:
    """A keyframe shape must be the garment in world space at its frame: its centroid within MAX_KEYFRAME_OFFSET_M
    of the template's and its spread within KEYFRAME_SPREAD of the template's, both in the character space of the
    frame (a shape 99 m off, or every vertex at one point, encoded to a junk latent and answered 200)."""
    offset, spread = garment.keyframe_placement(vertices, poses, trans, frame)
    if offset > MAX_KEYFRAME_OFFSET_M:
        raise InvalidInput(f"the shape's centre lies {offset:.2f} m from where the garment sits on the body at frame "
                           f"{frame} (at most {MAX_KEYFRAME_OFFSET_M:g} m): give the vertices in metres, world space at "
                           "that frame of the motion", field)
    if not KEYFRAME_SPREAD[0] <= spread <= KEYFRAME_SPREAD[1]:
        raise InvalidInput(f"the shape spreads {spread:.2f}x as far about its centre as the template does (allowed "
                           f"{KEYFRAME_SPREAD[0]:.2f}x to {KEYFRAME_SPREAD[1]:g}x): it is not this garment at this "
                           "scale", field)


def check_int(value: Any, low: int, high: int, field: str) -> int:
    """An integer in [low, high] (an npz or form scalar; the JSON models check theirs)."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise InvalidInput(f"expected an integer, got {quoted(value, 40)}", field)
    if not low <= int(value) <= high:
        raise InvalidInput(f"must be in [{low}, {high}], got {int(value)}", field)
    return int(value)


def encode(settings: Settings, garment: IntrinsicGarment, request: dict) -> np.ndarray:
    """request {"vertices": (N, 3) m world space at `frame`, "motion": {...}, "frame": int} -> latent (Z,) float32."""
    poses, trans, fps = check_motion(request["motion"], settings)
    frame = check_frame(request.get("frame"), len(poses), "frame")
    vertices = check_shape(request.get("vertices"), garment, "vertices")
    check_on_body(vertices, garment, poses, trans, frame, "vertices")
    return check_encoded(garment.encode(vertices, poses, trans, frame, fps), "vertices")


@dataclass(frozen=True)
class KeyframePlan:
    """A garment's stream to compute: latents (T, Z) float32, one per frame of the motion (poses (T, 24, 3) rad,
    translation (T, 3) m), refined against the garment's body when `refine` is set."""

    garment: IntrinsicGarment
    poses: np.ndarray
    translation: np.ndarray
    fps: float
    latents: np.ndarray
    refine: RefineSettings | None = None
    residual: KeyframeResidual | None = None

    @property
    def num_frames(self) -> int:
        return len(self.poses)


# a keyframe read from an npz carries (frames member, values member, index) under this key, so that its errors
# name the members the client wrote (latent_frames[0], latents[0]), not the JSON request's keyframes[i].frame
NPZ_MEMBERS_KEY = "npz_members"


def plan_keyframes(settings: Settings, garment: IntrinsicGarment, request: dict,
                   max_posed: int | None) -> KeyframePlan:
    """request {"motion", "keyframes": [{"frame", "vertices" | "latent"}, ...], "match_keyframes", "refine"} -> the
    plan: keyframes given as vertices encoded with the motion up to their frame, latents interpolated over every
    frame, and (match_keyframes, default true) the residual that makes the stream meet the shape keyframes."""
    keyframes = request.get("keyframes")
    if not isinstance(keyframes, list) or not keyframes:
        raise InvalidInput("give at least one keyframe", "keyframes")
    poses, trans, fps = check_motion(request["motion"], settings)
    T = len(poses)
    if len(keyframes) > T:
        raise InvalidInput(f"{len(keyframes)} keyframes for a motion of {T} frames (one keyframe per frame at most)",
                           "keyframes")
    check_answer_size(T, garment.num_vertices, max_posed, "motion")
    latent_keys: list[tuple[int, np.ndarray]] = []
    shapes: list[tuple[int, np.ndarray]] = []
    shape_fields: list[str] = []
    frame_fields: dict[int, str] = {}
    for i, key in enumerate(keyframes):
        field = f"keyframes[{i}]"
        if not isinstance(key, dict):
            raise InvalidInput("expected an object with 'frame' and one of 'vertices' and 'latent'", field)
        given_v, given_z = key.get("vertices") is not None, key.get("latent") is not None
        # where the client wrote it: keyframes[i].frame in JSON, latent_frames[j] / latents[j] in an npz
        members = key.get(NPZ_MEMBERS_KEY)
        frame_field = f"{members[0]}[{members[2]}]" if members else f"{field}.frame"
        value_field = f"{members[1]}[{members[2]}]" if members else f"{field}.{'latent' if given_z else 'vertices'}"
        frame = check_frame(key.get("frame"), T, frame_field)
        if frame in frame_fields:
            raise InvalidInput(f"frame {frame} is also the frame of {frame_fields[frame]}: one keyframe per frame",
                               frame_field)
        frame_fields[frame] = frame_field  # each keyframe's frame, by where the client wrote it
        if given_v == given_z:
            raise InvalidInput("give exactly one of 'vertices' and 'latent'", field)
        if given_z:
            latent_keys.append((frame, check_latent(key["latent"], garment, value_field)))
        else:
            shape = check_shape(key["vertices"], garment, value_field)
            check_on_body(shape, garment, poses, trans, frame, value_field)
            shapes.append((frame, shape))
            shape_fields.append(value_field)
    match = request.get("match_keyframes", True)
    if not isinstance(match, bool):
        raise InvalidInput(f"expected true or false, got {type(match).__name__}", "match_keyframes")
    refine = check_refine(request.get("refine"))
    if not shapes:
        return KeyframePlan(garment, poses, trans, fps, interpolate(latent_keys, T), refine)
    motion = garment.motion_frames(poses, trans, fps)
    frames = [f for f, _ in shapes]
    given = [f for f, _ in latent_keys]
    stacked = np.stack([v for _, v in shapes])
    encoded = garment.encode_at(stacked, frames, motion)
    latent_keys += [(f, check_encoded(z, name)) for f, z, name in zip(frames, encoded, shape_fields, strict=True)]
    latents = interpolate(latent_keys, T)
    residual = garment.keyframe_residual(stacked, frames, given, latents, motion, fps) if match else None
    return KeyframePlan(garment, poses, trans, fps, latents, refine, residual)


def sample(settings: Settings, garment: IntrinsicGarment, request: dict,
           max_values: int | None) -> tuple[np.ndarray, np.ndarray]:
    """request {"count", "seed", "motion", "frame"} -> (latents (count, Z) float32, vertices (count, N, 3) float32
    m world space at the frame); `max_values` bounds the numbers of the answer's format (None: unbounded)."""
    count = check_int(request.get("count"), 1, MAX_SAMPLES, "count")
    seed = check_int(request.get("seed", 0), 0, MAX_SEED, "seed")
    poses, trans, fps = check_motion(request["motion"], settings)
    frame = check_frame(request.get("frame", 0), len(poses), "frame")
    numbers = count * (garment.num_vertices * 3 + garment.latent_size)
    if max_values is not None and numbers > max_values:
        raise LimitExceeded(f"{count} samples of {garment.num_vertices} vertices are {numbers} numbers, over the limit "
                            f"of {max_values} for one answer in this format; ask for application/x-npz", "count")
    return garment.sample(count, seed, frame, poses, trans, fps)
