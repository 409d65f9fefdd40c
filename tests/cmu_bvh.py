"""A CMU-named BVH made in the tests: CMU's hierarchy and offsets (zero-length segments included), smooth
random joint angles (ZYX channels); shared by the importer's and the upload route's tests."""

import numpy as np

CMU = [
    ("Hips", None, (0, 0, 0)), ("LHipJoint", "Hips", (0, 0, 0)), ("LeftUpLeg", "LHipJoint", (1.645, -1.709, 0.846)),
    ("LeftLeg", "LeftUpLeg", (2.250, -6.181, 0)), ("LeftFoot", "LeftLeg", (2.718, -7.467, 0)),
    ("LeftToeBase", "LeftFoot", (0.188, -0.516, 2.247)), ("RHipJoint", "Hips", (0, 0, 0)),
    ("RightUpLeg", "RHipJoint", (-1.588, -1.709, 0.846)), ("RightLeg", "RightUpLeg", (-2.250, -6.182, 0)),
    ("RightFoot", "RightLeg", (-2.728, -7.496, 0)), ("RightToeBase", "RightFoot", (-0.215, -0.592, 2.106)),
    ("LowerBack", "Hips", (0, 0, 0)), ("Spine", "LowerBack", (0.031, 2.105, -0.110)),
    ("Spine1", "Spine", (-0.019, 2.109, -0.070)), ("Neck", "Spine1", (0, 0, 0)), ("Neck1", "Neck", (-0.023, 1.732, 0.005)),
    ("Head", "Neck1", (-0.058, 1.547, -0.617)), ("LeftShoulder", "Spine1", (0, 0, 0)),
    ("LeftArm", "LeftShoulder", (3.449, 0.503, 0.219)), ("LeftForeArm", "LeftArm", (5.419, 0, 0)),
    ("LeftHand", "LeftForeArm", (2.444, 0, 0)), ("LeftFingerBase", "LeftHand", (0, 0, 0)),
    ("LeftHandIndex1", "LeftFingerBase", (0.728, 0, 0)), ("LThumb", "LeftHand", (0, 0, 0)),
    ("RightShoulder", "Spine1", (0, 0, 0)), ("RightArm", "RightShoulder", (-3.230, 0.558, 0.311)),
    ("RightForeArm", "RightArm", (-5.590, 0, 0)), ("RightHand", "RightForeArm", (-2.481, 0, 0)),
    ("RightFingerBase", "RightHand", (0, 0, 0)), ("RightHandIndex1", "RightFingerBase", (-0.816, 0, 0)),
    ("RThumb", "RightHand", (0, 0, 0)),
]
TPOSE = {"LeftUpLeg": -21.0, "RightUpLeg": 21.0, "LeftArm": -16.0, "RightArm": 11.0}  # Z degrees, as cgspeed's


def cmu_bvh(frames: int = 40, fps: float = 120.0, tpose: bool = False, seed: int = 0,
            rename: dict[str, str] | None = None) -> bytes:
    """A BVH with CMU's names, hierarchy and offsets, smooth random joint angles (ZYX channels)."""
    kids: dict[str | None, list[str]] = {}
    for name, parent, _ in CMU:
        kids.setdefault(parent, []).append(name)
    offset = {name: off for name, _, off in CMU}
    lines = ["HIERARCHY"]

    def emit(name: str, depth: int) -> None:
        pad = "\t" * depth
        shown = (rename or {}).get(name, name)
        lines.append(f"{pad}{'ROOT' if depth == 0 else 'JOINT'} {shown}\n{pad}{{")
        lines.append(f"{pad}\tOFFSET {' '.join(f'{v:.5f}' for v in offset[name])}")
        pos = "Xposition Yposition Zposition " if depth == 0 else ""
        lines.append(f"{pad}\tCHANNELS {6 if depth == 0 else 3} {pos}Zrotation Yrotation Xrotation")
        for k in kids.get(name, []):
            emit(k, depth + 1)
        if name not in kids:
            lines.append(f"{pad}\tEnd Site\n{pad}\t{{\n{pad}\t\tOFFSET 0.5 0.5 0.5\n{pad}\t}}")
        lines.append(pad + "}")

    emit("Hips", 0)
    order = [n for n, _, _ in CMU]
    rng = np.random.default_rng(seed)
    amp, phase = rng.uniform(2, 15, (len(order), 3)), rng.uniform(0, 6, (len(order), 3))
    lines += ["MOTION", f"Frames: {frames}", f"Frame Time: {1 / fps:.7f}"]
    for t in range(frames):
        if tpose and t == 0:
            vals = [1.0, 17.0, -30.0] + [v for n in order for v in (TPOSE.get(n, 0.0), 0.0, 0.0)]
            lines.append(" ".join(f"{v:g}" for v in vals))
            continue
        ang = amp * np.sin(2 * np.pi * 0.7 * t / fps + phase)
        vals = [1.0 + 0.01 * t, 17.0, -30.0 + 0.02 * t] + list(ang.ravel())
        lines.append(" ".join(f"{v:.5f}" for v in vals))
    return ("\n".join(lines) + "\n").encode()
