"""graphs/examples/pressure_ball.yaml with solver: implicit at several values of
implicit_solver.friction_slip_curvature (the friction block's curvature kept along the slip
direction of analytic-collider contacts; 'irls' = friction_hessian irls), with and without
the ball's Pressure: per setting the largest vertex speed after landing (frames 12 on), Newton
iterations and line-search halvings per frame, CPU per frame and the lowest vertex. One process,
the settings stepped frame by frame in turn (interleaved).

    NUMBA_NUM_THREADS=1 python graphs/bench/implicit_friction_floor.py [frames] [values ...]

values: floats in [0, 1] or 'irls' (default 0 0.1 0.2 0.5 irls); frames default 48.
"""

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lokigraph.api import compile_file
from lokigraph.run import Simulation

EX = Path(__file__).resolve().parents[1] / "examples" / "pressure_ball.yaml"
PRESSURE = "      Pressure: {mode: volume, volume_scale: 1.3}\n"


def scene(value, pressure):
    text = EX.read_text()
    assert PRESSURE in text
    if not pressure:
        text = text.replace(PRESSURE, "")
    ov = ("{friction_hessian: irls}" if value == "irls"
          else f"{{friction_slip_curvature: {float(value)}}}")
    text = text.replace("graph: default\n", "graph: default\nsolver: implicit\n"
                        f"graph_overrides: {{implicit_solver: {ov}}}\n", 1)
    p = Path(tempfile.mkdtemp()) / "ball.yaml"
    p.write_text(text)
    return Simulation(compile_file(p))


def main(argv):
    frames = int(argv[0]) if argv else 48
    values = argv[1:] or ["0", "0.1", "0.2", "0.5", "irls"]
    runs = [(v, pr, scene(v, pr)) for pr in (True, False) for v in values]
    rec = {(v, pr): [] for v, pr, _ in runs}
    for f in range(frames):
        for v, pr, sim in runs:
            t = time.process_time()
            st = sim.step_frame()
            cpu = time.process_time() - t
            q, qd = sim.state.particle_q, sim.state.particle_qd
            rec[(v, pr)].append((cpu, float(np.linalg.norm(qd, axis=1).max()),
                                 st.get("newton_iterations", 0),
                                 st.get("line_search_halvings", 0), float(q[:, 1].min()),
                                 bool(np.isfinite(q).all())))
    print("| Pressure | friction_slip_curvature | largest speed frames 12+ m/s | Newton / frame "
          "| halvings / frame | CPU ms / frame (median) | lowest vertex m | finite |")
    print("|---|---|---|---|---|---|---|---|")
    for (v, pr), r in rec.items():
        a = np.array([x[:5] for x in r])
        print(f"| {'yes' if pr else 'no'} | {v} | {a[11:, 1].max():.2f} | {a[:, 2].mean():.1f} "
              f"| {a[:, 3].mean():.1f} | {1000 * np.median(a[1:, 0]):.0f} | {a[:, 4].min():.4f} "
              f"| {all(x[5] for x in r)} |")


if __name__ == "__main__":
    main(sys.argv[1:])
