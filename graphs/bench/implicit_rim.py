"""A skirt over a collider's rim with the implicit solver (issue #11):
graphs/examples/skirt_follow.yaml run with Nucleus and with ``solver: implicit`` at each
``edge_endpoint_rows`` setting; per frame the skirt's largest speed [m/s] (which vertex, its
ring: 0 the hem .. 8 the pinned waist) and the Newton iterations of the frame, per run the
largest count of intersecting pairs (skirt-body and skirt self) in a frame; with ``--rows
FRAME`` the contact rows with the largest normal forces at some Newton iterations of that
frame's substeps (the implicit solver's ``trace`` hook).

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_rim.py [frames] [--rows F] \
        [--modes keep skip skip_collider]

The skirt (24 x 9 vertices, radius 0.106 m, 3 mm thickness) hangs over the body (radius 0.1 m,
3 mm thickness, capped at y = 0.75 m): every skirt vertex sits at its contact distance, and the
skirt's rings 1-2 wrap the body's bottom rim. Measured (48 frames, one thread, one run after the
other):

    Nucleus                         largest skirt speed 0.458 m/s (frame 3)
    implicit, keep (the default)    0.941 m/s (frame 16; hem vertices in single frames: 0.5-0.94
                                    m/s in frames 3, 7, 9, 11, 12, 15, 16, 17, 20, 27, 34)
    implicit, skip                  0.342 m/s
    implicit, skip_collider         0.529 m/s

(the pinned waist ring rides the turning body at 0.289 m/s: the floor of every run after frame
24). ``--rows 30`` (keep): Newton ends at its cap (20) in all 4 substeps of the calm frame 30;
the largest normal forces, 11-17 N a row on a 0.05 kg skirt, sit at y = 0.743-0.75 (the rim);
summed over the rows up to 1,830 N (edge-edge) and 690 N (vertex-face) at a substep's first two
Newton iterations, 100-430 N and 50-210 N at iterations 10-20; the
contact of one skirt vertex there is one vertex-face row and 4-5 edge-edge rows (the skirt's
vertical edge against each body edge at the rim vertex, closest point that vertex) with the same
gap, so the penalty there is ~6 times a row's stiffness. Why ``skip`` is not the default: the
sleeve elbow and the trouser knee get faster (implicit_solver.edge_endpoint_rows' description).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from implicit_newton import solver_data  # noqa: E402

from lokigraph.api import compile_file  # noqa: E402
from lokigraph.bench.stress import cloth_body_pairs  # noqa: E402
from lokigraph.behaviors.solvers.implicit import solver as S  # noqa: E402
from lokigraph.run import Simulation  # noqa: E402

SCENE = Path(__file__).resolve().parents[1] / "examples" / "skirt_follow.yaml"


def build(mode):
    """(simulation, compiled) of skirt_follow with Nucleus (mode None) or the implicit solver
    with ``edge_endpoint_rows: mode``."""
    text = SCENE.read_text()
    assert text.count("lokigraph: 1\n") == 1
    if mode is not None:
        text = text.replace("lokigraph: 1\n", "lokigraph: 1\nsolver: implicit\ngraph_overrides: "
                            f"{{implicit_solver: {{edge_endpoint_rows: {mode}}}}}\n", 1)
    p = Path(tempfile.mkdtemp()) / "skirt_follow.yaml"
    p.write_text(text)
    c = compile_file(p)
    return Simulation(c), c


def speeds(mode, frames):
    """Per frame: (largest skirt speed, its vertex, Newton iterations, CPU s, skirt-body
    intersecting pairs + skirt self-intersecting pairs)."""
    sim, c = build(mode)
    sk, body = c.scene.element("skirt"), c.scene.element("body")
    sl = sk.vertex_slice
    out = []
    for _ in range(frames):
        t0 = time.process_time()
        st = sim.step_frame()
        cpu = time.process_time() - t0
        q = sim.state.particle_q
        s = np.linalg.norm(sim.state.particle_qd[sl], axis=1)
        n_pen, n_self = cloth_body_pairs(q, sk, [body])
        out.append((float(s.max()), int(s.argmax()), int(st.get("newton_iterations", 0)), cpu,
                    n_pen + n_self))
    return out


def rows_at(mode, frame, its=(1, 2, 10, 20), top=5):
    """The rows with the largest normal forces at Newton iterations ``its`` of every substep of
    ``frame`` (1-based), classified per vertex: B body, P pinned skirt, f free skirt."""
    sim, c = build(mode)
    sd = solver_data(sim)
    n_skirt = c.scene.element("skirt").vertex_slice.stop
    on = [False]
    orig = S.ImplicitSolver._trace_end

    def trace_end(self, ctx, d, x, xt, opts, tr0, it_n, *a):
        orig(self, ctx, d, x, xt, opts, tr0, it_n, *a)
        if not on[0] or it_n not in its:
            return
        fixed = d.cur_fixed
        for rows, nrm, tgt, mu, coef, kr, lam, _lp, is_vf, _mk, sel, ns in d.rows["sets"]:
            s = sel[:ns[0]]
            kind = "vf" if is_vf else "ee"
            for r in s[np.argsort(-lam[s])[:top]]:
                vs = rows[r]
                cls = "".join("B" if v >= n_skirt else ("P" if fixed[v] else "f") for v in vs)
                gap = float(nrm[r] @ (coef[r] @ x[vs])) - tgt[r]
                print(f"  it {it_n:2d} {kind} row {r:5d} {str(vs.tolist()):22s} {cls} lam "
                      f"{lam[r]:6.2f} N gap {1e3 * gap:+.3f} mm coef "
                      f"{np.round(coef[r], 3).tolist()} y {x[vs[0], 1]:.3f}")
            print(f"  it {it_n:2d} {kind}: live {ns[0]}, active {int((lam[s] > 0).sum())}, "
                  f"normal forces summed {lam[s].sum():.1f} N")

    S.ImplicitSolver._trace_end = trace_end
    try:
        for _ in range(frame - 1):
            sim.step_frame()
        sd.data.trace = []
        on[0] = True
        st = sim.step_frame()
    finally:
        S.ImplicitSolver._trace_end = orig
    print(f"frame {frame} ({mode}): Newton {st.get('newton_iterations')} over "
          f"{c.model.substeps} substeps, line-search halvings {st.get('line_search_halvings')}")


def main(argv):
    args = list(argv)
    rows = None
    if "--rows" in args:
        i = args.index("--rows")
        rows = int(args[i + 1])
        del args[i:i + 2]
    modes = ["keep", "skip", "skip_collider"]
    if "--modes" in args:
        i = args.index("--modes")
        modes = args[i + 1:]
        del args[i:]
    frames = int(args[0]) if args else 48
    if rows is not None:
        for m in modes:
            rows_at(m, rows)
        return
    runs = {"nucleus": speeds(None, frames)}
    for m in modes:
        runs[m] = speeds(m, frames)
    names = list(runs)
    print("frame | " + " | ".join(f"{n}: vmax (vertex, ring) newton" for n in names))
    for f in range(frames):
        cells = []
        for n in names:
            v, i, nw, _, _ = runs[n][f]
            cells.append(f"{v:.3f} ({i}, {i // 24}) {nw}")
        print(f"{f + 2:5d} | " + " | ".join(cells))
    for n in names:
        v = np.array([r[0] for r in runs[n]])
        cpu = sum(r[3] for r in runs[n][1:])
        pairs = max(r[4] for r in runs[n])
        print(f"{n}: largest skirt speed {v.max():.3f} m/s (frame {int(v.argmax()) + 2}), "
              f"frames over 0.458 m/s {int((v > 0.458).sum())}, CPU frames 3-{frames + 1} "
              f"{cpu:.1f} s, intersecting pairs (skirt-body + skirt self) at most {pairs} in "
              f"a frame")


if __name__ == "__main__":
    main(sys.argv[1:])
