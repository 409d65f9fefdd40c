"""How often the fit's up-axis inference reads a generated garment right, against the thinnest-axis rule it
replaced, in one run: every garment type and four layered outfits x seeds 8-15 x the four bodies, each as
generated (Y-up) and turned Z-up; a garment counts as read right when both copies are.

    PYTHONPATH=. .venv/bin/python -m bench.fit_up [--seeds 8-15] [--vertices 1200]

(Seeds 0-7 were the cases the rule's slice range and margin were chosen on; 8-15 were not looked at then.)
"""

from __future__ import annotations

import argparse

import numpy as np

from drape.assets.outfits import GARMENT_TYPES, generate_outfit
from drape.geometry.fitting import Z_UP_TO_Y_UP, infer_up

OUTFITS = (*GARMENT_TYPES, "tshirt,trousers", "tanktop,skirt", "tanktop,shorts", "longsleeve,long_skirt")
BODIES = ("neutral", "female", "male", "heavy")


def thinnest_axis_up(vertices: np.ndarray) -> str:
    """The rule before 2026-12-03: 'z' when the thinnest bounding-box axis is Y."""
    return "z" if int(np.argmin(np.ptp(vertices, axis=0))) == 1 else "y"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="8-15")
    parser.add_argument("--vertices", type=int, default=1200)
    args = parser.parse_args()
    first, last = (int(x) for x in args.seeds.split("-"))
    to_z_up = np.linalg.inv(Z_UP_TO_Y_UP).T
    wrong: dict[str, list[str]] = {"infer_up": [], "thinnest axis": []}
    count = 0
    for kind in OUTFITS:
        for seed in range(first, last + 1):
            for body in BODIES:
                v = generate_outfit(kind, vertices=args.vertices, seed=seed, body=body).vertices.astype(np.float64)
                count += 1
                for name, rule in (("infer_up", infer_up), ("thinnest axis", thinnest_axis_up)):
                    if (rule(v), rule(v @ to_z_up)) != ("y", "z"):
                        wrong[name].append(f"{kind}/{seed}/{body}")
    for name, cases in wrong.items():
        kinds = sorted({c.split("/")[0] for c in cases})
        print(f"{name}: {len(cases)} of {count} garments read wrong (as generated or Z-up){': ' if kinds else ''}"
              f"{', '.join(kinds)}")


if __name__ == "__main__":
    main()
