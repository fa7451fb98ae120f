"""The hard rows' augmented Lagrangian multipliers of the implicit solver per frame (issue #11):
the largest stretch multipliers (tension, compression) [N], the cloth's edge strain range, its
largest speed [m/s] and the projection pass's largest move [m], on the scenes of
graphs/bench/implicit_knee.py.

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_multipliers.py knee 16 \
        hard_multipliers=always

Measured on the knee (16 frames): with hard_multipliers=always the largest multiplier grows from
10 N at frame 2 to 1,660 N (and -1,680 N) at frame 17, edge strain -0.71 .. +1.18 at frame 17
(+1.63 at frame 12), speed up to 4.95 m/s, projection moves up to 3.2 cm; with the default
(converged) the multipliers stay 0 (Newton stops at its cap in every substep), strain
-0.43 .. +0.53 at frame 17, speed up to 1.60 m/s, projection moves up to 7.3 mm.

Since stop 36 the implicit solver's defaults put compliant kinematic vertices in the solve
(compliant_kinematics: energy, compliant_depth 0.01); the figures above for the defaults were
measured with compliant_kinematics: dirichlet (add compliant_kinematics=dirichlet to rerun them).
"""

from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import implicit_knee as K  # noqa: E402

from lokigraph.api import compile_file  # noqa: E402
from lokigraph.run import Simulation  # noqa: E402


def main(name, frames, overrides):
    yaml, maps, cloth_name, _, _ = K.SCENES[name]
    tmp = Path(tempfile.mkdtemp())
    for m in maps:
        shutil.copy(K.EX / m, tmp / m)
    p = tmp / f"{name}_implicit.yaml"
    p.write_text(K.scene_text(name, overrides))
    c = compile_file(p)
    sim = Simulation(c)
    stretch = [b.data for b in sim.schedule.constraints
               if type(b.behavior).__name__ == "StretchConstraint"][0]
    cl = c.scene.element(cloth_name)
    for f in range(frames):
        st = sim.step_frame()
        lam = getattr(stretch, "_implicit_lam", np.zeros(1))
        q = sim.state.particle_q
        e = stretch.idx
        strain = np.linalg.norm(q[e[:, 0]] - q[e[:, 1]], axis=1) / stretch.rest - 1.0
        v = np.linalg.norm(sim.state.particle_qd[cl.vertex_slice], axis=1).max()
        print(f"frame {f + 2}: multipliers {lam.max():8.2f} {lam.min():8.2f} N, strain "
              f"{strain.min():+.3f} {strain.max():+.3f}, vmax {v:.2f} m/s, projection move "
              f"{st.get('max_projection_move', 0.0):.4f} m, kept "
              f"{st.get('kept_multipliers', 0):.0f}", flush=True)


if __name__ == "__main__":
    name = sys.argv[1] if len(sys.argv) > 1 else "knee"
    args = sys.argv[2:]
    frames = int(args.pop(0)) if args and args[0].isdigit() else 16
    main(name, frames, dict(a.split("=", 1) for a in args))
