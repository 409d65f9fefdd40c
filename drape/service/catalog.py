"""Handlers for the embedded catalogue; they know nothing of HTTP."""

from __future__ import annotations

from functools import lru_cache

from drape.assets.body import Body, list_bodies, load_body
from drape.assets.motion import list_clips, load_clip
from drape.schemas.catalog import BodyInfo, BodyList, MotionInfo, MotionList


def body_info(body: Body, proxy: Body | None = None, preset: bool = True) -> BodyInfo:
    """A body's catalogue entry (proxy: its collision proxy; a user body is its own)."""
    return BodyInfo(
        name=body.name,
        preset=preset,
        num_vertices=len(body.vertices),
        num_faces=len(body.faces),
        proxy_vertices=len((proxy or body).vertices),
        height=float(body.vertices[:, 1].max() - body.vertices[:, 1].min()),
        joint_names=list(body.joint_names),
        parents=[int(p) for p in body.parents],
        rest_joints=body.joints.astype(float).tolist(),
    )


@lru_cache(maxsize=1)
def bodies() -> BodyList:
    """The presets' entries."""
    return BodyList(bodies=[body_info(load_body(name), load_body(name, proxy=True)) for name in list_bodies()])


@lru_cache(maxsize=1)
def motions() -> MotionList:
    out = []
    for name in list_clips():
        m = load_clip(name)
        out.append(MotionInfo(name=name, frames=m.num_frames, fps=m.fps, duration=m.num_frames / m.fps))
    return MotionList(motions=out)
