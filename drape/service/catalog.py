"""Handlers for the embedded catalogue; they know nothing of HTTP."""

from __future__ import annotations

from functools import lru_cache

from drape.assets.body import list_bodies, load_body
from drape.assets.motion import list_clips, load_clip
from drape.schemas.catalog import BodyInfo, BodyList, MotionInfo, MotionList


@lru_cache(maxsize=1)
def bodies() -> BodyList:
    out = []
    for name in list_bodies():
        b = load_body(name)
        proxy = load_body(name, proxy=True)
        out.append(
            BodyInfo(
                name=name,
                num_vertices=len(b.vertices),
                num_faces=len(b.faces),
                proxy_vertices=len(proxy.vertices),
                height=float(b.vertices[:, 1].max() - b.vertices[:, 1].min()),
                joint_names=list(b.joint_names),
                parents=[int(p) for p in b.parents],
                rest_joints=b.joints.astype(float).tolist(),
            )
        )
    return BodyList(bodies=out)


@lru_cache(maxsize=1)
def motions() -> MotionList:
    out = []
    for name in list_clips():
        m = load_clip(name)
        out.append(MotionInfo(name=name, frames=m.num_frames, fps=m.fps, duration=m.num_frames / m.fps))
    return MotionList(motions=out)
