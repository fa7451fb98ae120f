"""The implicit solver's exact speedups on the cloth-on-sphere drop (issue #11, speed), measured
against the code before them in one process: two simulations of the same scene, one with the
speedups switched back off (per instance), frames interleaved (ABBA: A B, B A, ...), positions
compared bitwise after every frame, CPU time per phase as graphs/bench/implicit_drop.py splits
it.

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_speedups.py 128 [frames]

The speedups (neither changes a result: the positions are bitwise the same in every frame):

* after a line search, the contact rows are lagged from the rows ``extend_live`` listed for the
  segment (``contact.lag_rows_sel``) instead of a pass over every row (``lag_rows_live``): the
  gap bound is concave, so a row it left out is inactive all along the segment;
* the block-Jacobi PCG fuses its vector passes into the matrix product and the preconditioner
  (``linear.pcg_block_jacobi``; ``pcg_block_jacobi_unfused`` is the loop before).

Measured (128x128, 1 substep, frames 6-10: the impact, Newton at its 20 cap and CG at its 500
cap in nearly every iteration; the shared 2-core machine at load 3-5; CPU s summed over the
five frames, before / after, ratio):

    total     82.37 / 69.99   0.850   (wall 178.9 / 160.8 s)
    cg        41.84 / 32.44   0.775
    lag       11.22 /  7.57   0.675
    assemble   5.38 /  5.08   0.943   (unchanged code: noise)
    energy     4.45 /  4.15   0.932   (unchanged code)
    detect    11.51 / 12.72   1.105   (unchanged code: collision pipeline)
    project    6.72 /  6.71   0.998   (unchanged code: collision projection pass)

64x64 (frames 7-14, separate runs for each change): lag 2.01 -> 1.32 s, CG 12.11 -> 11.36 s.
The per-frame cost at 128x128 stays 14-19 s CPU at impact: CG 6-8 s (20 Newton iterations x
~500 CG iterations x ~0.8 ms, one read of the 183,555 3x3 blocks each, memory bound), the
collision detection 3-5 s and projection pass 1.5-2.3 s (behaviors/collision), lag 1.8-2.8 s
(one pass over the ~5.2 M contact rows per Newton iteration, ``extend_live``; 20-60 k are live).
Preconditioners measured on the Newton matrices of frame 8 (128x128, 19,203 vertices; CPU s per
linear solve at cg_tolerance 1e-3, cap 500): block-Jacobi 500 iterations (residual 2e-2 ..
1e-3) in 0.31-0.45 s; pyamg smoothed aggregation rebuilt for the matrix: setup 1.3 s, 46
iterations, 3.6 s (pyamg's Python V-cycle); the hierarchy of the first Newton iteration reused
at the 6th / 20th: 500 iterations, residual 2.1e-2 / 1.5e-2 (worse than block-Jacobi: the
contact and strain-limit blocks change between iterations); scipy splu (COLAMD) of the matrix:
3.2 s, so a factorization reused as preconditioner: 500 iterations, residual 1.8e-2 / 1.6e-2.
"""

from __future__ import annotations

import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import implicit_drop as D  # noqa: E402

from lokigraph.api import compile_file  # noqa: E402
from lokigraph.behaviors.solvers.implicit import linear as L  # noqa: E402
from lokigraph.behaviors.solvers.implicit import solver as S  # noqa: E402
from lokigraph.run import Simulation  # noqa: E402

KEYS = ("detect", "assemble", "energy", "cg", "lag", "project")


def make(n, before):
    """A simulation of the n x n drop with CPU phase timers; ``before``: the speedups off."""
    p = Path(tempfile.mkdtemp()) / f"cloth_sphere_{n}_implicit.yaml"
    p.write_text(D.scene_text(n, 1, {}))
    sim = Simulation(compile_file(p))
    acc = defaultdict(float)
    sv = [b.behavior for b in sim.schedule.all() if isinstance(b.behavior, S.ImplicitSolver)][0]
    if before:
        prepare = sv._prepare

        def prep(ctx, d):
            prepare(ctx, d)
            pc = d.precond

            def solve(A, b, tol, maxit, x, work):
                return L.pcg_block_jacobi_unfused(A.indptr, A.indices, A.data, pc.inv, b, tol,
                                                  maxit, x, work["r"], work["z"], work["p"],
                                                  work["Ap"])
            pc.solve = solve
        sv._prepare = prep
        lag = sv._lag_rows

        def lag_all(ctx, d, x, live=False, on_segment=False):
            return lag(ctx, d, x, live, False)
        sv._lag_rows = lag_all
    D._timers(sim, acc)
    return sim, acc


def main(n=128, frames=10, skip=5):
    sims = {"before": make(n, True), "after": make(n, False)}
    tot = {k: defaultdict(float) for k in sims}
    same_all = True
    for f in range(frames):
        order = list(sims) if f % 2 == 0 else list(reversed(list(sims)))
        res = {}
        for name in order:
            sim, acc = sims[name]
            for k in list(acc):
                acc[k] = 0.0
            t, w = time.process_time(), time.perf_counter()
            sim.step_frame()
            dt, dw = time.process_time() - t, time.perf_counter() - w
            res[name] = (dt, dict(acc), sim.state.particle_q.copy())
            if f >= skip:
                tot[name]["total"] += dt
                tot[name]["wall"] += dw
                for k in KEYS:
                    tot[name][k] += acc.get(k, 0.0)
        same = np.array_equal(res["before"][2], res["after"][2])
        same_all &= same
        print(f"frame {f + 1}: positions bitwise equal {same}; CPU s before / after "
              f"{res['before'][0]:.2f} / {res['after'][0]:.2f} | "
              + " ".join(f"{k} {res['before'][1].get(k, 0.0):.2f}/{res['after'][1].get(k, 0.0):.2f}"
                         for k in KEYS), flush=True)
    print(f"frames {skip + 1}..{frames}, sums before / after (ratio); bitwise equal in every "
          f"frame: {same_all}")
    for k in ("total", "wall") + KEYS:
        a, b = tot["before"][k], tot["after"][k]
        print(f"  {k:9s} {a:8.2f} {b:8.2f}  {b / a if a else float('nan'):.3f}")


if __name__ == "__main__":
    args = [int(a) for a in sys.argv[1:]]
    main(*args[:2])
