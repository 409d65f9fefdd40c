"""Python client for the drape service (httpx; depends on drape.schemas only).

    import drape
    with drape.Client("http://127.0.0.1:8000") as client:
        rig = client.rig("outfit.obj")                           # weights, blend shapes, outfit_id
        verts = client.animate(outfit_id=rig.outfit_id, motion="walk")   # (T, N, 3) float32
        for frame in client.animate_stream(outfit_id=rig.outfit_id, motion="walk"):
            ...                                                   # (N, 3) float32, as it arrives

Garments (the intrinsic space of trained templates; a keyframe is a shape or a latent):

    client.garments()                                              # what is served
    tpl = client.garment("skirt")                                  # its template mesh
    z = client.encode_keyframe("skirt", vertices=shape, motion="walk", frame=10)        # (Z,)
    verts = client.animate_keyframes("skirt", motion="walk", keyframes=[{"frame": 10, "latent": z}])
    designs = client.sample_designs("skirt", count=8, seed=1, motion="walk", frame=0)  # latents, shapes

Outfits: a mesh file path (OBJ, PLY, GLB), a (vertices, faces) pair of arrays, or any
object with `.vertices` and `.faces` (a trimesh.Trimesh). Motions: an embedded clip
name, a poses array (T, 24, 3) or (T, 72), an object/mapping with poses, trans or
translation, fps, or a motion capture file the service imports (`MotionFile("walk.bvh", fps=30,
up="y")`, or a bare Path). Refinement: `refine=True` or `refine=RefineOptions(eps=0.005)`.
Answers travel as npz or the binary frame stream by default. What the service did as asked but found
suspicious (a motion file that looks Z-up sent as Y-up) arrives as a `DrapeWarning` (Python's warnings).
"""

from drape.client.client import (
    AsyncClient,
    BodyArrays,
    Client,
    DesignSamples,
    DrapeAPIError,
    DrapeWarning,
    FitResult,
    GarmentTemplate,
    LayerFrames,
    MotionFile,
    RefineOptions,
    RigResult,
)

__all__ = ["AsyncClient", "BodyArrays", "Client", "DesignSamples", "DrapeAPIError", "DrapeWarning", "FitResult", "GarmentTemplate", "LayerFrames",
           "MotionFile", "RefineOptions", "RigResult"]
