"""Constitutive strain limiting solved with the contacts vs a post-collision strain pass."""

import numpy as np
import pytest

from lokigraph.api import compile_file
from lokigraph.behaviors.collision.intersect import intersect_meshes
from lokigraph.behaviors.topology import triangle_edges
from lokigraph.run import Simulation

ENDS = ", ".join([str(j * 21) for j in range(21)] + [str(j * 21 + 20) for j in range(21)])


def pushed_cloth(mode, limit=True, frames=36, substeps=4, head="", overrides=""):
    """A soft cloth (E t = 0.3 N/m) pinned at two sides, pushed up by a kinematic ball; with
    ``limit`` eps_e = 0.1. ``head``: extra top-level lines (``solver: implicit``),
    ``overrides``: extra strain_limit overrides (``, implicit: energy``)."""
    ms = "max_strain: 0.1, " if limit else ""
    return f"""
    lokigraph: 1
    {head}frames: {{start: 1, end: {frames + 1}, fps: 24}}
    substeps: {substeps}
    graph_overrides: {{strain_limit: {{mode: {mode}, importance: 1.0{overrides}}}}}
    elements:
      - name: cloth
        geometry: {{generator: grid, params: {{size: [0.6, 0.6], resolution: [20, 20], plane: xz}}}}
        channels: {{ends: {{vertices: [{ENDS}]}}}}
        components:
          Dynamic: {{mass_density: 0.3, damping: 1.0}}
          DiscreteShell: {{youngs_modulus: 300.0, thickness: 1.0e-3, {ms}bend_resistance: 1.0e-6}}
          Pins: {{map: ends}}
          Collider: {{thickness: 0.002, friction: 0.0}}
      - name: ball
        geometry: {{generator: sphere, params: {{radius: 0.1, subdivisions: 3, center: [0, -0.3, 0]}}}}
        components:
          Kinematic: {{keys: [{{frame: 1}}, {{frame: 25, translate: [0, 0.2, 0]}}]}}
          Collider: {{thickness: 0.002, friction: 0.0}}
      - name: contact
        components: {{CollisionGroup: {{members: [cloth, ball], methods: [vertex_face, edge_edge]}}}}
    """


def measure(path, frames):
    """Run ``frames`` frames of a ``pushed_cloth`` scene: per frame the worst edge strain and
    the cloth-ball intersecting pairs, the simulation and the per-frame statistics."""
    c = compile_file(path)
    sim = Simulation(c)
    cl, b = c.scene.element("cloth"), c.scene.element("ball")
    E = triangle_edges(cl.geometry.triangles)
    X = cl.geometry.points
    L0 = np.linalg.norm(X[E[:, 1]] - X[E[:, 0]], axis=1)
    strain, pen, stats = [], [], []
    for _ in range(frames):
        stats.append(sim.step_frame())
        q = sim.state.particle_q
        qc = q[cl.vertex_slice]
        strain.append((np.linalg.norm(qc[E[:, 1]] - qc[E[:, 0]], axis=1) / L0 - 1).max())
        _, rows = intersect_meshes([(qc, cl.geometry.triangles),
                                    (q[b.vertex_slice], b.geometry.triangles)], touching=False)
        pen.append(int((rows[:, 0] != rows[:, 2]).sum()))
    return np.array(strain), np.array(pen), sim, stats


def _run(scene_file, mode, limit=True, frames=36, name="s.yaml"):
    return measure(scene_file(pushed_cloth(mode, limit, frames), name), frames)[:2]


def test_constitutive_strain_limit_with_contacts(scene_file):
    """A soft cloth (E t = 0.3 N/m) pinned at two sides, pushed up by a kinematic ball, with
    eps_e = 0.1. Without a limit it stretches by >100 %; with the constitutive limit every edge
    stays within (1 + eps_e) L0 + 2 % (measured: 1.4 % over at rest, 5.6 % in the impact
    transient; the stated bound is 1.02 after frame 8 and 1.07 overall) with zero cloth-ball
    intersections; the post-collision pass (same limit) leaves intersections with the ball."""
    free, _ = _run(scene_file, "constitutive", limit=False, name="free.yaml")
    assert free.max() > 1.0
    s, pen = _run(scene_file, "constitutive", name="c.yaml")
    assert (pen == 0).all()
    assert s[8:].max() < 0.1 + 0.02
    assert s.max() < 0.1 + 0.07
    s_post, pen_post = _run(scene_file, "post", name="p.yaml")
    assert pen_post.max() > 0 or s_post[8:].max() > 0.12  # the post pass fails one way or other
    assert pen_post.max() > 0  # measured: it penetrates (144 intersecting pairs)
