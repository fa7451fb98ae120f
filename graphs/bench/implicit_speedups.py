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

Measured and not kept (exact, bitwise the same positions, but not paying; commits 10dcd4b and
5006e8a of branch he): a float32 copy of the contact rows screening the live-row tests
(``lag_rows_live`` 186 -> 30 ms per call; on ``extend_live`` nothing: its cost is the
vertex gathers, not the row data), and a running lower bound per row carried from one segment
extension to the next (decremented by twice the largest vertex move; per vertex instead: slower).
cloth_sphere_128, frames 2-10, interleaved, CPU ms/frame without / with both: total 10,740 /
10,460 (0.974), lag 1,796 / 1,732; cloth_sphere_64 over four runs 0.91-1.09x.

``--table`` steps settings side by side (interleaved per frame, ABBA) on the drape and
cloth-on-sphere bench scenes and prints CPU and wall ms/frame, Newton and CG iterations per
frame, the worst edge strain, the most intersecting triangle pairs and whether the positions
were bitwise those of the first setting in every frame:

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_speedups.py --table \
        --scenes cloth_sphere_64 cloth_sphere_128 drape_64 drape_128 --frames 10 \
        --settings fixed ew:cg_forcing=eisenstat_walker \
        ew5:cg_forcing=eisenstat_walker,cg_forcing_max=0.5 nucleus

(a setting is ``name`` or ``name:k=v,...`` with implicit_solver overrides; ``nucleus`` runs the
scene's own solver settings; the cloth-on-sphere scenes run the implicit solver at 1 substep.)

Measured with it (frames 2-10, the machine at load ~5: wall 2.2-2.5x CPU; CPU ms/frame, CG
iterations per frame, worst strain, 0 intersecting pairs in every frame of every run):

    cloth_sphere_64   fixed (defaults) 1,798 / 3,597 / 4.45 %
                      cg_forcing eisenstat_walker, max 0.1: 962 / 513 / 5.65 %; max 0.5: 737 / 235 / 3.08 %
                      nucleus 401 / 6.63 %
    cloth_sphere_128  fixed (defaults) 9,613 / 4,720 / 3.57 %
                      max 0.1: 4,507 / 631 / 7.01 %; max 0.5: 2,333 / 286 / 3.07 %
                      nucleus 2,817 / 15.93 %
    drape_64          fixed 2,987 / 9,419 / 0.26 %;
                      max 0.1: 2,181 / 2,954; max 0.5: 1,992 / 1,957 / 0.26 %; nucleus 127 / 1.11 %
    drape_128         (frames 2-5) fixed 16,114 / 11,729 / 1.40 %; max 0.5: 7,577 / 2,507 /
                      1.43 %; nucleus 498 / 1.72 %

The forcing term's gates (issue #11: the forcing term as the default), ``cg_forcing_after``
(a solve at cg_tolerance for its first N CG iterations, the Eisenstat-Walker tolerance only
after them) and ``cg_forcing_scope: contacts`` (the forcing term only in substeps with
contacts in the solve):

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_speedups.py --table \
        --scenes cloth_sphere_64 cloth_sphere_128 drape_64 --frames 10 --settings defaults \
        ew5:cg_forcing=eisenstat_walker,cg_forcing_max=0.5 \
        g25c:cg_forcing=eisenstat_walker,cg_forcing_max=0.5,cg_forcing_after=25,cg_forcing_scope=contacts \
        g50a:cg_forcing=eisenstat_walker,cg_forcing_max=0.5,cg_forcing_after=50,cg_forcing_scope=all

    (CPU ms/frame, wall ms/frame, CPU ratio to the defaults, Newton / CG iterations per
    frame, worst edge strain, frames 2-10 interleaved, 1 thread, machine at load ~5; 0
    intersecting pairs in every frame of every run)
    cloth_sphere_64   defaults 1,659 / 4,221 / 1.000 / 11.6 / 3,597 / 4.45 %
                      ew5      692 / 1,676 / 0.417 / 11.6 / 235 / 3.08 %
                      g25c     763 / 1,924 / 0.460 / 11.6 / 281 / 4.00 %
                      g50a     1,076 / 2,615 / 0.648 / 11.6 / 555 / 3.68 %
    cloth_sphere_128  defaults 9,482 / 22,724 / 1.000 / 11.6 / 4,720 / 3.57 %
                      ew5      2,214 / 5,501 / 0.233 / 11.6 / 286 / 3.07 %
                      g25c     1,949 / 4,680 / 0.206 / 11.6 / 285 / 5.49 % (over 5 %)
                      g50a     3,373 / 8,376 / 0.356 / 11.6 / 561 / 7.35 % (over 5 %)
    drape_64          defaults 2,828 / 7,743 / 1.000 / 30.9 / 9,419 / 0.26 %
                      ew5      1,903 / 5,044 / 0.673 / 32.0 / 1,957 / 0.26 %
                      g25c     bitwise the defaults (no contacts): 2,915 / 7,994 / 1.031
                      g50a     2,166 / 5,595 / 0.766 / 31.3 / 2,841 / 0.26 %
    drape_128         (no contacts: g25c is bitwise the defaults; not rerun here)
    At 128 x 128 the gates keep the ungated saving (0.21x) but the worst strain of the drop
    reaches 5.49 % (g25c) and 7.35 % (g50a) against the issue's 5 % bound: Newton stops at its
    cap in every contact substep with each setting, where the strain moves both ways with the
    tolerance (ungated 3.07 %, fixed 3.57 %; max 0.1 above 7.01 %). Neither is a default.

Why the gates: without contacts Newton converges, and a loose solve costs it iterations under
its cap. graphs/bench/catenary.yaml at 1 substep (72 frames): 7 Newton iterations a substep at
the fixed tolerance, 0.0003 mm from the exact catenary at rest (bound 1 mm); measured with
exploratory code that is not committed, each at the cap of 8 in (nearly) every substep: plain
eisenstat_walker 108.5 mm, its first iteration of a substep at cg_tolerance 0.12 mm (574 of 576
iterations), EW choice 2 on the preconditioned gradient norm (g.P^-1 g, CG stopping on r.z)
88.5 mm, EW choice 1 (the linear model's agreement, safeguard eta^1.618) 78.3 mm, a CG stop on
the relative energy-norm error of the step (Hestenes-Stiefel sums over 5 iterations) at 0.1 /
0.03 22.0 / 5.2 mm (at 0.01: 7 iterations a substep, 0.0001 mm, but 26,867 CG iterations
against 28,120 and cloth_sphere_64 at 0.81x CPU), the gate after 25 with scope all 19.1 mm
(after 50: 0.0006 mm, 7 iterations). With contacts Newton stops at its cap whatever the
tolerance, and the small solves of the pinch (<= 22 CG iterations in frame 2) stay tight under
the gate after 25 (its Newton counts are the fixed tolerance's through frame 26, where the plain
forcing term took 10.5 a substep against the bound 6, measured before this change). A rate
predictor (loose for the rest of a substep once the last two Newton steps' ratio predicts no
convergence within the cap) was measured and not kept: the pinch's 7 Newton iterations in frame
2 (bound 6) and 18 intersecting pairs on the implicit sleeve_pinch.

g25c as the default (eisenstat_walker, max 0.5, after 25, scope contacts, swapped in by a local
edit of the defaults), ``python -m pytest -q -m "slow or not slow" tests/test_implicit*.py
tests/test_fluid*.py tests/test_rod_twist.py tests/test_cloth_strain.py``: 3 failed, 136 passed
(8.6 min). Of the 9 tests the plain eisenstat_walker failed, the catenary, the elastica, the pin
statistics, the contact complementarity, the pinch's Newton counts, the thrown cloth's momentum
and the fluid coupling iterations pass; the three failures are comparisons whose figures were
measured at the fixed tolerance, no physical bound: test_cut_step_is_not_convergence (the old
line_search_step test's false stops: 0 of the >= 2 frames), test_hard_limit_holds_a_32x32_drop
(its control, the penalty alone without hard_limit, reaches 2.03 % instead of > 3.5 %; with the
limit 2.12 %, bound 2.5 %) and test_compliant_unknowns_block_preconditioner (cg_identity 32,360
against 5x block's 10,182 CG iterations: the loose tolerance stops the unpreconditioned solves
early). Pinning cg_forcing: fixed in those three comparisons is a decision for their owners; the
gated forcing term stays opt-in here.

Where the 128 x 128 impact frame goes (frames 6-10 at 1 substep, 1 thread, defaults; cProfile
of frames 2-10 and per-iteration logs at frame 8): Newton at its 20 cap in every contact
substep, CG at its 500 cap in 19 of 20 iterations (relative residual 1e-3 .. 4e-2, 0.8 ms per
CG iteration idle, ~400 ms per solve), 0-2 line-search halvings per iteration, Newton steps still
0.02-0.1 m/s at the cap (tolerance 1e-3) while |grad| falls from ~70 to ~4; 1.43 M vertex-face
and 3.64 M edge-edge rows per substep, 10-60 k of them live. CPU: PCG 34 %, the collision
pipeline's detection and projection (behaviors/collision) ~30 %, the live-row passes 15 %
(extend_live 9 %, lag_rows_live 5 %), row_energy 4 %, assembly's scatter_blocks 3 %, dihedral_energy 2 %.

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


# -- --table: settings side by side on the drape and cloth-on-sphere scenes ---------------------

SCENES = ("drape_64", "drape_128", "cloth_sphere_64", "cloth_sphere_128")


def table_sim(scene, setting):
    """A simulation of graphs/bench/<scene>.yaml for ``setting`` (name, overrides): the name
    ``nucleus`` runs the scene as it is; any other ``solver: implicit`` with the overrides as
    ``graph_overrides.implicit_solver`` (``substeps`` sets the scene's substeps). The cloth
    -on-sphere scenes run the implicit solver at 1 substep (the issue's "at 1 substep")."""
    from lokigraph.compile import compile_scene
    from lokigraph.scene import load_scene

    name, ov = setting
    sc = load_scene(D.BENCH / f"{scene}.yaml")
    ov = dict(ov)
    if name != "nucleus":
        sub = int(ov.pop("substeps", 1 if scene.startswith("cloth_sphere") else
                         sc.spec.substeps))
        go = {k: dict(v) for k, v in sc.spec.graph_overrides.items()}
        go.setdefault("implicit_solver", {}).update(ov)
        sc.spec = sc.spec.model_copy(update={"solver": "implicit", "graph_overrides": go,
                                             "substeps": sub})
    c = compile_scene(sc)
    return Simulation(c), c


def _frame_measures(c):
    """Worst edge strain and intersecting triangle pairs (cloth self + cloth-collider) of a
    compiled bench scene's state: a function of the positions."""
    from lokigraph.behaviors.collision.intersect import intersect_meshes

    sd = c.schedule.find("StretchConstraint")[0].data
    idx, rest = sd.idx, sd.rest
    cl = c.scene.element("cloth")
    others = [e for e in c.scene.elements if e is not cl and e.geometry is not None
              and e.vertex_count and len(e.geometry.triangles)]

    def measure(q):
        e = np.linalg.norm(q[idx[:, 1]] - q[idx[:, 0]], axis=1) / rest - 1.0
        cm = (q[cl.vertex_slice], cl.geometry.triangles)
        pairs = int(intersect_meshes([cm], touching=False)[0])
        for o in others:
            _, pr = intersect_meshes([cm, (q[o.vertex_slice], o.geometry.triangles)],
                                     touching=False)
            pairs += int((pr[:, 0] != pr[:, 2]).sum())
        return float(e.max()), pairs
    return measure


def table(scenes, settings, frames, skip=1):
    """Per scene, the settings stepped frame by frame in one process, interleaved (ABBA: the
    order reverses every frame); after the first ``skip`` frames (JIT warm-up) the CPU
    (process_time) and wall ms per frame, Newton and CG iterations per frame, and over every
    frame the worst edge strain and the most intersecting triangle pairs, and whether the
    positions were bitwise those of the first setting in every frame. Returns the rows."""
    out = []
    print(f"{'scene':17} {'setting':22} {'CPU ms/fr':>9} {'wall ms/fr':>10} {'CPU ratio':>9} "
          f"{'Newton/fr':>9} {'CG/fr':>8} {'max strain %':>12} {'max pairs':>9} "
          f"{'bitwise':>7}", flush=True)
    for scene in scenes:
        runs = {}
        phases = {}
        for st in settings:
            sim, c = table_sim(scene, st)
            runs[st[0]] = (sim, _frame_measures(c))
            phases[st[0]] = defaultdict(float)
            D._timers(sim, phases[st[0]])  # CPU per phase (implicit_drop's split)
        acc = {k: defaultdict(float) for k in runs}
        first = settings[0][0]
        same = {k: True for k in runs}
        for f in range(frames):
            order = list(runs) if f % 2 == 0 else list(reversed(list(runs)))
            for k in order:
                sim, measure = runs[k]
                t, w = time.process_time(), time.perf_counter()
                st = sim.step_frame()
                dt, dw = time.process_time() - t, time.perf_counter() - w
                strain, pairs = measure(sim.state.particle_q)
                a = acc[k]
                a["strain"] = max(a["strain"], strain)
                a["pairs"] = max(a["pairs"], pairs)
                if f == skip - 1:
                    phases[k].clear()
                if f >= skip:
                    a["cpu"] += dt
                    a["wall"] += dw
                    a["newton"] += st.get("newton_iterations", 0)
                    a["cg"] += st.get("cg_iterations", 0)
            q0 = runs[first][0].state.particle_q
            for k in runs:
                same[k] &= np.array_equal(runs[k][0].state.particle_q, q0)
        m = max(frames - skip, 1)
        base = acc[settings[0][0]]["cpu"] or 1.0
        for k, a in acc.items():
            row = dict(scene=scene, setting=k, cpu=1e3 * a["cpu"] / m, wall=1e3 * a["wall"] / m,
                       ratio=a["cpu"] / base, newton=a["newton"] / m, cg=a["cg"] / m,
                       strain=100 * a["strain"], pairs=int(a["pairs"]), bitwise=same[k])
            out.append(row)
            row["phases"] = {p: 1e3 * phases[k].get(p, 0.0) / m for p in KEYS}
            print(f"{scene:17} {k:22} {row['cpu']:9.0f} {row['wall']:10.0f} {row['ratio']:9.3f} "
                  f"{row['newton']:9.1f} {row['cg']:8.0f} {row['strain']:12.2f} "
                  f"{row['pairs']:9d} {str(row['bitwise']):>7}  CPU ms/frame: "
                  + " ".join(f"{p} {v:.0f}" for p, v in row["phases"].items()), flush=True)
    return out


def _setting(text):
    """``name`` or ``name:k=v,k=v`` -> (name, {k: v}) with numbers parsed."""
    name, _, rest = text.partition(":")
    ov = {}
    for kv in filter(None, rest.split(",")):
        k, v = kv.split("=", 1)
        try:
            v = int(v)
        except ValueError:
            try:
                v = float(v)
            except ValueError:
                pass
        ov[k] = v
    return name, ov


if __name__ == "__main__":
    if "--table" in sys.argv:
        import argparse

        ap = argparse.ArgumentParser()
        ap.add_argument("--table", action="store_true")
        ap.add_argument("--scenes", nargs="+", default=list(SCENES))
        ap.add_argument("--frames", type=int, default=10)
        ap.add_argument("--settings", nargs="+", default=["defaults"])
        a = ap.parse_args()
        table(a.scenes, [_setting(t) for t in a.settings], a.frames)
    else:
        args = [int(a) for a in sys.argv[1:]]
        main(*args[:2])
