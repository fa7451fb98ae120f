"""Compliant kinematics as unknowns of the implicit solve (issue #11, Loki supplement section 1):
what the compliant unknowns' own block-diagonal preconditioner block gains. The impossible-
collision scenes of graphs/bench/implicit_knee.py run with ``compliant_kinematics: energy`` and
each ``compliant_solve`` (``block``: the compliant unknowns solved apart by their diagonal
block, CG on the cloth; ``cg``: in CG with block-Jacobi, their blocks; ``cg_identity``: in CG
with the identity as their preconditioner block), interleaved frame by frame in one process.

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_compliant.py pinch [frames] \
        [modes=block,cg,cg_identity] [k=v ...]

Per mode: Newton iterations, CG iterations, CG per Newton iteration, the largest CG count of
one solve, CPU per frame [ms] (time.process_time, the frame's step), the
largest cloth speed from frame 5 [m/s], the most intersecting cloth-body pairs of a frame and
the worst relative CG residual.

Measured (60 frames each, the shared 2-core machine; compliant_kinematics: energy):

    pinch         Newton      CG  CG/Newton  max CG  ms/frame  vmax fr5+  pen  max res
    block           1171   22504       19.2      91       197      0.001    0   1.0e-03
    cg              1143   22483       19.7      64       191      0.001    0   1.0e-03
    cg_identity     1137  222724      195.9     500       271      0.000    0   3.1e-01
    sleeve_pinch
    block           4529 1522806      336.2     500      1266      0.140    0   4.3e-02
    cg              4477 1440383      321.7     500      1233      0.140    0   4.3e-02
    cg_identity     4518 1620014      358.6     500      1311      0.115    0   2.6e-01

Without a preconditioner block of their own the compliant lid's unknowns (goal spring K of a
few N/m beside contact blocks of 1e4 m / h^2) cost the pinch ~10x the CG iterations; in the
sleeve pinch the cloth's own CG (at its cap in most iterations) dominates (+6 %). Solving them
apart (block) or in CG with their block (cg) costs the same at these sizes.
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from lokigraph.api import compile_file
from lokigraph.behaviors.collision.intersect import intersect_meshes
from lokigraph.run import Simulation

sys.path.insert(0, str(Path(__file__).resolve().parent))
from implicit_knee import EX, SCENES, scene_text  # noqa: E402
from implicit_precond import step_counted  # noqa: E402


def _sim(name, overrides, tmp):
    yaml, maps, cloth, bodies, nf = SCENES[name]
    for m in maps:
        shutil.copy(EX / m, tmp / m)
    p = tmp / f"{name}_{abs(hash(str(overrides)))}.yaml"
    p.write_text(scene_text(name, overrides))
    c = compile_file(p)
    return c, Simulation(c)


def main(argv):
    name = argv[0] if argv else "pinch"
    args = argv[1:]
    frames = int(args.pop(0)) if args and args[0].isdigit() else None
    ov = dict(a.split("=", 1) for a in args)
    modes = ov.pop("modes", "block,cg,cg_identity").split(",")
    yaml, maps, cloth_name, bodies, nf = SCENES[name]
    frames = nf if frames is None else frames
    tmp = Path(tempfile.mkdtemp())
    runs = {}
    for mode in modes:
        o = {"compliant_kinematics": "energy", "compliant_solve": mode, **ov}
        runs[mode] = _sim(name, o, tmp)
    acc = {m: {"newton": 0, "cg": 0, "cg_max": 0, "cpu": 0.0, "res": 0.0,
               "vmax": [], "pen": []} for m in modes}
    for f in range(frames):
        for mode, (c, sim) in runs.items():
            r = acc[mode]
            step_counted(sim, r)
            q, v = sim.state.particle_q, sim.state.particle_qd
            cl = c.scene.element(cloth_name)
            r["vmax"].append(float(np.linalg.norm(v[cl.vertex_slice], axis=1).max()))
            cmesh = (q[cl.vertex_slice], cl.geometry.triangles)
            pen = 0
            for b in bodies:
                e = c.scene.element(b)
                _, pairs = intersect_meshes([cmesh, (q[e.vertex_slice], e.geometry.triangles)],
                                            touching=False)
                pen += int((pairs[:, 0] != pairs[:, 2]).sum())
            r["pen"].append(pen)
        print(f"  frame {f + 2}: " + "  ".join(
            f"{m} cg {acc[m]['cg']} v {acc[m]['vmax'][-1]:.3f} pen {acc[m]['pen'][-1]}"
            for m in modes), flush=True)
    print(f"{name}, {frames} frames, compliant_kinematics: energy {ov or ''}")
    print(f"{'compliant_solve':16} {'Newton':>7} {'CG':>8} {'CG/Newton':>10} {'max CG':>7} "
          f"{'ms/frame CPU':>13} {'vmax fr5+':>10} {'max pen':>8} {'max res':>9}")
    for m in modes:
        r = acc[m]
        print(f"{m:16} {r['newton']:7.0f} {r['cg']:8.0f} {r['cg'] / max(r['newton'], 1):10.1f} "
              f"{r['cg_max']:7.0f} {1e3 * r['cpu'] / frames:13.0f} "
              f"{max(r['vmax'][3:] or [0.0]):10.3f} {max(r['pen']):8d} {r['res']:9.1e}")


if __name__ == "__main__":
    main(sys.argv[1:])
