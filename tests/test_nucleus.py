"""The Nucleus solver: interleaving, convergence to analytic statics, example scenes."""

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import DATA, EXAMPLES, ROOT
from lokigraph.api import compile_file
from lokigraph.behaviors.materials.pressure import mesh_volume
from lokigraph.behaviors.solvers.nucleus import interleave_plan
from lokigraph.run import Simulation

REF = json.loads((DATA / "analytic" / "reference_values.json").read_text())


def _run(path, frames=None):
    c = compile_file(path)
    sim = Simulation(c)
    n = frames if frames is not None else (c.scene.spec.frames.end - c.scene.spec.frames.start)
    for _ in range(n):
        sim.step_frame()
    return c, sim


def test_interleave_plan_figure_11():
    # Figure 9 importances: stretch 26, bend 9, shear 7, self-collision 7, collision 6 of 26
    types = [("bend", 9 / 26, 10), ("shear", 7 / 26, 20), ("stretch", 1.0, 30),
             ("self", 7 / 26, 40), ("coll", 6 / 26, 50)]
    plan = interleave_plan(types, 26)
    assert len(plan) == 26
    counts = [sum(i in s for s in plan) for i in range(5)]
    assert counts == [9, 7, 26, 7, 6]
    assert plan[-1] == [0, 1, 2, 3, 4]  # every type in the final pass, in order
    # spread evenly: gaps between runs of 'coll' differ by at most one slot
    runs = [k for k, s in enumerate(plan) if 4 in s]
    gaps = np.diff(runs)
    assert gaps.max() - gaps.min() <= 1
    flat = interleave_plan(types, 26, interleave=False)
    assert [s[0] for s in flat][:9] == [0] * 9 and len(flat) == 9 + 7 + 26 + 7 + 6


def _band(tmp, interleave, iters=10, n=60, frames=96):
    """A rubber band (closed curve, rest length 0.7 x its start length) stretched around two
    bars (capsule colliders), Nucleus Figures 10 and 12."""
    a, r = 0.3, 0.06
    per = 4 * a + 2 * np.pi * r
    s = np.linspace(0, per, n, endpoint=False)
    pts = []
    for t in s:
        if t < 2 * a:
            pts.append([-a + t, r, 0])
        elif t < 2 * a + np.pi * r:
            th = (t - 2 * a) / r
            pts.append([a + r * np.sin(th), r * np.cos(th), 0])
        elif t < 4 * a + np.pi * r:
            pts.append([a - (t - 2 * a - np.pi * r), -r, 0])
        else:
            th = (t - 4 * a - np.pi * r) / r
            pts.append([-a - r * np.sin(th), -r * np.cos(th), 0])
    pts = np.array(pts)
    with open(tmp / "band.obj", "w") as f:
        for p in pts:
            f.write("v %.17g %.17g %.17g\n" % tuple(p))
        f.write("l " + " ".join(str(i + 1) for i in range(n)) + " 1\n")
    (tmp / "band.yaml").write_text(f"""
lokigraph: 1
frames: {{start: 1, end: {frames + 1}, fps: 24}}
substeps: 4
gravity: [0, 0, 0]
graph_overrides: {{nucleus_solver: {{iterations: {iters}, interleave: {str(interleave).lower()}}}}}
elements:
  - name: band
    geometry: {{file: band.obj}}
    components:
      Dynamic: {{mass_density: 0.05, damping: 2.0}}
      Rod: {{youngs_modulus: 2.0e4, radius: 0.002, rest_length_scale: 0.7, bend_resistance: 0}}
  - name: left_bar
    components: {{ShapeCollider: {{shape: capsule, center: [-0.3, 0, 0], radius: 0.05}}}}
  - name: right_bar
    components: {{ShapeCollider: {{shape: capsule, center: [0.3, 0, 0], radius: 0.05}}}}
""")
    c, sim = _run(tmp / "band.yaml", frames)
    q = sim.state.particle_q
    e = c.scene.element("band").geometry.edges
    L0 = np.linalg.norm(pts[e[:, 1]] - pts[e[:, 0]], axis=1) * 0.7
    strain = np.linalg.norm(q[e[:, 1]] - q[e[:, 0]], axis=1) / L0 - 1
    mid = 0.5 * (q[e[:, 0]] + q[e[:, 1]])
    return strain, mid


def test_rubber_band_interleaving(tmp_path):
    """With interleaving the strain along the band is uniform (spread < 5 % of the mean strain);
    with the types run back to back (stretch, then collisions) the ends at the bars
    over-stretch (spread > 15 %, maximum next to a bar)."""
    s_il, _ = _band(tmp_path, True)
    s_seq, mid = _band(tmp_path, False)
    spread = lambda s: (s.max() - s.min()) / s.mean()  # noqa: E731
    assert spread(s_il) < 0.05, spread(s_il)
    assert spread(s_seq) > 0.15, spread(s_seq)
    worst = mid[np.argmax(s_seq)]
    assert abs(abs(worst[0]) - 0.3) < 0.1  # over-stretched where the band wraps a bar
    assert abs(s_il.mean() - s_seq.mean()) < 0.01  # same total length


def _chain(tmp, N, iters, frames=240, solve="gauss_seidel"):
    case = [c for c in REF["catenary_discrete"]["cases"] if c["N"] == N][0]
    L = case["length"]
    half = N // 2
    depth = np.sqrt((L / 2) ** 2 - 0.25)
    xs = np.concatenate([np.linspace(-0.5, 0, half + 1), np.linspace(0, 0.5, half + 1)[1:]])
    ys = -depth * (1 - np.abs(xs) / 0.5)
    with open(tmp / "chain.obj", "w") as f:
        for x, y in zip(xs, ys):
            f.write(f"v {x:.17g} {y:.17g} 0\n")
        f.write("l " + " ".join(str(i + 1) for i in range(N + 1)) + "\n")
    (tmp / "chain.yaml").write_text(f"""
lokigraph: 1
frames: {{start: 1, end: {frames + 1}, fps: 24}}
substeps: 4
graph_overrides: {{nucleus_solver: {{iterations: {iters}}}}}
elements:
  - name: chain
    geometry: {{file: chain.obj}}
    components:
      Dynamic: {{mass_density: 0.1, damping: 4.0}}
      Rod: {{bend_resistance: 0, tethers: false, solve: {solve}}}
      Pins: {{vertices: [0, {N}]}}
""")
    _, sim = _run(tmp / "chain.yaml", frames)
    q = sim.state.particle_q
    return np.abs(q[:, :2] - np.column_stack([case["x"], case["y"]])).max()


def test_catenary_converges_with_iterations(tmp_path):
    """N = 20 links pinned at both ends, Gauss-Seidel: the error against the exact discrete
    catenary decreases monotonically with iterations (measured 3.9e-2, 1.6e-2, 7.6e-3, 3.6e-3 at
    2, 5, 10, 20 iterations)."""
    errs = [_chain(tmp_path, 20, it) for it in (2, 5, 10, 20)]
    assert all(b < 0.7 * a for a, b in zip(errs, errs[1:])), errs
    assert errs[-1] < 5e-3
    # the default direct per-strand solve (Rod.solve) is there at 2 iterations (measured 3.4e-4)
    assert _chain(tmp_path, 20, 2, solve="direct") < 1e-3


def test_pressure_sphere_holds_volume():
    """A hard volume target (1.3 x rest) holds within 0.1 % in every frame, through the drop
    onto the ground and at rest (issue #13; pressure is projected after stretch, in every
    iteration: before, it sat 0.15 % below and reached 0.44 % at impact)."""
    c = compile_file(EXAMPLES / "pressure_ball.yaml")
    sim = Simulation(c)
    tris = c.scene.element("ball").geometry.triangles
    V0 = mesh_volume(c.model.particle_q0, tris)
    worst = 0.0
    for _ in range(c.scene.spec.frames.end - c.scene.spec.frames.start):
        sim.step_frame()
        worst = max(worst, abs(mesh_volume(sim.state.particle_q, tris) / (1.3 * V0) - 1))
    assert worst < 1e-3, worst
    q = sim.state.particle_q
    assert q[:, 1].min() >= -1e-9  # on the ground, not through it
    assert np.abs(sim.state.particle_qd).max() < 0.5  # came (nearly) to rest


def test_example_cloth_pinned_hangs():
    c, sim = _run(EXAMPLES / "cloth_pinned.yaml")
    q, q0 = sim.state.particle_q, c.model.particle_q0
    assert np.array_equal(q[[0, 32]], q0[[0, 32]])
    assert np.isfinite(q).all()
    d = c.schedule.find("StretchConstraint")[0].data
    strain = np.linalg.norm(q[d.idx[:, 1]] - q[d.idx[:, 0]], axis=1) / d.rest - 1
    assert np.median(strain) < 0.01  # the bulk is not stretched
    assert q[:, 1].min() < 0.6 and q[:, 1].mean() < 0.8  # it fell and swings below the pins
    # nothing below the tether reach: the lowest point is within the rest geodesic of a pin
    assert q[:, 1].min() > 1.0 - np.sqrt(1 + 0.5 ** 2) - 0.02


def test_example_hair_droops_without_stretch():
    c, sim = _run(EXAMPLES / "hair_strands.yaml")
    q, q0 = sim.state.particle_q, c.model.particle_q0
    roots = c.scene.element("hair").geometry.channels["root"] > 0.5
    assert np.array_equal(q[roots], q0[roots])
    e = c.scene.element("hair").geometry.edges
    L0 = np.linalg.norm(q0[e[:, 1]] - q0[e[:, 0]], axis=1)
    L = np.linalg.norm(q[e[:, 1]] - q[e[:, 0]], axis=1)
    assert np.abs(L / L0 - 1).max() < 0.02
    tips = c.scene.element("hair").geometry.channels["s"] == 1.0
    drop = q0[tips, 1] - q[tips, 1]
    assert (drop > 0.02).all() and (drop < 0.25).all()  # droops, but bending holds some of it


def test_hanging_64_cloth_stretch(scene_file):
    """64 x 64 cloth hanging from two corners at the default solver settings (4 substeps x 15
    iterations), brought to rest by damping: every edge within 1 % (measured max 0.74 %, 99th
    percentile 0.35 %; at 10 iterations the max was 1.11 %)."""
    p = scene_file("""
    lokigraph: 1
    frames: {start: 1, end: 97, fps: 24}
    elements:
      - name: cloth
        geometry: {generator: grid, params: {size: [1, 1], resolution: [64, 64], plane: xz}}
        components:
          Dynamic: {mass_density: 0.15, damping: 1.0}
          DiscreteShell: {}
          Pins: {vertices: [0, 64]}
    """)
    c, sim = _run(p, 96)
    e = c.schedule.find("StretchConstraint")[0].data
    q = sim.state.particle_q
    s = np.linalg.norm(q[e.idx[:, 1]] - q[e.idx[:, 0]], axis=1) / e.rest - 1
    assert np.percentile(s, 99) < 0.005
    assert s.max() < 0.01


def test_chebyshev_acceleration_lowers_strain():
    """Chebyshev semi-iterative acceleration (NucleusParams.chebyshev_rho, off by default) at
    the same 15 iterations: the 64 x 64 drape hanging from two corners stretches less (measured
    3.3 % -> 1.1 % worst frame over 10 frames) and stays finite; off is the plain loop."""
    from lokigraph.bench.sweep import _apply, worst_strain
    from lokigraph.compile import compile_scene
    from lokigraph.scene import load_scene

    worst = {}
    for rho in ("0", "0.97"):
        scene = _apply(load_scene(ROOT / "graphs" / "bench" / "drape_64.yaml"),
                       {"nucleus_solver.chebyshev_rho": rho})
        c = compile_scene(scene)
        sim = Simulation(c)
        w = 0.0
        for _ in range(10):
            sim.step_frame()
            w = max(w, worst_strain(c, sim.state.particle_q)[0])
        assert np.isfinite(sim.state.particle_q).all()
        worst[rho] = w
    assert worst["0.97"] < 0.5 * worst["0"], worst
