"""Benchmark of the fluid pressure projection and of the two-way coupling (issue 15).

    lokigraph bench --fluid 64                      (the pressure solve table)
    python -m lokigraph.bench.fluid [--n 64] [--repeats 3] [--cloth]
    python -m lokigraph.bench.fluid --cape

1. The pressure solve of an n^3 MAC grid (walls on five faces, open top; a random velocity
   field, relative residual 1e-8): CG preconditioned by one pyamg smoothed-aggregation V-cycle
   (``amg``), Jacobi-preconditioned CG (``jacobi``) and plain CG (``cg``), interleaved, from a
   zero initial guess. Reports the setup (matrix + preconditioner, once per grid), iterations,
   CPU seconds (time.process_time) and wall seconds per solve (median of the repeats).
2. ``--cloth``: a 64x64 cloth falling through an n^3 air grid, two-way coupled (4 substeps per
   frame) with Nucleus (one weak pass per substep) and with the implicit solver (the Figure 2
   loop inside it), interleaved frame by frame: ms per frame (CPU and wall), the share of the
   fluid work (advection, drag reaction and pressure solves), and with the implicit solver the
   solid solves per substep of the coupling loop.
3. ``--cape``: graphs/examples/cape_run.yaml (a cape on a torso running through still air, the
   torso a moving obstacle of the grid) with Nucleus, with Nucleus and ``obstacles: []`` (what
   the moving obstacle costs) and with the implicit solver, interleaved frame by frame: ms per
   frame (CPU and wall), pressure-solve CPU per frame, solid solves per substep.

``bench_pressure(n, repeats)`` returns the table as a list of dicts (for ``lokigraph bench``).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


def bench_pressure(n: int = 64, repeats: int = 3, solvers=("amg", "jacobi", "cg")) -> list[dict]:
    from lokigraph.behaviors.fluid.grid import OPEN, WALL, MacGrid

    rng = np.random.default_rng(0)
    kinds = np.array([WALL, WALL, WALL, WALL, WALL, OPEN])
    for s in solvers:  # JIT / import warm-up, not timed
        w = MacGrid(np.zeros(3), (6, 6, 6), np.full(3, 0.1), 1.2, kinds, np.zeros(6), solver=s)
        w.u[2, 2, 2] = 1.0
        w.project(1e-2)
    grids, rows = {}, {}
    for s in solvers:
        t0, c0 = time.perf_counter(), time.process_time()
        g = MacGrid(np.zeros(3), (n, n, n), np.full(3, 1.0 / n), 1.2, kinds, np.zeros(6),
                    solver=s, tolerance=1e-8, max_iterations=5000)
        grids[s] = g
        rows[s] = {"solver": s, "cells": n ** 3, "setup_cpu_s": time.process_time() - c0,
                   "setup_wall_s": time.perf_counter() - t0, "cpu": [], "wall": [], "its": []}
    fields = [tuple(rng.normal(size=a.shape) for a in (grids[solvers[0]].u, grids[solvers[0]].v,
                                                       grids[solvers[0]].w))
              for _ in range(repeats)]
    for f in fields:  # interleaved: every solver on the same field, one after the other
        for s in solvers:
            g = grids[s]
            g.u[...], g.v[...], g.w[...] = f
            g.apply_boundaries()
            g._q[:] = 0.0
            t0, c0 = time.perf_counter(), time.process_time()
            st = g.project(1e-2)
            rows[s]["cpu"].append(time.process_time() - c0)
            rows[s]["wall"].append(time.perf_counter() - t0)
            rows[s]["its"].append(st.iterations)
            rows[s]["residual"] = st.residual
            rows[s]["max_divergence"] = st.max_divergence
    out = []
    for s in solvers:
        r = rows[s]
        out.append({"solver": s, "cells": r["cells"], "setup_cpu_s": r["setup_cpu_s"],
                    "iterations": int(statistics.median(r["its"])),
                    "solve_cpu_s": statistics.median(r["cpu"]),
                    "solve_wall_s": statistics.median(r["wall"]),
                    "residual": r["residual"], "max_divergence": r["max_divergence"]})
    return out


CLOTH = """
lokigraph: 1
frames: {{start: 1, end: {end}, fps: 24}}
substeps: 4
elements:
  - name: cloth
    geometry: {{generator: grid, params: {{size: [1.0, 1.0], resolution: [63, 63], plane: xz,
                                          center: [0.0, 1.4, 0.0]}}}}
    components:
      Dynamic: {{mass_density: 0.1}}
      DiscreteShell: {{}}
      Drag: {{model: ergun, xi_D: 20.0, fiber_diameter: 2.0e-4, material_fraction: 0.4,
             thickness: 5.0e-4}}
  - name: air
    components:
      FluidDomain: {{simulate: true, origin: [-1.0, 0.0, -1.0], size: [2.0, 2.0, 2.0],
                    cell_size: {cell}, z_max: {{type: open}}}}
"""


def bench_cloth(n: int = 64, frames: int = 6, solvers=("nucleus", "implicit")) -> list[dict]:
    import tempfile
    from pathlib import Path

    from lokigraph.compile import compile_scene
    from lokigraph.run import Simulation
    from lokigraph.scene import load_scene

    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "cloth_air.yaml"
        p.write_text(CLOTH.format(end=frames + 2, cell=2.0 / n))
        for solver in solvers:
            sc = load_scene(p)
            sc.spec = sc.spec.model_copy(update={"solver": solver})
            runs.append((solver, Simulation(compile_scene(sc))))
    rows = []
    for solver, sim in runs:
        b = sim.schedule.find("FluidTwoWay")[0]
        fluid = [0.0]

        def timed(fn, fluid=fluid):  # bind this run's accumulator (not the loop's last)
            def wrapped(*a):
                c0 = time.process_time()
                try:
                    return fn(*a)
                finally:
                    fluid[0] += time.process_time() - c0
            return wrapped

        b.behavior.step = timed(b.behavior.step)  # instance attributes: this run only
        cp = b.data.solver_coupling
        if cp is not None:
            cp.iterate = timed(cp.iterate)
        sim.step_frame()  # JIT warm-up
        fluid[0] = 0.0
        rows.append({"solver": solver, "sim": sim, "fluid": fluid, "cpu": 0.0, "wall": 0.0,
                     "coupling": 0.0, "substeps": 0})
    for _ in range(frames):  # interleaved, one frame each in turn
        for r in rows:
            t0, c0 = time.perf_counter(), time.process_time()
            st = r["sim"].step_frame()
            r["cpu"] += time.process_time() - c0
            r["wall"] += time.perf_counter() - t0
            r["coupling"] += st.get("coupling_iterations", 0.0)
            r["substeps"] += r["sim"].model.substeps
    out = []
    for r in rows:
        d = r["sim"].schedule.find("FluidTwoWay")[0].data
        out.append({"solver": r["solver"], "cloth_vertices": 64 * 64,
                    "cells": int(np.prod(d.grid.n)),
                    "ms_per_frame_cpu": 1e3 * r["cpu"] / frames,
                    "ms_per_frame_wall": 1e3 * r["wall"] / frames,
                    "fluid_share_cpu": r["fluid"][0] / r["cpu"],
                    "solid_solves_per_substep": (r["coupling"] / r["substeps"]
                                                 if r["coupling"] else 1.0)})
    return out


def bench_cape(frames: int = 12) -> list[dict]:
    from pathlib import Path

    from lokigraph.compile import compile_scene
    from lokigraph.run import Simulation
    from lokigraph.scene import load_scene

    import lokigraph.graphs

    path = Path(lokigraph.graphs.__file__).resolve().parent / "examples" / "cape_run.yaml"

    def make(solver, obstacles=None):
        sc = load_scene(path)
        sc.spec = sc.spec.model_copy(update={"solver": solver})
        air = next(e for e in sc.elements if e.name == "air")
        upd = {"write_fields": False}
        if obstacles is not None:
            upd["obstacles"] = obstacles
        air.components["FluidDomain"] = air.components["FluidDomain"].model_copy(update=upd)
        return Simulation(compile_scene(sc))

    runs = {"nucleus": make("nucleus"), "nucleus, obstacles: []": make("nucleus", []),
            "implicit": make("implicit")}
    acc = {k: {"cpu": 0.0, "wall": 0.0, "pressure": 0.0, "coupling": 0.0} for k in runs}
    for sim in runs.values():  # JIT warm-up frame, not counted
        sim.step_frame()
    for _ in range(frames):
        for k, sim in runs.items():
            t0, c0 = time.perf_counter(), time.process_time()
            st = sim.step_frame()
            a = acc[k]
            a["cpu"] += time.process_time() - c0
            a["wall"] += time.perf_counter() - t0
            a["pressure"] += st.get("fluid_pressure_cpu_s", 0.0)
            a["coupling"] += st.get("coupling_iterations", 0.0)
    out = []
    for k, a in acc.items():
        sub = runs[k].model.substeps * frames
        out.append({"setting": k, "ms_per_frame_cpu": 1e3 * a["cpu"] / frames,
                    "ms_per_frame_wall": 1e3 * a["wall"] / frames,
                    "pressure_ms_per_frame_cpu": 1e3 * a["pressure"] / frames,
                    "solid_solves_per_substep": a["coupling"] / sub if a["coupling"] else 1.0})
    return out


def format_pressure(rows, n, repeats) -> str:
    lines = [f"pressure solve, {n}^3 cells, rtol 1e-8, median of {repeats} (interleaved)",
             f"{'solver':8} {'setup cpu s':>11} {'iters':>6} {'solve cpu s':>11} "
             f"{'solve wall s':>12} {'residual':>9} {'max div':>9}"]
    for r in rows:
        lines.append(f"{r['solver']:8} {r['setup_cpu_s']:11.3f} {r['iterations']:6d} "
                     f"{r['solve_cpu_s']:11.3f} {r['solve_wall_s']:12.3f} {r['residual']:9.1e} "
                     f"{r['max_divergence']:9.1e}")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=64)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cloth", action="store_true")
    ap.add_argument("--cape", action="store_true")
    a = ap.parse_args(argv)
    if a.cape:
        for r in bench_cape():
            print(f"cape_run, {r['setting']:24}: {r['ms_per_frame_cpu']:6.0f} ms/frame CPU, "
                  f"{r['ms_per_frame_wall']:6.0f} wall, pressure solves "
                  f"{r['pressure_ms_per_frame_cpu']:5.0f} ms CPU/frame, "
                  f"{r['solid_solves_per_substep']:.2f} solid solves per substep")
        return
    print(format_pressure(bench_pressure(a.n, a.repeats), a.n, a.repeats))
    if a.cloth:
        for r in bench_cloth(a.n):
            print(f"64x64 cloth in {a.n}^3 air, {r['solver']}: {r['ms_per_frame_cpu']:.0f} "
                  f"ms/frame CPU, {r['ms_per_frame_wall']:.0f} ms/frame wall, fluid "
                  f"{100 * r['fluid_share_cpu']:.0f} % of the CPU time, "
                  f"{r['solid_solves_per_substep']:.2f} solid solves per substep")


if __name__ == "__main__":
    main()
