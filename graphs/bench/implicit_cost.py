"""Where one implicit frame of the cloth-on-sphere drop goes, stage by stage (issue #11: the cost
per Newton iteration and per CG iteration), with call counts.

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_cost.py 128 [frames] [--from F] \
        [--save FRAME:ITER:PATH] [k=v ...]

The drop is graphs/bench/cloth_sphere_{N}.yaml at 1 substep with ``solver: implicit``
(``implicit_drop.scene_text``); ``k=v`` become implicit_solver overrides. Every stage below is
timed with ``time.process_time`` around the solver's own calls (per instance / per module
attribute: the code timed is the code that runs) and counted; the table sums frames ``--from``
(default 2: frame 1 compiles the kernels) .. ``frames`` and prints CPU ms per frame, calls per
frame and ms per call:

``detect`` CollisionDetect.step; ``assemble`` the potential with gradient and Newton matrix
(``_potential`` mode 2), of which ``assemble.elastic[T]`` the energy kernels of type T,
``assemble.scatter`` their blocks' scatter into the matrix (``gather_blocks``), ``assemble.limit``
the hard rows' strain-limit terms, ``assemble.rows`` the contact rows (``row_energy_coupled``), the
rest (inertia, diagonal and Dirichlet rows) ``assemble.other``; ``precond`` the preconditioner's
setup; ``cg`` the linear solve (with the CG iterations per frame and ms per CG iteration);
``linesearch`` the line-search potentials (``_potential`` mode 0 inside a Newton iteration),
``linesearch.rows`` their contact rows; ``start`` the potentials of ``start_at_rest``; ``lag``
``_lag_rows``; ``extend`` ``_extend_live``; ``residuals`` ``_row_residuals``; ``project`` the
projection pass (collision final rounds: re-detection, CCD: the safety projection of the contact
rows); ``newton.other`` the rest of ``_newton``; ``frame.other`` the rest of the frame.

``--ab COMMIT``: two simulations in one process, frames interleaved (ABBA), "before" with
the block-Jacobi PCG of COMMIT's ``linear.py`` (serial) and the energies' blocks added by
``scatter_blocks``, "after" the tree as it is; per frame whether positions
and velocities are bitwise equal; then the stage table of each, side by side, and the ratio:

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_cost.py 128 10 --ab bc9a2e2
    NUMBA_NUM_THREADS=2 .venv/bin/python graphs/bench/implicit_cost.py 128 10 --ab bc9a2e2 \
        --parallel

(``--parallel``: ``linear.PARALLEL_PCG`` on, the opt-in parallel PCG.)

``--save FRAME:ITER:PATH`` (repeatable) writes the Newton system of that frame's ITER-th Newton
iteration (1-based, counted over the frame) to PATH (.npz: indptr, indices, data, diag, b,
fixed) for ``implicit_cost_cg.py``.

Measured (issue #11, this machine shared with three other jobs, load 3-5; 1 substep, defaults):

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_cost.py 128 10    # at bc9a2e2

frames 2-10 (frames 2-5 fall freely, 0.26 s each; 6-10 the impact, 5.6-20.7 s each, Newton at
its cap of 20 and CG at its 500 cap in nearly every Newton iteration), CPU ms per frame (share),
calls per frame, ms per call; 11.6 Newton and 4,720 CG iterations per frame:

    total 7,832 | cg 3,160 (40 %), 11.6 solves x 273 ms, 0.67 ms per CG iteration
    detect 1,171 (15 %) | extend (_extend_live) 838 (11 %), 13.1 x 64 ms | project 808 (10 %)
    lag (_lag_rows) 606 (8 %), 13.6 x 45 ms | assemble 557 (7 %), 11.6 x 48 ms: scatter 294
    (23.1 x 12.7 ms), hinge kernel 91 (7.8 ms), stretch 17, contact rows 62 (2 x 2.7 ms), limit
    9, the rest 84 (7.3 ms) | line search 510 (6.5 %), 31.7 potentials x 16 ms: contact rows
    312 (2 x 4.9 ms), hinges 119 (3.7 ms), stretch 23, the rest 57 | precond setup 11 (0.9 ms)
    | newton.other 88 | frame.other 80 | row residuals 3

The impact frames alone on the final tree of this bench's commits (``128 10 --from 6``, frames
6-10: 20 Newton, 8,497 CG iterations, 33.4 halvings per frame): total 13,074 | cg 5,397 (41 %),
20 x 270 ms, 0.635 ms per CG iteration | detect 1,957 (15 %) | extend 1,470 (11 %), 22 x 67 ms |
project 1,331 (10 %) | lag 1,020 (8 %), 22 x 46 ms | line search 910 (7 %), 55.4 x 16.4 ms:
contact rows 587, hinges 197, stretch 40, the rest 87 | assemble 718 (5.5 %), 20 x 36 ms:
scatter 270 (40 x 6.8 ms), hinges 163, rows 111, the rest 125, stretch 29, limit 20 | newton.other
141 | frame.other 106 | precond 19.

Before / after this bench's commits (``--ab bc9a2e2``, interleaved, positions and velocities
bitwise equal in every frame of every run; CPU ms per frame over frames 2..N, ratio):

    128 (10 frames), 1 thread, run 1: total 8,180 -> 8,046 (0.984); cg 3,423 -> 3,249 (0.949,
        0.725 -> 0.688 ms per CG iteration); assemble 517 -> 511 (the hinges' blocks added
        straight into the matrix, since reverted: no gain)
    128 (10 frames), 1 thread, run 2 (gather_blocks): total 8,065 -> 8,212 (1.018); cg 3,403 ->
        3,581 (1.052, 0.721 -> 0.759 ms per CG iteration: the loop's gain is within this
        machine's noise here); assemble 508 -> 438 (0.863), scatter 10.9 -> 7.5 ms per call
    128 (10 frames), 2 threads, serial PCG (the defaults): total 7,102 -> 7,299 (1.028); cg
        3,033 -> 3,061 (1.009); assemble 457 -> 384 (0.841), scatter 9.6 -> 6.4 ms per call;
        wall 13,255 -> 14,635 (detect 935 -> 1,109: noise, unchanged code)
    128 (10 frames), 2 threads with the parallel PCG (linear.PARALLEL_PCG, before the flag):
        wall 15,943 -> 20,347 ms per frame (1.28), CPU 8,263 -> 8,619: opt-in
    64 (12 frames), 1 thread: total 1,837 -> 1,710 (0.931); cg 906 -> 820 (0.904; 0.206 ->
        0.186 ms per CG iteration); wall 3,809 -> 3,505
    64 (12 frames), 2 threads, --parallel: CPU 1,800 -> 2,114 (1.174), wall 5,520 -> 5,186
        (0.94); cg 0.200 -> 0.271 CPU ms per CG iteration (both threads' CPU)
    64 (12 frames), 2 threads, serial PCG: total 1,788 -> 1,695 (0.948), wall 3,722 -> 3,441

The PCG loops alone on three saved 128 x 128 impact systems (frame 7 iteration 1, frame 8
iterations 10 and 11; 500 iterations each, 12 interleaved repeats): 0.783 -> 0.709 ms per CG
iteration (medians; paired ratio 0.910).
"""

from __future__ import annotations

import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import implicit_drop as D  # noqa: E402

from lokigraph.api import compile_file  # noqa: E402
from lokigraph.behaviors.solvers.implicit import energy as E  # noqa: E402
from lokigraph.behaviors.solvers.implicit import solver as S  # noqa: E402
from lokigraph.run import Simulation  # noqa: E402


class Clock:
    """CPU seconds and calls per key; ``stack`` holds the key of the enclosing timed call."""

    def __init__(self):
        self.t = defaultdict(float)
        self.n = defaultdict(int)
        self.stack = []

    def wrap(self, obj, name, key_of):
        f = getattr(obj, name)

        def g(*a, **k):
            key = key_of(a, k)
            if key is None:
                return f(*a, **k)
            self.stack.append(key)
            t = time.process_time()
            try:
                return f(*a, **k)
            finally:
                self.t[key] += time.process_time() - t
                self.n[key] += 1
                self.stack.pop()
        setattr(obj, name, g)
        return f

    def inside(self):
        return self.stack[-1] if self.stack else ""

    def clear(self):
        self.t.clear()
        self.n.clear()


def instrument(sim, clk, save=()):
    """Time the stages of ``sim`` into ``clk`` (module docstring); ``save``: (frame, iter,
    path) triples, the Newton systems to write."""
    beh = [b.behavior for b in sim.schedule.all()]
    sv = [b for b in beh if isinstance(b, S.ImplicitSolver)][0]
    state = {"frame": 0, "newton": 0}

    def pot_key(a, k):
        mode = a[3]
        if mode >= 2:
            return "assemble"
        return "linesearch" if clk.inside() == "newton" else "start"
    clk.wrap(sv, "_newton", lambda a, k: "newton")
    clk.wrap(sv, "_potential", pot_key)
    clk.wrap(sv, "_lag_rows", lambda a, k: "lag")
    clk.wrap(sv, "_extend_live", lambda a, k: "extend")
    clk.wrap(sv, "_row_residuals", lambda a, k: "residuals")
    clk.wrap(sv, "_project", lambda a, k: "project")
    clk.wrap(sv, "_limit_energy", lambda a, k: "assemble.limit" if a[2] >= 2 else None)

    def sub(name):
        def key(a, k):
            outer = clk.inside()
            return f"{outer}.{name}" if outer in ("assemble", "linesearch") else None
        return key
    clk.wrap(S, "row_energy_coupled", sub("rows"))
    clk.wrap(S, "gather_blocks", sub("scatter"))
    orig_prepare = sv._prepare

    def prepare(ctx, d):
        orig_prepare(ctx, d)
        clk.wrap(d.precond, "setup", lambda a, k: "precond")
        solve = clk.wrap(d.precond, "solve", lambda a, k: "cg")
        for e in d.energies:
            b = e[0]
            tn = type(b).__name__
            clk.wrap(b, "energy", (lambda tn: lambda a, k: (
                f"{clk.inside()}.elastic[{tn}]" if clk.inside() in ("assemble", "linesearch")
                else None))(tn))
        if save:
            inner = d.precond.solve

            def solve_saving(A, b, *rest, **kw):
                state["newton"] += 1
                for f, i, path in save:
                    if state["frame"] == f and state["newton"] == i:
                        np.savez(path, indptr=A.indptr, indices=A.indices, data=A.data,
                                 diag=d.diag, b=b, fixed=d.cur_fixed)
                        print(f"saved frame {f} Newton iteration {i} to {path}", flush=True)
                return inner(A, b, *rest, **kw)
            d.precond.solve = solve_saving
        del solve
    sv._prepare = prepare
    for b in beh:
        if type(b).__name__ == "CollisionDetect":
            clk.wrap(b, "step", lambda a, k: "detect")
    return sv, state


ORDER = ("detect", "assemble", "assemble.elastic[StretchConstraint]",
         "assemble.elastic[BendConstraint]", "assemble.scatter", "assemble.limit",
         "assemble.rows", "assemble.other", "precond", "cg", "linesearch",
         "linesearch.elastic[StretchConstraint]", "linesearch.elastic[BendConstraint]",
         "linesearch.rows", "linesearch.other", "start", "lag", "extend", "residuals",
         "newton.other", "project", "frame.other", "total")


def derived(t, n):
    """The ``.other`` rows: a stage minus its timed parts."""
    t = dict(t)
    for outer in ("assemble", "linesearch"):
        t[f"{outer}.other"] = t.get(outer, 0.0) - sum(v for k, v in t.items()
                                                      if k.startswith(outer + "."))
        n[f"{outer}.other"] = n.get(outer, 0)
    inner = ("assemble", "precond", "cg", "linesearch", "start", "lag", "extend")
    t["newton.other"] = t.get("newton", 0.0) - sum(t.get(k, 0.0) for k in inner)
    n["newton.other"] = n.get("newton", 0)
    top = ("detect", "newton", "residuals", "project")
    t["frame.other"] = t["total"] - sum(t.get(k, 0.0) for k in top)
    n["frame.other"] = n["total"]
    return t, n


def before_linear(commit):
    """COMMIT's ``behaviors/solvers/implicit/linear.py`` as a module (its own file under the
    temp directory, so numba caches it)."""
    import importlib
    import subprocess
    import tempfile
    root = Path(__file__).resolve().parents[2]
    src = subprocess.run(["git", "-C", str(root), "show",
                          f"{commit}:behaviors/solvers/implicit/linear.py"],
                         capture_output=True, text=True, check=True).stdout
    d = Path(tempfile.gettempdir()) / "implicit_cost_before"
    d.mkdir(exist_ok=True)
    name = f"linear_{commit}"
    f = d / f"{name}.py"
    if not f.exists() or f.read_text() != src:
        f.write_text(src)
    sys.path.insert(0, str(d))
    return importlib.import_module(name)


def _gather_or_scatter(A, ptr, src, hl):
    """The solver's ``gather_blocks`` call, or for the "before" simulation (``ptr`` None,
    ``src`` the block map) ``scatter_blocks`` as before."""
    if ptr is None:
        return E.scatter_blocks(A, src, hl)
    return E.gather_blocks(A, ptr, src, hl)


def make_before(sim, lb):
    """The "before" of ``--ab``: COMMIT's serial block-Jacobi PCG, the energies' blocks added by
    ``scatter_blocks``."""
    sv = [b.behavior for b in sim.schedule.all() if isinstance(b.behavior, S.ImplicitSolver)][0]
    prepare = sv._prepare
    S.gather_blocks = _gather_or_scatter

    def prep(ctx, d):
        prepare(ctx, d)
        d.gather = [[(None, mp) for mp in e[3]] for e in d.energies]
        pc = d.precond

        def solve(A, b, tol, maxit, x, work, after=0, loose=0.0):
            w = (work["r"], work["z"], work["p"], work["Ap"])
            if after > 0:
                return lb.pcg_block_jacobi_after(A.indptr, A.indices, A.data, pc.inv, b, tol,
                                                 after, loose, maxit, x, *w)
            return lb.pcg_block_jacobi(A.indptr, A.indices, A.data, pc.inv, b, tol, maxit, x,
                                       *w)
        pc.solve = solve
    sv._prepare = prep


def table(runs, first, frames, stats, wall):
    """The stage table of each run side by side (CPU ms per frame, calls per frame, ms per
    call) and the CPU ratio of the last to the first."""
    m = max(frames - first + 1, 1)
    der = {k: derived(*v) for k, v in runs.items()}
    names = list(runs)
    for k in names:
        st = stats[k]
        print(f"{k}: per frame Newton {st['newton_iterations'] / m:.1f}, CG "
              f"{st['cg_iterations'] / m:.0f}, halvings {st['line_search_halvings'] / m:.1f}, "
              f"wall {1e3 * wall[k] / m:.0f} ms, max strain {100 * st['strain']:.2f} %, max "
              f"pairs {int(st['pairs'])}")
    head = " ".join(f"{k + ' ms/fr':>14s} {'calls':>7s} {'ms/call':>8s}" for k in names)
    print(f"{'stage':40s} {head} {'ratio':>6s}")
    keys = [k for k in ORDER if any(k in der[r][0] for r in names)]
    keys += sorted(set().union(*(der[r][0] for r in names)) - set(ORDER) - {"newton"})
    for key in keys:
        cells = []
        for r in names:
            t, cnt = der[r]
            c = cnt.get(key, 0)
            v = t.get(key, 0.0)
            cells.append(f"{1e3 * v / m:14.1f} {c / m:7.1f} "
                         f"{1e3 * v / c if c else float('nan'):8.3f}")
        a, b = der[names[0]][0].get(key, 0.0), der[names[-1]][0].get(key, 0.0)
        print(f"{key:40s} {' '.join(cells)} {b / a if a else float('nan'):6.3f}")
    for r in names:
        if stats[r]["cg_iterations"]:
            print(f"{r}: {1e3 * der[r][0]['cg'] / stats[r]['cg_iterations']:.3f} ms per CG "
                  f"iteration")


def main(argv):
    frames, first, save, ov, ab = 10, 2, [], {}, None
    n = int(argv.pop(0)) if argv and argv[0].isdigit() else 128
    if argv and argv[0].isdigit():
        frames = int(argv.pop(0))
    while argv:
        a = argv.pop(0)
        if a == "--from":
            first = int(argv.pop(0))
        elif a == "--parallel":  # linear.PARALLEL_PCG on (opt-in; the same iterates)
            from lokigraph.behaviors.solvers.implicit import linear as L
            L.PARALLEL_PCG = True
        elif a == "--ab":
            ab = argv.pop(0)
        elif a == "--save":
            f, i, p = argv.pop(0).split(":", 2)
            save.append((int(f), int(i), p))
        else:
            k, v = a.split("=", 1)
            ov[k] = v
    import tempfile
    p = Path(tempfile.mkdtemp()) / f"cloth_sphere_{n}_implicit.yaml"
    p.write_text(D.scene_text(n, 1, ov))
    if ab is not None:
        return main_ab(p, n, frames, first, ov, ab)
    sim = Simulation(compile_file(p))
    clk = Clock()
    _, state = instrument(sim, clk, save)
    tot_t, tot_n = defaultdict(float), defaultdict(int)
    stats = defaultdict(float)
    wall = 0.0
    print(f"cloth_sphere_{n} implicit, 1 substep, overrides {ov}, numba threads "
          f"{__import__('numba').get_num_threads()}", flush=True)
    for f in range(1, frames + 1):
        state["frame"], state["newton"] = f, 0
        clk.clear()
        t, w = time.process_time(), time.perf_counter()
        st = sim.step_frame()
        clk.t["total"] = time.process_time() - t
        clk.n["total"] = 1
        dw = time.perf_counter() - w
        print(f"frame {f}: CPU {1e3 * clk.t['total']:.0f} ms (wall {1e3 * dw:.0f}), Newton "
              f"{st.get('newton_iterations', 0)}, CG {st.get('cg_iterations', 0)}, halvings "
              f"{st.get('line_search_halvings', 0)}, rows {st.get('max_contact_rows', 0)}, "
              f"cg {1e3 * clk.t['cg']:.0f} ms, detect {1e3 * clk.t['detect']:.0f}, project "
              f"{1e3 * clk.t['project']:.0f}", flush=True)
        if f >= first:
            wall += dw
            for k, v in clk.t.items():
                tot_t[k] += v
            for k, v in clk.n.items():
                tot_n[k] += v
            for k in ("newton_iterations", "cg_iterations", "line_search_halvings"):
                stats[k] += st.get(k, 0)
    m = max(frames - first + 1, 1)
    t, cnt = derived(tot_t, tot_n)
    print(f"\nframes {first}..{frames}: per frame Newton {stats['newton_iterations'] / m:.1f}, "
          f"CG {stats['cg_iterations'] / m:.0f}, halvings {stats['line_search_halvings'] / m:.1f}"
          f", wall {1e3 * wall / m:.0f} ms")
    print(f"{'stage':40s} {'CPU ms/frame':>12s} {'%':>6s} {'calls/frame':>11s} {'ms/call':>9s}")
    for k in ORDER + tuple(sorted(set(t) - set(ORDER) - {"newton"})):
        if k not in t:
            continue
        c = cnt.get(k, 0)
        print(f"{k:40s} {1e3 * t[k] / m:12.1f} {100 * t[k] / t['total']:6.1f} {c / m:11.1f} "
              f"{1e3 * t[k] / c if c else float('nan'):9.3f}")
    if stats["cg_iterations"]:
        print(f"CG: {1e3 * t['cg'] / stats['cg_iterations']:.3f} ms per CG iteration")


def main_ab(p, n, frames, first, ov, commit):
    """``--ab``: before / after interleaved (module docstring)."""
    from lokigraph.behaviors.collision.intersect import intersect_meshes

    lb = before_linear(commit)
    runs, clocks, stats, wall, sims = {}, {}, {}, {}, {}
    for name in ("before", "after"):
        sim = Simulation(compile_file(p))
        if name == "before":
            make_before(sim, lb)
        clk = Clock()
        instrument(sim, clk)
        sims[name], clocks[name] = sim, clk
        runs[name] = (defaultdict(float), defaultdict(int))
        stats[name] = defaultdict(float)
        wall[name] = 0.0
    print(f"cloth_sphere_{n} implicit, 1 substep, overrides {ov}, numba threads "
          f"{__import__('numba').get_num_threads()}, before = {commit}'s PCG",
          flush=True)
    same_all = True
    for f in range(1, frames + 1):
        order = ["before", "after"] if f % 2 else ["after", "before"]
        q = {}
        for name in order:
            sim, clk = sims[name], clocks[name]
            clk.clear()
            t, w = time.process_time(), time.perf_counter()
            st = sim.step_frame()
            clk.t["total"] = time.process_time() - t
            clk.n["total"] = 1
            dw = time.perf_counter() - w
            x = sim.state.particle_q
            q[name] = np.concatenate([x, sim.state.particle_qd])
            sd = sim.compiled.schedule.find("StretchConstraint")[0].data
            strain = float((np.linalg.norm(x[sd.idx[:, 1]] - x[sd.idx[:, 0]], axis=1)
                            / sd.rest - 1.0).max())
            cl, ball = sim.compiled.scene.element("cloth"), sim.compiled.scene.element("ball")
            cm = (x[cl.vertex_slice], cl.geometry.triangles)
            pairs = int(intersect_meshes([cm], touching=False)[0])
            _, pr = intersect_meshes([cm, (x[ball.vertex_slice], ball.geometry.triangles)],
                                     touching=False)
            pairs += int((pr[:, 0] != pr[:, 2]).sum())
            print(f"frame {f} {name}: CPU {1e3 * clk.t['total']:.0f} ms (wall {1e3 * dw:.0f}),"
                  f" Newton {st.get('newton_iterations', 0)}, CG {st.get('cg_iterations', 0)},"
                  f" cg {1e3 * clk.t['cg']:.0f} ms, assemble {1e3 * clk.t['assemble']:.0f} ms, "
                  f"strain {100 * strain:.2f} %, pairs {pairs}", flush=True)
            stats[name]["strain"] = max(stats[name]["strain"], strain)
            stats[name]["pairs"] = max(stats[name]["pairs"], pairs)
            if f >= first:
                wall[name] += dw
                tt, tn = runs[name]
                for k, v in clk.t.items():
                    tt[k] += v
                for k, v in clk.n.items():
                    tn[k] += v
                for k in ("newton_iterations", "cg_iterations", "line_search_halvings"):
                    stats[name][k] += st.get(k, 0)
        same = bool(np.array_equal(q["before"], q["after"]))
        same_all &= same
        print(f"frame {f}: positions and velocities bitwise equal: {same}", flush=True)
    print(f"\nframes {first}..{frames}, bitwise equal in every frame: {same_all}")
    table(runs, first, frames, stats, wall)


if __name__ == "__main__":
    main(sys.argv[1:])
