"""A rope over a drum (capsule R = 5 cm, wrap pi): the capstan threshold T1/T2 = exp(mu pi)
with both solvers. Settings measured in one run (on a shared machine compare ratios).

    .venv/bin/python graphs/bench/capstan.py implicit   # end weights: ratio sweep
    .venv/bin/python graphs/bench/capstan.py ablation   # the implicit contact fixes one by one
    .venv/bin/python graphs/bench/capstan.py nucleus    # uniform heavy rope, Nucleus settings
    .venv/bin/python graphs/bench/capstan.py heavy      # the same rope, implicit settings

``implicit`` / ``ablation``: the scene of tests/test_implicit_capstan.py (light rope, 0.01
kg/m, with end weights; its discrete limit is 1.011 exp(mu pi)). ``nucleus``: a uniform rope
of 0.05 kg/m hanging 8 cm on the light side and ``f exp(mu pi)`` times that on the heavy side
(no end weights): the rope on the drum (16 chords, 8 g) weighs twice the light side, so its
limit, from a force balance of every arc vertex
(``lokigraph.bench.references.capstan_limit``), is 1.49 exp(mu pi), not
exp(mu pi). Columns: the heavy end's displacement, the largest segment strain, the wrap's
largest lift off the drum, Newton iterations per substep (implicit), CPU seconds.
"""

from __future__ import annotations

import math
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lokigraph.bench.references import capstan_limit

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))

import test_implicit_capstan as T  # noqa: E402  (the test's scene and measurements)

from lokigraph.compile import compile_scene  # noqa: E402
from lokigraph.run import Simulation  # noqa: E402
from lokigraph.scene import load_scene  # noqa: E402

MU = 0.3
E = math.exp(MU * math.pi)


def _tmp() -> Path:
    return Path(tempfile.mkdtemp(prefix="capstan_"))


def implicit(ratios=(0.9, 0.95, 0.98, 1.02, 1.05, 1.1), overrides="", label="defaults"):
    for f in ratios:
        frames = 48 if f < 1 else 20
        c, sim, m = T._scene(_tmp(), f * E, MU, frames, overrides)
        q0 = c.model.particle_q0
        t0 = time.process_time()
        newton, ys = [], []
        L0 = np.linalg.norm(np.diff(q0, axis=0), axis=1)
        strain, lift = 0.0, 0.0
        for _ in range(frames):
            st = sim.step_frame()
            q = sim.state.particle_q
            ys.append(q[:, 1].copy())
            newton.append(st["newton_iterations"])
            strain = max(strain, float(np.abs(np.linalg.norm(np.diff(q, axis=0), axis=1)
                                              / L0 - 1).max()))
            r = np.hypot(q[:, 0], q[:, 1])
            up = q[:, 1] > 0
            lift = max(lift, float(r[up].max()) - T.R if up.any() else np.inf)
        cpu = time.process_time() - t0
        ys = np.array(ys)
        s = (f"{label:26s} W1/W2 = {f:.2f} e: end {1000 * (ys[-1, 0] - q0[0, 1]):+9.2f} mm at "
             f"{frames / 24:.2f} s (from 0.5 s {1000 * (ys[-1, 0] - ys[11, 0]):+8.3f}); strain "
             f"{100 * strain:.2f} %; lift {1000 * lift:.3f} mm; Newton {np.mean(newton):.1f}; "
             f"CPU {cpu:.2f} s")
        if f > 1:
            r12, _ = T._tension_ratio(ys, m, (6, frames))
            s += f"; sliding T1/T2 = {r12 / E:.3f} e"
        print(s, flush=True)


def ablation():
    import lokigraph.behaviors.materials.rod as rod

    keep = rod._rod_hard_k
    for label, ov, strand in (("all (defaults)", "", True),
                              ("contact_multipliers off", ", contact_multipliers: false", True),
                              ("contact_start inertial", ", contact_start: inertial", True),
                              ("per-row hard k", "", False),
                              ("none (as before)", ", contact_multipliers: false, "
                                                   "contact_start: inertial", False)):
        rod._rod_hard_k = keep if strand else (lambda d, opts: opts.hard_k)
        try:
            implicit((0.95, 1.05), ov, label)
        finally:
            rod._rod_hard_k = keep


def heavy_rope(d: Path, f: float, substeps: int, overrides: str = "", R=0.05, L2=0.08,
               seg=0.01, na=16, rho=0.05, solver="nucleus"):
    """The uniform heavy rope (module docstring)."""
    L1 = f * E * L2
    n1, n2 = int(round(L1 / seg)), int(round(L2 / seg))
    left = [(-R, -L1 + L1 * k / n1, 0.0) for k in range(n1)]
    arc = [(R * math.cos(math.pi - math.pi * k / na), R * math.sin(math.pi - math.pi * k / na),
            0.0) for k in range(na + 1)]
    right = [(R, -L2 * k / n2, 0.0) for k in range(1, n2 + 1)]
    P = np.array(left + arc + right)
    with open(d / "rope.obj", "w") as fh:
        for p in P:
            fh.write("v %.17g %.17g %.17g\n" % tuple(p))
        fh.write("l " + " ".join(str(i + 1) for i in range(len(P))) + "\n")
    (d / "rope.yaml").write_text(f"""
lokigraph: 1
frames: {{start: 1, end: 25, fps: 24}}
substeps: {substeps}
solver: {solver}
{f"graph_overrides: {{{overrides}}}" if overrides else ""}
elements:
  - name: rope
    geometry: {{file: rope.obj}}
    components:
      Dynamic: {{mass_density: {rho}}}
      Rod: {{radius: 1.0e-3, bend_resistance: 1.0e-7}}
  - name: drum
    components: {{ShapeCollider: {{shape: capsule, center: [0, 0, 0], axis: [0, 0, 1],
                                  radius: {R}, length: 0.4, friction: {MU}}}}}
""")
    c = compile_scene(load_scene(d / "rope.yaml"))
    return c, Simulation(c), n1


def nucleus(solver="nucleus", runs=((1, ""), (1, "nucleus_solver: {iterations: 60}"), (4, ""),
                                     (4, "nucleus_solver: {iterations: 60}"), (16, ""))):
    c, _sim, n1 = heavy_rope(_tmp(), 1.0, 1)
    m = c.model.particle_mass
    lim = capstan_limit(c.model.particle_q0, m, n1, n1 + 16, MU)
    print(f"uniform heavy rope: its limit W1/W2 = {lim / E:.3f} exp(mu pi) (f = 1 hangs "
          f"W1/W2 = {m[:n1].sum() / m[n1 + 17:].sum() / E:.3f} exp(mu pi): the last half "
          f"segments)")
    for f in (0.95, 1.3, 1.7):
        for subs, ov in runs:
            c, sim, n1 = heavy_rope(_tmp(), f, subs, ov, solver=solver)
            q0 = c.model.particle_q0
            L0 = np.linalg.norm(np.diff(q0, axis=0), axis=1)
            t0 = time.process_time()
            strain, lift = 0.0, 0.0
            for _ in range(24):
                sim.step_frame()
                q = sim.state.particle_q
                strain = max(strain, float(np.abs(np.linalg.norm(np.diff(q, axis=0), axis=1)
                                                  / L0 - 1).max()))
                r = np.hypot(q[:, 0], q[:, 1])
                up = q[:, 1] > 0
                lift = max(lift, float(r[up].max()) - 0.05 if up.any() else np.inf)
            it = re.search(r"iterations: (\d+)", ov)
            mm = c.model.particle_mass
            x = mm[:n1].sum() / mm[n1 + 17:].sum() / lim
            how = ((it.group(1) if it else "15") + " iterations" if solver == "nucleus" else ov)
            print(f"{solver} f {f:.2f} ({x:.2f} x its limit) substeps {subs:2d} {how}: end "
                  f"{1000 * (q[0, 1] - q0[0, 1]):+9.2f} mm in 1 s; strain {100 * strain:7.2f} %; "
                  f"lift {1000 * lift:.2f} mm; CPU {time.process_time() - t0:.2f} s", flush=True)


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "implicit"
    irls = "implicit_solver: {friction_hessian: irls}"
    {"implicit": implicit, "ablation": ablation, "nucleus": nucleus,
     "heavy": lambda: nucleus("implicit", ((1, ""), (4, ""), (1, irls), (4, irls)))}[what]()
