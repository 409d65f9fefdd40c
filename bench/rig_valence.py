"""Peak memory and time of one rig request whose mesh has a vertex of high valence (a fan, an n-gon line).

The rig network's neighbour table is as wide as its widest row, capped at drape.runtime.deepsd.MAX_NEIGHBOURS
(16) since 2026-12-03; before, one 120-gon line in a 1,000-vertex OBJ took a rig from 0.5 to 3.7 GB. Each case
runs in a fresh process (the shipped models, the service in-process through TestClient, an npz body) so that
its peak RSS is its own: a 1,000-vertex t-shirt as generated (the baseline), then with a fan of K triangles
around vertex 0 (K = 120, 500). Printed: peak RSS over the process before the request, seconds, and both as
ratios to the baseline measured in the same run.

Run: PYTHONPATH=. .venv/bin/python -m bench.rig_valence   (about a minute on 2 cores)
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import time

import numpy as np

FANS = (0, 120, 500)


def one(fan: int) -> dict:
    """Rig the t-shirt with a fan of `fan` triangles (0: none) -> {"status", "seconds", "mb"} (peak RSS added)."""
    from fastapi.testclient import TestClient

    from drape.assets.outfits import generate_outfit
    from drape.schemas.binary import encode_npz
    from drape.service.app import create_app

    o = generate_outfit("tshirt", vertices=1000, seed=1)
    faces = o.faces
    if fan:
        faces = np.vstack([faces, np.stack([np.zeros(fan, int), np.arange(1, fan + 1), np.arange(2, fan + 2)], 1)])
    body = encode_npz({"vertices": o.vertices, "faces": faces.astype(np.int32)})
    with TestClient(create_app()) as client:
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        t = time.perf_counter()
        r = client.post("/v1/outfits/rig", content=body,
                        headers={"Content-Type": "application/x-npz", "Accept": "application/x-npz"})
        seconds = time.perf_counter() - t
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {"status": r.status_code, "seconds": seconds, "mb": peak - before}


def main() -> None:
    if len(sys.argv) > 1:  # a child: one case
        print(json.dumps(one(int(sys.argv[1]))))
        return
    rows = {}
    for fan in FANS:
        out = subprocess.run([sys.executable, "-m", "bench.rig_valence", str(fan)], capture_output=True, text=True,
                             check=True)
        rows[fan] = json.loads(out.stdout.strip().splitlines()[-1])
    base = rows[0]
    print("| mesh | status | peak RSS added, MB | x baseline | seconds | x baseline |\n| --- | --: | --: | --: | --: | --: |")
    for fan, r in rows.items():
        name = "t-shirt, 1,000 vertices (baseline)" if fan == 0 else f"the same + a fan of {fan} triangles"
        print(f"| {name} | {r['status']} | {r['mb']:.0f} | {r['mb'] / base['mb']:.1f} | {r['seconds']:.1f} | "
              f"{r['seconds'] / base['seconds']:.1f} |")


if __name__ == "__main__":
    main()
