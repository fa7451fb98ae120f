"""The exact CCD in the simulation loop (the final safe step of ``CollisionConstraint``) and the
side memory of closed two-sided kinematic meshes."""

import numpy as np
import pytest

from lokigraph.api import compile_file
from lokigraph.run import Simulation


def _dot_on_ball(scene_file, name="ball.yaml"):
    """A free point in front of a two-sided kinematic ball (radius 0.08 m) that comes at it at
    20 m/s (0.21 m, 2.6 radii, per substep): the ball must carry the point in front of it."""
    return scene_file("""
    lokigraph: 1
    frames: {start: 1, end: 9, fps: 24}
    substeps: 4
    gravity: [0, 0, 0]
    elements:
      - name: dot
        geometry: {generator: points, params: {positions: [[0.01, 0.005, 0.0]]}}
        components:
          Dynamic: {point_mass: 0.001}
          Collider: {thickness: 0.003}
      - name: ball
        geometry: {generator: sphere, params: {radius: 0.08, subdivisions: 3, center: [0, 0, 0.5]}}
        components:
          Kinematic: {keys: [{frame: 1}, {frame: 25, translate: [0, 0, -20.0]}]}
          Collider: {thickness: 0.003, one_sided: false}
      - name: contact
        components: {CollisionGroup: {members: [dot, ball], methods: [vertex_face]}}
    """, name)


def _filter_ball(order):
    """Vertex-face rows of one point just outside a closed two-sided kinematic ball against
    every triangle of the ball, the candidates in the given order ("far" first or "near")."""
    from lokigraph.behaviors.collision.contacts import _NEVER, _filter_vf
    from lokigraph.generators import icosphere

    g = icosphere(0.1, 2)
    nt = len(g.triangles)
    c = g.points[g.triangles].mean(1)
    u = c[np.argmin(c[:, 2])]  # above the centroid of a bottom triangle, 3 mm out
    u /= np.linalg.norm(u)
    x = np.vstack([u * (np.linalg.norm(c, axis=1).min() + 0.003), g.points])
    tris = g.triangles.astype(np.int64) + 1
    centroid = x[tris].mean(1)
    dist = np.linalg.norm(centroid - x[0], axis=1)
    t_order = np.argsort(-dist if order == "far" else dist)
    cand = np.stack([np.zeros(nt, np.int64), t_order], 1)
    n = len(x)
    elem = np.r_[0, np.ones(n - 1, np.int64)]
    allow = np.array([[False, True], [True, False]])
    th = np.full(n, 0.003)
    rows, nrm = np.zeros((nt, 4), np.int64), np.zeros((nt, 3))
    tgt, mu, one = np.zeros(nt), np.zeros(nt), np.zeros(nt, np.bool_)
    k, _ = _filter_vf(cand, np.array([0]), tris, np.ones(nt, np.int64), elem, allow,
                      np.zeros((2, 2), np.bool_), th, th, np.zeros(n), np.ones(n, np.bool_),
                      np.zeros(n, np.int64), np.zeros(2, np.bool_), x, np.zeros((n, 3)), 0.01,
                      0.0, 0.002, rows, nrm, tgt, mu, one, np.array([False, True]),
                      np.zeros((n, 2), np.int8), np.full((n, 2), _NEVER),
                      np.full((n, 2), _NEVER), 1, np.full((n, 2), np.inf),
                      np.zeros((n, 2), np.int8))
    return x, rows[:k], nrm[:k], tgt[:k]


@pytest.mark.parametrize("order", ["far", "near"])
def test_side_memory_of_a_closed_two_sided_body(order):
    """The side a vertex remembers of a closed two-sided body is that of the body's nearest
    triangle: the far triangles of the ball, whose planes the point is also below, must not
    flag it as crossed, whatever the candidate order (a crossed flag pushed the point into the
    ball: the 137 penetrations of the full-size stress projectile)."""
    from lokigraph.behaviors.collision.narrowphase import point_triangle_distance

    x, rows, nrm, tgt = _filter_ball(order)
    assert len(rows) == 320  # every triangle is a candidate row
    for r, n, t in zip(rows, nrm, tgt):
        _, b0, b1, b2 = point_triangle_distance(x[r[0]], x[r[1]], x[r[2]], x[r[3]])
        sep = x[r[0]] - (b0 * x[r[1]] + b1 * x[r[2]] + b2 * x[r[3]])
        assert n @ sep > 0.0  # the contact pushes the point away from the ball, never in
        assert t > 0.0


def test_closed_two_sided_ball_carries_a_point(scene_file):
    """The ball carries the point ahead of it, never inside."""
    c = compile_file(_dot_on_ball(scene_file))
    sim = Simulation(c)
    ball, dot = c.scene.element("ball"), c.scene.element("dot")
    carried = 0
    for _ in range(8):
        sim.step_frame()
        q = sim.state.particle_q
        centre = q[ball.vertex_slice].mean(0)
        p = q[dot.vertex_slice][0]
        r = np.linalg.norm(p - centre)
        # never inside the ball (inscribed radius of the subdivision-3 icosphere > 0.079 m)
        assert r > 0.079
        if centre[2] < 0.0:  # the ball has reached the point: it is ahead of the ball
            assert p[2] < centre[2] - 0.07
            carried += 1
    assert carried >= 5


def _dot_on_floor(scene_file, ccd, name):
    """A point thrown at a static floor at 10 m/s (0.21 m per substep, 100 thicknesses) with
    contacts that do (almost) nothing (strength 1e-9): only the safe step can stop it."""
    return scene_file(f"""
    lokigraph: 1
    frames: {{start: 1, end: 7, fps: 24}}
    substeps: 2
    gravity: [0, 0, 0]
    graph_overrides: {{collisions: {{ccd: {ccd}}}}}
    elements:
      - name: dot
        geometry: {{generator: points, params: {{positions: [[0.013, 0.3, 0.021]]}}}}
        components:
          Dynamic: {{point_mass: 0.001, velocity: [1.0, -10.0, 0.5]}}
          Collider: {{thickness: 0.002}}
      - name: floor
        geometry: {{generator: grid, params: {{size: [2, 2], resolution: [8, 8], plane: xz}}}}
        components: {{Kinematic: {{}}, Collider: {{thickness: 0.002}}}}
      - name: contact
        components:
          CollisionGroup: {{members: [dot, floor], methods: [vertex_face]}}
          CollisionResponse: {{strength: 1.0e-9}}
    """, name)


@pytest.mark.parametrize("ccd", [True, False])
def test_impact_zone_stops_a_point(scene_file, ccd):
    """With contacts that cannot push, the impact zone with the static floor stops the point
    above it; without the safe step it goes through (the check can fail)."""
    c = compile_file(_dot_on_floor(scene_file, str(ccd).lower(), f"floor_{ccd}.yaml"))
    sim = Simulation(c)
    dot = c.scene.element("dot")
    ys = []
    for _ in range(6):
        st = sim.step_frame()
        ys.append(sim.state.particle_q[dot.vertex_slice][0, 1])
    if ccd:
        assert min(ys) > 0.0
        assert ys[-1] == ys[-2]  # stopped by the impact zone with the static floor
        assert st.get("ccd_unresolved", 0) == 0
    else:
        assert min(ys) < 0.0


def _segment_on_floor(scene_file, ccd, name):
    """A one-segment strand lying along x, longer than the floor is wide (its ends are beyond
    the floor), falls at 8 m/s onto it; only edge-edge contacts, which do almost nothing: to
    get through, the strand has to cross the floor's edges, which the safe step's edge-edge
    CCD must stop."""
    return scene_file(f"""
    lokigraph: 1
    frames: {{start: 1, end: 5, fps: 24}}
    substeps: 2
    gravity: [0, 0, 0]
    graph_overrides: {{collisions: {{ccd: {ccd}}}}}
    elements:
      - name: strand
        geometry: {{generator: strands, params: {{count: [1, 1], length: 1.2, segments: 1,
                   direction: [1, 0, 0], center: [-0.6, 0.2, 0.013]}}}}
        components:
          Dynamic: {{point_mass: 0.001, velocity: [0, -8.0, 0]}}
          Collider: {{thickness: 0.002}}
      - name: floor
        geometry: {{generator: grid, params: {{size: [0.4, 0.4], resolution: [4, 4], plane: xz}}}}
        components: {{Kinematic: {{}}, Collider: {{thickness: 0.002}}}}
      - name: contact
        components:
          CollisionGroup: {{members: [strand, floor], methods: [edge_edge]}}
          CollisionResponse: {{strength: 1.0e-9}}
    """, name)


@pytest.mark.parametrize("ccd", [True, False])
def test_edge_edge_ccd_stops_a_strand(scene_file, ccd):
    c = compile_file(_segment_on_floor(scene_file, str(ccd).lower(), f"seg_{ccd}.yaml"))
    sim = Simulation(c)
    s = c.scene.element("strand")
    ys = []
    for _ in range(4):
        sim.step_frame()
        ys.append(sim.state.particle_q[s.vertex_slice][:, 1].min())
    if ccd:
        assert min(ys) > 0.0
    else:
        assert min(ys) < 0.0


@pytest.mark.parametrize("is_vf", [True, False], ids=["vf", "ee"])
def test_ccd_selection_drops_only_pairs_that_cannot_hit(is_vf):
    """The safe step runs the CCD only on pairs whose motion can close their distance (bounds
    from the relative motion, the end distance and, for a translated triangle, its plane); on
    random pairs (a third of them with a translated triangle) it finds exactly the hits of the
    CCD of every pair."""
    from lokigraph.behaviors.collision.contacts import _CCDWork, _ccd_hits
    from lokigraph.behaviors.collision.narrowphase import ee_ccd_batch, vf_ccd_batch

    rng = np.random.default_rng(3)
    n = 3000
    x = rng.uniform(-0.05, 0.05, (4 * n, 3))
    step = rng.uniform(-0.03, 0.03, (4 * n, 3)) * rng.uniform(0, 1, (4 * n, 1)) ** 3
    rows = np.arange(4 * n).reshape(n, 4)
    rigid = rng.uniform(size=n) < 1 / 3
    step[rows[rigid, 2]] = step[rows[rigid, 1]]
    step[rows[rigid, 3]] = step[rows[rigid, 1]]
    if not is_vf:
        step[rows[rigid, 0]] = step[rows[rigid, 1]]
    p = x + step
    # stored normals: the start separation direction (every pair starts on its side)
    sep = x[rows[:, 0]] - x[rows[:, 1:]].mean(1) if is_vf else \
        x[rows[:, :2]].mean(1) - x[rows[:, 2:]].mean(1)
    nrm = np.zeros((n, 3))
    target = np.full(n, 0.004)
    from lokigraph.behaviors.collision.narrowphase import (edge_edge_distance,
                                                            point_triangle_distance)
    keep = np.zeros(n, bool)
    d0 = np.zeros(n)
    for r in range(n):
        i = rows[r]
        if is_vf:
            d, b0, b1, b2 = point_triangle_distance(x[i[0]], x[i[1]], x[i[2]], x[i[3]])
            s = x[i[0]] - (b0 * x[i[1]] + b1 * x[i[2]] + b2 * x[i[3]])
        else:
            d, s_, t_ = edge_edge_distance(x[i[0]], x[i[1]], x[i[2]], x[i[3]])
            s = (1 - s_) * x[i[0]] + s_ * x[i[1]] - (1 - t_) * x[i[2]] - t_ * x[i[3]]
        if d > 1e-9:
            nrm[r] = s / d
            keep[r] = True
            d0[r] = d
    rows, nrm, target, d0 = rows[keep], nrm[keep], target[keep], d0[keep]
    work = _CCDWork(*(np.zeros(1),) * 5)
    sel, toi, dd = _ccd_hits(work, rows, nrm, target, is_vf, x, p, 0.1)
    d_all = np.minimum(0.1 * target, 0.5 * d0)
    if is_vf:
        ref = vf_ccd_batch(x, p, rows[:, 0], rows[:, 1:], d_all)
    else:
        ref = ee_ccd_batch(x, p, rows[:, :2], rows[:, 2:], d_all)
    hits = np.flatnonzero(ref <= 1.0)
    assert 20 < len(hits) < len(rows) // 2  # the data has both
    assert np.array_equal(np.sort(sel), hits)
    assert np.allclose(toi[np.argsort(sel)], ref[hits])
