"""The sleeve_elbow per frame with compliant_kinematics: energy (issue #11): the sleeve's
largest speed, the largest within 0.15 m of the joint (tests/test_elbow.py's crease speed,
bound 0.73 m/s) and where the fastest vertex is, the compliant vertices' largest and mean
distance from their animation (recession) and Newton iterations per substep.

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_compliant_elbow.py 100 [k=v ...]

The first argument is compliant_shape_stiffness; compliant_depth 0.01 unless given; other
``k=v`` become implicit_solver overrides. Measured at 0 / 100: near-joint speed 0.928 m/s
(frame 42) / 1.473 m/s (frame 16); mean recession at frame 8 1.85 / 10.1 mm, largest 10.1 /
13.0 mm (graphs/bench/implicit_compliant_shape.py).
"""

import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import implicit_knee as K  # noqa: E402

from lokigraph.api import compile_file  # noqa: E402
from lokigraph.run import Simulation  # noqa: E402

s = sys.argv[1] if len(sys.argv) > 1 else "0"
ov = {"compliant_kinematics": "energy", "compliant_depth": "0.01",
      "compliant_shape_stiffness": s, **dict(a.split("=", 1) for a in sys.argv[2:])}
tmp = Path(tempfile.mkdtemp())
for m in K.SCENES["sleeve_elbow"][1]:
    shutil.copy(K.EX / m, tmp / m)
p = tmp / "sleeve_elbow.yaml"
p.write_text(K.scene_text("sleeve_elbow", ov))
c = compile_file(p)
sim = Simulation(c)
cl = c.scene.element("sleeve")
comp = np.flatnonzero(c.model.particle_compliant)
for f in range(60):
    st = sim.step_frame()
    q, v, a = sim.state.particle_q, sim.state.particle_qd, sim.control.kinematic_q
    sp = np.linalg.norm(v[cl.vertex_slice], axis=1)
    near = np.linalg.norm(q[cl.vertex_slice], axis=1) < 0.15
    rc = np.linalg.norm(q[comp] - a[comp], axis=1)
    i = int(sp.argmax())
    print(f"frame {f + 2}: vmax {sp.max():.3f} near {sp[near].max() if near.any() else 0:.3f} "
          f"(fastest at |x| {np.linalg.norm(q[cl.vertex_slice][i]):.3f}), recession max "
          f"{1000 * rc.max():.1f} mm mean {1000 * rc.mean():.2f} mm, newton/sub "
          f"{st.get('newton_iterations', 0) / c.model.substeps:.1f}", flush=True)
