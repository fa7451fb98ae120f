"""The implicit solver's aggregation multigrid with its aggregation reused
(``preconditioner: amg_reuse``, ``linear.AggregationReuse``; issue #11) against the block-Jacobi
PCG, two ways:

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_amg.py drop 64 10 [--from 2] \\
        VARIANT [VARIANT ...]
    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_amg.py systems 'DIR/f*.npz' \\
        VARIANT [VARIANT ...]

``drop N FRAMES``: the cloth-on-sphere drop (``implicit_drop.scene_text``, 1 substep), one
simulation per variant plus the default (block_jacobi), stepped frame by frame in turn in one
process; per variant, summed over frames ``--from`` (default 2: frame 1 compiles) .. FRAMES:
CPU s (time.process_time) of the frame and of its linear solves (``cg``: preconditioner setup
and PCG), Newton and CG iterations, line-search halvings, the worst edge strain over the frames
and the most intersecting triangle pairs (self, cloth-ball) in any frame.

``systems GLOB``: saved Newton systems (.npz with indptr, indices, data, diag, b; as
``implicit_cost.py --save`` writes them), in name order as the Newton iterations of a run (a
name ending in ``_01.npz`` starts a substep): per system the block-Jacobi solve
(``pcg_block_jacobi``, cg_tolerance 1e-3, cap 500) and each variant's (setup, solve), CG
iterations and relative residual; then the sums.

VARIANT: ``cycle:smooth:growth`` (``additive:tentative:2``, the defaults of amg_cycle,
amg_smooth, amg_rebuild_growth; ``v:tentative:0`` ...); in ``drop`` mode any extra
``k=v`` implicit_solver overrides follow after a ``+``: ``additive:tentative:2+cg_tolerance=1e-2``,
``block_jacobi+cg_forcing=eisenstat_walker``.

Measured (the shared 2-core machine, load 3-5, 1 thread; block_jacobi the default):

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_amg.py drop 128 9 --from 6 \
        additive:tentative:2 v:tentative:2

    variant                               CPU s    cg s  Newton   CG it  halv strain% self ball
    block_jacobi                          60.42   25.89      80   33776   127    3.32    0    0
    additive:tentative:2                  42.15   12.57      80    8729   118    4.38    0    0
    v:tentative:2                         44.34   15.70      80    4068   120    6.06    0    0

(frames 6-9, the impact; per frame the linear solves take 3.7-7.6 s with block_jacobi, 2.2-3.5 s
with the additive cycle; the frames' other phases are the same code, their CPU noisy under the
load). Two earlier runs of the same command, with the same cycles before two changes that only
move rounding (the coarse matrices refreshed lazily, the coarsest inverse by potri), gave cg s
26.47 / 16.03 / 17.50 and 26.47 / 15.47 / 16.33, worst strain 3.32 / 6.08 / 5.13 % and 3.32 /
4.53 / 5.13 %: the strain at 128x128 moves both ways with the linear solve.
``drop 64 12 --from 6`` (frames 6-12): cg s
10.22 / 7.04 / 8.21, CG iterations 48,369 / 19,689 / 8,735, strain 4.45 / 3.54 / 2.85 %, 0
intersecting pairs. ``systems`` on the 128x128 drop's Newton systems of frames 7-8 (saved with
every Newton iteration: 40 systems, as ``implicit_cost.py 128 8 --save 7:1:f07_01.npz ...
--save 8:20:f08_20.npz`` writes them): block_jacobi 19,257 CG iterations, 15.3 s;
additive:tentative:2 5,370, 7.5 s; v:tentative:2 2,427, 9.5 s; additive:smoothed:2 4,439,
9.2 s; additive:tentative:0 (rebuilt every substep) 5,369, 7.5 s. The previous Newton step as
CG's initial guess (additive cycle, same systems) saves 9 % of the iterations (5,376 -> 4,897;
half that step 5,102): not taken. Newton stops at its cap of 20 in every impact substep with
each preconditioner, so amg_reuse stays opt-in. With the inexact-Newton forcing
(``drop 64 12 --from 6 block_jacobi+cg_forcing=eisenstat_walker
additive:tentative:2+cg_forcing=eisenstat_walker``, frames 6-12: cg s block_jacobi 10.50, with
the forcing 0.75, amg_reuse with the forcing 2.08; CG iterations 48,369 / 3,235 / 1,177; strain
4.45 / 3.08 / 4.16 %) the loose solves take a few block-Jacobi iterations each, and the
multigrid's refresh and dearer iterations cost more than they save: amg_reuse pays at
cg_tolerance's tight solves only.
"""

from __future__ import annotations

import glob
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import scipy.sparse as sp

sys.path.insert(0, str(Path(__file__).resolve().parent))
import implicit_drop as D  # noqa: E402

from lokigraph.api import compile_file  # noqa: E402
from lokigraph.behaviors.collision.intersect import intersect_meshes  # noqa: E402
from lokigraph.behaviors.solvers.implicit import linear as L  # noqa: E402
from lokigraph.run import Simulation  # noqa: E402


def parse(v):
    """VARIANT -> (label, implicit_solver overrides)."""
    head, *extra = v.split("+")
    if head == "block_jacobi":
        ov = {}
    else:
        cycle, smooth, growth = (head.split(":") + ["tentative", "2"])[:3]
        ov = {"preconditioner": "amg_reuse", "amg_cycle": cycle, "amg_smooth": smooth,
              "amg_rebuild_growth": float(growth)}
    for e in extra:
        k, val = e.split("=", 1)
        ov[k] = val
    return v, ov


def drop(n, frames, first, variants):
    runs = {}
    for label, ov in [parse("block_jacobi")] + [parse(v) for v in variants]:
        p = Path(tempfile.mkdtemp()) / f"cloth_sphere_{n}_implicit.yaml"
        p.write_text(D.scene_text(n, 1, ov))
        c = compile_file(p)
        sim = Simulation(c)
        acc = defaultdict(float)
        D._timers(sim, acc)
        sd = c.schedule.find("StretchConstraint")[0].data
        runs[label] = dict(sim=sim, acc=acc, c=c, idx=sd.idx, rest=sd.rest,
                           tot=defaultdict(float), strain=0.0, self=0, ball=0)
    print(f"cloth_sphere_{n}, 1 substep, frames {first}..{frames}; per frame: CPU s (cg s) "
          f"Newton CG strain%")
    for f in range(1, frames + 1):
        line = [f"{f:3d}"]
        for label, r in runs.items():
            acc = r["acc"]
            acc.clear()
            t0 = time.process_time()
            st = r["sim"].step_frame()
            tot = time.process_time() - t0
            q = r["sim"].state.particle_q
            e = float((np.linalg.norm(q[r["idx"][:, 1]] - q[r["idx"][:, 0]], axis=1)
                       / r["rest"] - 1.0).max())
            cl, ball = r["c"].scene.element("cloth"), r["c"].scene.element("ball")
            cm = (q[cl.vertex_slice], cl.geometry.triangles)
            nself = intersect_meshes([cm], touching=False)[0]
            _, pairs = intersect_meshes([cm, (q[ball.vertex_slice], ball.geometry.triangles)],
                                        touching=False)
            nball = int((pairs[:, 0] != pairs[:, 2]).sum())
            r["strain"] = max(r["strain"], e)
            r["self"] = max(r["self"], int(nself))
            r["ball"] = max(r["ball"], nball)
            if f >= first:
                t = r["tot"]
                t["cpu"] += tot
                t["cg"] += acc.get("cg", 0.0)
                t["newton"] += st.get("newton_iterations", 0)
                t["cgit"] += st.get("cg_iterations", 0)
                t["halv"] += st.get("line_search_halvings", 0)
            line.append(f"{tot:6.2f} ({acc.get('cg', 0.0):5.2f}) "
                        f"{st.get('newton_iterations', 0):3.0f} "
                        f"{st.get('cg_iterations', 0):5.0f} {100 * e:5.2f}")
        print(" | ".join(line), flush=True)
    print(f"{'variant':34} {'CPU s':>8} {'cg s':>7} {'Newton':>7} {'CG it':>7} {'halv':>5} "
          f"{'strain%':>7} {'self':>4} {'ball':>4}  (frames {first}..{frames})")
    for label, r in runs.items():
        t = r["tot"]
        print(f"{label:34} {t['cpu']:8.2f} {t['cg']:7.2f} {t['newton']:7.0f} {t['cgit']:7.0f} "
              f"{t['halv']:5.0f} {100 * r['strain']:7.2f} {r['self']:4d} {r['ball']:4d}")


def systems(pattern, variants):
    files = sorted(glob.glob(pattern))
    pcs = {}
    for v in variants:
        cycle, smooth, growth = (v.split(":") + ["tentative", "2"])[:3]
        pcs[v] = L.AggregationReuse(1, smooth, float(growth), cycle=cycle)
    tot = {k: [0, 0.0, 0.0] for k in ["block_jacobi"] + list(pcs)}
    for f in files:
        z = np.load(f)
        b = z["b"]
        n = len(b)
        A = sp.bsr_matrix((z["data"], z["indices"], z["indptr"]), shape=(3 * n, 3 * n),
                          blocksize=(3, 3))
        w = {k: np.zeros((n, 3)) for k in ("r", "z", "p", "Ap")}
        x = np.zeros((n, 3))
        inv = np.zeros((n, 3, 3))
        for _ in range(3):  # touch the loaded matrix first: its first pass pays page faults,
            L.bsr_matvec(A.indptr, A.indices, A.data, b, x)  # which the solver's does not
        t0 = time.process_time()
        L.invert_blocks(A.data[z["diag"]], inv)
        it, res = L.pcg_block_jacobi(A.indptr, A.indices, A.data, inv, b, 1e-3, 500, x,
                                     w["r"], w["z"], w["p"], w["Ap"])
        t = time.process_time() - t0
        tot["block_jacobi"][0] += it
        tot["block_jacobi"][1] += t
        row = [Path(f).name, f"block_jacobi {it} {res:.1e} {t:.3f}"]
        for k, pc in pcs.items():
            if pc.B.shape[0] != 3 * n:
                pc.B = np.kron(np.ones((n, 1)), np.eye(3))
            if f.endswith("_01.npz"):
                pc.begin_substep()
            t0 = time.process_time()
            pc.setup(A, z["diag"])
            ts = time.process_time() - t0
            t0 = time.process_time()
            it, res = pc.solve(A, b, 1e-3, 500, x, w)
            t1 = time.process_time() - t0
            row.append(f"{k} {it} {res:.1e} setup {ts:.3f} solve {t1:.3f} builds {pc.builds}")
            tot[k][0] += it
            tot[k][1] += t1
            tot[k][2] += ts
        print(" | ".join(row), flush=True)
    print(f"{'variant':24} {'CG it':>7} {'solve s':>8} {'setup s':>8} {'total s':>8}")
    for k, (it, ts, su) in tot.items():
        print(f"{k:24} {it:7d} {ts:8.3f} {su:8.3f} {ts + su:8.3f}")


if __name__ == "__main__":
    a = sys.argv[1:]
    if a[0] == "systems":
        systems(a[1], a[2:])
    else:
        first = 2
        if "--from" in a:
            i = a.index("--from")
            first = int(a[i + 1])
            del a[i:i + 2]
        drop(int(a[1]), int(a[2]), first, a[3:])
