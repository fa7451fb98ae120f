"""Before/after table of the Newton-at-contact settings (issue #11), interleaved in one process:
every setting's simulation steps one frame in turn (the order rotated each frame, ABBA-like), so
that the shared machine's load falls on all of them alike.

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_newton_table.py drop 64 10
    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_newton_table.py elbow 60

Settings (implicit_solver overrides): ``base`` (the defaults), ``coupled`` (contact_hessian:
coupled), ``sticky`` (coupled + contact_sticky), ``irls`` (coupled + contact_sticky +
friction_hessian: irls); ``--only a,b`` picks some. Per setting: CPU and wall ms per frame
(mean over frames 2..), Newton and CG iterations per frame, line-search halvings per frame, the
worst edge strain [%], the most intersecting pairs in a frame (cloth self + cloth-body), and for
the elbow the largest cloth speed within 0.15 m of the joint from frame 4
(tests/test_elbow.py's crease bound 0.73 m/s) and Newton iterations per substep over the
frames at rest (50..). The strain column of the elbow reads the scene's first
StretchConstraint, which is not the sleeve's: ignore it there.

Measured (1 thread, the shared machine, wall 2-2.5x CPU; means over frames 2..; 0 intersecting
pairs in every frame of every run; Newton at its cap of 20 in every contact substep of the
drops with each setting):

    scene (frames)   setting  CPU ms/frame  Newton  CG/frame  halv.  strain %  near m/s  N/sub rest
    drop 64 (10)     base     1,555 (1.00)  11.6     3,597    23    4.45      -         -
                     coupled  1,487 (0.96)  11.6     3,327    18    3.05
                     sticky   1,464 (0.94)  11.6     3,137    11    2.10
                     irls     1,388 (0.89)  11.6     2,917    11    2.49
    drop 128 (10)    base     8,798 (1.00)  11.6     4,720    19    3.57
                     sticky   9,264 (1.05)  11.6     4,227    10    3.03
                     irls     9,631 (1.09)  11.6     4,187     8    2.80
    sleeve_elbow     base       937 (1.00)  80.0    15,533   125    -         0.897     20.0
    (60, 4 substeps) coupled    925 (0.99)  79.9    14,388   127              0.948     19.8
                     sticky     887 (0.95)  80.0    12,788    96              0.871     20.0
                     irls       801 (0.85)  77.4    11,249    16              0.783     16.5

(Newton: Newton iterations per frame; halv.: line-search halvings per frame; near: the
largest speed within 0.15 m of the joint, bound 0.73 m/s; N/sub rest: Newton iterations per
substep over frames 50-60.)

Since stop 36 the implicit solver's defaults put compliant kinematic vertices in the solve
(compliant_kinematics: energy, compliant_depth 0.01); the figures above for the defaults were
measured with compliant_kinematics: dirichlet (add compliant_kinematics=dirichlet to rerun them).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import implicit_newton as N  # noqa: E402

SETTINGS = {
    "base": {},
    "coupled": {"contact_hessian": "coupled"},
    "sticky": {"contact_hessian": "coupled", "contact_sticky": "true"},
    "irls": {"contact_hessian": "coupled", "contact_sticky": "true",
             "friction_hessian": "irls"},
}


def main(argv):
    kind = argv.pop(0)
    n = int(argv.pop(0)) if kind == "drop" else 0
    frames = int(argv.pop(0))
    names = list(SETTINGS)
    if "--only" in argv:
        i = argv.index("--only")
        names = argv[i + 1].split(",")
        del argv[i:i + 2]
    sims = {k: N.build(kind, n, SETTINGS[k]) for k in names}
    acc = {k: [] for k in names}
    for f in range(1, frames + 1):
        order = names if f % 2 else names[::-1]
        for k in order:
            sim, c, cl, bodies = sims[k]
            t0, w0 = time.process_time(), time.perf_counter()
            st = sim.step_frame()
            cpu, wall = time.process_time() - t0, time.perf_counter() - w0
            r = N.frame_row(kind, sim, c, cl, bodies, st, cpu, [], 10**9, 0.0)
            r["wall"] = wall
            r["substeps"] = c.model.substeps
            acc[k].append(r)
        print(f"frame {f}: " + ", ".join(
            f"{k} {1e3 * acc[k][-1]['cpu']:.0f} ms N {acc[k][-1]['newton']} CG "
            f"{acc[k][-1]['cg']} strain {100 * acc[k][-1]['strain']:.2f} % pairs "
            f"{acc[k][-1]['self'] + acc[k][-1]['pen']} vnear {acc[k][-1]['vnear']:.3f}"
            for k in names), flush=True)
    print(f"\n{kind} {n or ''}, {frames} frames, means over frames 2..{frames}")
    print("| setting | CPU ms/frame | wall ms/frame | Newton/frame | CG/frame |"
          " halvings/frame | max strain % | max pairs | near-joint m/s |"
          " Newton/substep at rest |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    base = None
    for k in names:
        rs = acc[k][1:]
        cpu = np.mean([r["cpu"] for r in rs])
        base = cpu if base is None else base
        rest = [r["newton"] / r["substeps"] for r in acc[k][49:]]
        print(f"| {k} | {1e3 * cpu:.0f} ({cpu / base:.2f}x) | "
              f"{1e3 * np.mean([r['wall'] for r in rs]):.0f} | "
              f"{np.mean([r['newton'] for r in rs]):.1f} | {np.mean([r['cg'] for r in rs]):.0f} |"
              f" {np.mean([r['halvings'] for r in rs]):.0f} |"
              f" {100 * max(r['strain'] for r in acc[k]):.2f} |"
              f" {max(r['self'] + r['pen'] for r in acc[k])} |"
              f" {max(r['vnear'] for r in acc[k][3:]) if kind != 'drop' else '-'} |"
              f" {np.mean(rest) if rest else '-'} |")


if __name__ == "__main__":
    main(sys.argv[1:])
