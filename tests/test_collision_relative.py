"""Space-time rows in the detection over the predicted motion made exact by a check (issue #12,
``contacts.SPACETIME_RELATIVE``): before every contact pass of the iterations
``contacts._relative_flags`` flags the vertices whose deviation from the detected end differs
from a nearby vertex's by more than 2 (infl_min + slack) - target_max; with no flag every pair
within its target at the iterate is among the rows, with flags the rows are detected again over
the motion to the iterate. Checked against brute force: the bound is sharp (two sheets moved
toward each other by just less / just more than it), the stopped walls of
``tests/test_collision_spacetime.py`` are flagged and recovered, and in a simulation every
check that passes leaves no pair within its target missing."""

import numpy as np
import pytest

from lokigraph.api import compile_file
from lokigraph.behaviors.collision import contacts as C
from lokigraph.behaviors.topology import triangle_edges
from lokigraph.run import Simulation
from test_collision_spacetime import _flat_tube_scene
from test_collision_spacetime import _pairs_within as _missing  # brute force, rows missing


def _rows(c):
    """The packed rows and ``RELATIVE_INCREMENTAL``'s added ones (vf, ee)."""
    vf = np.concatenate([c.vf] + [e[0][0] for e in c.rel_extra])
    ee = np.concatenate([c.ee] + [e[1][0] for e in c.rel_extra])
    return vf, ee


def _mesh(sim):
    tris = np.concatenate([e.geometry.triangles + e.vertex_offset for e in sim.model.elements
                           if e.geometry is not None])
    edges = np.concatenate([triangle_edges(e.geometry.triangles) + e.vertex_offset
                            for e in sim.model.elements if e.geometry is not None])
    return tris, edges


def _capture_first_detection(monkeypatch, sim, fn):
    """Run ``fn(ctx, d)`` right after the first ``CollisionDetect.step`` of ``sim``'s frame."""
    orig = C.CollisionDetect.step
    out = {}

    def step(self, ctx, d):
        orig(self, ctx, d)
        if not out:
            out["r"] = fn(ctx, d)

    monkeypatch.setattr(C.CollisionDetect, "step", step)
    sim.step_frame()
    return out["r"]


def test_relative_bound_is_sharp(scene_file, monkeypatch):
    """Two resting sheets 0.5 mm farther apart than twice the (slack-widened) inflation: the
    space-time rows hold no pair between them. Moving one sheet toward the other by a bit less
    than the check's bound leaves every pair outside its target and the check passes; by a bit
    more than gap - target puts pairs within their target that the rows miss, and the check
    flags them; the re-detection over the motion to that iterate then misses none."""
    monkeypatch.setattr(C, "SPACETIME_RELATIVE", True)
    th, margin, slack = 0.002, 0.002, C.RELATIVE_SLACK
    r = th + 0.5 * margin + slack
    gap = 2 * r + 0.0005
    sheets = "\n".join(f"""
      - name: {nm}
        geometry:
          generator: grid
          params: {{size: [0.1, 0.1], resolution: [6, 6], plane: xz, center: [0, {y}, 0]}}
        components:
          Dynamic: {{mass_density: 0.15}}
          Collider: {{thickness: {th}}}""" for nm, y in (("a", 0.5), ("b", 0.5 + gap)))
    path = scene_file(f"""
    lokigraph: 1
    frames: {{start: 1, end: 2, fps: 24}}
    substeps: 1
    gravity: [0, 0, 0]
    elements:{sheets}
      - name: contact
        components:
          CollisionGroup: {{members: [a, b], methods: [vertex_face, edge_edge, self],
                            margin: {margin}}}
    """, "sheets.yaml")
    sim = Simulation(compile_file(path))
    tris, edges = _mesh(sim)

    def at_detection(ctx, d):
        x = ctx.state.particle_q.copy()
        bound, t_max = d.rel_bounds[0]
        assert bound == pytest.approx(2 * r - 2 * th) and t_max == pytest.approx(2 * th)
        upper = x[:, 1] > 0.5 + 0.5 * gap
        res = []
        for dy in (bound - 0.0002, gap - t_max + 0.0003):
            p = x.copy()
            p[upper, 1] -= dy
            d.rel_ref = d.x1
            flagged = C._relative_check(d, x, p)
            miss = _missing(p, d.vf, d.ee, tris, edges, t_max)
            res.append((flagged, len(miss)))
        # the re-detection of CollisionConstraint.project over x -> p
        C._detect_all(d, x, p, ctx.state.particle_qd, ctx.dt, "relative", slack)
        res.append(len(_missing(p, d.vf, d.ee, tris, edges, t_max)))
        return res

    (f_in, m_in), (f_out, m_out), m_after = _capture_first_detection(monkeypatch, sim,
                                                                     at_detection)
    assert f_in == 0 and m_in == 0
    assert m_out > 10 and f_out >= 2 * 7 * 7  # both sheets' vertices flagged
    assert m_after == 0


def test_relative_check_flags_stopped_walls(scene_file, monkeypatch):
    """The case of ``test_iteration_rows_hold_vertices_stopped_on_their_path``: a tube falls as
    a whole, its lower wall stops where it starts while the upper one arrives on it. The
    space-time rows miss the wall-wall pairs; the check flags the walls' vertices, and the
    re-detection over the motion to that iterate holds every pair within its target."""
    monkeypatch.setattr(C, "SPACETIME_RELATIVE", True)
    sim = Simulation(compile_file(_flat_tube_scene(scene_file)))
    fall = 0.02
    sim.state.particle_qd[:] = [0.0, -fall * 24, 0.0]
    tris, edges = _mesh(sim)

    def at_detection(ctx, d):
        x = ctx.state.particle_q.copy()
        p = d.x1.copy()
        lower = x[:, 1] < 0.5
        p[lower] = x[lower]  # stopped at the start; the upper wall moved on
        t_max = d.rel_bounds[0][1]
        miss = len(_missing(p, d.vf, d.ee, tris, edges, t_max))
        flagged = C._relative_check(d, x, p)
        added = C._relative_extra(d, x, p, ctx.state.particle_qd, ctx.dt)
        incremental = len(_missing(p, *_rows(d), tris, edges, t_max))
        C._detect_all(d, x, p, ctx.state.particle_qd, ctx.dt, "relative", C.RELATIVE_SLACK)
        return miss, flagged, added, incremental, len(_missing(p, d.vf, d.ee, tris, edges,
                                                             t_max))

    miss, flagged, added, incremental, after = _capture_first_detection(monkeypatch, sim,
                                                                        at_detection)
    assert miss > 10  # as test_collision_spacetime's space-time rows (1,114 measured there)
    assert flagged > 0
    assert added >= miss and incremental == 0  # the rows added for the flagged vertices
    assert after == 0  # or a full detection over x -> p


@pytest.mark.parametrize("incremental", [1.0, 0.0])
def test_relative_check_holds_in_a_simulation(scene_file, monkeypatch, incremental):
    """A tube thrown down onto a kinematic floor (it flattens: its upper wall comes down onto
    the lower one), simulated with ``SPACETIME_RELATIVE``: at every check that passes,
    brute force finds no pair within its target missing from the rows; the check fails and
    re-detects in some passes (rows added for the flagged vertices, or everything detected
    again), every pass then holds every pair within its target, and the frames end without
    intersections."""
    monkeypatch.setattr(C, "SPACETIME_RELATIVE", True)
    monkeypatch.setattr(C, "RELATIVE_INCREMENTAL", incremental)  # added rows / detect again
    path = scene_file("""
    lokigraph: 1
    frames: {start: 1, end: 4, fps: 24}
    substeps: 2
    elements:
      - name: tube
        geometry:
          generator: tube
          params: {radius: 0.03, length: 0.2, segments: [16, 10], axis: x, center: [0, 0.06, 0]}
        components:
          Dynamic: {mass_density: 0.15}
          Collider: {thickness: 0.002}
      - name: floor
        geometry:
          generator: grid
          params: {size: [0.6, 0.6], resolution: [8, 8], plane: xz, center: [0, 0.0, 0]}
        components:
          Kinematic: {}
          Collider: {thickness: 0.002}
      - name: contact
        components:
          CollisionGroup: {members: [tube, floor], methods: [vertex_face, edge_edge, self]}
    """, "tube_floor.yaml")
    sim = Simulation(compile_file(path))
    sim.state.particle_qd[:] = [0.0, -2.0, 0.0]
    tris, edges = _mesh(sim)
    orig, orig_extra = C._relative_check, C._relative_extra
    seen = {"pass": 0, "fail": 0, "missing": 0, "missing_added": 0, "added": 0}

    def check(c, x, p):
        k = orig(c, x, p)
        if k:
            seen["fail"] += 1
        else:
            seen["pass"] += 1
            seen["missing"] += len(_missing(p, c.vf, c.ee, tris, edges,
                                            c.rel_bounds[0][1]))
        return k

    def extra(c, x, p, v, h):
        n = orig_extra(c, x, p, v, h)
        seen["added"] += n
        seen["missing_added"] += len(_missing(p, *_rows(c), tris, edges, c.rel_bounds[0][1]))
        return n

    monkeypatch.setattr(C, "_relative_check", check)
    monkeypatch.setattr(C, "_relative_extra", extra)
    for _ in range(3):
        st = sim.step_frame()
        assert st.get("penetrations", 0) == 0
    print(seen)
    assert seen["missing"] == 0 and seen["missing_added"] == 0
    assert seen["pass"] > 0 and seen["fail"] > 0
    assert (seen["added"] > 0) == (incremental > 0)
