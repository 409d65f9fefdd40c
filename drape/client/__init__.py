"""Python client for the drape service (httpx; depends on drape.schemas only).

    import drape
    with drape.Client("http://127.0.0.1:8000") as client:
        rig = client.rig("outfit.obj")                           # weights, blend shapes, outfit_id
        verts = client.animate(outfit_id=rig.outfit_id, motion="walk")   # (T, N, 3) float32
        for frame in client.animate_stream(outfit_id=rig.outfit_id, motion="walk"):
            ...                                                   # (N, 3) float32, as it arrives

Outfits: a mesh file path (OBJ, PLY, GLB), a (vertices, faces) pair of arrays, or any
object with `.vertices` and `.faces` (a trimesh.Trimesh). Motions: an embedded clip
name, a poses array (T, 24, 3) or (T, 72), or an object/mapping with poses, trans or
translation, fps. Answers travel as npz or the binary frame stream by default.
"""

from drape.client.client import AsyncClient, Client, DrapeAPIError, RigResult

__all__ = ["AsyncClient", "Client", "DrapeAPIError", "RigResult"]
