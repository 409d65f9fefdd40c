"""The `drape` command line. Each subcommand imports what it needs only when it runs."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from drape.assets.body import Body
    from drape.sim.params import SimParams

ASSETS = Path(__file__).parent / "assets"


def _require(module: str, extra: str, command: str) -> None:
    """Exit with a message naming the extra when `command` needs a package that serving does not install."""
    import importlib.util

    if importlib.util.find_spec(module) is None:
        raise SystemExit(f"`drape {command}` needs {module}, which is not installed (it is not in [serve]): "
                         f"pip install 'drape[{extra}]'")


def _serve(args: argparse.Namespace) -> None:
    from drape.service.server import serve
    from drape.service.settings import Settings

    given = {k: v for k, v in (("host", args.host), ("port", args.port)) if v is not None}
    settings = Settings(**given)  # DRAPE_* environment variables for everything not given here
    if args.ray is None:
        if args.replicas != 1 or args.replica_cpus != 1.0:
            raise SystemExit("--replicas and --replica-cpus need --ray ADDRESS")
        serve(settings)
        return
    try:
        import ray.serve  # noqa: F401
    except ImportError as e:
        raise SystemExit(f"`drape serve --ray` needs Ray Serve ({e}): pip install 'drape[serve,cluster]'") from None
    from drape.service.ray_serve import deploy

    deploy(args.ray, args.replicas, settings, replica_cpus=args.replica_cpus)


def _bake_body(args: argparse.Namespace) -> None:
    from drape.assets.body_bake import bake_bodies

    for path in bake_bodies(Path(args.out), args.presets or None):
        print(path)


def _import_deepmimic(args: argparse.Namespace) -> None:
    from drape.assets import deepmimic
    from drape.assets.body import load_body

    body = load_body(args.body)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"{'clip':18s} {'frames':>6s} {'fps':>5s} {'lower-foot height median (mm)':>30s}")
    for path in deepmimic.deepmimic_clip_paths():
        motion = deepmimic.import_clip(path, body, fps=args.fps)
        motion.save(out / f"{motion.name}.npz")
        err = float(np.median(np.abs(deepmimic.foot_heights(motion, body)))) * 1e3
        print(f"{motion.name:18s} {motion.num_frames:6d} {motion.fps:5.0f} {err:30.1f}")
    (out / "ATTRIBUTION.md").write_text(deepmimic.ATTRIBUTION + "\n")


def _index_list(text: str) -> list[int]:
    """An argparse type: a comma list of indices >= 0, e.g. "36,37,38,39"."""
    try:
        values = [int(t) for t in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a comma list of integers, got {text!r}") from None
    if any(v < 0 for v in values):
        raise argparse.ArgumentTypeError(f"indices must be >= 0, got {text!r}")
    return values


def _int_in(low: int, high: int | None = None):  # noqa: ANN202 - an argparse type
    """An argparse type: an integer in [low, high] (high None: no upper bound), else argparse's one-line error
    naming the option (exit 2) before any work."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < low or (high is not None and value > high):
            bound = f">= {low}" if high is None else f"in [{low}, {high:,}]"
            raise argparse.ArgumentTypeError(f"must be {bound}, got {value}")
        return value

    return parse


MAX_GENERATED_FRAMES = 108_000  # `motions generate --frames`: an hour at 30 fps


def _check_fps_option(fps: float | None) -> None:
    """A clip's frame rate given as --fps: within a motion file's bounds (a BVH's Frame Time, AMASS's rate), so
    the float32 it is stored as is a rate the loaders read (1e-300 stored as 0)."""
    from drape.assets.motion import MAX_FILE_FPS, MIN_FILE_FPS

    if fps is not None and not MIN_FILE_FPS <= fps <= MAX_FILE_FPS:
        raise SystemExit(f"drape: error: --fps must be within [{MIN_FILE_FPS:g}, {MAX_FILE_FPS:g}] fps, got {fps:g}")


def _out_path(out: str, *inputs: str | None, suffixes: tuple[str, ...] = ()) -> Path:
    """An --out about to be written: not one of the command's `inputs` (the same file by any path, hard links
    too: writing it would replace the input), not a folder, ending in one of `suffixes` when given; its folder is
    made here (a file in the way is main's one-line OSError). Called before any work."""
    if not str(out).strip():
        raise SystemExit("drape: error: --out: give a file name, got an empty one")
    path = Path(out)
    if path.is_dir():
        raise SystemExit(f"drape: error: --out {out} is a folder: give a file name")
    if suffixes and path.suffix.lower() not in suffixes:  # "" among them: no suffix is fine (the writer adds one)
        raise SystemExit(f"drape: error: --out {out}: expected a file ending in {' or '.join(x for x in suffixes if x)}")
    for given in inputs:
        if given and path.exists() and Path(given).exists() and os.path.samefile(path, given):
            raise SystemExit(f"drape: error: --out {out} is the input {given}: choose another path (writing it would "
                             "replace the input)")
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


BODY_FILE_SUFFIXES = (".glb", ".gltf", ".npz")
MAX_SMOOTH = 10_000  # render --smooth: weight diffusion steps (1e8 ran until killed)


def _body_file(text: str) -> str | None:
    """--body when it names a body file (an input that no --out may replace), else None (a preset)."""
    return text if text.lower().endswith(BODY_FILE_SUFFIXES) else None


def _body_arg(text: str) -> Body:
    """--body: a preset's name, or a body file (a skinned GLB / glTF with SMPL joint names, or an npz of the body's
    arrays), read and checked as POST /v1/bodies reads one; a bad file is one line naming it."""
    from drape.assets.body import load_body

    if _body_file(text) is None:
        try:
            return load_body(text)
        except KeyError as exc:  # the presets are not all --body takes: say what else it reads
            raise KeyError(f"--body: {exc.args[0]}; or a body file ({', '.join(BODY_FILE_SUFFIXES)})") from None
    from drape.service.bodies import read_body_file
    from drape.service.errors import DrapeError
    from drape.service.settings import Settings

    path = Path(text)
    data = path.read_bytes()  # OSError: main's one line with the path
    try:
        return read_body_file(data, path.name, Settings(), field="body")
    except DrapeError as exc:  # the field is the file's HTTP name (body_file) or "body": --body says it here
        said = exc.detail
        for name in ("body_file", "body"):
            if exc.field == name or (exc.field or "").startswith(f"{name}."):
                said = said.removeprefix(f"{name}.").removeprefix(f"{name}: ")
                break
        raise SystemExit(f"drape: error: --body {text}: {said}") from None


def _motion_out(out: str, *inputs: str | None) -> str:
    """A motion command's --out: an .npz file, or a name without a suffix (.npz is added, as Motion.save adds it);
    -> the name written, checked (`_out_path`) against the command's inputs as written, so that `--out me` with
    `--body me.npz` cannot replace the body."""
    _out_path(out, suffixes=(".npz", ""))
    written = out if str(out).lower().endswith(".npz") else f"{out}.npz"
    _out_path(written, *inputs)
    return written


def _motions_generate(args: argparse.Namespace) -> None:
    from drape.assets.procedural import generate_motion

    _check_fps_option(args.fps)
    written = _motion_out(args.out, _body_file(args.body))
    motion = generate_motion(args.frames, seed=args.seed, fps=args.fps, body=_body_arg(args.body), walk=args.walk)
    out = motion.save(written)
    print(f"{out}: {motion.num_frames} frames at {motion.fps:g} fps")


def _motions_import(args: argparse.Namespace) -> None:
    import time

    from drape.assets.motion import MotionFileError, import_motion

    src = Path(args.file)
    if src.suffix.lower() not in (".bvh", ".npz"):
        raise SystemExit(f"drape: error: {src}: expected a .bvh (CMU joint names) or an AMASS-style .npz file")
    _check_fps_option(args.fps)
    written = _motion_out(args.out, args.file, _body_file(args.body))
    body = _body_arg(args.body)
    start = time.perf_counter()
    try:
        data = src.read_bytes()
        imported = import_motion(data, body, fps=args.fps, up=args.up, floor=not args.no_floor,
                                 flips=not args.keep_flips, name=src.stem)
    except OSError as exc:
        raise SystemExit(f"drape: error: {src}: {exc.strerror or exc}") from exc
    except MotionFileError as exc:
        raise SystemExit(f"drape: error: {src}: {exc}") from exc
    motion = imported.motion
    out = motion.save(written)
    print(imported.summary())
    print(f"{out}: {motion.num_frames} frames at {motion.fps:g} fps (imported in {time.perf_counter() - start:.2f} s)")


def _outfits_generate(args: argparse.Namespace) -> None:
    from drape.assets.outfits import generate_outfit
    from drape.geometry.mesh_io import save_mesh

    _out_path(args.out, _body_file(args.body))
    outfit = generate_outfit(args.type, vertices=args.vertices, seed=args.seed, body=_body_arg(args.body),
                             looseness=args.looseness, length=args.length)
    vertices, faces, parts = outfit.vertices, outfit.faces, None
    if len(outfit.garments) > 1:  # each garment's vertices together, one named OBJ object each (the rig's parts)
        order = np.argsort(outfit.garment, kind="stable")
        new_index = np.empty_like(order)
        new_index[order] = np.arange(len(order))
        vertices, faces = vertices[order], new_index[faces].astype(np.int32)
        stops = np.cumsum(np.bincount(outfit.garment, minlength=len(outfit.garments)))
        parts = [(name, int(start), int(stop)) for name, start, stop in zip(outfit.garments, [0, *stops[:-1]], stops, strict=True)]
    save_mesh(args.out, vertices, faces, parts)
    print(f"{args.out}: {len(outfit.vertices)} vertices, {len(outfit.faces)} faces, garments {outfit.garments}")


def _write_fitted(mesh: str, out: str, vertices: np.ndarray, faces: np.ndarray, normal_turn: np.ndarray | None,
                  ) -> str:
    """Write the fitted mesh to `out`; -> a sentence saying what of the input file it kept.

    OBJ to OBJ: the input file itself with its vertices moved (drape.geometry.mesh_io.rewrite_obj): UVs,
    materials, objects and groups kept, normals turned with the fit's transform (normal_turn (3, 3)) or, after
    an un-posing (None), left out. Otherwise the geometry alone, an OBJ's objects kept as objects."""
    from drape.geometry.mesh_io import obj_parts, rewrite_obj, save_mesh

    data = Path(mesh).read_bytes()
    if Path(mesh).suffix.lower() == Path(out).suffix.lower() == ".obj":
        try:
            text, normals = rewrite_obj(data, vertices, normal_turn)
        except ValueError:
            pass  # the file's v lines are not what was read: the geometry alone, below
        else:
            Path(out).write_bytes(text)
            return (f"kept from {mesh}: every line but the vertex positions (texture coordinates, materials, objects, "
                    f"groups); normals: {normals}")
    # an OBJ's objects (one garment each) stay objects: the fit keeps the vertex order
    found = obj_parts(data, mesh, len(vertices))
    try:
        save_mesh(out, vertices, faces, [(p["name"], p["start"], p["stop"]) for p in found or []])
    except ValueError:  # a face joins two objects (OBJ indices are global): written as one mesh
        save_mesh(out, vertices, faces)
    return (f"written: the geometry only (vertices, triangles{', objects' if found else ''}); texture coordinates, "
            "normals and materials are kept only from an .obj to an .obj")


def _outfits_fit(args: argparse.Namespace) -> None:
    import json
    import time

    from drape.geometry.fitting import FitError, fit_garment
    from drape.geometry.mesh_io import load_mesh

    _out_path(args.out, args.mesh, _body_file(args.body))
    if args.report:
        _out_path(args.report, args.mesh, _body_file(args.body))
        if Path(args.report).resolve() == Path(args.out).resolve():
            raise SystemExit(f"drape: error: --report {args.report} is --out: give the report its own file")
    vertices, faces = load_mesh(args.mesh)
    body = _body_arg(args.body)
    start = time.perf_counter()
    try:
        result = fit_garment(vertices, faces, body, units=args.units, up=args.up, pose=args.pose)
    except FitError as exc:
        raise SystemExit(f"drape: error: {args.mesh}: {exc}") from None
    r = result.report
    kept = _write_fitted(args.mesh, args.out, result.vertices, faces, result.transform[:3, :3] if r["pose"] == "t"
                         else None)
    print(f"{args.out}: {len(vertices)} vertices fitted onto {args.body} in {time.perf_counter() - start:.1f} s; "
          f"units {r['units']}{' (inferred)' if r['units_inferred'] else ''}, "
          f"up {r['up']}{' (inferred)' if r['up_inferred'] else ''}, pose {r['pose']}")
    print(f"inside the body at rest: {100 * r['inside_before']:.2f}% before the push-out, "
          f"{100 * r['inside_after']:.2f}% after; moves {r['mean_move_mm']:.1f} mm mean, {r['max_move_mm']:.1f} mm "
          f"max; largest edge lengthening {r['max_stretch_mm']:.1f} mm")
    print(kept)
    for warning in r["warnings"]:
        print(f"warning: {warning}")
    if args.report:  # its folder was made with the checks, before the fit (_out_path)
        Path(args.report).write_text(json.dumps({"transform": result.transform.tolist(), "report": r}, indent=1))


def _frames_arg(text: str, num_frames: int, option: str = "--frames") -> list[int]:
    """A comma list of frame indices, each checked against 0..num_frames - 1; a ValueError naming the option
    otherwise (main's one line, exit 2; '0,x' printed int()'s "invalid literal for int() with base 10")."""
    try:
        frames = [int(f) for f in text.split(",")]
    except ValueError:
        raise ValueError(f"{option}: expected a comma list of frame indices, got {text!r}") from None
    bad = [f for f in frames if not 0 <= f < num_frames]
    if bad:
        raise ValueError(f"{option}: frames {bad} outside 0..{num_frames - 1}")
    return frames


def _port(text: str) -> int:
    """An argparse type: a TCP port, 1-65535 (99999 was handed on and the server listened on another port)."""
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a port number, got {text!r}") from None
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"must be in [1, 65535], got {port}")
    return port


def _finite_float(text: str) -> float:
    """An argparse type: a finite float (an --azimuth of nan or inf drew every panel blank)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not np.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def _render(args: argparse.Namespace) -> None:
    _require("matplotlib", "tools", "render")
    from drape.assets.motion import load_clip, load_motion_npz
    from drape.geometry.lbs import linear_blend_skinning, smooth_weights
    from drape.geometry.mesh_io import load_mesh
    from drape.geometry.queries import nearest_vertex_weights
    from drape.geometry.skeleton import forward_kinematics
    from drape.render import Layer, render_frames

    def given(*options: str) -> list[str]:
        return [o for o in options if getattr(args, o[2:].replace("-", "_"))]

    clash = given("--outfit", "--clip", "--motion") if args.sim else \
        given("--keyframes", "--unmatched", "--served", "--garment-model")
    if clash:  # they were ignored without a word
        raise ValueError(f"{', '.join(clash)}: not used {'with' if args.sim else 'without'} --sim")
    if args.clip and args.motion:
        raise ValueError("--clip, --motion: give one motion, not both")
    if args.frames and not (args.sim or args.clip or args.motion):  # drew the rest pose at frame 0 without a word
        raise ValueError("--frames: frames of a motion; give --clip, --motion or --sim")
    if args.frames == "":
        raise ValueError("--frames: expected a comma list of frame indices, got an empty one")
    if not 0 <= args.smooth <= MAX_SMOOTH:
        raise ValueError(f"--smooth: must be in [0, {MAX_SMOOTH}], got {args.smooth}")
    _out_path(args.out, args.sim, args.outfit, args.motion, _body_file(args.body))
    if args.sim:
        _render_sim(args)
        return
    body = _body_arg(args.body)
    if args.motion:
        motion = load_motion_npz(args.motion)
    elif args.clip:
        motion = load_clip(args.clip)
    else:
        motion = None
    if motion is not None:  # by default four frames spread over the motion (0, 10, 20, 30 where it is long enough)
        frames = _frames_arg(args.frames, motion.num_frames) if args.frames else \
            sorted({min(f, motion.num_frames - 1) for f in (0, 10, 20, 30)})
        poses, trans = motion.poses[frames], motion.trans[frames]
    else:
        frames = [0]
        poses, trans = np.zeros((1, 24, 3)), np.zeros((1, 3))
    transforms, _ = forward_kinematics(poses, body.joints, body.parents, trans)
    layers = [Layer(linear_blend_skinning(body.vertices, body.weights, transforms), body.faces, (0.86, 0.74, 0.62))]
    if args.outfit:
        verts, faces = load_mesh(args.outfit)
        from drape.geometry.placement import FAR_M, body_distance

        near = float(np.abs(body_distance(body.vertices, body.faces).signed_distance(verts)).min())
        if near > FAR_M:  # drawn outside the picture: a PNG of the body alone, exit 0
            raise ValueError(f"--outfit {args.outfit}: no vertex comes within {100 * FAR_M:.0f} cm of the body at "
                             f"rest (the nearest is {near:.2f} m off); fit it first: drape outfits fit")
        # LBS with nearest-body-vertex weights diffused over the cloth: a look, not a cloth model
        weights = smooth_weights(nearest_vertex_weights(verts, body.vertices, body.weights), faces,
                                 iterations=args.smooth)
        layers.append(Layer(linear_blend_skinning(verts, weights, transforms), faces, (0.25, 0.45, 0.8)))
    name = motion.name if motion is not None else "rest pose"
    caption = (f"outfit posed by LBS with nearest-body-vertex weights diffused {args.smooth} steps "
               "(a preview, not a cloth model)") if args.outfit else None
    titles = [f"{body.name} - {name} - frame {f}" for f in frames]
    print(render_frames(layers, list(range(len(frames))), args.out, azimuth=args.azimuth, titles=titles,
                        caption=caption))


SIM_MEMBERS = ("body", "poses", "trans", "params", "garment", "motion", "fps")


def _read_sim(path: str) -> dict[str, np.ndarray]:
    """A simulated sequence npz (drape sim run / a dataset item) with what `render --sim` draws: its members, each
    checked; SystemExit naming the file and the member otherwise (a 0-byte file, 0 frames, fewer poses than
    frames or faces past the vertices were tracebacks)."""
    import json
    import zipfile

    try:
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):  # a single .npy array under an .npz name
            raise ValueError("a single array, not an npz archive of the sequence's members")
        with loaded as z:
            seq = {k: z[k] for k in z.files}
    except (ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise SystemExit(f"drape: error: {path}: not a simulated sequence npz ({type(exc).__name__}: {exc})") from None
    layered = "inner_vertices" in seq
    meshes = (("inner_vertices", "inner_faces"), ("outer_vertices", "outer_faces")) if layered else \
        (("vertices", "faces"),)
    missing = [k for k in (*SIM_MEMBERS, *(m for pair in meshes for m in pair)) if k not in seq]
    if missing:
        raise SystemExit(f"drape: error: {path}: a simulated sequence (drape sim run) needs {', '.join(missing)}")
    frames = len(seq[meshes[0][0]]) if seq[meshes[0][0]].ndim else 0
    for vname, fname in meshes:
        v, f = seq[vname], seq[fname]
        if v.dtype.kind not in "fiu" or v.ndim != 3 or v.shape[2] != 3 or len(v) != frames or not frames:
            raise SystemExit(f"drape: error: {path}: '{vname}' must be (T, N, 3) numbers with T >= 1, got {v.shape} "
                             f"{v.dtype}")
        if not np.isfinite(v).all():
            raise SystemExit(f"drape: error: {path}: '{vname}' holds NaN or infinite values")
        if f.dtype.kind not in "iu" or f.ndim != 2 or f.shape[1] != 3 or not len(f) or f.min() < 0 or \
                f.max() >= v.shape[1]:
            raise SystemExit(f"drape: error: {path}: '{fname}' must be (F, 3) indices into the {v.shape[1]} vertices")
    if seq["poses"].shape not in ((frames, 24, 3), (frames, 72)) or seq["trans"].shape != (frames, 3):
        raise SystemExit(f"drape: error: {path}: 'poses' and 'trans' must have the {frames} frames of the cloth, got "
                         f"{seq['poses'].shape} and {seq['trans'].shape}")
    try:
        params = json.loads(str(seq["params"]))
    except ValueError:
        raise SystemExit(f"drape: error: {path}: 'params' is not JSON text") from None
    needed = ("young", "density", "thickness", *(("inner_thickness",) if layered else ()))
    if not isinstance(params, dict) or not all(isinstance(params.get(k), int | float) for k in needed):
        raise SystemExit(f"drape: error: {path}: 'params' must be a JSON object with the numbers {', '.join(needed)}")
    return seq


def _render_sim(args: argparse.Namespace) -> None:
    """A simulated sequence (an `drape sim run` / dataset item npz) next to the posed body."""
    import json

    from drape.assets.body import load_body
    from drape.render import Layer, render_frames

    seq = _read_sim(args.sim)
    body = load_body(str(seq["body"]))
    layered = "inner_vertices" in seq  # a two-layer sequence (drape sim run --outer)
    T = len(seq["inner_vertices" if layered else "vertices"])
    frames = _frames_arg(args.frames, T) if args.frames else [int(f) for f in np.linspace(0, T - 1, 6)]
    posed = body.pose(seq["poses"][frames], seq["trans"][frames])
    if args.served and not layered:
        raise SystemExit("--served needs a two-layer sequence (drape sim run --outer, make layers-data)")
    if layered:
        if args.keyframes:
            raise SystemExit("--keyframes needs a single-garment sequence")
        layers = [Layer(posed, body.faces, (0.86, 0.74, 0.62)),
                  Layer(seq["inner_vertices"][frames], seq["inner_faces"], (0.85, 0.45, 0.2)),
                  Layer(seq["outer_vertices"][frames], seq["outer_faces"], (0.25, 0.45, 0.8))]
    else:
        layers = [Layer(posed, body.faces, (0.86, 0.74, 0.62)),
                  Layer(seq["vertices"][frames], seq["faces"], (0.25, 0.45, 0.8))]
    params = json.loads(str(seq["params"]))
    caption = (f"MuJoCo simulation: {seq['garment']} on {body.name}, clip {seq['motion']}; "
               f"young {params['young']:.3g} Pa, density {params['density']:.3g} kg/m2, "
               f"thickness {1000 * params['thickness']:.2g} mm")
    if layered:
        caption += f"; inner (orange) thickness H_in {1000 * params['inner_thickness']:.3g} mm, outer blue"
    titles = [f"frame {f}" for f in frames]
    if args.keyframes:
        from drape.render import view_matrix
        from drape.runtime.intrinsic import INTRINSIC_DIR, IntrinsicGarment

        garment = IntrinsicGarment(args.garment_model or INTRINSIC_DIR / str(seq["garment"]))
        keys = _frames_arg(args.keyframes, T, "--keyframes")
        keyed = garment.keyframed(seq["vertices"][keys], keys, seq["poses"], seq["trans"], float(seq["fps"]),
                                  match_keyframes=not args.unmatched)[frames]
        side = 0.45 * view_matrix(args.azimuth)[0]  # screen x in world space
        layers = [Layer(posed - side, body.faces, (0.86, 0.74, 0.62)),
                  Layer(seq["vertices"][frames] - side, seq["faces"], (0.25, 0.45, 0.8)),
                  Layer(posed + side, body.faces, (0.86, 0.74, 0.62)),
                  Layer(keyed + side, garment.faces, (0.85, 0.45, 0.2))]
        titles = [f"frame {f}" + (" (keyframe)" if f in keys else "") for f in frames]
        caption = (f"left: the simulation ({caption.split(': ', 1)[1]}); right: drape's intrinsic space "
                   f"from keyframes at frames {', '.join(map(str, keys))} of it, "
                   + ("unmatched" if args.unmatched else "matched"))
    if args.served:
        layers, model = _served_layers_beside(seq, frames, body, layers, args.azimuth)
        caption = (f"left: MuJoCo ({seq['garment']}, clip {seq['motion']}, inner orange, H_in "
                   f"{1000 * params['inner_thickness']:.3g} mm); right: drape ({model}), same motion and H_in, "
                   "no refinement")
    print(render_frames(layers, list(range(len(frames))), args.out, azimuth=args.azimuth, titles=titles,
                        caption=caption, follow_all=bool(args.keyframes or args.served)))


def _served_layers_beside(seq: dict, frames: list[int], body, sim_layers: list, azimuth: float) -> tuple[list, str]:
    """The simulation's layers moved left, the served combination's (as POST /v1/layers/animate poses them, at
    the sequence's H_in, no refinement) moved right; and what poses them."""
    from drape.render import Layer, view_matrix
    from drape.runtime.engine import Engine

    engine = Engine(refine_workers=1)
    try:
        c = engine.layers.find(str(seq["inner_garment"]), str(seq["outer_garment"]))
        if c is None or c.inner.num_vertices != seq["inner_vertices"].shape[1] \
                or c.outer.num_vertices != seq["outer_vertices"].shape[1]:
            raise SystemExit(f"{seq['inner_garment']}+{seq['outer_garment']} is not a served combination's templates")
        parts = list(engine.layer_chunks(c, float(seq["inner_thickness"]), seq["poses"].astype(np.float64),
                                         seq["trans"].astype(np.float64), fps=float(seq["fps"])))
    finally:
        engine.close()
    inner = np.concatenate([p[0] for p in parts])[frames]
    outer = np.concatenate([p[1] for p in parts])[frames]
    side = 0.45 * view_matrix(azimuth)[0]  # screen x in world space
    body_layer = sim_layers[0]
    moved = [Layer(x.vertices - side, x.faces, x.color) for x in sim_layers]
    return moved + [Layer(body_layer.vertices + side, body_layer.faces, body_layer.color),
                    Layer(inner + side, c.inner.faces, (0.85, 0.45, 0.2)),
                    Layer(outer + side, c.outer.faces, (0.25, 0.45, 0.8))], c.model


def _train_deepsd(args: argparse.Namespace) -> None:
    import json

    from drape.training.deepsd import load_config, train

    config = load_config(args.config)
    _, _, summary = train(config, args.checkpoints, device=args.device)
    if config.get("validation"):  # the checkpoint `drape export deepsd` exports is chosen on the validation split
        from drape.training.deepsd_validation import choose_checkpoint

        summary["validation"] = choose_checkpoint(config, args.checkpoints)
    out = Path(args.checkpoints) / "summary.json"
    out.write_text(json.dumps({"config_file": str(args.config), **summary}, indent=2) + "\n")
    print(json.dumps(summary, indent=2))


def _train_intrinsic(args: argparse.Namespace) -> None:
    import json

    from drape.training.intrinsic import export_trained, load_config, train
    from drape.training.intrinsic_shrink import calibrate

    config = load_config(args.template, args.config)
    out = args.out or ASSETS / "models" / "intrinsic" / args.template
    if not args.calibrate_only:
        model, summary = train(config, args.checkpoints)
        print(json.dumps({k: v for k, v in summary.items() if k not in ("config", "latent_mean", "latent_std")},
                         indent=2))
        for path in export_trained(model, summary, out):
            print(path)
    calibrate(out, config)


def _train_mgn_inner(args: argparse.Namespace) -> None:
    import json
    import platform
    import time

    from drape.training.layers_inner import export_trained, load_config, train

    t0 = time.time()
    model, task, summary = train(load_config(args.inner, args.config), args.checkpoints or f"checkpoints/mgn_inner_{args.inner}")
    summary["wall_seconds"] = round(time.time() - t0, 1)
    summary["machine"] = f"{platform.machine()}, {os.cpu_count()} CPUs"
    print(json.dumps({k: v for k, v in summary.items() if k != "validation"}, indent=2))
    out = args.out or ASSETS / "models" / "mgn_inner" / args.inner
    for path in export_trained(model, task, summary, out):
        print(path)
    if "collision_fit" in task.cfg:  # the rig's collision fit, kept where it measures better on validation
        from drape.training.layers_inner_fit import apply

        apply(out, task.cfg)


def _inner_config_args(parser: argparse.ArgumentParser) -> None:
    """--inner and --config of the inner-layer network's commands."""
    parser.add_argument("--inner", required=True, help="tshirt or tanktop: drape/training/configs/mgn_inner_<inner>.json")
    parser.add_argument("--config", help="another config file")


def _train_mgn_inner_fit(args: argparse.Namespace) -> None:
    import time

    from drape.training.layers_inner import load_config
    from drape.training.layers_inner_fit import apply

    t0 = time.time()
    cfg = load_config(args.inner, args.config)
    if "collision_fit" not in cfg:
        raise SystemExit(f"the config of {args.inner} has no collision_fit")
    try:
        record = apply(args.folder or ASSETS / "models" / "mgn_inner" / args.inner, cfg)
    except ValueError as e:
        raise SystemExit(str(e)) from None
    print(f"served: {record['served']} ({time.time() - t0:.0f} s)")


def _train_mgn_outer(args: argparse.Namespace) -> None:
    import json
    import platform
    import time

    from drape.training.layers_outer import export_trained, load_config, train

    t0 = time.time()
    cfg = load_config(args.outer, args.config)
    model, task, summary = train(cfg, args.checkpoints or f"checkpoints/mgn_outer_{args.outer}")
    summary["wall_seconds"] = round(time.time() - t0, 1)
    summary["machine"] = f"{platform.machine()}, {os.cpu_count()} CPUs"
    print(json.dumps({k: v for k, v in summary.items() if k not in ("validation", "val_seqs", "clip_val_seqs")}, indent=2))
    out = args.out or ASSETS / "models" / "mgn_outer" / f"{cfg['inner']}_{args.outer}"
    for path in export_trained(model, task, summary, out):
        print(path)


def _export_deepsd(args: argparse.Namespace) -> None:
    from drape.export.deepsd import export_deepsd_from_checkpoints

    for path in export_deepsd_from_checkpoints(args.checkpoints, args.out, init=args.init):
        print(path)


LAYER_MEMBERS = ("inner_vertices", "inner_faces", "outer_vertices", "outer_faces")  # a layers/animate npz answer


def _layers_as_one_mesh(path: str, z: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A layers answer's members -> {"vertices" (T, Ni + No, 3), "faces" (Fi + Fo, 3) int64, "fps" if given}."""
    vi, vo = z["inner_vertices"], z["outer_vertices"]
    for name, v in (("inner_vertices", vi), ("outer_vertices", vo)):
        if v.dtype.kind not in "fiu" or v.ndim != 3 or v.shape[2] != 3:
            raise SystemExit(f"{path}: {name!r} must be (T, N, 3) numbers, got {v.shape} {v.dtype}")
    if vi.shape[0] != vo.shape[0]:
        raise SystemExit(f"{path}: 'inner_vertices' {vi.shape} and 'outer_vertices' {vo.shape} must have the same "
                         "frames")
    faces = []
    for name, offset, n in (("inner_faces", 0, vi.shape[1]), ("outer_faces", vi.shape[1], vo.shape[1])):
        f = z[name]
        if f.dtype.kind not in "iu" or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise SystemExit(f"{path}: {name!r} must be (F, 3) integers, F >= 1, got {f.shape} {f.dtype}")
        if int(f.min()) < 0 or int(f.max()) >= n:
            raise SystemExit(f"{path}: {name!r} index vertices {int(f.min())}..{int(f.max())}; its layer has {n}")
        faces.append(f.astype(np.int64) + offset)
    return {"vertices": np.concatenate([vi, vo], axis=1), "faces": np.concatenate(faces),
            **({"fps": z["fps"]} if "fps" in z else {})}


def _read_stream(path: str, faces: bool = True) -> tuple[np.ndarray, dict[str, np.ndarray], str]:
    """An npz stream on disk (an animate/refine npz answer, a simulated sequence) -> (vertices (T, N, 3) float32 m,
    finite, T and N >= 1; the archive's members); SystemExit naming the file and the member otherwise (faces
    False: a stream without 'faces' is read too, for a PC2, which holds points only). A layers
    answer (inner_vertices (T, Ni, 3), inner_faces, outer_vertices (T, No, 3), outer_faces) is read as the one
    mesh the service's GLB and PC2 answers hold: the inner layer's vertices first, then the outer's. The third
    item is the mesh's name in a GLB, as the service names it: "layers" or "garment"."""
    from drape.schemas.binary import decode_npz

    try:
        z = decode_npz(Path(path).read_bytes(), ("vertices", "faces", "fps", *LAYER_MEMBERS))
    except ValueError as exc:
        raise SystemExit(f"{path}: {exc}") from None
    name = "garment"
    if "vertices" not in z and all(m in z for m in LAYER_MEMBERS):
        z, name = _layers_as_one_mesh(path, z), "layers"
    if "vertices" not in z or (faces and "faces" not in z):
        needs = "'vertices' (T, N, 3) and 'faces' (F, 3)" if faces else "'vertices' (T, N, 3)"
        raise SystemExit(f"{path}: an npz stream needs {needs} (or a layers answer's {', '.join(LAYER_MEMBERS)})")
    v = z["vertices"]
    if v.dtype.kind not in "fiu" or v.ndim != 3 or v.shape[2] != 3:
        raise SystemExit(f"{path}: 'vertices' must be (T, N, 3) numbers, got {v.shape} {v.dtype}")
    if v.shape[0] == 0 or v.shape[1] == 0:
        raise SystemExit(f"{path}: 'vertices' {v.shape} holds no frames or no vertices")
    with np.errstate(over="ignore"):
        v = v.astype(np.float32, copy=False)
    if not np.isfinite(v).all():
        raise SystemExit(f"{path}: 'vertices' holds NaN or infinite values (or values beyond float32)")
    return v, z, name


def _glb_faces_fps(path: str, z: dict[str, np.ndarray], frames: int, vertices: int) -> tuple[np.ndarray, float]:
    """A stream's faces (F, 3), F >= 1, indexing its vertices, and its frame rate (default 30), one positive number
    whose float32 key times (frame / fps s) are finite; and a bound on the GLB's frames x (frames - 1) weights."""
    faces = z["faces"]
    if faces.dtype.kind not in "iu" or faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise SystemExit(f"{path}: 'faces' must be (F, 3) integers, F >= 1, got {faces.shape} {faces.dtype}")
    low, high = int(faces.min()), int(faces.max())
    if low < 0 or high >= vertices:
        raise SystemExit(f"{path}: 'faces' index vertices {low}..{high}; the stream has {vertices} "
                         f"(0..{vertices - 1})")
    fps = 30.0
    if "fps" in z:
        given = z["fps"]
        fps = float(given.reshape(-1)[0]) if given.size == 1 and given.dtype.kind in "fiu" else float("nan")
        if not (np.isfinite(fps) and fps > 0):
            got = repr(given.reshape(-1)[0].item()) if given.size == 1 else f"{given.shape} {given.dtype}"
            raise SystemExit(f"{path}: 'fps' must be one positive number, got {got}")
    from drape.schemas.gltf import frame_target_weights, key_times_finite
    from drape.service.settings import Settings

    if not key_times_finite(frames, fps):
        raise SystemExit(f"{path}: {fps:g} fps is too {'low' if fps < 1 else 'high'} for a glTF animation: the key "
                         f"times of {frames} frames (frame / fps seconds, float32) would not be finite and increasing; "
                         "use `drape export pc2`")
    limit = Settings().max_posed_values  # the service's bound on the same weights (DRAPE_MAX_POSED_VALUES)
    if frame_target_weights(frames) > limit:
        raise SystemExit(f"{path}: {frames} frames need {frames} x {frames - 1} morph-target weights in a GLB (one "
                         f"target a frame), over the limit of {limit}; export fewer frames or use `drape export pc2`")
    return faces, fps


def _export_pc2(args: argparse.Namespace) -> None:
    import math

    from drape.schemas.pc2 import encode_pc2

    if not (math.isfinite(args.start_frame) and abs(args.start_frame) <= float(np.finfo(np.float32).max)):
        raise SystemExit(f"--start-frame must be a finite float32 frame number, got {args.start_frame}")
    _out_path(args.out, args.stream)
    v, _, _ = _read_stream(args.stream, faces=False)  # a point cache holds no faces
    with open(args.out, "wb") as f:
        for piece in encode_pc2([v], v.shape[1], len(v), start_frame=args.start_frame):
            f.write(piece)
    print(f"{args.out}: {len(v)} frames x {v.shape[1]} points")


def _export_glb(args: argparse.Namespace) -> None:
    from drape.schemas.gltf import vertex_animation_glb

    _out_path(args.out, args.stream, suffixes=(".glb",))
    v, z, name = _read_stream(args.stream)
    faces, fps = _glb_faces_fps(args.stream, z, v.shape[0], v.shape[1])
    Path(args.out).write_bytes(vertex_animation_glb(v, faces, fps, name=name))
    print(f"{args.out}: {len(v)} frames x {v.shape[1]} vertices at {fps:g} fps")
    print("a vertex animation: positions only (a stream carries no texture coordinates or normals); the rig's GLB "
          "keeps the garment file's UVs: POST /v1/outfits/animate (or rig) with Accept: model/gltf-binary")


def _eval_deepsd(args: argparse.Namespace) -> None:
    from drape.training import DEFAULT_GROUND_TRUTH
    from drape.training.deepsd_eval import evaluate, format_table, write_results

    folders = {}
    for option, name, default in (("--ground-truth", "ground_truth", DEFAULT_GROUND_TRUTH),
                                  ("--real-mocap", "real_mocap", "../shared/data/mocap"),
                                  ("--external", "external", "../shared/data/external")):
        given = getattr(args, name)
        if given and not Path(given).is_dir():  # a folder named on purpose was skipped without a word
            raise SystemExit(f"drape: error: {option} {given}: no such folder")
        folders[name] = (given or None) if given is not None else str(default)
    results = evaluate(args.config, args.model, **folders)
    print(format_table(results))
    if args.write:
        for path in write_results(results, args.model):
            print(path)


def _eval_layers(args: argparse.Namespace) -> None:
    from drape.training.layers_eval import evaluate, format_table, write_results

    results = evaluate(frames=args.frames)
    table = format_table(results)
    print(table)
    if args.write:
        for path in write_results(results):
            print(path)
        docs = Path(args.docs)
        docs.write_text("# Layered garments against the two-layer simulation (`drape eval layers`)\n\n"
                        "Written by `drape eval layers --write`; what each row and column is: "
                        "drape/training/layers_eval.py and docs/layers.md.\n\n" + table)
        print(docs)


def _eval_intrinsic(args: argparse.Namespace) -> None:
    from drape.training.intrinsic_eval import evaluate, format_table, write_results

    model_dir = Path(args.model) if args.model else ASSETS / "models" / "intrinsic" / args.template
    dataset = args.dataset or f"data/intrinsic/{args.template}"
    long_dataset = args.long_dataset if args.long_dataset is not None else f"data/intrinsic/{args.template}_long"
    results = evaluate(dataset, args.template, model_dir, long_dataset=long_dataset or None)
    table = format_table(results)
    print(table)
    if args.write:
        write_results(results, model_dir)
        docs = Path(args.docs)
        text = docs.read_text() if docs.exists() else ""
        begin, end = f"<!-- eval intrinsic {args.template} -->", f"<!-- /eval intrinsic {args.template} -->"
        block = f"{begin}\n{table}\n{end}"
        if begin in text and end in text:
            text = text[:text.index(begin)] + block + text[text.index(end) + len(end):]
        else:
            text = text.rstrip() + "\n\n" + block + "\n"
        docs.write_text(text)
        print(model_dir / "manifest.json", docs)


def _motion_arg(name: str):  # noqa: ANN202 - Motion
    """An embedded clip name or a motion npz path."""
    from drape.assets.motion import load_clip, load_motion_npz

    return load_motion_npz(name) if name.endswith(".npz") else load_clip(name)


def _params_file(path: str) -> dict:
    """--params: a JSON object of intrinsic parameters; SystemExit naming the file otherwise."""
    import json

    try:
        given = json.loads(Path(path).read_text())
    except json.JSONDecodeError as exc:
        raise SystemExit(f"--params {path}: is not JSON: {exc}") from None
    if not isinstance(given, dict):
        raise SystemExit(f"--params {path}: must be a JSON object of parameters, got {type(given).__name__}")
    return given


def _params_option(source: str, kind: type[SimParams], given: dict) -> SimParams:
    """The parameters, validated before any work; pydantic's errors as one line naming where they came from."""
    from pydantic import ValidationError

    try:
        return kind(**given)
    except ValidationError as exc:
        errors = "; ".join(f"{'.'.join(map(str, e['loc'])) or 'parameters'}: {e['msg']}" for e in exc.errors())
        raise SystemExit(f"{source}: {errors}") from None


def _sim_run(args: argparse.Namespace) -> None:
    import json

    from drape.assets.body import load_body
    from drape.geometry.mesh_io import load_mesh
    from drape.sim.dataset import save_layer_sequence, save_sequence
    from drape.sim.params import LayerParams, SimParams
    from drape.sim.quality import LayerGate, QualityGate
    from drape.sim.simulate import simulate

    given = _params_file(args.params) if args.params else {}
    if args.thickness is not None and not args.outer:
        raise SystemExit("--thickness is the inner garment's thickness: it needs --outer")
    if args.outer and args.thickness is not None:
        given = given | {"inner_thickness": args.thickness}
    source = " and ".join([*([f"--params {args.params}"] if args.params else []),
                           *(["--thickness"] if args.thickness is not None else [])])
    params = _params_option(source, LayerParams if args.outer else SimParams, given)
    _out_path(args.out, args.garment, args.outer,
              args.clip if args.clip.endswith(".npz") else None, args.params)
    verts, faces = load_mesh(args.garment)
    motion = _motion_arg(args.clip)
    from tqdm import tqdm

    with tqdm(desc="frames", unit="frame") as bar:
        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.update(done - bar.n)

        if args.outer:
            from drape.sim.layers import simulate_layers

            assert isinstance(params, LayerParams)
            lp = params
            outer_v, outer_f = load_mesh(args.outer)
            lr = simulate_layers(verts, faces, outer_v, outer_f, load_body(args.body), motion, lp,
                                 frames=args.frames, progress=progress)
            stats, frames_done, spf = lr.stats, len(lr.poses), lr.seconds_per_frame
            failures = LayerGate().failures(stats)
            save_layer_sequence(args.out, inner_vertices=lr.inner_vertices, inner_faces=faces,
                                outer_vertices=lr.outer_vertices, outer_faces=outer_f, poses=lr.poses,
                                trans=lr.trans, fps=motion.fps, params=lp, stats=stats,
                                inner_garment=Path(args.garment).stem, outer_garment=Path(args.outer).stem,
                                body=args.body, motion=motion.name)
        else:
            r = simulate(verts, faces, load_body(args.body), motion, params, frames=args.frames, progress=progress)
            stats, frames_done, spf = r.stats, len(r.vertices), r.seconds_per_frame
            failures = QualityGate().failures(stats)
            save_sequence(args.out, vertices=r.vertices, faces=faces, poses=r.poses, trans=r.trans, fps=motion.fps,
                          params=params, stats=stats, garment=Path(args.garment).stem, body=args.body,
                          motion=motion.name)
    print(json.dumps(stats, indent=1))
    if failures:
        print(f"{args.out}: FAILS the quality gate: {'; '.join(failures)}", file=sys.stderr)
        raise SystemExit(1)
    print(f"{args.out}: {frames_done} frames, {spf:.3f} s per simulated frame")


def _sim_dataset(args: argparse.Namespace) -> None:
    from drape.geometry.mesh_io import load_mesh
    from drape.sim.dataset import build_dataset
    from drape.sim.params import sample_layer_params, sample_params

    params: list[SimParams]
    garments: dict[str, tuple[np.ndarray, ...]]
    # the last --holdout-params sets and --holdout-motions motions are the test split: each split needs one
    for option, held, total, what in (
            ("--holdout-params", args.holdout_params, args.params, "parameter sets (--params)"),
            ("--holdout-motions", args.holdout_motions, len(args.motions.split(",")), "motions (--motions)")):
        if not 0 < held < total:
            raise SystemExit(f"drape: error: {option} {held}: the last ones of the {total} {what} are held out for "
                             f"the test split, so it must be in [1, {total - 1}]"
                             + (f"; give at least 2 {what}" if total < 2 else ""))
    if args.outer:
        if len(args.outer) != len(args.garment):
            raise SystemExit("--outer takes one outer mesh per --garment (the inner), in the same order")
        garments = {f"{Path(g).stem}+{Path(o).stem}": (*load_mesh(g), *load_mesh(o))
                    for g, o in zip(args.garment, args.outer, strict=True)}
        try:
            low, high = (float(x) for x in args.thickness.split(","))
        except ValueError:
            raise SystemExit(f"--thickness takes LOW,HIGH in m, got {args.thickness!r}") from None
        params = list(sample_layer_params(args.params, seed=args.seed, thickness=(low, high),
                                          held_out=args.holdout_params, material=args.material))
    else:
        if args.material != "sampled":
            raise SystemExit("--material fixed is for two layers (--outer): one garment's parameter sets differ "
                             "only by the sampled material")
        garments = {Path(g).stem: load_mesh(g) for g in args.garment}
        params = sample_params(args.params, seed=args.seed)
    if args.substeps is not None:
        if not 1 <= args.substeps <= 64:
            raise SystemExit(f"--substeps must be in [1, 64], got {args.substeps}")
        # the solver's steps per frame, not a sampled parameter: the same sets, each run finer in time
        params = [type(p).model_validate(p.model_dump() | {"substeps": args.substeps}) for p in params]
    motions = [_motion_arg(m) for m in args.motions.split(",")]
    manifest = build_dataset(
        args.out, garments, params, motions, args.frames, body=args.body,
        holdout_params=args.holdout_params, holdout_motions=args.holdout_motions, workers=args.workers,
        ray_address=args.ray, only_splits=tuple(args.splits.split(",")) if args.splits else None,
        only_params=args.only_params,
    )
    summ = manifest["summary"]
    print(f"{args.out}: {summ['items']} sequences accepted, {len(manifest['rejected'])} rejected, "
          f"{manifest['last_run']['simulated']} simulated in this run ({manifest['last_run']['seconds']} s)")
    import json

    print(json.dumps(summ, indent=1))


def _sim_outfit(args: argparse.Namespace) -> None:
    from drape.geometry.mesh_io import save_mesh
    from drape.sim.layers import split_outfit

    (vi, fi), (vo, fo) = split_outfit(args.type, args.vertices, seed=args.seed, body=args.body,
                                      looseness=args.looseness, length=args.length)
    inner_name, outer_name = (t.strip() for t in args.type.split(","))
    out = Path(args.out)
    for name, v, f in ((inner_name, vi, fi), (outer_name, vo, fo)):
        print(f"{save_mesh(out / f'{name}.obj', v, f)}: {len(v)} vertices, {len(f)} faces")


def _sim_sweep(args: argparse.Namespace) -> None:
    from drape.sim.sweep import run_sweep

    run_sweep(args.out, workers=args.workers, frames=args.frames, vertices=args.vertices)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="drape", description="drape: neural garment animation service and tools")
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("serve", help="run the HTTP service")
    s.add_argument("--host", help="default: DRAPE_HOST or 127.0.0.1")
    s.add_argument("--port", type=_port, help="default: DRAPE_PORT or 8000")
    s.add_argument("--ray", metavar="ADDRESS", default=None,
                   help="deploy on this Ray cluster with Ray Serve (auto, or the head's HOST:6379); "
                        "Serve's HTTP proxies listen on host:port")
    s.add_argument("--replicas", type=int, default=1, help="with --ray: copies of the service (default 1)")
    s.add_argument("--replica-cpus", type=float, default=1.0, help="with --ray: CPUs reserved per replica (default 1)")
    s.set_defaults(func=_serve)

    assets = sub.add_parser("assets", help="re-create the embedded assets").add_subparsers(dest="what", required=True)
    b = assets.add_parser("bake-body", help="bake body presets from anny (slow: ~2 min the first time)")
    b.add_argument("--presets", nargs="*", help="presets to bake (default: all)")
    b.add_argument("--out", default=str(ASSETS / "bodies"))
    b.set_defaults(func=_bake_body)
    d = assets.add_parser("import-deepmimic", help="retarget the DeepMimic clips from the pybullet wheel")
    d.add_argument("--out", default=str(ASSETS / "motions"))
    d.add_argument("--body", default="neutral")
    d.add_argument("--fps", type=float, default=30.0)
    d.set_defaults(func=_import_deepmimic)

    motions = sub.add_parser("motions", help="make or convert motions").add_subparsers(dest="what", required=True)
    g = motions.add_parser("generate", help="a seeded procedural motion (gait, reaching, turning)")
    g.add_argument("--frames", type=_int_in(1, MAX_GENERATED_FRAMES), required=True)
    g.add_argument("--seed", type=_int_in(0, 2**32 - 1), default=0)
    g.add_argument("--fps", type=float, default=30.0)
    g.add_argument("--walk", type=float, default=0.6, help="share of time walking (0..1)")
    g.add_argument("--body", default="neutral", help="a preset, or a body file (skinned GLB / glTF with SMPL joint "
                   "names, or npz of the body's arrays)")
    g.add_argument("--out", required=True, help="an .npz file (.npz is added to a name without a suffix)")
    g.set_defaults(func=_motions_generate)
    i = motions.add_parser("import", help="convert a CMU-named BVH or an AMASS-style npz to a drape clip "
                           "(retarget, Y-up, feet on the floor; docs/motion_import.md)")
    i.add_argument("file", help="a .bvh with CMU joint names, or an npz: drape's clip, AMASS (SMPL-H (T, 156) or "
                   "(T, 52, 3)), SMPL (T, 72) or (T, 24, 3), SMPL-X (T, 165)")
    i.add_argument("--fps", type=float, default=None, help="resample to this frame rate (slerp; default: the file's)")
    i.add_argument("--body", default="neutral", help="body to retarget onto and to put on the floor: a preset, or a "
                   "body file (skinned GLB / glTF with SMPL joint names, or npz of the body's arrays)")
    i.add_argument("--up", choices=["y", "z"], default=None,
                   help="the file's up axis (default: detected; AMASS is Z-up, CMU BVH Y-up)")
    i.add_argument("--no-floor", action="store_true", help="keep the file's heights (no floor step)")
    i.add_argument("--keep-flips", action="store_true", help="keep rotation flips (a joint jumping by up to half a "
                   "turn for a few frames and back: capture errors in real CMU files) instead of slerping over them")
    i.add_argument("--out", required=True)
    i.set_defaults(func=_motions_import)

    outfits = sub.add_parser("outfits", help="template outfits").add_subparsers(dest="what", required=True)
    o = outfits.add_parser("generate", help="generate an outfit in rest pose")
    o.add_argument("--type", required=True,
                   help="tshirt, tanktop, longsleeve, trousers, shorts, skirt, dress, jacket, long_skirt, "
                        "or a comma list")
    o.add_argument("--vertices", type=int, default=4000, help="total vertex count, met within ~10%% (default 4000)")
    o.add_argument("--seed", type=_int_in(0, 2**32 - 1), default=0, help="drives every random choice (default 0)")
    o.add_argument("--body", default="neutral", help="a preset, or a body file (skinned GLB / glTF with SMPL joint "
                   "names, or npz of the body's arrays)")
    o.add_argument("--looseness", type=float, default=None,
                   help="0 (tight) .. 1 (loose), up to 3 for an oversize garment; random if omitted")
    o.add_argument("--length", type=float, default=None, help="0 (short) .. 1 (long); random if omitted")
    o.add_argument("--out", required=True, help="a mesh file; an OBJ of several garments holds one named object "
                   "each (inner first), which the rig answers as its parts")
    o.set_defaults(func=_outfits_generate)
    of = outfits.add_parser("fit", help="fit a garment made for another body (any units, Y- or Z-up, T- or A-pose) "
                            "onto a body at rest")
    of.add_argument("mesh", help="OBJ, PLY, GLB or glTF")
    of.add_argument("--body", default="neutral", help="a preset, or a body file (skinned GLB / glTF with SMPL "
                    "joint names, or npz of the body's arrays; as POST /v1/bodies reads it)")
    of.add_argument("--units", choices=["m", "cm", "mm"], default=None, help="default: inferred from the size")
    of.add_argument("--up", choices=["y", "z"], default=None, help="default: inferred (the axis the garment wraps "
                    "around, else the thinner of Y and Z is its depth)")
    of.add_argument("--pose", choices=["t", "a"], default="t", help="the pose the garment was made in")
    of.add_argument("--out", required=True, help="the fitted mesh (OBJ, PLY, ...)")
    of.add_argument("--report", default=None, help="also write the transform and the report as JSON here")
    of.set_defaults(func=_outfits_fit)

    from drape.training import DEFAULT_DEEPSD_CONFIG, DEFAULT_GROUND_TRUTH

    models_dir = ASSETS / "models" / "deepsd"
    t = sub.add_parser("train", help="train a network").add_subparsers(dest="what", required=True)
    ti = t.add_parser("intrinsic", help="the intrinsic garment space of one template (resumes from checkpoints)")
    ti.add_argument("--template", required=True, help="e.g. skirt: drape/training/configs/intrinsic_<template>.json")
    ti.add_argument("--config", help="another config file")
    ti.add_argument("--checkpoints", help="default checkpoints/intrinsic/<template>")
    ti.add_argument("--out", help="where the ONNX model goes (default drape/assets/models/intrinsic/<template>)")
    ti.add_argument("--calibrate-only", action="store_true",
                    help="do not train: only measure the exported model's keyframe_shrink on the config's validation "
                         "sets and write it into its manifest (the last step of training)")
    ti.set_defaults(func=_train_intrinsic)
    tm = t.add_parser("mgn-inner", help="MGN's inner-layer network of one served inner template, by physics "
                      "(resumes from checkpoints; exported with DeePSD's rig measured on the same validation split)")
    _inner_config_args(tm)
    tm.add_argument("--checkpoints", help="default checkpoints/mgn_inner_<inner>")
    tm.add_argument("--out", help="default drape/assets/models/mgn_inner/<inner>")
    tm.set_defaults(func=_train_mgn_inner)
    tf = t.add_parser("mgn-inner-fit", help="refit an exported inner-layer network's rig to keep the layer out of the "
                      "body (its config's collision_fit; kept where it measures better on the validation split; "
                      "`mgn-inner` runs it after the export)")
    _inner_config_args(tf)
    tf.add_argument("--folder", help="the exported network, default drape/assets/models/mgn_inner/<inner>")
    tf.set_defaults(func=_train_mgn_inner_fit)
    to = t.add_parser("mgn-outer", help="MGN's outer-layer network of one served combination, on its two-layer "
                      "simulations (make layers-data; resumes from checkpoints; exported with DeePSD's outer rig "
                      "measured on the same validation sequences)")
    to.add_argument("--outer", required=True, help="jacket: drape/training/configs/mgn_outer_<outer>.json")
    to.add_argument("--config", help="another config file")
    to.add_argument("--checkpoints", help="default checkpoints/mgn_outer_<outer>")
    to.add_argument("--out", help="default drape/assets/models/mgn_outer/<inner>_<outer>")
    to.set_defaults(func=_train_mgn_outer)
    td = t.add_parser("deepsd", help="train DeePSD by physics on generated outfits (resumes from checkpoints)")
    td.add_argument("--config", default=str(DEFAULT_DEEPSD_CONFIG))
    td.add_argument("--checkpoints", default="checkpoints/deepsd")
    td.add_argument("--device", default="auto",
                    help="where the training steps run: auto (a CUDA GPU if torch sees one, else the CPU), cpu, cuda")
    td.set_defaults(func=_train_deepsd)
    e = sub.add_parser("export", help="export a network to ONNX, or a stream to an engine format").add_subparsers(
        dest="what", required=True)
    ep = e.add_parser("pc2", help="an npz stream (vertices (T, N, 3), faces; or a layers answer, "
                                    "inner_* then outer_*) -> a PC2 point cache")
    ep.add_argument("stream")
    ep.add_argument("--out", required=True)
    ep.add_argument("--start-frame", type=float, default=0.0)
    ep.set_defaults(func=_export_pc2)
    eg = e.add_parser("glb", help="an npz stream (vertices (T, N, 3), faces, fps; or a layers "
                                    "answer, inner_* then outer_*) -> a GLB vertex animation")
    eg.add_argument("stream")
    eg.add_argument("--out", required=True)
    eg.set_defaults(func=_export_glb)
    ed = e.add_parser("deepsd", help="export the latest DeePSD checkpoint to ONNX + manifest")
    ed.add_argument("--checkpoints", default="checkpoints/deepsd")
    ed.add_argument("--init", action="store_true", help="export a freshly initialised (untrained) model")
    ed.add_argument("--out", default=str(models_dir))
    ed.set_defaults(func=_export_deepsd)
    ev = sub.add_parser("eval", help="evaluate a shipped network").add_subparsers(dest="what", required=True)
    evd = ev.add_parser("deepsd", help="held-out outfits x held-out clips: collisions, edge error, bending")
    evd.add_argument("--config", default=str(DEFAULT_DEEPSD_CONFIG))
    evd.add_argument("--model", default=str(models_dir))
    evd.add_argument("--write", action="store_true", help="store the table in the manifest and docs/")
    evd.add_argument("--real-mocap", default=None,
                     help="folder of real CMU BVH clips for the second table (default ../shared/data/mocap, skipped "
                          "when absent; '' to skip)")
    evd.add_argument("--external", default=None,
                     help="folder of garment meshes (*.obj) made for other bodies: fitted onto the neutral body and "
                          "measured on the real clips (default ../shared/data/external, skipped when absent; '' to "
                          "skip)")
    evd.add_argument("--ground-truth", default=None,
                     help=f"a `drape sim dataset` directory: mean vertex error against its sequences (default "
                          f"{DEFAULT_GROUND_TRUTH}, skipped when absent)")
    evd.set_defaults(func=_eval_deepsd)

    evl = ev.add_parser("layers", help="the served layer combinations against two-layer simulations on held-out "
                        "motions: RMSE, Hausdorff, STED, H-Coll, L-Coll, speed (simulates what data/layers_eval lacks)")
    evl.add_argument("--frames", type=_int_in(1), default=60, help="motion frames simulated per sequence")
    evl.add_argument("--write", action="store_true", help="into the inner networks' manifests and --docs")
    evl.add_argument("--docs", default="docs/layers_eval.md")
    evl.set_defaults(func=_eval_layers)
    evi = ev.add_parser("intrinsic", help="a template's intrinsic garment space on held-out parameters x motions")
    evi.add_argument("--template", required=True)
    evi.add_argument("--dataset", help="the `drape sim dataset` folder (default data/intrinsic/<template>)")
    evi.add_argument("--model", help="default drape/assets/models/intrinsic/<template>")
    evi.add_argument("--long-dataset", help="long test sequences for the keyframe-ratio table "
                                            "(default data/intrinsic/<template>_long; '' to skip)")
    evi.add_argument("--write", action="store_true", help="store the tables in the manifest and docs/intrinsic.md")
    evi.add_argument("--docs", default="docs/intrinsic.md")
    evi.set_defaults(func=_eval_intrinsic)

    sim = sub.add_parser("sim", help="ground-truth cloth simulation (MuJoCo)").add_subparsers(dest="what", required=True)
    sr = sim.add_parser("run", help="simulate one garment on a body along a clip")
    sr.add_argument("--garment", required=True, help="garment mesh (OBJ/PLY/GLB) in the body's rest pose")
    sr.add_argument("--body", default="neutral", help="body preset")
    sr.add_argument("--clip", required=True, help="embedded clip name or a motion npz")
    sr.add_argument("--frames", type=int, default=None, help="motion frames to simulate (default: all)")
    sr.add_argument("--params", help="intrinsic parameters JSON (default: drape.sim.params.SimParams())")
    sr.add_argument("--outer", help="an outer garment mesh around --garment (then the inner): two layers together")
    sr.add_argument("--thickness", type=float, default=None,
                    help="with --outer: the inner garment's thickness H_in, m (the outer-to-inner gap; default 0.006)")
    sr.add_argument("--out", required=True)
    sr.set_defaults(func=_sim_run)
    sd = sim.add_parser("dataset", help="garments x sampled parameter sets x motions -> npz per sequence + manifest")
    sd.add_argument("--garment", required=True, nargs="+", help="garment mesh file(s) (the inner ones with --outer)")
    sd.add_argument("--outer", nargs="+", help="two layers: one outer garment mesh per --garment, same order")
    sd.add_argument("--thickness", default="0.004,0.012",
                    help="with --outer: LOW,HIGH range of the sampled inner thickness H_in, m (held-out parameter "
                         "sets get their own bins of it)")
    sd.add_argument("--material", choices=("sampled", "fixed"), default="sampled",
                    help="with --outer: sample the cloth's parameters per set (default) or keep the defaults and "
                         "vary H_in alone (MGN's setting: its outer network is conditioned on H_in only)")
    sd.add_argument("--params", type=_int_in(1), default=8, help="number of parameter sets to sample")
    sd.add_argument("--seed", type=_int_in(0, 2**32 - 1), default=0, help="seed of the parameter sampler")
    sd.add_argument("--motions", required=True, help="comma list of clip names or motion npz files")
    sd.add_argument("--frames", type=_int_in(1), default=90, help="frames simulated per sequence")
    sd.add_argument("--body", default="neutral")
    sd.add_argument("--holdout-params", type=int, default=2)
    sd.add_argument("--holdout-motions", type=int, default=1)
    sd.add_argument("--splits", help="simulate only these splits, comma list of train,test,test_params,test_motions")
    sd.add_argument("--only-params", metavar="I,J,...", type=_index_list,
                    help="simulate only these parameter-set indices (0-based), comma list, e.g. a training "
                         "config's validation sets")
    sd.add_argument("--substeps", type=int, default=None,
                    help="simulation steps per motion frame for every parameter set (default: the sets' own, 4); "
                         "a long skirt needs 8 (docs/sim.md)")
    sd.add_argument("--workers", type=_int_in(1), default=None, help="local processes (default: all cores)")
    sd.add_argument("--ray", metavar="ADDRESS", default=None, help="run the items as tasks on this Ray cluster")
    sd.add_argument("--out", required=True)
    sd.set_defaults(func=_sim_dataset)
    so = sim.add_parser("outfit", help="two layers' rest meshes: INNER,OUTER generated as one layered outfit, "
                                       "written as OUT/<inner>.obj and OUT/<outer>.obj")
    so.add_argument("--type", required=True, help="inner,outer garment types, e.g. tshirt,jacket")
    so.add_argument("--vertices", type=int, default=4000, help="target vertex count of the two together")
    so.add_argument("--seed", type=_int_in(0, 2**32 - 1), default=0)
    so.add_argument("--body", default="neutral")
    so.add_argument("--looseness", type=float, default=None, help="0 (tight) .. 1 (loose); random if omitted")
    so.add_argument("--length", type=float, default=None, help="0 (short) .. 1 (long); random if omitted")
    so.add_argument("--out", required=True, help="folder for the two OBJ files")
    so.set_defaults(func=_sim_outfit)
    sw = sim.add_parser("sweep", help="vary one parameter at a time from the base (Wang 2019 Sec. 3.6)")
    sw.add_argument("--out", default="docs/sim_sweep.json")
    sw.add_argument("--workers", type=_int_in(1), default=None, help="local processes (default: all cores)")
    sw.add_argument("--frames", type=int, default=45)
    sw.add_argument("--vertices", type=int, default=1200)
    sw.set_defaults(func=_sim_sweep)

    r = sub.add_parser("render", help="PNG of a body (and outfit) at frames of a motion")
    r.add_argument("--body", default="neutral", help="a preset, or a body file (skinned GLB / glTF, or npz)")
    r.add_argument("--outfit", help="mesh file of an outfit in the body's rest pose")
    r.add_argument("--clip", help="embedded clip name")
    r.add_argument("--motion", help="motion npz file")
    r.add_argument("--sim", help="a simulated sequence npz (drape sim run / dataset item): cloth next to the body")
    r.add_argument("--keyframes", help="with --sim: comma list of frames given to the template's intrinsic model as "
                                       "keyframes (matched, as the service answers by default); its sequence is drawn "
                                       "beside the simulation")
    r.add_argument("--unmatched", action="store_true", help="with --keyframes: the decoded latents alone "
                   "(match_keyframes false)")
    r.add_argument("--served", action="store_true", help="with a two-layer --sim: drape's served layers (as POST "
                   "/v1/layers/animate poses them, at the sequence's H_in) drawn beside the simulation")
    r.add_argument("--garment-model", help="with --keyframes: the model folder (default the shipped one of the "
                                           "sequence's garment)")
    r.add_argument("--frames", default=None, help="comma list (default 0,10,20,30; six spread frames with --sim)")
    r.add_argument("--azimuth", type=_finite_float, default=25.0, help="view angle about +Y from the front, degrees")
    r.add_argument("--smooth", type=_int_in(0), default=40, help="weight diffusion steps for the outfit's skinning")
    r.add_argument("--out", required=True)
    r.set_defaults(func=_render)
    return p


# packages that only some commands need, and the extra that installs each (pyproject.toml)
OPTIONAL_PACKAGES = {"torch": "train", "onnx": "train", "onnxscript": "train", "tqdm": "train", "mujoco": "sim",
                     "matplotlib": "tools", "anny": "assets", "pybullet": "assets", "ray": "cluster"}


def main(argv: list[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except KeyboardInterrupt:  # Ctrl-C: one line (training and datasets resume from their checkpoints)
        print("drape: interrupted", file=sys.stderr)
        raise SystemExit(130) from None
    except ModuleNotFoundError as exc:  # `make serve`'s venv has none of the training tools: one line, not a traceback
        package = (exc.name or "").split(".")[0]
        if package not in OPTIONAL_PACKAGES:
            raise
        command = " ".join(x for x in (args.command, getattr(args, "what", None)) if x)
        print(f"drape: error: `drape {command}` needs {package}, which is not installed (it is not in [serve]): "
              f"pip install 'drape[{OPTIONAL_PACKAGES[package]}]'", file=sys.stderr)
        raise SystemExit(1) from exc
    except OSError as exc:  # a file that is not there, a folder given as a file, an --out that cannot be written
        where = f"{exc.filename}: " if exc.filename is not None else ""
        print(f"drape: error: {where}{exc.strerror or exc}", file=sys.stderr)
        raise SystemExit(1) from exc
    except (ValueError, KeyError) as exc:
        # a KeyError's str() is the repr of its message; print the message itself
        text = exc.args[0] if isinstance(exc, KeyError) and len(exc.args) == 1 and isinstance(exc.args[0], str) \
            else exc
        print(f"drape: error: {text}", file=sys.stderr)
        raise SystemExit(2) from exc


if __name__ == "__main__":
    main()
