"""Why Newton does not converge at contact (issue #11): the implicit solver's Newton iterations
one by one, from the solver's ``trace`` hook (``_ImplicitData.trace``), on the cloth-on-sphere
drops and the sleeve elbow.

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_newton.py drop 64 10 [k=v ...]
    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_newton.py elbow 60 [k=v ...]

``k=v`` become implicit_solver overrides. Per frame: Newton iterations, substeps that reached
the cap, and which stop test held them there (``step``: the Newton step was still above
newton_tolerance at the cap; ``lag``: the step was below it but a lagged normal force still
changed by more than contact_tolerance). With ``--iters F`` (a frame, 1-based) every Newton
iteration of that frame's substeps: |dx| [m/s] (the Newton step, before the line search),
alpha (the line search's), E0 -> E1 the incremental potential before and after the line
search (rows lagged at the old iterate), E2 after re-lagging at the new iterate, the largest
lagged normal-force change dl [N] and the largest force top [N], its largest change over
stiffness dgap [m], live rows, active rows, rows entering / leaving the active set, and the
2-norms of the gradient, of the contact rows' friction part and of their normal part; with
``--brief`` a shorter table with the full Newton step's energy change by parts (penalty of the
contact rows, their friction, the rest: inertia + elastic) against the quadratic model's
prediction g.dx + dx.A dx / 2.

Since stop 36 the implicit solver's defaults put compliant kinematic vertices in the solve
(compliant_kinematics: energy, compliant_depth 0.01); the figures below for the defaults were
measured with compliant_kinematics: dirichlet (add compliant_kinematics=dirichlet to rerun them).

Measured (defaults, 1 thread; frames 1-based):

- Which stop test holds Newton at its cap: the step test, in every capped substep of the 64x64
  drop (frames 6-10) and of the sleeve_elbow (60 frames, 4 substeps a frame, frames 50-60 at
  rest): the lagged-force test was never the only one failing (``capped(step/lag)`` k/0).
- 64x64 drop, frame 8 (impact): the Newton step is 3.2 m/s at the first iteration and 0.14 m/s
  at the 20th, over newton_tolerance at every free vertex (4,225 of 4,225) in every iteration,
  not at a few contact vertices; line-search alpha 2^-8 .. 1 (mostly 0.25-0.5); 100-700 rows
  enter and leave the active set per iteration; re-lagging moves E by as much as the line
  search lowered it (E2 - E1 up to 1.1e-2 J against E0 - E1 6e-3 J). Without friction
  (``--nofric``) and with contact_newton_iterations=100 it still ends at the cap (20 / 100).
- sleeve_elbow at rest, frame 58: steps 0.004-0.18 m/s, alpha 2^-9 .. 2^-2 in most
  iterations. The full step's energy change by parts: the model predicts -1e-6 .. -1e-4 J,
  the contact penalty rises by +1e-6 .. +6.6e-2 J (the step drives into rows open at the
  iterate, which have no curvature in the model), friction and the rest stay within the
  prediction. With contact_sticky (+ contact_hessian: coupled) the penalty's excess is gone
  after the second iteration, and then friction (+8e-6 J against a predicted -4e-6 J) and
  the rest (+5e-6 J: the elastic energies' nonlinearity) cut the steps; Newton still ends at
  its cap. Freezing the lag after 4 iterations (tried with a setting since removed: the later
  iterations then minimise one fixed energy) does not make the line search take full steps
  either (alpha 1/16-1/8).
- contact_reach=0.0005 (+ coupled) at the elbow: full steps (alpha 1) and a stable active set,
  but the step shrinks only ~10 % per iteration (the near rows' curvature damps the vertices
  leaving them): 19.6 Newton iterations per substep at rest, near-joint speed 0.999 / 1.052
  m/s.
"""

from __future__ import annotations

import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import implicit_drop as D  # noqa: E402
import implicit_knee as K  # noqa: E402

from lokigraph.api import compile_file  # noqa: E402
from lokigraph.behaviors.collision.intersect import intersect_meshes  # noqa: E402
from lokigraph.run import Simulation  # noqa: E402


def solver_data(sim):
    from lokigraph.behaviors.solvers.implicit.solver import ImplicitSolver
    return next(b for b in sim.schedule.all() if isinstance(b.behavior, ImplicitSolver))


def build(kind, n, overrides, nofric=False):
    """(simulation, compiled, cloth element, body elements) of the scene; ``nofric``: every
    ``friction:`` of the scene text set to 0."""
    tmp = Path(tempfile.mkdtemp())
    if kind == "drop":
        p = tmp / f"cloth_sphere_{n}_implicit.yaml"
        text = D.scene_text(n, 1, overrides)
        cloth, bodies = "cloth", ("ball",)
    else:
        yaml, maps, cloth, bodies, _ = K.SCENES["sleeve_elbow"]
        for m in maps:
            shutil.copy(K.EX / m, tmp / m)
        p = tmp / "sleeve_elbow_implicit.yaml"
        text = K.scene_text("sleeve_elbow", overrides)
    if nofric:
        text = re.sub(r"friction: [0-9.e+-]+", "friction: 0.0", text)
    p.write_text(text)
    c = compile_file(p)
    sim = Simulation(c)
    return sim, c, c.scene.element(cloth), [c.scene.element(b) for b in bodies]


def substeps_of(trace):
    """Split a trace into substeps (it restarts at 1)."""
    out = []
    for r in trace:
        if r["it"] == 1:
            out.append([])
        out[-1].append(r)
    return out


def frame_row(kind, sim, c, cl, bodies, st, cpu, trace, cap, tol):
    q, v = sim.state.particle_q, sim.state.particle_qd
    cm = (q[cl.vertex_slice], cl.geometry.triangles)
    nself = int(intersect_meshes([cm], touching=False)[0])
    pen = 0
    for e in bodies:
        _, pairs = intersect_meshes([cm, (q[e.vertex_slice], e.geometry.triangles)],
                                    touching=False)
        pen += int((pairs[:, 0] != pairs[:, 2]).sum())
    sd = c.schedule.find("StretchConstraint")[0].data
    strain = float((np.linalg.norm(q[sd.idx[:, 1]] - q[sd.idx[:, 0]], axis=1) / sd.rest
                    - 1.0).max())
    speed = np.linalg.norm(v[cl.vertex_slice], axis=1)
    near = np.linalg.norm(q[cl.vertex_slice], axis=1) < 0.15
    subs = substeps_of(trace)
    capped = [s for s in subs if len(s) >= cap]
    by_step = sum(1 for s in capped if s[-1]["dx"] >= tol)
    return dict(strain=strain, self=nself, pen=pen, vmax=float(speed.max()),
                vnear=float(speed[near].max()) if near.any() else 0.0,
                newton=int(st.get("newton_iterations", 0)), cg=int(st.get("cg_iterations", 0)),
                subs=len(subs), capped=len(capped), by_step=by_step,
                by_lag=len(capped) - by_step, cpu=cpu,
                halvings=int(st.get("line_search_halvings", 0)))


def print_iters(trace, brief=False):
    if brief:
        print("   it    |dx|m/s  alpha  +in -out      |g|   |g_fric| |g_norm|  cg |"
              " full step dE: model    actual   penalty  friction      rest")
        for r in trace:
            print(f"  {r['it']:3d} {r['dx']:10.3e} {r['alpha']:6.3g} {r['enter']:4d}"
                  f" {r['leave']:4d} {r['g']:8.2e} {r['g_fric']:10.2e} {r['g_normal']:8.2e}"
                  f" {r['cg']:3d} | {r['dE_pred']:18.2e} {r['dE_full']:9.2e}"
                  f" {r['dE_pen']:9.2e} {r['dE_fric']:9.2e} {r['dE_rest']:9.2e}")
        return
    print("   it    |dx|m/s  alpha         E0-E1     E2-E1       dl_N      top_N     dgap_m"
          "   live active  +in -out      |g|   |g_fric| |g_norm|  cg  cg_res lag_ok"
          "  over(rows)  p99")
    for r in trace:
        print(f"  {r['it']:3d} {r['dx']:10.3e} {r['alpha']:6.3g} {r['E0'] - r['E1']:13.4e}"
              f" {r['E2'] - r['E1']:9.2e} {r['dl']:10.3e} {r['top']:10.3e} {r['dgap']:10.3e}"
              f" {r['live']:6d} {r['active']:6d} {r['enter']:4d} {r['leave']:4d}"
              f" {r['g']:8.2e} {r['g_fric']:10.2e} {r['g_normal']:8.2e} {r['cg']:3d}"
              f" {r['cg_res']:7.1e}"
              f" {int(r['lagged_ok'])} {r['n_over']:6d}({r['n_over_rows']:5d}) {r['p99']:8.2e}")


def main(argv):
    kind = argv.pop(0)
    n = int(argv.pop(0)) if kind == "drop" else 0
    frames = int(argv.pop(0))
    iters = set()
    while "--iters" in argv:
        i = argv.index("--iters")
        iters.add(int(argv[i + 1]))
        del argv[i:i + 2]
    nofric = "--nofric" in argv
    brief = "--brief" in argv
    argv = [a for a in argv if a not in ("--nofric", "--brief")]
    ov = dict(a.split("=", 1) for a in argv)
    sim, c, cl, bodies = build(kind, n, ov, nofric)
    b = solver_data(sim)
    P = b.behavior.params
    cap, tol = P.contact_newton_iterations, P.newton_tolerance
    print(f"{kind} {n or ''} implicit, overrides {ov}, cap {cap}, tol {tol}"
          f"{', no friction' if nofric else ''}")
    print(" frame strain%  self  pen  vmax  vnear newton  cg  subs capped(step/lag) halv  cpu_ms")
    for f in range(1, frames + 1):
        b.data.trace = []
        t0 = time.process_time()
        st = sim.step_frame()
        cpu = time.process_time() - t0
        r = frame_row(kind, sim, c, cl, bodies, st, cpu, b.data.trace, cap, tol)
        print(f" {f:5d} {100 * r['strain']:7.2f} {r['self']:5d} {r['pen']:4d} {r['vmax']:5.3f}"
              f" {r['vnear']:5.3f} {r['newton']:6d} {r['cg']:5d} {r['subs']:4d}"
              f" {r['capped']:4d}({r['by_step']}/{r['by_lag']}) {r['halvings']:5d}"
              f" {1e3 * cpu:7.0f}", flush=True)
        if f in iters:
            for k, s in enumerate(substeps_of(b.data.trace)):
                print(f"  frame {f} substep {k + 1}")
                print_iters(s, brief)
                if brief:
                    break
    b.data.trace = None


if __name__ == "__main__":
    main(sys.argv[1:])
