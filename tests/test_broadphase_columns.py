"""Sorted column grid (``broadphase.column_query_self`` / ``column_query_pairs``): exactly the
candidate set of the BVH queries (set equality, rows in another order) on the broad-phase
benchmark's rolled sheet, on cloth and triangle soups with space-time boxes, inactive primitives
and groups, and on random boxes of very different sizes (the big-box path), and the same rows
in the same order on one and two threads."""

import numba
import numpy as np
import pytest

from lokigraph.behaviors.collision import broadphase as bp
from lokigraph.bench.broadphase import rolled_sheet

from test_broadphase import as_set, brute_cross, brute_self, make_mesh


def _bvh_self(lo, hi, P, st_prims=None, X0=None, X1=None, thick=0.0, active=None, group=None):
    tree = bp.build_bvh(lo, hi)
    st = None
    if X0 is not None:
        st = bp.spacetime_boxes(tree, X0, P, X1, thick, active, group)
    return bp.query_self(tree, P, st=st)


def _bvh_pairs(lo_a, hi_a, lo_b, hi_b, Pa, Pb, X0=None, X1=None, thick=0.0, act=(None, None),
               grp=(None, None)):
    ta, tb = bp.build_bvh(lo_a, hi_a), bp.build_bvh(lo_b, hi_b)
    sa = sb = None
    if X0 is not None:
        sa = bp.spacetime_boxes(ta, X0, Pa, X1, thick, act[0], grp[0])
        sb = bp.spacetime_boxes(tb, X0, Pb, X1, thick, act[1], grp[1])
    return bp.query_pairs(ta, tb, Pa, Pb, st_a=sa, st_b=sb)


@pytest.mark.parametrize("n", [20, 45])
def test_rolled_sheet_matches_bvh(n):
    X0, F, h = rolled_sheet(n, 0.0)
    X1, _, _ = rolled_sheet(n, 1.0)
    E = bp.mesh_edges(F)
    V = np.arange(len(X0))
    thick = np.full(len(X0), 0.1 * h)
    lo_e, hi_e = bp.primitive_boxes(X0, E, X1, thick)
    lo_v, hi_v = bp.primitive_boxes(X0, V, X1, thick)
    lo_f, hi_f = bp.primitive_boxes(X0, F, X1, thick)
    ee = bp.column_query_self(lo_e, hi_e, E)
    assert len(ee) > 1000
    assert as_set(ee) == as_set(_bvh_self(lo_e, hi_e, E))
    assert np.all(ee[:, 0] < ee[:, 1])
    vf = bp.column_query_pairs(lo_v, hi_v, lo_f, hi_f, V, F)
    assert len(vf) > 100
    assert as_set(vf) == as_set(_bvh_pairs(lo_v, hi_v, lo_f, hi_f, V, F))
    # with space-time boxes (two groups, some inactive primitives)
    rng = np.random.default_rng(n)
    ge, gv, gf = (rng.integers(0, 2, len(E)), rng.integers(0, 2, len(V)),
                  rng.integers(0, 2, len(F)))
    ae, av, af = (rng.random(len(E)) > 0.3, rng.random(len(V)) > 0.3, rng.random(len(F)) > 0.3)
    se = bp.spacetime_prim_boxes(X0, E, X1, thick, ae, ge)
    got = bp.column_query_self(lo_e, hi_e, E, st=se)
    ref = _bvh_self(lo_e, hi_e, E, X0=X0, X1=X1, thick=thick, active=ae, group=ge)
    assert 0 < len(got) < len(ee)
    assert as_set(got) == as_set(ref)
    sv = bp.spacetime_prim_boxes(X0, V, X1, thick, av, gv)
    sf = bp.spacetime_prim_boxes(X0, F, X1, thick, af, gf)
    got = bp.column_query_pairs(lo_v, hi_v, lo_f, hi_f, V, F, st_a=sv, st_b=sf)
    ref = _bvh_pairs(lo_v, hi_v, lo_f, hi_f, V, F, X0, X1, thick, (av, af), (gv, gf))
    assert 0 < len(got) < len(vf)
    assert as_set(got) == as_set(ref)


@pytest.mark.parametrize("kind", ["cloth", "soup"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_meshes_match_bvh_with_spacetime(kind, seed):
    X0, X1, _, F = make_mesh(kind, seed)
    E = bp.mesh_edges(F)
    V = np.arange(len(X0))
    rng = np.random.default_rng(seed)
    thick = 0.02 * rng.random(len(X0))
    lo_e, hi_e = bp.primitive_boxes(X0, E, X1, thick)
    lo_v, hi_v = bp.primitive_boxes(X0, V, X1, thick)
    lo_f, hi_f = bp.primitive_boxes(X0, F, X1, thick)
    assert as_set(bp.column_query_self(lo_e, hi_e, E)) == brute_self(lo_e, hi_e, E)
    assert as_set(bp.column_query_pairs(lo_v, hi_v, lo_f, hi_f, V, F)) == \
        brute_cross(lo_v, hi_v, lo_f, hi_f, V, F)
    g = rng.integers(0, 3, len(E))
    a = rng.random(len(E)) > 0.5
    se = bp.spacetime_prim_boxes(X0, E, X1, thick, a, g)
    assert as_set(bp.column_query_self(lo_e, hi_e, E, st=se)) == \
        as_set(_bvh_self(lo_e, hi_e, E, X0=X0, X1=X1, thick=thick, active=a, group=g))


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_random_boxes_of_mixed_sizes_match_brute_force(seed):
    """Boxes from points to the whole scene (the big boxes are tested against all), flat boxes,
    boxes sharing faces exactly (closed overlap), no primitives (nothing skipped)."""
    rng = np.random.default_rng(seed)
    n = 700
    c = rng.random((n, 3))
    ext = 0.03 * rng.random((n, 3)) ** 3
    ext[rng.random(n) < 0.02] *= 400.0  # a few big boxes
    ext[rng.random((n, 3)) < 0.05] = 0.0  # flat and point boxes
    lo = c - ext
    hi = c + ext
    lo[1] = hi[0]  # touching boxes overlap
    lo[5] = -10.0
    hi[5] = 10.0  # one box over everything
    got = bp.column_query_self(lo, hi)
    ref = brute_self(lo, hi, np.arange(n)[:, None] + n)  # no shared vertices
    assert as_set(got) == ref
    m = 300
    got = bp.column_query_pairs(lo[:m], hi[:m], lo[m:], hi[m:])
    assert as_set(got) == brute_cross(lo[:m], hi[:m], lo[m:], hi[m:])


def test_degenerate_inputs():
    z = np.zeros((0, 3))
    assert bp.column_query_self(z, z).shape == (0, 2)
    one = np.zeros((1, 3))
    assert bp.column_query_self(one, one).shape == (0, 2)
    assert bp.column_query_pairs(one, one, z, z).shape == (0, 2)
    same = np.zeros((50, 3))  # 50 equal point boxes: every pair
    assert len(bp.column_query_self(same, same)) == 50 * 49 // 2
    assert len(bp.column_query_pairs(same[:20], same[:20], same, same)) == 20 * 50
    big = np.stack([np.zeros(3), 5 * np.ones(3)])  # every box big (spread over two columns)
    lo = np.concatenate([big[:1] - 1, big[:1] + 3])
    assert as_set(bp.column_query_self(lo, lo + 3)) == brute_self(lo, lo + 3, [[0], [1]])
    with pytest.raises(ValueError):
        bp.column_query_self(np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((2, 2), np.int64))


@pytest.mark.parametrize("par_min", [None, 0])
def test_rows_independent_of_thread_count(monkeypatch, par_min):
    """Same rows in the same order at 1 and 2 threads; ``par_min`` 0: the column count and
    fill in parallel chunks (``_COL_PAR_MIN``) at 2 threads, serial at 1."""
    if par_min is not None:
        monkeypatch.setattr(bp, "_COL_PAR_MIN", par_min)
    X0, F, h = rolled_sheet(30, 0.0)
    X1, _, _ = rolled_sheet(30, 1.0)
    E = bp.mesh_edges(F)
    V = np.arange(len(X0))
    lo, hi = bp.primitive_boxes(X0, E, X1, 0.1 * h)
    lo_v, hi_v = bp.primitive_boxes(X0, V, X1, 0.1 * h)
    lo_f, hi_f = bp.primitive_boxes(X0, F, X1, 0.1 * h)
    threads = numba.get_num_threads()
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("numba has one thread")
    try:
        numba.set_num_threads(1)
        one = bp.column_query_self(lo, hi, E).copy()
        one_vf = bp.column_query_pairs(lo_v, hi_v, lo_f, hi_f, V, F).copy()
        numba.set_num_threads(2)
        two = bp.column_query_self(lo, hi, E, out=bp.PairBuffer())
        two_vf = bp.column_query_pairs(lo_v, hi_v, lo_f, hi_f, V, F, out=bp.PairBuffer())
    finally:
        numba.set_num_threads(threads)
    assert np.array_equal(one, two) and len(one) > 1000
    assert np.array_equal(one_vf, two_vf) and len(one_vf) > 100


@pytest.mark.parametrize("threads", [1, 2])
def test_single_pass_with_buffer_gives_the_two_pass_rows(threads):
    """A reused PairBuffer sweeps once into scratch sized from its previous query; slots that
    overflow (the pair count grows 10x between queries here) are swept again. The rows and
    their order are those of the two-pass query without a buffer, big boxes included."""
    if threads > numba.config.NUMBA_NUM_THREADS:
        pytest.skip("numba has one thread")
    X0, F, h = rolled_sheet(30, 0.0)
    X1, _, _ = rolled_sheet(30, 1.0)
    E = bp.mesh_edges(F)
    V = np.arange(len(X0))
    old = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        bee, bvf = bp.PairBuffer(), bp.PairBuffer()
        for r in (0.0, 0.1 * h, 0.01 * h, 0.3 * h, 0.3 * h):
            lo_e, hi_e = bp.primitive_boxes(X0, E, X1, r)
            lo_v, hi_v = bp.primitive_boxes(X0, V, X1, r)
            lo_f, hi_f = bp.primitive_boxes(X0, F, X1, r)
            lo_f[3] -= 1.0  # a big box
            ref = bp.column_query_self(lo_e, hi_e, E)
            assert np.array_equal(bp.column_query_self(lo_e, hi_e, E, out=bee), ref)
            ref = bp.column_query_pairs(lo_v, hi_v, lo_f, hi_f, V, F)
            assert np.any(ref[:, 1] == 3)
            assert np.array_equal(bp.column_query_pairs(lo_v, hi_v, lo_f, hi_f, V, F, out=bvf),
                                  ref)
    finally:
        numba.set_num_threads(old)


def test_contacts_detect_the_same_rows_with_either_broad_phase(tmp_path, monkeypatch):
    """``contacts.COLUMN_GRID``: every detection of the cloth dropped on the sphere (24 x 24,
    7 frames: the cloth lands around frame 6; swept-box and space-time detections, the sphere
    in the same group) gives the same filtered vertex-face and edge-edge rows with the column
    grid as with the trees (as sets: only their order differs)."""
    from pathlib import Path

    from lokigraph.api import compile_file
    from lokigraph.behaviors.collision import contacts as C
    from lokigraph.run import Simulation

    src = Path(__file__).resolve().parents[1] / "graphs" / "bench" / "cloth_sphere_64.yaml"
    path = tmp_path / "drop.yaml"
    path.write_text(src.read_text().replace("resolution: [64, 64]", "resolution: [24, 24]"))
    monkeypatch.setattr(C, "COLUMN_GRID_MIN_TRIS", 0)
    orig = C._detect_group
    seen = {"calls": 0, "rows": 0, "st": 0}

    def both(g, x, x1, infl, v, h, spacetime=False):
        out = {}
        for flag in (False, True):
            monkeypatch.setattr(C, "COLUMN_GRID", flag)
            out[flag] = orig(g, x, x1, infl, v, h, spacetime)
            out[flag] = [(r[0].copy(), r[2].copy()) for r in out[flag][:2]]
        for (rows_t, tgt_t), (rows_c, tgt_c) in zip(out[False], out[True]):
            key_t = sorted(zip(map(tuple, rows_t.tolist()), tgt_t.tolist()))
            key_c = sorted(zip(map(tuple, rows_c.tolist()), tgt_c.tolist()))
            assert key_t == key_c
            seen["rows"] += len(rows_t)
        seen["calls"] += 1
        seen["st"] += bool(spacetime)
        return orig(g, x, x1, infl, v, h, spacetime)

    monkeypatch.setattr(C, "_detect_group", both)
    sim = Simulation(compile_file(path))
    for _ in range(7):
        sim.step_frame()
    assert seen["calls"] > 10 and seen["st"] > 0 and seen["rows"] > 1000


def test_non_finite_boxes_fall_back_to_the_trees():
    """NaN or infinite coordinates (a diverged simulation) would overflow the column indices:
    the trees answer instead, the same rows as the tree query."""
    rng = np.random.default_rng(5)
    lo = rng.random((200, 3))
    hi = lo + 0.05
    lo[7] = np.nan
    hi[9, 1] = np.inf
    P = np.arange(200)[:, None]
    ref = bp.query_self(bp.build_bvh(lo, hi), P)
    assert np.array_equal(bp.column_query_self(lo, hi, P), ref)
    assert len(ref) > 0
    ref = bp.query_pairs(bp.build_bvh(lo[:80], hi[:80]), bp.build_bvh(lo[80:], hi[80:]))
    assert np.array_equal(bp.column_query_pairs(lo[:80], hi[:80], lo[80:], hi[80:]), ref)
    X0 = rng.random((60, 3))
    X1 = X0 + 0.01
    X0[3] = 1e200  # far beyond any column count
    E = np.stack([np.arange(59), np.arange(1, 60)], 1)
    lo_e, hi_e = bp.primitive_boxes(X0, E, X1, 0.02)
    st = bp.spacetime_prim_boxes(X0, E, X1, 0.02)
    tree = bp.build_bvh(lo_e, hi_e)
    ref = bp.query_self(tree, E, st=bp.spacetime_boxes(tree, X0, E, X1, 0.02))
    assert as_set(bp.column_query_self(lo_e, hi_e, E, st=st)) == as_set(ref)


@pytest.mark.parametrize("seed", [0, 1])
def test_sort_pairs_is_lexicographic(seed):
    """``sort_pairs``: rows sorted by (first, second), or by given ranks, as numpy's lexsort;
    the same set of rows; with and without a buffer."""
    rng = np.random.default_rng(seed)
    na, nb = 300, 500
    pairs = np.stack([rng.integers(0, na, 5000), rng.integers(0, nb, 5000)], 1).astype(np.int64)
    ref = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    buf = bp.PairBuffer()
    p1 = pairs.copy()
    assert np.array_equal(bp.sort_pairs(p1, na), ref)
    p2 = buf.reserve(len(pairs))
    p2[:] = pairs
    assert np.array_equal(bp.sort_pairs(p2, na, buf), ref)
    ra, rb = rng.permutation(na).astype(np.int64), rng.permutation(nb).astype(np.int64)
    p3 = pairs.copy()
    bp.sort_pairs(p3, na, None, ra, rb)
    assert np.array_equal(p3, pairs[np.lexsort((rb[pairs[:, 1]], ra[pairs[:, 0]]))])


@pytest.mark.parametrize("order", ["index", "morton", "zorder"])
def test_canonical_order_makes_the_broad_phases_agree_row_for_row(tmp_path, monkeypatch, order):
    """``contacts.CANONICAL_ORDER``: the filtered rows of every detection of the 24 x 24 drop
    (7 frames) are equal in order, not only as sets, with the trees and with the column grid."""
    from pathlib import Path

    from lokigraph.api import compile_file
    from lokigraph.behaviors.collision import contacts as C
    from lokigraph.run import Simulation

    src = Path(__file__).resolve().parents[1] / "graphs" / "bench" / "cloth_sphere_64.yaml"
    path = tmp_path / "drop.yaml"
    path.write_text(src.read_text().replace("resolution: [64, 64]", "resolution: [24, 24]"))
    monkeypatch.setattr(C, "CANONICAL_ORDER", order)
    monkeypatch.setattr(C, "COLUMN_GRID_MIN_TRIS", 0)
    orig = C._detect_group
    seen = {"rows": 0}

    def both(g, x, x1, infl, v, h, spacetime=False):
        out = {}
        for flag in (False, True):
            monkeypatch.setattr(C, "COLUMN_GRID", flag)
            out[flag] = [(r[0].copy(), r[1].copy(), r[2].copy())
                         for r in orig(g, x, x1, infl, v, h, spacetime)[:2]]
        for a, b in zip(out[False], out[True]):
            for u, w in zip(a, b):
                assert np.array_equal(u, w)
            seen["rows"] += len(a[0])
        return orig(g, x, x1, infl, v, h, spacetime)

    monkeypatch.setattr(C, "_detect_group", both)
    sim = Simulation(compile_file(path))
    for _ in range(7):
        sim.step_frame()
    assert seen["rows"] > 1000


def test_zsort_pairs_is_the_z_order_of_the_ranks():
    """``zsort_pairs``: rows sorted by the bit interleaving of (rank_a[i], rank_b[j]) (self:
    of the smaller and larger rank), as a numpy argsort of the same keys."""
    rng = np.random.default_rng(3)
    na, nb = 3000, 5000
    ra, rb = rng.permutation(na).astype(np.int64), rng.permutation(nb).astype(np.int64)
    pairs = np.unique(np.stack([rng.integers(0, na, 20000), rng.integers(0, nb, 20000)], 1),
                      axis=0)
    rng.shuffle(pairs)

    def spread(v):
        out, v = np.zeros(len(v), np.uint64), v.astype(np.uint64)
        for i in range(32):
            out |= ((v >> np.uint64(i)) & np.uint64(1)) << np.uint64(2 * i)
        return out

    for self_mode in (False, True):
        p = np.unique(np.sort(pairs % na, axis=1), axis=0) if self_mode else pairs.copy()
        r2 = ra if self_mode else rb
        ka, kb = ra[p[:, 0]], r2[p[:, 1]]
        if self_mode:
            ka, kb = np.minimum(ka, kb), np.maximum(ka, kb)
        ref = p[np.argsort((spread(ka) << np.uint64(1)) | spread(kb))]
        q = p.copy()
        assert np.array_equal(bp.zsort_pairs(q, ra, r2, self_mode), ref)
        buf = bp.PairBuffer()
        q2 = buf.reserve(len(p))
        q2[:] = p
        assert np.array_equal(bp.zsort_pairs(q2, ra, r2, self_mode, buf), ref)


@pytest.mark.parametrize("kind", ["cloth", "soup"])
def test_sweep_rows_match_the_references_at_one_and_two_threads(kind):
    """The sweep on the gathered vertices and flags, self and two-set queries, with and without
    primitives and space-time boxes, a big box among them: every query's rows are distinct and
    their set is the brute force's (the trees' with space-time boxes); 1 and 2 threads give the
    same rows in the same order."""
    X0, X1, _, F = make_mesh(kind, 4)
    E = bp.mesh_edges(F)
    V = np.arange(len(X0))
    rng = np.random.default_rng(4)
    thick = 0.02 * rng.random(len(X0))
    lo_e, hi_e = bp.primitive_boxes(X0, E, X1, thick)
    lo_v, hi_v = bp.primitive_boxes(X0, V, X1, thick)
    lo_f, hi_f = bp.primitive_boxes(X0, F, X1, thick)
    lo_f[2] -= 1.0  # a big box
    g = rng.integers(0, 3, len(E))
    a = rng.random(len(E)) > 0.5
    se = bp.spacetime_prim_boxes(X0, E, X1, thick, a, g)
    gv, gf = np.zeros(len(V), np.int64), np.zeros(len(F), np.int64)
    sv = bp.spacetime_prim_boxes(X0, V, X1, thick, None, gv)
    sf = bp.spacetime_prim_boxes(X0, F, X1, thick, None, gf)

    def queries():
        return [bp.column_query_self(lo_e, hi_e, E).copy(),
                bp.column_query_self(lo_e, hi_e).copy(),
                bp.column_query_self(lo_e, hi_e, E, st=se, out=bp.PairBuffer()).copy(),
                bp.column_query_pairs(lo_v, hi_v, lo_f, hi_f, V, F).copy(),
                bp.column_query_pairs(lo_v, hi_v, lo_f, hi_f).copy(),
                bp.column_query_pairs(lo_v, hi_v, lo_f, hi_f, V, F, out=bp.PairBuffer(),
                                      st_a=sv, st_b=sf).copy()]

    every_e = {r for r in brute_cross(lo_e, hi_e, lo_e, hi_e) if r[0] < r[1]}
    refs = [brute_self(lo_e, hi_e, E), every_e,
            as_set(_bvh_self(lo_e, hi_e, E, X0=X0, X1=X1, thick=thick, active=a, group=g)),
            brute_cross(lo_v, hi_v, lo_f, hi_f, V, F), brute_cross(lo_v, hi_v, lo_f, hi_f),
            as_set(_bvh_pairs(lo_v, hi_v, lo_f, hi_f, V, F, X0=X0, X1=X1, thick=thick,
                              grp=(gv, gf)))]
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = queries()
        if numba.config.NUMBA_NUM_THREADS >= 2:
            numba.set_num_threads(2)
            for x, y in zip(queries(), one):
                assert np.array_equal(x, y)
    finally:
        numba.set_num_threads(old)
    for rows, ref in zip(one, refs):
        assert len(ref) > 0 and len(as_set(rows)) == len(rows) and as_set(rows) == ref
    assert len(refs[1]) > len(refs[0]) > len(refs[2])  # primitives and space-time boxes skip rows
    assert any(r[1] == 2 for r in refs[3])  # the big box has rows


@pytest.mark.parametrize("par_min", [None, 0])
def test_sweep_order_is_the_stable_argsort(monkeypatch, par_min):
    """``_sweep_order`` (the bucket sort ``_bucket_order``) orders the boxes as
    ``np.argsort(kind="stable")``: ties by index, negative values, -0.0 equal to 0.0, tiny and
    huge magnitudes (a spread that overflows), one value, few values in many ties, a bucket
    sorted past its insertion budget (merge sorted); ``par_min`` 0: in chunks on all threads."""
    if par_min is not None:
        monkeypatch.setattr(bp, "_COL_PAR_MIN", par_min)
    rng = np.random.default_rng(5)

    class Out:
        pass

    out = Out()
    for t in range(60):
        n = int(rng.integers(256, 3000))
        if t % 5 == 0:
            x = rng.choice([-2.5, -1.0, -0.0, 0.0, 1e-300, 3.0, 7.25, -1e300, 1e300], n)
        elif t % 5 == 1:
            x = rng.normal(size=n) * 10.0 ** rng.integers(-5, 5)
        elif t % 5 == 2:
            x = np.full(n, 0.5)
        elif t % 5 == 3:
            x = np.round(rng.random(n) * rng.integers(1, 60)) / 7.0  # few values, many ties
        else:
            x = np.concatenate([rng.random(n - 8) * 1e-6, [1e3, -1e3, 5.0, 2.0, 0, 0, 1, 1]])
            x[: n // 2] = np.sort(x[: n // 2])[::-1]  # one crowded bucket in reverse order
        lo = rng.random((n, 3))
        lo[:, t % 3] = x
        assert np.array_equal(bp._sweep_order(lo, t % 3, out),
                              np.argsort(lo[:, t % 3], kind="stable"))
