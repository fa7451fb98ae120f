"""The figures of the two-way fluid coupling's closing note (issue 15), measured.

    python graphs/bench/fluid_checks.py

Prints: the momentum budget of a cloth thrown at 5 m/s through still air in a closed box;
the pressure drop of a held porous sheet across a duct against the Ergun law by hand; the fall
velocity of a patch in still air with one- and two-way coupling; a strand under water at three
densities; the cost of the flag tunnel per frame. tests/test_fluid.py asserts the same physics.
"""

from __future__ import annotations

import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lokigraph.api import compile_file
from lokigraph.run import Simulation

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
from test_fluid import FALL  # noqa: E402  (the falling patch: the test's scene, one copy)

THROWN = """
lokigraph: 1
frames: {start: 1, end: 13, fps: 24}
substeps: 4
gravity: [0, 0, 0]
elements:
  - name: cloth
    geometry: {generator: grid, params: {size: [0.4, 0.4], resolution: [10, 10], plane: yz,
                                         center: [0.5, 0.5, 0.5]}}
    components:
      Dynamic: {mass_density: 0.1, velocity: [5, 0, 0]}
      DiscreteShell: {}
      Drag: {model: ergun, xi_D: 20.0, fiber_diameter: 2.0e-4, material_fraction: 0.4,
             thickness: 5.0e-4}
  - name: air
    components:
      FluidDomain: {simulate: true, size: [2, 1, 1], cell_size: 0.05, buoyancy: false}
"""

DUCT = """
lokigraph: 1
frames: {{start: 1, end: 10, fps: 24}}
substeps: 2
gravity: [0, 0, 0]
elements:
  - name: sheet
    geometry: {{generator: grid, params: {{size: [0.4, 0.4], resolution: [8, 8], plane: yz,
                                          center: [0.6, 0.2, 0.2]}}}}
    components:
      Dynamic: {{mass_density: 0.1}}
      Pins: {{vertices: {pins}}}
      Drag: {{model: ergun, xi_D: {xi_D}, xi_N: {xi_N}, fiber_diameter: 2.0e-4,
             material_fraction: 0.4, thickness: 5.0e-4}}
  - name: air
    components:
      FluidDomain: {{simulate: true, size: [1.2, 0.4, 0.4], cell_size: 0.05, uniform: [{U}, 0, 0],
                    x_min: {{type: inflow, velocity: {U}}}, x_max: {{type: open}}}}
"""

STRAND = """
lokigraph: 1
frames: {{start: 1, end: 49, fps: 24}}
substeps: 2
elements:
  - name: strand
    geometry: {{generator: strands, params: {{count: [1, 1], length: 0.2, segments: 10,
                                              direction: [1, 0, 0], center: [0.1, 0.2, 0.2]}}}}
    components:
      Dynamic: {{mass_density: {lin}}}
      Drag: {{model: linear, coefficient: 0.01, fiber_diameter: 2.0e-3}}
  - name: water
    components:
      FluidDomain: {{simulate: true, size: [0.4, 0.4, 0.4], cell_size: 0.05, density: 998.0,
                    gravity: true}}
"""


def _sim(text, tmp, name="s.yaml"):
    p = Path(tmp) / name
    p.write_text(text)
    c = compile_file(p)
    return c, Simulation(c)


def _grid(sim):
    return sim.schedule.find("FluidTwoWay")[0].data


def thrown(tmp):
    c, sim = _sim(THROWN, tmp)
    d = _grid(sim)
    inv = c.model.particle_inv_mass
    m = np.where(inv > 0, 1.0 / np.where(inv > 0, inv, 1.0), 0.0)
    st = sim.state
    worst_ex = worst_bal = 0.0
    grew = 0
    e = lambda: 0.5 * float((m * (st.particle_qd ** 2).sum(1)).sum()) + d.grid.kinetic_energy()  # noqa: E731,E501
    p0 = (m[:, None] * st.particle_qd).sum(0)
    for _ in range(32):  # 1/3 s: the cloth stays clear of the far wall
        pc0, pa0, e0 = (m[:, None] * st.particle_qd).sum(0), d.grid.momentum(), e()
        sim.step_substep()
        pc1, pa1, e1 = (m[:, None] * st.particle_qd).sum(0), d.grid.momentum(), e()
        s = np.abs(pc0).max()
        L = d.last
        worst_ex = max(worst_ex, np.abs(L["exchange"] + L["drag"]).max() / s)
        bal = (pc1 + pa1) - (pc0 + pa0) - L["wall"] - L["advection"]
        worst_bal = max(worst_bal, np.abs(bal).max() / s)
        grew += e1 > e0
    p1 = (m[:, None] * st.particle_qd).sum(0)
    print(f"thrown cloth, 32 substeps: cloth px {p0[0]:.4f} -> {p1[0]:.4f} kg m/s; "
          f"exchange error {worst_ex:.1e}, budget error {worst_bal:.1e} (relative per step); "
          f"steps where kinetic energy grew: {grew}")


def duct(tmp):
    mu, rho, D, gamma, t = 1.81e-5, 1.204, 2e-4, 0.4, 5e-4
    print("porous sheet in a duct: U [m/s], xi_D, xi_N, dp grid [Pa], dp Ergun by hand [Pa], "
          "ratio")
    for U, xi_D, xi_N in ((1.0, 2000.0, 1.0), (3.0, 500.0, 1.0), (1.0, 2000.0, 0.0),
                          (8.0, 20.0, 1.0)):
        _, sim = _sim(DUCT.format(pins=list(range(81)), xi_D=xi_D, xi_N=xi_N, U=U), tmp)
        g = _grid(sim).grid
        for _ in range(12):
            sim.step_substep()
        inv_k = xi_D / 1e4
        C = inv_k + xi_N * 1.75 / math.sqrt(150 / inv_k) * (1 - gamma) ** -1.5 * rho * D * U / mu
        hand = mu * t * C * U / D ** 2
        grid = g.p[2].mean() - g.p[g.n[0] - 3].mean()
        print(f"  {U:4.1f} {xi_D:7.0f} {xi_N:3.0f} {grid:10.5f} {hand:10.5f} {grid / hand:8.5f}")


def fall(tmp):
    out = {}
    for name, fl in (("one-way", "{uniform: [0, 0, 0], size: [1, 3, 1]}"),
                     ("two-way", "{simulate: true, size: [1, 3, 1], cell_size: 0.0625, "
                      "y_min: {type: open}, y_max: {type: open}}")):
        _, sim = _sim(FALL.replace("FLUID", fl), tmp, name + ".yaml")
        vs = []
        for _ in range(36):
            sim.step_frame()
            vs.append(float(sim.state.particle_qd[:, 1].mean()))
        out[name] = vs
        if name == "two-way":
            g = _grid(sim).grid
            j = int(float(sim.state.particle_q[:, 1].mean()) / g.h[1])
            below = float(g.v[6:10, j - 3:j, 6:10].mean())
    print("falling patch, mean vy [m/s] at t = 0.25 / 0.5 / 0.75 / 1.0 / 1.5 s (one-way terminal "
          f"{-0.05 * 9.81 / 0.5:.3f}):")
    for k, v in out.items():
        print(f"  {k}: " + " / ".join(f"{v[i]:.3f}" for i in (5, 11, 17, 23, 35)))
    print(f"  air under the two-way patch at 1.5 s: vy = {below:.3f} m/s")


def strand(tmp):
    area = math.pi * 1e-3 ** 2
    print("strand under water, 2 s: density ratio, mean dy [m], max |dy| [m]")
    for r in (1.0, 1.5, 0.5):
        _, sim = _sim(STRAND.format(lin=r * 998.0 * area), tmp)
        y0 = sim.state.particle_q.copy()
        for _ in range(48):
            sim.step_frame()
        dy = sim.state.particle_q - y0
        print(f"  {r:3.1f} {dy[:, 1].mean():10.3e} {np.abs(dy).max():10.3e}")


def tunnel():
    root = Path(__file__).resolve().parents[1] / "examples" / "flag_tunnel.yaml"
    c = compile_file(root)
    sim = Simulation(c)
    sim.step_frame()
    b = sim.schedule.find("FluidTwoWay")[0]
    fluid = [0.0]
    orig = b.behavior.step

    def timed(ctx, d):
        c0 = time.process_time()
        orig(ctx, d)
        fluid[0] += time.process_time() - c0

    b.behavior.step = timed
    t0, c0 = time.perf_counter(), time.process_time()
    its = 0.0
    for _ in range(12):
        its += sim.step_frame().get("fluid_pressure_iterations", 0.0)
    cpu, wall = (time.process_time() - c0) / 12, (time.perf_counter() - t0) / 12
    g = b.data.grid
    print(f"flag_tunnel ({g.n[0]}x{g.n[1]}x{g.n[2]} cells, 425 vertices, 4 substeps): "
          f"{1e3 * cpu:.0f} ms/frame CPU, {1e3 * wall:.0f} wall; coupling pass "
          f"{1e3 * fluid[0] / 12 / 4:.1f} ms CPU per substep ({100 * fluid[0] / 12 / cpu:.0f} %),"
          f" {its / 12 / 4:.1f} pressure iterations per substep")


def main():
    with tempfile.TemporaryDirectory() as tmp:
        thrown(tmp)
        duct(tmp)
        fall(tmp)
        strand(tmp)
    tunnel()


if __name__ == "__main__":
    main()
