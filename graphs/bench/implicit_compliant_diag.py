"""Why compliant_kinematics: energy fails at the trouser knee (issue #11): per frame, the
compliant leg vertices' largest distance from their animation ("recession"), how many thigh /
shin triangles are inverted against their animated pose, the cloth's largest speed, the held
contact rows, the rows' complementarity residual and the projection pass's largest move.

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_compliant_diag.py 25 \
        [scale=10] [k=v ...]

``scale`` multiplies the knee's painted compliant stiffness (2e4); other ``k=v`` become
implicit_solver overrides (compliant_kinematics=energy to put the compliant vertices in the
solve). Measured (energy, compliant_solve block, painted stiffness): 2 inverted triangles at
frame 5, 22 at 16, 97 at 23; recession 20.9 mm at frame 5, 63.8 mm at 22, 138 mm at 23; the
trouser intersects the leg from frame 24 (graphs/bench/implicit_knee.py). With scale=10: 0
inverted to frame 12, 25 at frame 25, recession 56.9 mm at 25, speeds <= 1.68 m/s to frame 26,
but intersecting pairs from frame 28 (graphs/bench/implicit_knee.py knee
compliant_kinematics=energy compliant_solve=block scale=10). With compliant_depth=0.01 (default
compliant_solve cg): at most 7 inverted triangles to frame 26, recession 10.2 mm at frame 5,
41.4 mm at 25 (the cap is a soft penalty), 0 intersecting pairs through the whole knee.
"""

import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from implicit_knee import scene_text  # noqa: E402

from lokigraph.api import compile_file  # noqa: E402
from lokigraph.run import Simulation  # noqa: E402

frames = int(sys.argv[1]) if len(sys.argv) > 1 else 25
ov = dict(a.split("=", 1) for a in sys.argv[2:])
scale = float(ov.pop("scale", 1.0))
tmp = Path(tempfile.mkdtemp())
p = tmp / "knee.yaml"
p.write_text(scene_text("knee", ov).replace("value: 2.0e4", f"value: {2.0e4 * scale:g}"))
c = compile_file(p)
sim = Simulation(c)
m = c.model
comp = np.flatnonzero(m.particle_compliant)
cl = c.scene.element("trouser")
for f in range(frames):
    st = sim.step_frame()
    q, a = sim.state.particle_q, sim.control.kinematic_q
    d = np.linalg.norm(q[comp] - a[comp], axis=1)
    v = np.linalg.norm(sim.state.particle_qd[cl.vertex_slice], axis=1)
    flips = 0
    for nm in ("thigh", "shin"):
        e = c.scene.element(nm)
        T = e.geometry.triangles
        qa, qb = q[e.vertex_slice], a[e.vertex_slice]
        na = np.cross(qa[T[:, 1]] - qa[T[:, 0]], qa[T[:, 2]] - qa[T[:, 0]])
        nb = np.cross(qb[T[:, 1]] - qb[T[:, 0]], qb[T[:, 2]] - qb[T[:, 0]])
        flips += int(((na * nb).sum(1) < 0).sum())
    print(f"frame {f + 2}: inverted triangles {flips}, recession max {d.max() * 1000:.1f} mm "
          f"(> 1 cm: {int((d > 0.01).sum())}), cloth vmax {v.max():.2f} m/s, held rows "
          f"{st.get('held_rows', 0)}, complementarity {1000 * st.get('max_complementarity', 0):.2f}"
          f" mm, projection move {st.get('max_projection_move', 0) * 1000:.1f} mm", flush=True)
