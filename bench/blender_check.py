"""Does Blender play drape's GLB and PC2 answers as drape's own vertices?

What is measured: for 2 held-out outfits (t-shirt + trousers, seed 90100; dress, seed 90101; ~3k
vertices, neutral body) x 2 held-out clips (walk, dance_b; 30 fps) x refinement off / on, the real app
(`create_app(Settings())` with the shipped model, through FastAPI's TestClient) answers
POST /v1/outfits/animate three times: as npz (the reference vertices (T, N, 3)), as GLB and as PC2.
Blender (bpy, in its own venv: bench/blender_eval.py, a subprocess) then

- imports the GLB with its glTF importer into a factory-empty scene whose fps is the clip's (set
  before the import), widens every shape key's slider range to the values it is animated with (Blender
  clamps animated shape-key values to it; the importer widens it only to the first key's value), and
  evaluates the skinned, morphed "outfit" mesh (armature + shape keys through the depsgraph, world
  matrix applied) at frames 0, T/2 and T-1 (glTF key t plays at Blender frame t), converted back from
  Blender's Z-up to glTF's Y-up; vertices are matched by the importer's order (checked: same count,
  rest positions equal);
- builds a mesh from the reference's frame 0 and faces, adds a Mesh Cache modifier reading the PC2
  (frame start 0, identity axes) and evaluates it at the same frames;
- once, re-keys one shape key outside [0, 1] and evaluates it with the importer's slider range and
  with a widened one (does Blender clamp animated shape-key values? it does, when it evaluates).

Per case the table gives the mean and max over those frames' vertices of the distance (mm) to the npz
answer. Bars: GLB mean <= 1 mm and max <= 5 mm (an engine plays the rig, 4 influences and float32
skinning, not drape's array); PC2 the same (it stores the array itself: 0 expected). Exits 1 when a
bar fails. The report also lists what the Blender side found (vertex matching, the importer's slider
ranges and stored key values, the evaluated shape-key values against the GLB's weights at each frame)
and, to show the check can tell, what a one-frame offset would give and how far refinement moved the
evaluated frames (the sparse correction targets the refine=on GLBs carry).

Run: make check-blender (creates .venv-blender with bpy once), or
     .venv/bin/python -m bench.blender_check [--keep] [--out docs/blender_check.md]
Files go to build/blender/ (removed at the end unless --keep). About 1 minute on 2 cores.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BLENDER_PY = ROOT / ".venv-blender" / "bin" / "python"
OUTFITS = (("tshirt,trousers", 90100), ("dress", 90101))
CLIPS = ("walk", "dance_b")
VERTICES = 3000
GLB_MEAN_MM, GLB_MAX_MM = 1.0, 5.0


def case_name(outfit: str, clip: str, refine: bool) -> str:
    return f"{outfit.replace(',', '+')}_{clip}_refine{int(refine)}"


def write_answers(folder: Path) -> list[dict]:
    """Every case's npz, GLB and PC2 answers into `folder`; -> the cases (name, fps, frames, ...)."""
    from fastapi.testclient import TestClient

    from drape.assets.outfits import generate_outfit
    from drape.schemas.binary import NPZ, decode_npz, encode_npz
    from drape.schemas.gltf import GLB
    from drape.schemas.pc2 import PC2, read_pc2
    from drape.service.app import create_app
    from drape.service.settings import Settings

    folder.mkdir(parents=True, exist_ok=True)
    cases = []
    with TestClient(create_app(Settings())) as http:
        for kind, seed in OUTFITS:
            o = generate_outfit(kind, vertices=VERTICES, seed=seed)
            for clip in CLIPS:
                for refine in (False, True):
                    name = case_name(kind, clip, refine)
                    body = encode_npz({"vertices": o.vertices, "faces": o.faces, "clip": np.array(clip),
                                       "refine": np.array(refine)})
                    answers = {}
                    for accept in (NPZ, GLB, PC2):
                        r = http.post("/v1/outfits/animate", content=body,
                                      headers={"content-type": NPZ, "accept": accept})
                        if r.status_code != 200:
                            raise RuntimeError(f"{name} {accept}: {r.status_code} {r.text[:300]}")
                        answers[accept] = r.content
                    ref = decode_npz(answers[NPZ])
                    v, fps = ref["vertices"], float(ref["fps"])
                    pc2, start, rate = read_pc2(answers[PC2])
                    np.savez(folder / f"{name}.npz", vertices=v, faces=ref["faces"], fps=np.array(fps))
                    (folder / f"{name}.glb").write_bytes(answers[GLB])
                    (folder / f"{name}.pc2").write_bytes(answers[PC2])
                    T = len(v)
                    cases.append({"name": name, "outfit": kind, "clip": clip, "refine": refine, "fps": fps,
                                  "frames": [0, T // 2, T - 1], "num_frames": T, "vertices": int(v.shape[1]),
                                  "pc2_equals_npz": bool(np.array_equal(pc2, v)),
                                  "pc2_header": [start, rate]})
                    print(f"wrote {name}: {T} frames x {v.shape[1]} vertices", flush=True)
    (folder / "cases.json").write_text(json.dumps({"cases": cases}, indent=1))
    return cases


def run_blender(folder: Path, timeout: float) -> str:
    if not BLENDER_PY.exists():
        sys.exit(f"{BLENDER_PY} is missing: run `make check-blender` (it creates .venv-blender with bpy)")
    cmd = [str(BLENDER_PY), str(ROOT / "bench" / "blender_eval.py"), str(folder)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    if r.returncode != 0:
        sys.exit(f"blender_eval failed ({r.returncode}):\n{r.stdout[-4000:]}\n{r.stderr[-4000:]}")
    return r.stdout


def errors_mm(got: np.ndarray, want: np.ndarray) -> tuple[float, float]:
    d = np.linalg.norm(got - want, axis=2) * 1e3
    if np.isnan(d).any():  # a vertex Blender does not have counts as failing
        return float("nan"), float("inf")
    return float(d.mean()), float(d.max())


def compare(folder: Path, cases: list[dict]) -> list[dict]:
    rows = []
    for case in cases:
        name = case["name"]
        with np.load(folder / f"{name}.npz") as z:
            want = z["vertices"][case["frames"]].astype(np.float64)
            # what a one-frame offset would cost: each evaluated frame against its neighbour
            nb = [f + 1 if f + 1 < case["num_frames"] else f - 1 for f in case["frames"]]
            offset = errors_mm(z["vertices"][nb].astype(np.float64), want)
        with np.load(folder / f"{name}.blender.npz") as b:
            glb, pc2, info = b["glb"], b["pc2"], json.loads(str(b["info"]))
        moved = None
        if case["refine"]:  # how far refinement moved the evaluated frames (what the correction targets carry)
            with np.load(folder / f"{case_name(case['outfit'], case['clip'], False)}.npz") as z:
                moved = errors_mm(z["vertices"][case["frames"]].astype(np.float64), want)
        per_frame = [errors_mm(glb[i:i + 1], want[i:i + 1]) for i in range(len(want))]
        rows.append({**case, "glb": errors_mm(glb, want), "pc2": errors_mm(pc2, want), "info": info,
                     "glb_per_frame": per_frame, "one_frame_offset": offset, "refine_moved": moved})
    return rows


def passes(row: dict) -> bool:
    return all(mean <= GLB_MEAN_MM and mx <= GLB_MAX_MM for mean, mx in (row["glb"], row["pc2"]))


def report(rows: list[dict], seconds: float, command: str, probe: dict) -> str:
    info0 = rows[0]["info"]
    lines = [
        "# drape's GLB and PC2 answers played by Blender",
        "",
        "Generated by `bench/blender_check.py` (its docstring says how); do not edit by hand.",
        "",
        f"- Command: `{command}`",
        f"- Date: {dt.datetime.now().astimezone().strftime('%Y-%m-%d %H:%M %Z')}",
        f"- Blender: bpy {info0['bpy']} (own venv .venv-blender, Python 3.11, numpy < 2); its glTF importer's defaults",
        f"- Input: POST /v1/outfits/animate on the shipped model; outfits {', '.join(f'{k} (seed {s})' for k, s in OUTFITS)}"
        f" at ~{VERTICES} vertices, neutral body; clips {', '.join(CLIPS)} ({rows[0]['num_frames']} frames,"
        f" {rows[0]['fps']:g} fps); frames evaluated: 0, T/2, T-1",
        f"- Bars: GLB and PC2 mean <= {GLB_MEAN_MM:g} mm, max <= {GLB_MAX_MM:g} mm, against the npz answer",
        f"- Runtime: {seconds:.0f} s",
        "",
        "| outfit | clip | refine | GLB mean mm | GLB max mm | PC2 mean mm | PC2 max mm | pass |",
        "|---|---|---|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        lines.append(f"| {r['outfit']} | {r['clip']} | {'on' if r['refine'] else 'off'} | {r['glb'][0]:.4f} |"
                     f" {r['glb'][1]:.4f} | {r['pc2'][0]:.4f} | {r['pc2'][1]:.4f} | {'yes' if passes(r) else 'NO'} |")
    lines += [
        "",
        "## What the Blender side found",
        "",
        "| case | Blender vertices / drape | skin sets | matched by | rest max mm | pose keys | pose key range |"
        " slider range after import | key values changed at import | evaluated keys vs GLB (max abs, per frame) |"
        " GLB max mm per frame | a 1-frame offset would give (mean / max mm) | refinement moved (mean / max mm) |",
        "|---|---|---:|---|---:|---:|---|---|---:|---|---|---|---|",
    ]
    for r in rows:
        i = r["info"]
        rng = i["pose_key_range"]
        lines.append(
            f"| {r['name']} | {i['blender_vertices']} / {r['vertices']} | {i['joint_sets']} | {i['vertex_match']} | {i['rest_max_mm']:.2g} |"
            f" {i['pose_keys']} (+{i['correction_keys']} corrections) | {rng[0]:.3f} .. {rng[1]:.3f} |"
            f" {i['importer_slider_range'][0]:g} .. {i['importer_slider_range'][1]:g} |"
            f" {i['stored_key_values_max_diff']:.2g} | {', '.join(f'{d:.2g}' for d in i['evaluated_key_diff'])} |"
            f" {', '.join(f'{m:.3f}' for _, m in r['glb_per_frame'])} |"
            f" {r['one_frame_offset'][0]:.1f} / {r['one_frame_offset'][1]:.1f} |"
            f" {'-' if r['refine_moved'] is None else '{:.2f} / {:.1f}'.format(*r['refine_moved'])} |")
    objects = sorted({r["info"]["outfit_object"] for r in rows})
    lines += [
        "",
        f"- The outfit mesh object Blender made: {', '.join(objects)} (the glTF node \"outfit\" has animated"
        " morph weights, so the importer leaves an Empty of that name at the node and moves the skinned mesh to"
        " a new child of the armature). Scene frame_start after the factory reset:"
        f" {rows[0]['info']['scene_frame_start']}; the imported keys sit at Blender frames"
        f" {rows[0]['info']['fcurve_frames'][0]:g} .. {rows[0]['info']['fcurve_frames'][1]:g} of the active"
        " action, so glTF key t is Blender frame t.",
        "- \"key values changed at import\": the largest difference between the importer's keyframe values and"
        " the GLB's weights (0: nothing clamped at import). \"evaluated keys vs GLB\": the shape-key values"
        " Blender evaluated at each checked frame against the GLB's weights at that key, after the slider"
        " ranges were widened.",
        f"- Clamping probe (key psd_0 re-keyed to {probe['keyed']} at frames 5, 6): evaluated as"
        f" {probe['with_importer_slider']} with the importer's slider range {probe['importer_slider']}, as"
        f" {probe['with_slider_-10_10']} with -10 .. 10: Blender keeps the keyframe values and clamps when it"
        " evaluates, so the check widens every key's range (an engine user importing drape's GLB would have"
        " to as well, were a key outside [0, 1]).",
        f"- Pose-key values outside [0, 1] over all frames: {sum(r['info']['pose_key_values_outside_0_1'] for r in rows)}"
        f"; beyond Blender's +-10 slider limit: {sum(r['info']['pose_key_values_beyond_10'] for r in rows)}.",
        "",
        f"PC2: drape's PC2 answer equals its npz answer byte for byte in every case: "
        f"{all(r['pc2_equals_npz'] for r in rows)}; header start frame, sample rate: {rows[0]['pc2_header']}.",
        "",
    ]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--keep", action="store_true", help="keep build/blender/ (the GLB, PC2 and npz files)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "blender_check.md")
    ap.add_argument("--dir", type=Path, default=ROOT / "build" / "blender")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds for the Blender subprocess")
    args = ap.parse_args()
    t0 = time.perf_counter()
    if args.dir.exists():
        shutil.rmtree(args.dir)
    cases = write_answers(args.dir)
    print(run_blender(args.dir, args.timeout), end="", flush=True)
    rows = compare(args.dir, cases)
    probe = json.loads((args.dir / "clamp_probe.json").read_text())
    seconds = time.perf_counter() - t0
    command = ".venv/bin/python -m bench.blender_check" + (" --keep" if args.keep else "")
    if args.out.resolve() != (ROOT / "docs" / "blender_check.md").resolve():
        command += f" --out {args.out}"
    text = report(rows, seconds, command, probe)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(text)
    if not args.keep:
        shutil.rmtree(args.dir)
    failed = [r["name"] for r in rows if not passes(r)]
    if failed:
        print(f"FAILED the bars: {', '.join(failed)}", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
