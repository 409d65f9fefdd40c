"""Simulated datasets: one compressed npz per (garment, parameter set, motion), plus a manifest.

Layout of a dataset directory:

    manifest.json                     what was asked, the splits, per-item quality stats
    items/<garment>__p<NN>__<motion>.npz       accepted sequences
    rejected/<garment>__p<NN>__<motion>.json   sequences that failed the quality gate, with the reasons

Item npz arrays: vertices (T, N, 3) float32 m (same frame as the body),
faces (F, 3) int32, poses (T, 24, 3) float32 rad, trans (T, 3) float32 m,
fps (), params (JSON string), stats (JSON string), garment / body / motion names.

Two-layer datasets (a garment given as inner + outer meshes, drape.sim.layers): instead of vertices and
faces, inner_vertices (T, Ni, 3), inner_faces (Fi, 3), outer_vertices (T, No, 3), outer_faces (Fo, 3), plus
inner_thickness () float32 m (also in params, a LayerParams JSON) and inner_garment / outer_garment names;
the garment name is "<inner>+<outer>"; stats are `quality.layer_stats` and the gate a `quality.LayerGate`.

Splits follow Wang et al. 2019: a share of the parameter sets and of the motions
is held out, and no parameter set or motion is shared between `train` and
`test`. The mixed items are kept as `test_motions` (seen parameters, unseen
motions) and `test_params` (unseen parameters, seen motions).

Resumable: an item is finished when its npz (or its rejection note) exists; a
rerun skips finished items. The manifest is rewritten after every item, so a dataset still being
simulated can already be read. Files are written to
a temporary name and renamed, so a killed run never leaves a half-written item. A sequence whose simulation raises is
reported and skipped (nothing written, so a rerun retries it) while the others go on; the run then ends
with an error naming it.
Items run in a local process pool, or as Ray tasks on an existing cluster
(`ray_address`); either way the driver writes the files, so both paths produce
the same bytes for the same inputs.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Generator, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drape.assets.body import load_body
from drape.assets.motion import Motion
from drape.sim.params import LayerParams, SimParams
from drape.sim.quality import LayerGate, QualityGate


@dataclass(frozen=True)
class Item:
    """One sequence to simulate: garment rest mesh (N, 3) m + faces (F, 3), a parameter set, a motion."""

    key: str
    garment: str
    vertices: np.ndarray
    faces: np.ndarray
    body: str
    params_index: int
    params: SimParams
    motion: Motion
    frames: int
    outer_vertices: np.ndarray | None = None  # two layers: `vertices`/`faces` are the inner garment's
    outer_faces: np.ndarray | None = None


def item_key(garment: str, params_index: int, motion: str) -> str:
    return f"{garment}__p{params_index:02d}__{motion}"


def run_item(item: Item) -> dict:
    """Simulate one item (in a worker): the arrays and stats to write. Pure function of the item."""
    if item.outer_vertices is not None:
        from drape.sim.layers import simulate_layers

        assert item.outer_faces is not None and isinstance(item.params, LayerParams)
        lr = simulate_layers(item.vertices, item.faces, item.outer_vertices, item.outer_faces, load_body(item.body),
                             item.motion, item.params, frames=item.frames)
        return {"key": item.key, "inner_vertices": lr.inner_vertices, "outer_vertices": lr.outer_vertices,
                "poses": lr.poses, "trans": lr.trans, "stats": lr.stats}
    from drape.sim.simulate import simulate

    r = simulate(item.vertices, item.faces, load_body(item.body), item.motion, item.params, frames=item.frames)
    return {
        "key": item.key,
        "vertices": r.vertices,
        "poses": r.poses,
        "trans": r.trans,
        "stats": r.stats,
    }


def save_sequence(
    path: str | Path, *, vertices: np.ndarray, faces: np.ndarray, poses: np.ndarray, trans: np.ndarray,
    fps: float, params: SimParams, stats: dict, garment: str, body: str, motion: str,
) -> Path:
    """Write one simulated sequence (the item npz layout above) atomically: temporary file, then rename."""
    return _save_npz(
        path,
        vertices=np.asarray(vertices, dtype=np.float32),
        faces=np.asarray(faces, dtype=np.int32),
        **_common(poses, trans, fps, params, stats, garment, body, motion),
    )


def save_layer_sequence(
    path: str | Path, *, inner_vertices: np.ndarray, inner_faces: np.ndarray, outer_vertices: np.ndarray,
    outer_faces: np.ndarray, poses: np.ndarray, trans: np.ndarray, fps: float, params: LayerParams, stats: dict,
    inner_garment: str, outer_garment: str, body: str, motion: str,
) -> Path:
    """Write one two-layer sequence (the two-layer item layout above) atomically."""
    return _save_npz(
        path,
        inner_vertices=np.asarray(inner_vertices, dtype=np.float32),
        inner_faces=np.asarray(inner_faces, dtype=np.int32),
        outer_vertices=np.asarray(outer_vertices, dtype=np.float32),
        outer_faces=np.asarray(outer_faces, dtype=np.int32),
        inner_thickness=np.array(params.inner_thickness, dtype=np.float32),
        inner_garment=np.array(inner_garment),
        outer_garment=np.array(outer_garment),
        **_common(poses, trans, fps, params, stats, f"{inner_garment}+{outer_garment}", body, motion),
    )


def _common(poses: np.ndarray, trans: np.ndarray, fps: float, params: SimParams, stats: dict, garment: str,
            body: str, motion: str) -> dict[str, np.ndarray]:
    return {
        "poses": np.asarray(poses, dtype=np.float32),
        "trans": np.asarray(trans, dtype=np.float32),
        "fps": np.array(fps, dtype=np.float32),
        "params": np.array(params.to_json()),
        "stats": np.array(json.dumps(stats, sort_keys=True)),
        "garment": np.array(garment),
        "body": np.array(body),
        "motion": np.array(motion),
    }


def _save_npz(path: str | Path, **arrays: Any) -> Path:
    """np.savez_compressed to a temporary name, then rename: a killed run leaves no half-written file."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)
    return path


def write_item(path: Path, item: Item, result: dict) -> None:
    """Write one accepted item (its stats without the wall-clock fields, so reruns write the same bytes)."""
    if item.outer_vertices is not None:
        assert item.outer_faces is not None and isinstance(item.params, LayerParams)
        inner_name, outer_name = item.garment.split("+", 1)
        save_layer_sequence(path, inner_vertices=result["inner_vertices"], inner_faces=item.faces,
                            outer_vertices=result["outer_vertices"], outer_faces=item.outer_faces,
                            poses=result["poses"], trans=result["trans"], fps=item.motion.fps, params=item.params,
                            stats=_stable_stats(result["stats"]), inner_garment=inner_name,
                            outer_garment=outer_name, body=item.body, motion=item.motion.name)
        return
    save_sequence(path, vertices=result["vertices"], faces=item.faces, poses=result["poses"],
                  trans=result["trans"], fps=item.motion.fps, params=item.params,
                  stats=_stable_stats(result["stats"]), garment=item.garment, body=item.body,
                  motion=item.motion.name)


def _stable_stats(stats: dict) -> dict:
    """Stats without the wall-clock fields (those differ run to run; they go to the manifest only)."""
    return {k: v for k, v in stats.items() if k not in ("seconds", "seconds_per_frame")}


def _write_json(path: Path, payload: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2, sort_keys=True))
    os.replace(tmp, path)


def splits(n_params: int, motions: list[str], holdout_params: int, holdout_motions: int) -> dict:
    """Held-out parameter indices and motions: the last `holdout_*` of each list."""
    if not 0 < holdout_params < n_params:
        raise ValueError(f"holdout_params must be in [1, {n_params - 1}], got {holdout_params}")
    if not 0 < holdout_motions < len(motions):
        raise ValueError(f"holdout_motions must be in [1, {len(motions) - 1}], got {holdout_motions}")
    return {
        "train_params": list(range(n_params - holdout_params)),
        "test_params": list(range(n_params - holdout_params, n_params)),
        "train_motions": motions[: len(motions) - holdout_motions],
        "test_motions": motions[len(motions) - holdout_motions:],
    }


def split_of(params_index: int, motion: str, s: dict) -> str:
    p_test = params_index in s["test_params"]
    m_test = motion in s["test_motions"]
    return {(False, False): "train", (True, True): "test", (False, True): "test_motions",
            (True, False): "test_params"}[(p_test, m_test)]


def _failed(key: str, exc: Exception) -> dict:
    """What a results iterator yields for an item whose simulation raised: nothing is written for it (a rerun
    retries it), and the other items go on."""
    return {"key": key, "error": f"{type(exc).__name__}: {exc}"}


def _local_results(todo: list[Item], workers: int) -> Generator[dict, None, None]:
    if workers <= 1:
        for it in todo:
            try:
                res = run_item(it)
            except Exception as exc:  # noqa: BLE001 - one failed sequence must not stop the others
                res = _failed(it.key, exc)
            yield res
        return
    import multiprocessing as mp

    with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as pool:
        futures = {pool.submit(run_item, it): it.key for it in todo}
        try:
            for fut in as_completed(futures):
                try:
                    res = fut.result()
                except Exception as exc:  # noqa: BLE001
                    res = _failed(futures[fut], exc)
                yield res
        finally:
            # stopped early (an interrupt, a driver error): leaving the pool would otherwise first simulate every
            # queued item, whose results nobody writes
            for fut in futures:
                fut.cancel()


def _ray_results(todo: list[Item], address: str) -> Generator[dict, None, None]:
    try:
        import ray
    except ImportError as exc:  # the optional extra
        raise RuntimeError("--ray needs the cluster extra: pip install 'drape[cluster]'") from exc
    if not ray.is_initialized():
        ray.init(address=address, log_to_driver=False)
    remote = ray.remote(num_cpus=1)(run_item)
    keys = {remote.remote(it): it.key for it in todo}
    pending = list(keys)
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            try:
                res = ray.get(done[0])
            except Exception as exc:  # noqa: BLE001 - a task error: the others go on
                res = _failed(keys[done[0]], exc)
            yield res
    finally:
        for ref in pending:
            ray.cancel(ref)


def build_dataset(
    out: str | Path,
    garments: Mapping[str, tuple[np.ndarray, ...]],
    params: Sequence[SimParams],
    motions: list[Motion],
    frames: int,
    body: str = "neutral",
    holdout_params: int = 2,
    holdout_motions: int = 1,
    gate: QualityGate | None = None,
    workers: int | None = None,
    ray_address: str | None = None,
    progress: bool = True,
    only_splits: tuple[str, ...] | None = None,
    only_params: Sequence[int] | None = None,
) -> dict:
    """Simulate every (garment, parameter set, motion) not yet finished under `out`; return the manifest.

    garments: name -> (rest vertices (N, 3) m on `body`, faces (F, 3)); or, for two layers, "inner+outer" ->
    (inner vertices, inner faces, outer vertices, outer faces) with `LayerParams` (the default gate is then a
    `LayerGate`). only_splits: simulate only the items of these splits ("train", "test", "test_params",
    "test_motions"), e.g. ("test",) for a set of long held-out sequences that shares the parameter sampler
    (same --params and --seed) with a dataset. only_params: simulate only the items of these parameter-set indices
    (e.g. a training config's validation sets, to measure a model on them before the rest is simulated).
    """
    layered = _check_layered(garments, params)
    if frames < 1:
        raise ValueError(f"frames must be at least 1, got {frames}")
    for m in motions:
        if m.num_frames < frames:
            raise ValueError(f"motion {m.name!r} has {m.num_frames} frames, fewer than frames={frames}")
    names = [m.name for m in motions]
    if len(set(names)) != len(names):
        raise ValueError("motion names must be unique")
    s = splits(len(params), names, holdout_params, holdout_motions)
    out = Path(out)  # made once the request is known to be whole: a refused one leaves no folder behind
    (out / "items").mkdir(parents=True, exist_ok=True)
    (out / "rejected").mkdir(exist_ok=True)
    gate = gate or (LayerGate() if layered else QualityGate())
    items = [
        Item(item_key(g, i, m.name), g, np.asarray(mesh[0], np.float32), np.asarray(mesh[1], np.int32), body, i, p,
             m, frames, *((np.asarray(mesh[2], np.float32), np.asarray(mesh[3], np.int32)) if layered else ()))
        for g, mesh in garments.items() for i, p in enumerate(params) for m in motions
    ]
    grid = items  # the manifest lists every finished item of the whole grid, whichever splits this run simulates
    if only_splits is not None:
        items = [it for it in items if split_of(it.params_index, it.motion.name, s) in only_splits]
    if only_params is not None:
        wanted = set(only_params)
        unknown = sorted(wanted - set(range(len(params))))
        if unknown:
            raise ValueError(f"only_params {unknown} are not among the {len(params)} parameter sets")
        items = [it for it in items if it.params_index in wanted]
    by_key = {it.key: it for it in items}

    def finished(it: Item) -> bool:
        return (out / "items" / f"{it.key}.npz").exists() or (out / "rejected" / f"{it.key}.json").exists()

    _check_resumed(out, grid, frames)

    # train items first, so that a dataset stopped part-way (it resumes) can already be trained on, then
    # the test items (held-out parameters x held-out motions: the evaluation's), then the partly held out
    # within a split, in diagonals of the parameter x motion grid, so that a part-way dataset already has every
    # parameter set and every motion about equally often
    order = {"train": 0, "test": 1, "test_params": 2, "test_motions": 3}
    motion_index = {n: i for i, n in enumerate(names)}
    todo = sorted((it for it in items if not finished(it)),
                  key=lambda it: (order[split_of(it.params_index, it.motion.name, s)],
                                  (motion_index[it.motion.name] - it.params_index) % len(names), it.params_index))
    timings = _load_timings(out)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(items), initial=len(items) - len(todo), desc="sequences", unit="seq")
    t0 = time.perf_counter()
    results = _ray_results(todo, ray_address) if ray_address else _local_results(todo, workers or os.cpu_count() or 1)
    failed: dict[str, str] = {}
    try:
        for res in results:
            it = by_key[res["key"]]
            if "error" in res:
                failed[it.key] = res["error"]
                print(f"failed {it.key}: {res['error']}")
                if bar is not None:
                    bar.update(1)
                continue
            timings[it.key] = {"seconds": res["stats"]["seconds"], "seconds_per_frame": res["stats"]["seconds_per_frame"]}
            reasons = gate.failures(res["stats"])
            if reasons:
                # the sequence is kept beside its reasons: a use that does not need the failed check may take it
                # (e.g. an outer-layer network, which never reads the simulated inner layer)
                write_item(out / "rejected" / f"{it.key}.npz", it, res)
                _write_json(out / "rejected" / f"{it.key}.json", {"reasons": reasons, "stats": _stable_stats(res["stats"])})
                print(f"rejected {it.key}: {'; '.join(reasons)}")
            else:
                write_item(out / "items" / f"{it.key}.npz", it, res)
            _write_json(out / "timings.json", timings)
            # the manifest after every item: a dataset still being simulated can be trained on
            _write_json(out / "manifest.json", _manifest(out, grid, params, s, gate, frames, body, garments, timings))
            if bar is not None:
                bar.update(1)
    finally:
        results.close()  # an early stop cancels the queued items (see _local_results)
    if bar is not None:
        bar.close()
    manifest = _manifest(out, grid, params, s, gate, frames, body, garments, timings)
    manifest["last_run"] = {"simulated": len(todo), "seconds": round(time.perf_counter() - t0, 1)}
    _write_json(out / "manifest.json", manifest)
    if failed:
        raise RuntimeError(f"{len(failed)} of {len(todo)} sequences failed to simulate (nothing written for them; "
                           "a rerun retries them): " + "; ".join(f"{k}: {e}" for k, e in sorted(failed.items())))
    return manifest


def _check_layered(garments: Mapping[str, tuple[np.ndarray, ...]], params: Sequence[SimParams]) -> bool:
    """True for a two-layer dataset (every garment four arrays, named inner+outer, LayerParams); else single."""
    sizes = {len(mesh) for mesh in garments.values()}
    if sizes not in ({2}, {4}):
        raise ValueError("garments must all be (vertices, faces) or all (inner v, inner f, outer v, outer f)")
    if sizes == {2}:
        return False
    for g in garments:
        if "+" not in g:
            raise ValueError(f"a two-layer garment is named 'inner+outer', got {g!r}")
    if not all(isinstance(p, LayerParams) for p in params):
        raise ValueError("two-layer garments need LayerParams (drape.sim.params.sample_layer_params)")
    return True


def _check_resumed(out: Path, grid: list[Item], frames: int) -> None:
    """Raise when a finished item under `out` was simulated with another parameter set or frame count than the
    same key asks for now (a rerun with another --params/--seed/--substeps/--thickness/--frames): resuming would
    silently mix two datasets under one manifest, whose `params` then misdescribe the older items."""
    for it in grid:
        for path in (out / "items" / f"{it.key}.npz", out / "rejected" / f"{it.key}.npz"):
            if not path.exists():
                continue
            with np.load(path, allow_pickle=False) as z:
                stored, length = str(z["params"]), len(z["poses"])
            try:  # through the model, so that a field added later with its default still matches
                same = type(it.params).model_validate_json(stored) == it.params
            except ValueError:
                same = False
            if not same or length != frames:
                raise ValueError(f"{path} was simulated with other parameters or frames than this run asks for "
                                 f"(parameter set {it.params_index}, {frames} frames); a dataset resumes only with "
                                 "the command that started it: use another --out for other settings")


def _load_timings(out: Path) -> dict:
    p = out / "timings.json"
    return json.loads(p.read_text()) if p.exists() else {}


def _manifest(out: Path, items: list[Item], params: Sequence[SimParams], s: dict, gate: QualityGate,
              frames: int, body: str, garments: Mapping[str, tuple[np.ndarray, ...]], timings: dict) -> dict:
    entries, rejected = [], []
    for it in items:
        npz = out / "items" / f"{it.key}.npz"
        rej = out / "rejected" / f"{it.key}.json"
        if npz.exists():
            with np.load(npz, allow_pickle=False) as z:
                stats = json.loads(str(z["stats"]))
            entries.append({"key": it.key, "file": f"items/{it.key}.npz", "garment": it.garment,
                            "params": it.params_index, "motion": it.motion.name,
                            "split": split_of(it.params_index, it.motion.name, s), "stats": stats,
                            **timings.get(it.key, {})})
        elif rej.exists():
            kept = out / "rejected" / f"{it.key}.npz"
            rejected.append({"key": it.key, "params": it.params_index, "motion": it.motion.name,
                             "split": split_of(it.params_index, it.motion.name, s),
                             **({"file": f"rejected/{it.key}.npz"} if kept.exists() else {}),
                             **json.loads(rej.read_text())})
    return {
        "format": "drape-sim-dataset/1",
        "body": body,
        "frames": frames,
        "garments": {g: _mesh_sizes(mesh) for g, mesh in garments.items()},
        "layers": any(len(mesh) == 4 for mesh in garments.values()),
        "params": [p.model_dump() for p in params],
        "motions": list(dict.fromkeys(it.motion.name for it in items)),
        "splits": s,
        "gate": gate.model_dump(),
        "items": entries,
        "rejected": rejected,
        "summary": summarize(entries),
    }


def _mesh_sizes(mesh: tuple[np.ndarray, ...]) -> dict:
    if len(mesh) == 4:
        return {"inner_vertices": int(len(mesh[0])), "inner_faces": int(len(mesh[1])),
                "outer_vertices": int(len(mesh[2])), "outer_faces": int(len(mesh[3]))}
    return {"vertices": int(len(mesh[0])), "faces": int(len(mesh[1]))}


SUMMARY_KEYS = ("penetration_p99_m", "penetration_max_m", "strain_mean", "strain_p99", "strain_max")
LAYER_SUMMARY_KEYS = (*(f"{p}_{k}" for p in ("inner", "outer") for k in SUMMARY_KEYS),
                      "outer_in_inner_share", "outer_in_inner_p99_m", "outer_in_inner_max_m", "outer_inner_gap_p10_m")


def summarize(entries: list[dict]) -> dict:
    """Dataset-level quality: penetration and strain percentiles over the accepted items (per layer, plus
    outer-through-inner, for two-layer items)."""
    if not entries:
        return {"items": 0}
    st = [e["stats"] for e in entries]

    def pct(key: str) -> dict:
        vals = np.array([x[key] for x in st])
        return {"min": float(vals.min()), "median": float(np.median(vals)), "max": float(vals.max())}

    spf = [e["seconds_per_frame"] for e in entries if "seconds_per_frame" in e]
    keys = LAYER_SUMMARY_KEYS if "inner_vertices" in st[0] else SUMMARY_KEYS
    return {"items": len(entries), **{k: pct(k) for k in keys},
            "seconds_per_frame_median": float(np.median(spf)) if spf else None}
