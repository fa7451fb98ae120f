"""compliant_shape_stiffness (issue #11): the four impossible-collision scenes against the
Nucleus tests' bounds, with compliant_kinematics: energy, compliant_depth 0.01 and the shape
stiffness s between neighbouring compliant unknowns (behaviors/solvers/implicit/compliant.py).

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_compliant_shape.py \
        sleeve_elbow,knee 0,10,100 [k=v ...]

Per (scene, s), scenes outer: the largest intersecting cloth-body pairs of any frame, the
bounded speed (knee: frames 37-48, bound 1.65; sleeve_elbow: within 0.15 m of the joint from
frame 4, bound 0.73; pinch, sleeve_pinch: from frame 5, bound 0.3), the overall speed (knee
from frame 8, bound 2.2; sleeve_elbow from frame 5, bound 1.47) and the CPU of the steps.
"""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from implicit_knee import run  # noqa: E402

BOUNDS = {"knee": (1.65, 2.2), "sleeve_elbow": (0.73, 1.47), "pinch": (0.3, None),
          "sleeve_pinch": (0.3, None)}


def measure(name, r):
    """(bounded speed, overall speed or None) as the Nucleus tests measure them."""
    vm = np.array(r["vmax"])  # vm[i] is frame i + 2
    if name == "knee":
        return float(vm[36:48].max()), float(vm[6:].max())
    if name == "sleeve_elbow":
        return float(np.max(r["vcrease"][3:])), float(vm[3:].max())
    return float(vm[3:].max()), None


if __name__ == "__main__":
    scenes = sys.argv[1].split(",") if len(sys.argv) > 1 else list(BOUNDS)
    ss = [float(s) for s in sys.argv[2].split(",")] if len(sys.argv) > 2 else [0.0, 100.0]
    ov = dict(a.split("=", 1) for a in sys.argv[3:])
    base = {"compliant_kinematics": "energy", "compliant_depth": "0.01", **ov}
    print("scene         s      pairs  bounded (bound)   overall (bound)  cpu s  s/frame")
    for name in scenes:
        for s in ss:
            o = dict(base, compliant_shape_stiffness=f"{s:g}")
            r = run(name, None, o)
            vb, vo = measure(name, r)
            b, bo = BOUNDS[name]
            ok = max(r["pen"]) == 0 and vb < b and (bo is None or vo < bo) and r["finite"]
            ostr = f"{vo:.3f} ({bo})" if vo is not None else "-"
            print(f"{name:12s} {s:6g} {max(r['pen']):6d}  {vb:.3f} ({b})    {ostr:16s} "
                  f"{r['cpu_s']:6.1f}  {r['cpu_s'] / len(r['vmax']):.2f}  "
                  f"{'pass' if ok else 'FAIL'}", flush=True)
