"""Is each shipped layer network still better than DeePSD? The layer networks were chosen over DeePSD's served
rig on their validation splits when they were trained (the manifest's `served`, `validation` and
`deepsd_validation`); a new DeePSD changes one side of that comparison. This re-measures DeePSD's served rig
(the model shipped now) on each network's validation split, by the same code and rule as at training time, and
prints both scores and what the rule would serve.

- inner networks (drape/assets/models/mgn_inner/<template>): score = inside % (closest triangle) + edge error mm
  on the validation split of drape.training.layers_inner (lower wins); the network's, or its refit rig's where
  that serves (the manifest's `collision_fit`, drape.training.layers_inner_fit);
- outer networks (drape/assets/models/mgn_outer/<pair>): RMSE mm to the simulated outer layer on the dataset's
  validation sequences, plus layers_outer.PENALTY where the config's collision caps (on those sequences, or on
  its real validation clips) are exceeded (drape.training.layers_outer; needs `make layers-data`'s sequences
  under data/layers).

Run: .venv/bin/python -m bench.layers_choice  (a few minutes on the 2-core machine)
"""

from __future__ import annotations

import json
from pathlib import Path

from drape.runtime.deepsd import MODEL_DIR as DEEPSD_DIR
from drape.training import layers_inner, layers_outer

ASSETS = DEEPSD_DIR.parent


def main() -> None:
    deepsd = json.loads((DEEPSD_DIR / "manifest.json").read_text())["version"]
    print(f"DeePSD shipped now: {deepsd}")
    print(f"{'network':28} {'score: network':>15} {'DeePSD then':>12} {'DeePSD now':>11}  served then -> by the rule now")
    for folder in sorted((ASSETS / "mgn_inner").iterdir()):
        m = json.loads((folder / "manifest.json").read_text())
        cfg = m["config"]
        vertices, faces = layers_inner.template(cfg)
        now = layers_inner.deepsd_validation(cfg, vertices, faces)
        fit = m.get("collision_fit", {})  # the rig that serves: refit out of the body where that measured better
        ours = (fit["validation_fitted"] if fit.get("served") == "fitted" else m["validation"])["score"]
        then = m["deepsd_validation"]["score"]
        rule = "mgn_inner" if ours < now["score"] else "deepsd"
        print(f"{'mgn_inner/' + folder.name:28} {ours:15.2f} {then:12.2f} {now['score']:11.2f}  {m['served']} -> {rule}"
              f"  (DeePSD now: {now['inside_triangle_pct']:.2f}% inside, {now['edge_error_mm']:.2f} mm)")
    for folder in sorted((ASSETS / "mgn_outer").iterdir()):
        m = json.loads((folder / "manifest.json").read_text())
        if not (Path(m["config"]["data"]) / "manifest.json").exists():
            print(f"{'mgn_outer/' + folder.name:28} skipped: its simulated sequences ({m['config']['data']}) are "
                  f"not here (make layers-data)")
            continue
        task = layers_outer.OuterTask(m["config"])
        seqs = task.sequences("test")
        # with the real validation clips and their caps, as training measured both sides (layers_outer.train)
        now = layers_outer.deepsd_validation(task, seqs, layers_outer.validation_clips(task))
        ours, then = m["validation"]["score"], m["deepsd_validation"]["score"]
        rule = "mgn_outer" if ours < now["score"] else "deepsd"
        print(f"{'mgn_outer/' + folder.name:28} {ours:15.2f} {then:12.2f} {now['score']:11.2f}  {m['served']} -> {rule}"
              f"  (DeePSD now: RMSE {now['rmse_mm']:.1f} mm, L-Coll {now['l_coll_pct']:.2f}%, STED {now['sted']:.3f};"
              f" {len(seqs)} sequences)")


if __name__ == "__main__":
    main()
