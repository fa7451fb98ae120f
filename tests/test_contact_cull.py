"""Exact contact culling (``contacts._cull_rows`` and the per-row gate of the projection): the
culled candidate set must give the same active contacts, in the same order, as the full set."""

import numpy as np
import pytest

from lokigraph.api import compile_file
from lokigraph.behaviors.collision import contacts as C
from lokigraph.behaviors.collision.narrowphase import _pt_tri_sq, _seg_seg_sq
from lokigraph.run import Simulation


def _random_rows(rng, x, n_rows, is_vf):
    """Random vertex-face / edge-edge rows over the vertices ``x`` with their start normals
    (closest-point direction at ``x``, as ``_filter_vf`` / ``_filter_ee`` record them)."""
    rows, nrm = [], []
    while len(rows) < n_rows:
        q = rng.choice(len(x), 4, replace=False)
        P = x[q]
        if is_vf:
            d2, b0, b1, b2 = _pt_tri_sq(*P[0], *P[1], *P[2], *P[3])
            d = P[0] - (b0 * P[1] + b1 * P[2] + b2 * P[3])
        else:
            d2, s, t = _seg_seg_sq(*P[0], *P[1], *P[2], *P[3])
            d = (1 - s) * P[0] + s * P[1] - (1 - t) * P[2] - t * P[3]
        if d2 < 1e-12:
            continue
        rows.append(q)
        nrm.append(d / np.sqrt(d2))
    return np.array(rows, np.int64), np.array(nrm)


def _passes(is_vf, p, x, w, rows, nrm, tgt, sel, nsel, ref, b, lb, n_pass=4, moved=False):
    """``n_pass`` Gauss-Seidel passes; returns the active count of each. ``moved``: with the
    per-vertex moved distances' pre-gate (``MOVED_GATE``), taken at the start of each pass."""
    mu = np.full(len(rows), 0.3)
    st = np.ones(len(rows))
    out = []
    u = np.zeros(len(p)) if moved else C._NO_U
    for _ in range(n_pass):
        if moved:
            C._moved_norms(p, ref, u)
        if is_vf:
            one = np.zeros(len(rows), np.bool_)
            a, r = C._project_vf_sel(p, x, w, rows, nrm, tgt, mu, st, 0.0, one, sel, nsel, 0,
                                     ref, b * b, lb, 0, u)
            if r >= 0:
                a += C._project_vf_sel(p, x, w, rows, nrm, tgt, mu, st, 0.0, one, sel, -1, r,
                                       ref, b * b, lb, 0, u)[0]
        else:
            a, r = C._project_ee_sel(p, x, w, rows, nrm, tgt, mu, st, 0.0, sel, nsel, 0, ref,
                                     b * b, lb, 0, u)
            if r >= 0:
                a += C._project_ee_sel(p, x, w, rows, nrm, tgt, mu, st, 0.0, sel, -1, r, ref,
                                       b * b, lb, 0, u)[0]
        if moved:  # the kernels kept the distances current
            assert np.allclose(u, np.linalg.norm(p - ref, axis=1), rtol=1e-14, atol=0.0)
        out.append(a)
    return out


def _compare(is_vf, lb_shift=0.0, seed=0):
    """Full rows vs culled rows on random scenes and motions: (all identical, rows culled by
    the index, rows skipped by the gate)."""
    rng = np.random.default_rng(seed)
    nv = 300
    x = rng.uniform(0.0, 0.08, (nv, 3))  # dense: many pairs within a few thicknesses
    ref = x + rng.normal(0.0, 0.003, (nv, 3))  # end of the detected motion
    w = rng.uniform(0.5, 2.0, nv)
    w[:20] = 0.0  # some kinematic vertices
    rows, nrm = _random_rows(rng, x, 3000, is_vf)
    tgt = rng.uniform(0.001, 0.004, len(rows))
    b = 0.004
    sel = np.zeros(len(rows), np.int64)
    lb = np.zeros(len(rows))
    k = C._cull_rows(rows, nrm, tgt, ref, is_vf, 2.0 * b + C._CULL_TOL, sel, lb)
    lb += lb_shift  # a wrong bound (test of the test): must be detected
    same, skipped = True, 0
    for scale in (0.0005, 0.002, 0.004, 0.02):
        p0 = ref + rng.normal(0.0, scale, ref.shape)
        p0[w == 0] = ref[w == 0]
        pf = p0.copy()
        full = _passes(is_vf, pf, x, w, rows, nrm, tgt, C._NO_SEL, -1, C._NO_REF, -1.0, C._NO_LB)
        pg = p0.copy()  # every row, with the per-row gate
        gated = _passes(is_vf, pg, x, w, rows, nrm, tgt, C._NO_SEL, -1, ref, b, lb)
        same &= full == gated and np.array_equal(pf, pg)
        pm = p0.copy()  # every row, the moved distances' pre-gate before the per-row gate
        same &= full == _passes(is_vf, pm, x, w, rows, nrm, tgt, C._NO_SEL, -1, ref, b, lb,
                                moved=True) and np.array_equal(pf, pm)
        if C._max_move(ref, p0) <= b:  # the culled index applies
            for moved in (False, True):
                pc = p0.copy()
                culled = _passes(is_vf, pc, x, w, rows, nrm, tgt, sel, k, ref, b, lb,
                                 moved=moved)
                same &= full == culled and np.array_equal(pf, pc)
        # rows the gate skips at the start of the first pass
        idx = rows
        s = np.einsum("rkj,rj->rk", p0[idx] - ref[idx], nrm)
        if is_vf:
            g = lb + s[:, 0] - s[:, 1:].max(axis=1)
        else:
            g = lb + s[:, :2].min(axis=1) - s[:, 2:].max(axis=1)
        skipped += int(np.count_nonzero(g >= C._CULL_TOL))
        assert full[0] > 0  # some contacts are active: the comparison means something
    return same, len(rows) - k, skipped


def test_culled_rows_give_the_same_active_contacts():
    for is_vf in (False, True):
        for seed in range(3):
            same, culled, skipped = _compare(is_vf, seed=seed)
            assert same, (is_vf, seed)
            assert culled > 0 and skipped > 0  # the culling does remove work


def test_an_unsound_bound_is_detected():
    """Test of the test: a bound 5 mm too optimistic culls rows that do activate, and the
    comparison above sees it."""
    for is_vf in (False, True):
        assert not all(_compare(is_vf, lb_shift=0.005, seed=s)[0] for s in range(3))


def _drop(scene_file, cull, monkeypatch):
    monkeypatch.setattr(C, "CONTACT_CULL", cull)
    path = scene_file("""
    lokigraph: 1
    frames: {start: 1, end: 9, fps: 24}
    substeps: 2
    elements:
      - name: cloth
        geometry:
          generator: grid
          params: {size: [0.8, 0.8], resolution: [20, 20], plane: xz, center: [0.05, 0.36, 0]}
        components:
          Dynamic: {mass_density: 0.15, damping: 0.2}
          DiscreteShell: {bend_resistance: 2.0e-6}
          Collider: {thickness: 0.004, friction: 0.3}
      - name: body
        geometry: {generator: sphere, params: {radius: 0.3, subdivisions: 3}}
        components: {Kinematic: {}, Collider: {thickness: 0.002, one_sided: true}}
      - name: contact
        components:
          CollisionGroup: {members: [cloth, body], methods: [vertex_face, edge_edge, self]}
    """, f"cull_{int(cull)}.yaml")
    sim = Simulation(compile_file(path))
    stats = [sim.step_frame() for _ in range(8)]
    c = sim.state.fields["contacts"]
    return sim.state.particle_q.copy(), stats, c


def test_scene_is_bitwise_unchanged_by_culling(scene_file, monkeypatch):
    q0, s0, c0 = _drop(scene_file, False, monkeypatch)
    q1, s1, c1 = _drop(scene_file, True, monkeypatch)
    assert c0.cull_passes == 0 and c1.cull_passes + c1.full_passes > 0
    assert max(s.get("max_active_contacts", 0) for s in s0) > 0  # the cloth is in contact
    assert [s.get("max_active_contacts") for s in s0] == [s.get("max_active_contacts")
                                                         for s in s1]
    assert np.array_equal(q0, q1)


def test_selection_pass_ends_when_a_contact_moves_a_vertex_past_the_bound():
    """A pass over the selected rows ends at the row whose contact moves one of its vertices
    farther than the cull bound from the reference (the rows left out of the selection may
    then activate). A vertex 1 mm over the corner of a kinematic triangle (closest point: the
    corner, barycentric (0, 0, 1)) with a 4 mm target is pushed 3 mm: past a 1 mm bound, so
    the pass ends after that row. Before stop 31 the vertex-face kernel compared the motion
    with the closest point's third barycentric coordinate instead of the bound (a name
    shadowed it), so it went on."""
    p = np.array([[0.0, 0.0, 0.001], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    w = np.array([1.0, 0.0, 0.0, 0.0])
    rows = np.array([[0, 1, 2, 3]], np.int64)
    nrm = np.array([[0.0, 0.0, 1.0]])
    ref = p.copy()
    active, resume = C._project_vf_sel(
        p, p.copy(), w, rows, nrm, np.array([0.004]), np.zeros(1), np.ones(1), 0.0,
        np.zeros(1, np.bool_), np.zeros(1, np.int64), 1, 0, ref, 1e-6, np.zeros(0))
    assert active == 1
    assert p[0, 2] == pytest.approx(0.004)
    assert resume == 1  # ended after row 0: resume every row from 1
