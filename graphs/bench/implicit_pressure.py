"""Enclosed-volume pressure in the implicit solve (issue #11, ``pressure.implicit``): volume
error, speeds and cost of each setting, one run after the other in one process.

    NUMBA_NUM_THREADS=1 python graphs/bench/implicit_pressure.py 1:2e5:energy 1:2e5:projection 4:2e5:energy 4:2e5:projection
    NUMBA_NUM_THREADS=1 python graphs/bench/implicit_pressure.py 4:2e4:energy 4:2e4:projection 8:2e4:energy 8:2e4:projection
    NUMBA_NUM_THREADS=1 python graphs/bench/implicit_pressure.py --diag 1:2e5:energy 4:2e5:energy

``SUBSTEPS:YOUNGS:IMPLICIT[:KEY=VALUE,...]``: graphs/examples/pressure_ball.yaml (a closed
cloth sphere inflated to 1.3 x its rest volume, dropped onto the ground from 1 m; 40 frames)
with ``solver: implicit``, that many substeps, the shell's Young's modulus (the example's is
2e4) and ``pressure: {implicit: IMPLICIT, KEY: VALUE}`` (``solver.KEY=VALUE``: an
implicit_solver parameter, e.g. ``solver.preconditioner=amg_reuse``; ``subdivisions=N``: the
ball's icosphere subdivisions, 3 in the example: 642 vertices, 4: 2,562). Per run: the
largest relative volume error at the end of a frame (after the projection pass and the ground's safety projection) and
in the Newton solution (``max_volume_error_solve``, before the projection pass), the largest
vertex speed from frame 12 on (the ball lands at frame ~10), the lowest vertex height, CPU
[s] per frame (frames 2-40, ``time.process_time``), Newton and CG iterations per frame.
``--diag``: each run twice, with the rank-one terms' diagonal blocks in the Newton matrix
(``solver.LOWRANK_DIAG`` True: the preconditioner holds them) and without (False, the
default).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

FRAMES = 40


def scene_text(substeps, youngs, implicit, frames=FRAMES, extra="", solver="", subdivisions=3):
    """pressure_ball.yaml with solver: implicit and the given settings (``extra``, ``solver``:
    ", key: value" text of the pressure / implicit_solver overrides)."""
    t = (ROOT / "graphs" / "examples" / "pressure_ball.yaml").read_text()
    t = t.replace("subdivisions: 3", f"subdivisions: {subdivisions}")
    over = (f"graph_overrides: {{pressure: {{implicit: {implicit}{extra}}}"
            + (f", implicit_solver: {{{solver[2:]}}}" if solver else "") + "}")
    t = t.replace("graph: default", f"graph: default\nsolver: implicit\n{over}", 1)
    t = t.replace("substeps: 4", f"substeps: {substeps}").replace("end: 48", f"end: {frames}")
    return t.replace("youngs_modulus: 2.0e4", f"youngs_modulus: {float(youngs)!r}")


def measure(path, frames=FRAMES):
    """Per frame: relative volume error at the frame's end, the frame's statistics, the
    largest speed and lowest height of the ball's vertices, CPU seconds."""
    from behaviors.materials.pressure import mesh_volume
    from lokigraph.api import compile_file
    from lokigraph.components.materials import Pressure
    from lokigraph.run import Simulation

    c = compile_file(path)
    sim = Simulation(c)
    e = c.scene.element("ball")
    tris = e.geometry.triangles + e.vertex_offset
    V0 = mesh_volume(sim.model.particle_rest, tris) * e.get(Pressure).volume_scale
    rows = []
    for _ in range(frames):
        t = time.process_time()
        st = sim.step_frame()
        cpu = time.process_time() - t
        q = sim.state.particle_q
        rows.append(dict(dv=abs(mesh_volume(q, tris) / V0 - 1.0), st=st, cpu=cpu,
                         v=float(np.abs(sim.state.particle_qd[e.vertex_slice]).max()),
                         y=float(q[e.vertex_slice, 1].min())))
    return rows, sim


def summary(rows):
    st = [r["st"] for r in rows]
    n = len(rows) - 1
    return (f"volume err {max(r['dv'] for r in rows) * 100:8.3f} % | in the solve "
            f"{max(s.get('max_volume_error_solve', 0.0) for s in st) * 100:9.3f} % | speed "
            f"{max(r['v'] for r in rows[12:]):8.2f} m/s | y min {min(r['y'] for r in rows):+.5f}"
            f" | CPU {sum(r['cpu'] for r in rows[1:]) / n:6.3f} s/frame | Newton "
            f"{sum(s['newton_iterations'] for s in st) / len(st):6.1f} | CG "
            f"{sum(s['cg_iterations'] for s in st) / len(st):7.0f} per frame")


def main(argv):
    import lokigraph.behaviors.solvers.implicit.solver as S

    diag = "--diag" in argv
    specs = [a for a in argv if not a.startswith("--")]
    tmp = Path(tempfile.mkdtemp())
    for spec in specs:
        sub, youngs, impl, *kv = spec.split(":")
        pairs = [p.split("=") for p in kv[0].split(",")] if kv else []
        sd = int(dict(pairs).get("subdivisions", 3))
        pairs = [(k, v) for k, v in pairs if k != "subdivisions"]
        extra = "".join(f", {k}: {v}" for k, v in pairs if not k.startswith("solver."))
        solver = "".join(f", {k[7:]}: {v}" for k, v in pairs if k.startswith("solver."))
        path = tmp / f"ball_{len(specs)}_{abs(hash(spec))}.yaml"
        path.write_text(scene_text(int(sub), float(youngs), impl, extra=extra, solver=solver,
                                   subdivisions=sd))
        for flag in ((True, False) if diag else (S.LOWRANK_DIAG,)):
            S.LOWRANK_DIAG = flag
            rows, _ = measure(path)
            tag = f"{spec:24s}" + (f" diag={flag!s:5s}" if diag else "")
            print(f"{tag} {summary(rows)}", flush=True)
        S.LOWRANK_DIAG = False


if __name__ == "__main__":
    main(sys.argv[1:])
