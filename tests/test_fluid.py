"""Two-way coupling of cloth and hair with a simulated fluid (FluidDomain simulate: true)."""

import json
import math

import numpy as np
import pytest

from conftest import EXAMPLES, run_cli
from lokigraph.api import compile_file
from lokigraph.behaviors.fluid import read_vti
from lokigraph.run import Simulation


def _two_way(sim):
    return sim.schedule.find("FluidTwoWay")[0].data


def _masses(c):
    inv = c.model.particle_inv_mass
    return np.where(inv > 0, 1.0 / np.where(inv > 0, inv, 1.0), 0.0)


THROWN = """
lokigraph: 1
solver: SOLVER
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
      FluidDomain: {simulate: true, origin: [0, 0, 0], size: [2, 1, 1], cell_size: 0.0625,
                    buoyancy: false, advection: ADV}
"""


@pytest.mark.parametrize("adv,solver", [("semi_lagrangian", "nucleus"), ("maccormack", "nucleus"),
                                        ("maccormack", "implicit")])
def test_thrown_cloth_gives_its_momentum_to_the_air(scene_file, adv, solver):
    """Closed box, no gravity, cloth thrown at 5 m/s through still air: per substep the cloth
    gains exactly the drag impulse, the air exactly its opposite, the walls' pressure force and
    the advection account for the rest (balance to 1e-6 of the cloth momentum), and the total
    kinetic energy never grows. With the implicit solver the exchange runs inside its loop
    (Figure 2), the impulse being that of the last solid solve."""
    c = compile_file(scene_file(THROWN.replace("ADV", adv).replace("SOLVER", solver)))
    sim = Simulation(c)
    d = _two_way(sim)
    g = d.grid
    m = _masses(c)
    st = sim.state

    def cloth_p():
        return (m[:, None] * st.particle_qd).sum(0)

    def energy():
        return 0.5 * float((m * (st.particle_qd ** 2).sum(1)).sum()) + g.kinetic_energy()

    p_start = cloth_p()
    air_moved = 0.0
    for _ in range(32):
        pc0, pa0, e0 = cloth_p(), g.momentum(), energy()
        sim.step_substep()
        pc1, pa1, e1 = cloth_p(), g.momentum(), energy()
        last = d.last
        scale = np.abs(pc0).max()
        np.testing.assert_allclose(pc1 - pc0, last["drag"], atol=1e-9 * scale)  # cloth: +J
        np.testing.assert_allclose(last["exchange"], -last["drag"], atol=1e-12 * scale)  # air: -J
        balance = (pc1 + pa1) - (pc0 + pa0) - last["wall"] - last["advection"]
        assert np.abs(balance).max() <= 1e-6 * scale
        assert e1 <= e0
        air_moved = max(air_moved, float(np.abs(g.u).max()))
    assert cloth_p()[0] < 0.8 * p_start[0]  # the cloth really was slowed by the air
    assert air_moved > 0.05  # and the air really moved (m/s)


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
      Drag: {{model: {model}, xi_D: {xi_D}, xi_N: {xi_N}, fiber_diameter: {D},
             material_fraction: {gamma}, thickness: {t}, fluid_density: {rho},
             fluid_viscosity: {mu}}}
  - name: air
    components:
      FluidDomain: {{simulate: true, origin: [0, 0, 0], size: [1.2, 0.4, 0.4], cell_size: 0.05,
                    density: {rho}, uniform: [{U}, 0, 0], x_min: {{type: inflow, velocity: {U}}},
                    x_max: {{type: open}}}}
"""


@pytest.mark.parametrize("U,xi_D,xi_N", [(1.0, 2000.0, 1.0), (3.0, 500.0, 1.0), (1.0, 2000.0, 0.0)])
def test_porous_sheet_in_a_duct_gives_the_ergun_pressure_drop(scene_file, U, xi_D, xi_N):
    """A held porous sheet across a duct in a uniform stream: the pressure drop equals the drag
    per unit area of the Ergun law, by hand: dp = mu t C_perp U / D^2 with
    C_perp = 1/k + xi_N 1.75 / sqrt(150 k) (1 - gamma)^-1.5 (rho D U / mu), 1/k = xi_D / 1e4."""
    mu, rho, D, gamma, t = 1.81e-5, 1.204, 2e-4, 0.4, 5e-4
    p = scene_file(DUCT.format(pins=list(range(81)), model="ergun", xi_D=xi_D, xi_N=xi_N, D=D,
                               gamma=gamma, t=t, rho=rho, mu=mu, U=U))
    sim = Simulation(compile_file(p))
    g = _two_way(sim).grid
    for _ in range(12):
        sim.step_substep()
    inv_k = xi_D / 1e4
    C = inv_k + xi_N * 1.75 / math.sqrt(150.0 / inv_k) * (1 - gamma) ** -1.5 * (rho * D * U / mu)
    dp_hand = mu * t * C * U / D ** 2
    nx = g.n[0]
    dp_grid = g.p[2].mean() - g.p[nx - 3].mean()  # upstream minus downstream section
    assert dp_grid == pytest.approx(dp_hand, rel=0.05)
    np.testing.assert_allclose(g.u[1:-1], U, rtol=1e-6)  # all the flow passes the sheet


FALL = """
lokigraph: 1
frames: {start: 1, end: 36, fps: 24}
substeps: 2
elements:
  - name: patch
    geometry: {generator: grid, params: {size: [0.3, 0.3], resolution: [8, 8], plane: xz,
                                         center: [0.5, 2.7, 0.5]}}
    components:
      Dynamic: {mass_density: 0.05}
      DiscreteShell: {bend_resistance: 1.0e-2}   # stiff: it falls flat
      Drag: {model: anisotropic, normal: 0.5, tangent: 0.05}
  - name: air
    components:
      FluidDomain: FLUID
"""


def test_falling_patch_drags_the_air_along(scene_file):
    """Still air: one way (an unmoving prescribed field) the patch reaches the terminal velocity
    m g / c_n; two way the air under it is pushed down with it, the relative velocity is smaller
    and the patch reaches a faster terminal velocity (measured -1.119 m/s at 1 s, -1.125 at
    1.5 s against -0.981 one way: the induced velocity of actuator-disk theory,
    T / (2 rho A V) = 0.2 m/s, is of that size). The patch is stiff: a limp one cups in its
    own wake, tilts and falls edge-on."""
    one = FALL.replace("FLUID", "{uniform: [0, 0, 0], origin: [0, 0, 0], size: [1, 3, 1]}")
    two = FALL.replace("FLUID", "{simulate: true, origin: [0, 0, 0], size: [1, 3, 1], "
                                "cell_size: 0.0625, y_min: {type: open}, y_max: {type: open}}")
    vy = {}
    for name, text in (("one", one), ("two", two)):
        sim = Simulation(compile_file(scene_file(text, name + ".yaml")))
        v = []
        for _ in range(36):
            sim.step_frame()
            v.append(float(sim.state.particle_qd[:, 1].mean()))
        vy[name] = v
        if name == "two":
            g = _two_way(sim).grid
            y = float(sim.state.particle_q[:, 1].mean())
            j = int(y / g.h[1])
            below = g.v[6:10, j - 3:j, 6:10].mean()  # faces under the patch
    v_terminal = -0.05 * 9.81 / 0.5
    assert vy["one"][-1] == pytest.approx(v_terminal, rel=0.01)
    two = vy["two"]
    assert two[-1] == pytest.approx(two[23], rel=0.01)  # terminal: steady from 1 s to 1.5 s
    assert two[-1] < 1.05 * v_terminal  # faster than one way (both negative)
    assert below < -0.02  # the air below moves down [m/s]


STRAND = """
lokigraph: 1
frames: {{start: 1, end: {end}, fps: 24}}
substeps: 2
elements:
  - name: strand
    geometry: {{generator: strands, params: {{count: [1, 1], length: 0.2, segments: 10,
                                              direction: [1, 0, 0], center: [0.1, 0.2, 0.2]}}}}
    components:
      Dynamic: {{mass_density: {lin}}}
      Drag: {{model: linear, coefficient: {drag}, fiber_diameter: 2.0e-3}}
  - name: water
    components:
      FluidDomain: {{simulate: true, origin: [0, 0, 0], size: [0.4, 0.4, 0.4], cell_size: 0.05,
                    density: 998.0, gravity: true}}
"""


def test_strand_with_the_density_of_water_stays_put(scene_file):
    area = math.pi * 1e-3 ** 2
    sim = Simulation(compile_file(scene_file(STRAND.format(end=49, lin=998.0 * area, drag=0.01))))
    y0 = sim.state.particle_q.copy()
    for _ in range(48):  # 2 s
        sim.step_frame()
    assert np.abs(sim.state.particle_q - y0).max() < 1e-3


@pytest.mark.parametrize("ratio", [1.5, 0.5])
def test_denser_strand_sinks_lighter_rises_with_archimedes_acceleration(scene_file, ratio):
    """First substep: a = g (1 - rho_water / rho_strand) (no drag here)."""
    area = math.pi * 1e-3 ** 2
    c = compile_file(scene_file(STRAND.format(end=3, lin=ratio * 998.0 * area, drag=0.0)))
    sim = Simulation(c)
    sim.step_substep()
    a = sim.state.particle_qd[:, 1].mean() / c.model.dt
    assert a == pytest.approx(-9.81 * (1 - 1 / ratio), rel=1e-3)
    for _ in range(11):
        sim.step_substep()
    dy = sim.state.particle_q[:, 1].mean() - 0.2
    assert (dy < -1e-3) if ratio > 1 else (dy > 1e-3)


def test_plan_prunes_every_coupling_behavior_without_a_fluid_element():
    r = run_cli("plan", EXAMPLES / "flag_wind.yaml", "--json")
    assert r.returncode == 0, r.stderr
    pruned = {p["type"]: p["reason"] for p in json.loads(r.stdout)["pruned"]}
    assert pruned["FluidCoupling"] == "no element carries FluidDomain"
    assert pruned["FluidTwoWay"] == "no element carries FluidDomain"


@pytest.mark.parametrize("extra,message", [
    ("simulate: true, file: flow.npz", "a simulated FluidDomain takes no velocity file"),
    ("simulate: true, x_min: {type: inflow, velocity: 2}", "an inflow face needs an open face"),
    ("simulate: true, cell_size: 0.001", "exceed the limit"),
    ("simulate: true, x_max: {type: door}", "x_max.type"),
])
def test_bad_fluid_domains_are_input_errors(scene_file, extra, message):
    p = scene_file(f"""
    lokigraph: 1
    elements:
      - name: c
        geometry: {{generator: grid, params: {{resolution: [2, 2]}}}}
        components: {{Dynamic: {{}}, Drag: {{coefficient: 1.0}}}}
      - name: air
        components: {{FluidDomain: {{{extra}}}}}
    """)
    r = run_cli("validate", p)
    assert r.returncode == 2 and message in r.stderr and "Traceback" not in r.stderr


def test_flag_tunnel_example_writes_fields_and_stats(tmp_path):
    out = tmp_path / "elsewhere"  # --out moves the frames and the fluid fields together
    r = run_cli("run", EXAMPLES / "flag_tunnel.yaml", "--frames", "1:6", "--out", out,
                cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert not (tmp_path / "out").exists()  # nothing left at the scene's output.dir
    run = json.loads((out / "run.json").read_text())
    st = run["per_frame"][-1]["stats"]
    assert st["fluid_pressure_iterations"] > 0 and st["max_fluid_exchange_error"] < 1e-9
    assert st["max_fluid_divergence"] < 1e-5  # [1/s], after the projection
    f = read_vti(out / "tunnel" / "0006.vti")
    assert f["velocity"].shape == (30, 16, 12, 3)
    assert np.isfinite(f["pressure"]).all()
    # the flag slows the air behind it (a wake): downstream of the flag vs beside it
    vel, o, h = f["velocity"], np.array(f["origin"]), np.array(f["spacing"])

    def ux(x, y, z):
        return vel[tuple(np.rint((np.array([x, y, z]) - o) / h).astype(int))][0]

    upstream = ux(-0.4, 2.0, 0.0)
    assert ux(1.4, 2.0, 0.0) < upstream - 0.03  # in the wake (measured 4.52 vs 4.59 m/s)
    assert ux(1.4, 2.0, 0.5) > upstream  # beside the flag the air goes round it, faster


def test_checkpoint_restores_the_fluid_bit_for_bit(tmp_path):
    """The grid (velocities, pressure, the pressure solve's warm start) is run state: a run
    restored from a checkpoint at frame 3 ends bit-identical to an uninterrupted one."""
    from lokigraph import checkpoint as ckpt

    text = (EXAMPLES / "flag_tunnel.yaml").read_text().replace("end: 48", "end: 6").replace(
        "write_fields: true", "write_fields: false")
    p = tmp_path / "tunnel.yaml"
    p.write_text(text)
    a = Simulation(compile_file(p))
    for _ in range(3):
        a.step_frame()
    saved = ckpt.capture(a)
    for _ in range(3):
        a.step_frame()
    b = Simulation(compile_file(p))
    ckpt.restore(b, saved)
    for _ in range(3):
        b.step_frame()
    assert np.array_equal(a.state.particle_q, b.state.particle_q)
    ga, gb = _two_way(a).grid, _two_way(b).grid
    assert np.array_equal(ga.u, gb.u) and np.array_equal(ga.p, gb.p)


def test_static_sphere_is_an_obstacle_for_the_air(scene_file):
    """A ShapeCollider sphere in a duct: no air through its faces, the flux through every cross
    section (open fraction x velocity x area) stays the inflow's, faster beside the sphere."""
    p = scene_file("""
    lokigraph: 1
    frames: {start: 1, end: 3, fps: 24}
    gravity: [0, 0, 0]
    elements:
      - name: c
        geometry: {generator: grid, params: {size: [0.1, 0.1], resolution: [2, 2], plane: yz,
                                             center: [0.2, 0.3, 0.3]}}
        components: {Dynamic: {}, Drag: {coefficient: 0.01}}
      - name: ball
        components: {ShapeCollider: {shape: sphere, center: [0.6, 0.3, 0.3], radius: 0.15}}
      - name: air
        components:
          FluidDomain: {simulate: true, size: [1.2, 0.6, 0.6], cell_size: 0.05,
                        uniform: [1.0, 0, 0], x_min: {type: inflow, velocity: 1.0},
                        x_max: {type: open}}
    """)
    sim = Simulation(compile_file(p))
    for _ in range(6):
        sim.step_substep()
    g = _two_way(sim).grid
    g.project(sim.model.dt)  # the state after (C) (a substep ends with the advection)
    a = g._solid[0][:g.u.size].reshape(g.u.shape)  # open fraction of the x faces
    assert (a == 0).any() and (g.u[a == 0] == 0).all()
    flux = (a * g.u).sum(axis=(1, 2)) * g.h[1] * g.h[2]
    np.testing.assert_allclose(flux, 1.0 * 0.6 * 0.6, rtol=1e-6)
    assert g.u[12, 6, 2] > 1.05  # beside the sphere, the air is faster
    assert np.abs(g.fluid_divergence()).max() < 1e-6
