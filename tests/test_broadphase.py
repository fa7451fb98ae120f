"""Broad phase: BVH and hash-grid candidate sets against brute force, and the cloth-funnel
whole-mesh check of the CCD data set (shared/data/ccd/README.md, "Whole-mesh test")."""

from pathlib import Path

import numpy as np
import pytest

from lokigraph.behaviors.collision import broadphase as bp

MESHES = Path(__file__).resolve().parent / "data" / "meshes"
FUNNEL = MESHES / "cloth_funnel_227_228_frames.npz"


# ---------------------------------------------------------------------------------------------
# references (numpy, O(n^2), independent of the BVH code)
# ---------------------------------------------------------------------------------------------


def brute_overlap(lo_a, hi_a, lo_b, hi_b):
    """(m_a, m_b) bool: closed boxes overlap."""
    return np.all((lo_a[:, None, :] <= hi_b[None, :, :]) & (lo_b[None, :, :] <= hi_a[:, None, :]), axis=2)


def shares_vertex(Pa, Pb):
    Pa = np.asarray(Pa).reshape(len(Pa), -1)
    Pb = np.asarray(Pb).reshape(len(Pb), -1)
    return (Pa[:, None, :, None] == Pb[None, :, None, :]).any(axis=(2, 3))


def as_set(pairs):
    pairs = np.asarray(pairs)
    s = set(map(tuple, pairs.tolist()))
    assert len(s) == len(pairs), "duplicate pairs in the output"
    return s


def brute_self(lo, hi, P):
    m = brute_overlap(lo, hi, lo, hi) & ~shares_vertex(P, P)
    i, j = np.nonzero(np.triu(m, 1))
    return set(zip(i.tolist(), j.tolist()))


def brute_cross(lo_a, hi_a, lo_b, hi_b, Pa=None, Pb=None):
    m = brute_overlap(lo_a, hi_a, lo_b, hi_b)
    if Pa is not None:
        m &= ~shares_vertex(Pa, Pb)
    i, j = np.nonzero(m)
    return set(zip(i.tolist(), j.tolist()))


# ---------------------------------------------------------------------------------------------
# test meshes
# ---------------------------------------------------------------------------------------------


def grid_mesh(nx, ny):
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), indexing="ij")
    a = (i * ny + j).ravel()
    b = a + ny
    F = np.concatenate([np.stack([a, b, a + 1], 1), np.stack([a + 1, b, b + 1], 1)])
    return F.astype(np.int64)


def crumpled_cloth(rng, nx=17, ny=15):
    """A jittered grid folded over itself (two layers close together) with random motion."""
    u, v = np.meshgrid(np.linspace(0, 1, nx), np.linspace(0, 1, ny), indexing="ij")
    ang = np.pi * u  # fold the sheet into a half cylinder of small radius: layers face each other
    X = np.stack([0.15 * np.cos(ang) + 0.6 * u, v, 0.08 * np.sin(ang)], axis=-1).reshape(-1, 3)
    X += 0.01 * rng.standard_normal(X.shape)
    F = grid_mesh(nx, ny)
    X1 = X + 0.03 * rng.standard_normal(X.shape)
    X2 = X1 + 0.03 * rng.standard_normal(X.shape)
    return X, X1, X2, F


def triangle_soup(rng, nv=150, nf=260):
    """Random vertices in a unit cube and random triangles over them (arbitrary vertex sharing:
    a random vertex and two of its 10 nearest neighbours)."""
    X = rng.random((nv, 3))
    near = np.argsort(((X[:, None, :] - X[None, :, :]) ** 2).sum(-1), axis=1)[:, 1:11]
    first = rng.integers(0, nv, nf)
    other = np.stack([rng.choice(10, 2, replace=False) for _ in range(nf)])
    F = np.stack([first, near[first, other[:, 0]], near[first, other[:, 1]]], axis=1).astype(np.int64)
    X1 = X + 0.05 * rng.standard_normal(X.shape)
    X2 = X1 + 0.05 * rng.standard_normal(X.shape)
    return X, X1, X2, F


def make_mesh(kind, seed):
    rng = np.random.default_rng(seed)
    return crumpled_cloth(rng) if kind == "cloth" else triangle_soup(rng)


def make_thickness(kind, nv, rng):
    if kind == "zero":
        return 0.0
    if kind == "scalar":
        return 0.01
    return 0.02 * rng.random(nv)  # per vertex


# ---------------------------------------------------------------------------------------------
# boxes and tree structure
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("k", [1, 2, 3])
def test_primitive_boxes_match_numpy(k):
    rng = np.random.default_rng(1)
    X0 = rng.standard_normal((60, 3))
    X1 = X0 + rng.standard_normal((60, 3))
    P = np.stack([rng.choice(60, k, replace=False) for _ in range(80)])
    lo, hi = bp.primitive_boxes(X0, P, X1)
    pts = np.concatenate([X0[P], X1[P]], axis=1)  # (m, 2k, 3)
    assert np.array_equal(lo, pts.min(axis=1)) and np.array_equal(hi, pts.max(axis=1))
    # static boxes
    lo_s, hi_s = bp.primitive_boxes(X0, P)
    assert np.array_equal(lo_s, X0[P].min(axis=1)) and np.array_equal(hi_s, X0[P].max(axis=1))
    # per-vertex thickness: max over the primitive's vertices, rounded outward by about one ulp
    t = rng.random(60) * 0.1
    lo_t, hi_t = bp.primitive_boxes(X0, P, X1, t)
    r = t[P].max(axis=1)[:, None]
    assert np.all(lo_t <= lo - r) and np.all(hi_t >= hi + r)
    assert np.allclose(lo_t, lo - r, rtol=0, atol=1e-14) and np.allclose(hi_t, hi + r, rtol=0, atol=1e-14)
    # 1-D vertex list = points
    lo_p, _ = bp.primitive_boxes(X0, np.arange(60), X1, 0.5)
    assert np.allclose(lo_p, np.minimum(X0, X1) - 0.5)


def test_primitive_boxes_rejects_bad_input():
    X = np.zeros((4, 3))
    with pytest.raises(ValueError, match="out of range"):
        bp.primitive_boxes(X, np.array([[0, 1, 7]]))
    with pytest.raises(ValueError, match="thickness"):
        bp.primitive_boxes(X, np.array([[0, 1, 2]]), thickness=np.ones(3))
    with pytest.raises(ValueError, match="thickness"):
        bp.primitive_boxes(X, np.array([[0, 1, 2]]), thickness=-1.0)
    with pytest.raises(ValueError, match="X0"):
        bp.primitive_boxes(np.zeros((4, 2)), np.array([[0, 1, 2]]))


def check_structure(bvh, lo, hi):
    n = bvh.leaf_count
    assert sorted(bvh.leaf_prim.tolist()) == list(range(n))
    base = n - 1
    # leaves hold the primitive boxes
    assert np.array_equal(bvh.node_lo[base:], lo[bvh.leaf_prim])
    assert np.array_equal(bvh.node_hi[base:], hi[bvh.leaf_prim])
    if n < 2:
        return
    # every node except the root is the child of exactly one internal node
    kids = np.sort(bvh.child.ravel())
    assert np.array_equal(kids, np.arange(1, 2 * n - 1))
    assert bvh.parent[0] == -1
    for c in range(2):
        assert np.array_equal(bvh.parent[bvh.child[:, c]], np.arange(n - 1))
    # internal boxes are exactly the union of the children
    l, r = bvh.child[:, 0], bvh.child[:, 1]
    assert np.array_equal(bvh.node_lo[:base], np.minimum(bvh.node_lo[l], bvh.node_lo[r]))
    assert np.array_equal(bvh.node_hi[:base], np.maximum(bvh.node_hi[l], bvh.node_hi[r]))
    # the refit order visits children before parents
    pos = np.empty(n - 1, dtype=np.int64)
    pos[bvh.refit_order] = np.arange(n - 1)
    for c in range(2):
        internal = bvh.child[:, c] < base
        assert np.all(pos[bvh.child[internal, c]] < pos[np.nonzero(internal)[0]])
    # leaf ranges: the root covers every leaf, a parent's range is the union of its children's
    assert bvh.node_range[0].tolist() == [0, n - 1]
    assert np.array_equal(bvh.node_range[base:], np.stack([np.arange(n)] * 2, axis=1))
    assert np.array_equal(bvh.node_range[:base, 0], bvh.node_range[l, 0])
    assert np.array_equal(bvh.node_range[:base, 1], bvh.node_range[r, 1])
    assert np.all(bvh.node_range[l, 1] + 1 == bvh.node_range[r, 0])
    assert bp.bvh_cost(bvh) >= 1.0  # the root is one of the internal nodes


@pytest.mark.parametrize("n", [1, 2, 3, 7, 64, 1000, 20000])
def test_bvh_structure(n):
    rng = np.random.default_rng(n)
    c = rng.random((n, 3))
    e = 0.01 * rng.random((n, 3))
    lo, hi = c - e, c + e
    bvh = bp.build_bvh(lo, hi)
    check_structure(bvh, lo, hi)
    assert bvh.max_depth <= 64 + int(np.ceil(np.log2(max(n, 2))))
    lo2, hi2 = lo + 0.05 * rng.standard_normal((n, 3)), hi + 0.05
    bp.refit_bvh(bvh, lo2, hi2)
    check_structure(bvh, lo2, hi2)
    if n >= 20000:  # big enough for the parallel subtree refit
        assert bvh.sub_ptr.shape[0] - 1 >= 64


# ---------------------------------------------------------------------------------------------
# BVH queries against brute force
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["cloth", "soup"])
@pytest.mark.parametrize("thick", ["zero", "scalar", "per_vertex"])
def test_self_queries_match_brute_force(kind, thick):
    X0, X1, X2, F = make_mesh(kind, 7)
    rng = np.random.default_rng(3)
    t = make_thickness(thick, len(X0), rng)
    E = bp.mesh_edges(F)
    V = np.arange(len(X0))
    boxes = lambda A, B, P: bp.primitive_boxes(A, P, B, t)  # noqa: E731
    lv, hv = boxes(X0, X1, V)
    le, he = boxes(X0, X1, E)
    lf, hf = boxes(X0, X1, F)
    bv, be, bf = bp.build_bvh(lv, hv), bp.build_bvh(le, he), bp.build_bvh(lf, hf)
    total = 0
    for step in range(2):
        ee = bp.query_self_ee(be, E)
        vf = bp.query_self_vf(bv, bf, F)
        ff = bp.query_self(bf, F)
        ref_ee = brute_self(le, he, E)
        ref_vf = brute_cross(lv, hv, lf, hf, V, F)
        assert as_set(ee) == ref_ee
        assert np.all(ee[:, 0] < ee[:, 1])
        assert as_set(vf) == ref_vf
        assert as_set(ff) == brute_self(lf, hf, F)
        total += len(ref_ee) + len(ref_vf)
        # next substep: new swept boxes, refit in place (same topology)
        lv, hv = boxes(X1, X2, V)
        le, he = boxes(X1, X2, E)
        lf, hf = boxes(X1, X2, F)
        for b, lo, hi in ((bv, lv, hv), (be, le, he), (bf, lf, hf)):
            assert bp.refit_bvh(b, lo, hi) is b
    assert total > 100  # the scenes do have candidates


@pytest.mark.parametrize("thick", ["zero", "per_vertex"])
def test_two_set_queries_match_brute_force(thick):
    rng = np.random.default_rng(11)
    Xc, Xc1, _, Fc = crumpled_cloth(rng)  # "cloth"
    Xo, _, _, Fo = triangle_soup(rng, 80, 120)  # "collider", static
    Xo = 0.5 * Xo + np.array([0.1, 0.2, -0.2])
    t = make_thickness(thick, len(Xc), rng)
    lv, hv = bp.primitive_boxes(Xc, np.arange(len(Xc)), Xc1, t)
    lo_f, hi_f = bp.primitive_boxes(Xo, Fo)
    bv, bo = bp.build_bvh(lv, hv), bp.build_bvh(lo_f, hi_f)
    pairs = bp.query_pairs(bv, bo)
    ref = brute_cross(lv, hv, lo_f, hi_f)
    assert len(ref) > 20
    assert as_set(pairs) == ref
    # reversed roles
    assert as_set(bp.query_pairs(bo, bv)) == {(b, a) for a, b in ref}
    # triangles vs triangles of two meshes
    lf, hf = bp.primitive_boxes(Xc, Fc, Xc1, t)
    bf = bp.build_bvh(lf, hf)
    assert as_set(bp.query_pairs(bf, bo)) == brute_cross(lf, hf, lo_f, hi_f)
    # arbitrary boxes
    qlo = rng.random((50, 3)) - 0.2
    qhi = qlo + 0.3 * rng.random((50, 3))
    assert as_set(bp.query_boxes(bo, qlo, qhi)) == brute_cross(qlo, qhi, lo_f, hi_f)


def test_query_pairs_skip_shared_equals_self_vf():
    X0, X1, _, F = make_mesh("soup", 5)
    V = np.arange(len(X0))
    lv, hv = bp.primitive_boxes(X0, V, X1, 0.02)
    lf, hf = bp.primitive_boxes(X0, F, X1, 0.02)
    bv, bf = bp.build_bvh(lv, hv), bp.build_bvh(lf, hf)
    a = as_set(bp.query_pairs(bv, bf, V, F))
    assert a == as_set(bp.query_self_vf(bv, bf, F)) == brute_cross(lv, hv, lf, hf, V, F)
    # without prims nothing is skipped
    assert as_set(bp.query_pairs(bv, bf)) == brute_cross(lv, hv, lf, hf)
    with pytest.raises(ValueError, match="both"):
        bp.query_pairs(bv, bf, V, None)


def test_degenerate_inputs():
    # empty, single, identical boxes (equal Morton codes), zero-size boxes
    empty = bp.build_bvh(np.zeros((0, 3)), np.zeros((0, 3)))
    assert bp.query_self(empty).shape == (0, 2)
    one = bp.build_bvh(np.zeros((1, 3)), np.ones((1, 3)))
    assert bp.query_self(one).shape == (0, 2)
    assert as_set(bp.query_pairs(one, one)) == {(0, 0)}
    assert as_set(bp.query_pairs(one, empty)) == set()
    for n in (2, 3, 5, 300):
        lo = np.zeros((n, 3))
        b = bp.build_bvh(lo, lo)  # all boxes are the same point
        check_structure(b, lo, lo)
        assert as_set(bp.query_self(b)) == {(i, j) for i in range(n) for j in range(i + 1, n)}
    # two far apart, then touching exactly (closed overlap)
    lo = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    hi = np.array([[0.5, 1, 1], [2.0, 1, 1]])
    assert len(bp.query_self(bp.build_bvh(lo, hi))) == 0
    hi[0, 0] = 1.0
    assert as_set(bp.query_self(bp.build_bvh(lo, hi))) == {(0, 1)}


def test_pair_buffer_reuse_and_determinism():
    import numba

    X0, X1, _, F = make_mesh("cloth", 2)
    E = bp.mesh_edges(F)
    le, he = bp.primitive_boxes(X0, E, X1, 0.01)
    be = bp.build_bvh(le, he)
    buf = bp.PairBuffer(4)
    a = bp.query_self(be, E, out=buf).copy()
    assert buf.capacity >= len(a) and len(a) > 4
    data_id = id(buf.data)
    b = bp.query_self(be, E, out=buf)
    assert id(buf.data) == data_id and np.shares_memory(b, buf.data)  # no reallocation
    assert np.array_equal(a, b)
    # same output, row order included, with a single thread
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        c = bp.query_self(be, E)
    finally:
        numba.set_num_threads(old)
    assert np.array_equal(a, c)


def test_sequential_task_order_gives_the_same_pairs(monkeypatch):
    """With one thread the traversal tasks run in their order (``SEQUENTIAL_ONE_THREAD``,
    faster: neighbouring tasks touch neighbouring nodes); every task writes at its own offset,
    so the pairs and their order are those of the shuffled order, in the single-pass query
    (a buffer that knows the pair count) and the two-pass one, with space-time boxes too."""
    import numba

    rng = np.random.default_rng(5)
    X0, _, _, F = crumpled_cloth(rng, nx=48, ny=40)
    X1 = X0 + [0.0, 0.0, -0.05] + 0.002 * rng.standard_normal(X0.shape)  # falling as a whole
    E = bp.mesh_edges(F)
    V = np.arange(len(X0))
    le, he = bp.primitive_boxes(X0, E, X1, 0.01)
    lv, hv = bp.primitive_boxes(X0, V, X1, 0.01)
    lf, hf = bp.primitive_boxes(X0, F, X1, 0.01)
    be, bv, bf = bp.build_bvh(le, he), bp.build_bvh(lv, hv), bp.build_bvh(lf, hf)
    se = bp.spacetime_boxes(be, X0, E, X1, 0.01)
    sv = bp.spacetime_boxes(bv, X0, V, X1, 0.01)
    sf = bp.spacetime_boxes(bf, X0, F, X1, 0.01)

    def queries():
        out = []
        for st in (False, True):
            for reuse in (False, True):
                b1, b2 = bp.PairBuffer(4), bp.PairBuffer(4)
                for _ in range(2 if reuse else 1):  # the second call: one pass
                    e = bp.query_self(be, E, out=b1, st=se if st else None)
                    p = bp.query_pairs(bv, bf, V, F, out=b2, st_a=sv if st else None,
                                       st_b=sf if st else None)
                out += [e.copy(), p.copy()]
        return out

    old = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        monkeypatch.setattr(bp, "SEQUENTIAL_ONE_THREAD", False)
        shuffled = queries()
        order = bp._task_order(2000)
        assert not np.array_equal(order, np.arange(2000))  # the shuffled order is not the order
        monkeypatch.setattr(bp, "SEQUENTIAL_ONE_THREAD", True)
        assert np.array_equal(bp._task_order(2000), np.arange(2000))
        sequential = queries()
    finally:
        numba.set_num_threads(old)
    assert len(shuffled[0]) > 1000 and len(shuffled[4]) < len(shuffled[0])  # st drops pairs
    for a, b in zip(shuffled, sequential):
        assert np.array_equal(a, b)


def test_needs_rebuild_and_update():
    rng = np.random.default_rng(4)
    X0, X1, _, F = make_mesh("cloth", 4)
    lf, hf = bp.primitive_boxes(X0, F, X1)
    bvh = bp.build_bvh(lf, hf)
    assert not bp.needs_rebuild(bvh)
    # small motion: the refit tree stays good
    bp.refit_bvh(bvh, *bp.primitive_boxes(X1, F, X1 + 1e-3 * rng.standard_normal(X1.shape)))
    assert not bp.needs_rebuild(bvh)
    # vertices scrambled: the old topology is now a bad tree
    Xs = X1[rng.permutation(len(X1))]
    lo, hi = bp.primitive_boxes(Xs, F)
    bp.refit_bvh(bvh, lo, hi)
    assert bp.needs_rebuild(bvh)
    fresh = bp.update_bvh(bvh, lo, hi)
    assert fresh is not bvh and not bp.needs_rebuild(fresh)
    assert as_set(bp.query_self(fresh, F)) == as_set(bp.query_self(bvh, F)) == brute_self(lo, hi, F)
    # a healthy tree is refit, not rebuilt
    assert bp.update_bvh(fresh, lo, hi) is fresh


# ---------------------------------------------------------------------------------------------
# hash grid
# ---------------------------------------------------------------------------------------------


def brute_point_pairs(P, r):
    d2 = ((P[:, None, :] - P[None, :, :]) ** 2).sum(-1)
    i, j = np.nonzero(np.triu(d2 <= r * r, 1))
    return set(zip(i.tolist(), j.tolist()))


@pytest.mark.parametrize("cell_factor,table", [(1.0, None), (0.3, None), (2.5, None), (1.0, 8)])
def test_hash_grid_pairs_match_brute_force(cell_factor, table):
    rng = np.random.default_rng(5)
    # clustered points (hair-like strands) plus uniform ones, negative coordinates included
    s = np.cumsum(0.02 * rng.standard_normal((40, 20, 3)), axis=1) + rng.random((40, 1, 3))
    P = np.concatenate([s.reshape(-1, 3), rng.random((400, 3)) * 2 - 1])
    for r in (0.01, 0.05, 0.2):
        grid = bp.build_hash_grid(P, cell_factor * r, table)
        pairs = bp.hash_grid_pairs(grid, P, r)
        ref = brute_point_pairs(P, r)
        assert len(ref) > 0
        assert as_set(pairs) == ref
        assert np.all(pairs[:, 0] < pairs[:, 1])


def test_hash_grid_box_query_matches_brute_force():
    rng = np.random.default_rng(6)
    P = rng.random((1500, 3)) * 2 - 1
    grid = bp.build_hash_grid(P, 0.05)
    lo = rng.random((200, 3)) * 2 - 1.1
    hi = lo + 0.2 * rng.random((200, 3))
    lo[0], hi[0] = -5, 5  # a box spanning far more cells than there are points (scan path)
    lo[1], hi[1] = P[3], P[3]  # a degenerate box exactly on a point
    pairs = bp.hash_grid_query_boxes(grid, P, lo, hi)
    inside = np.all((P[None, :, :] >= lo[:, None, :]) & (P[None, :, :] <= hi[:, None, :]), axis=2)
    ref = set(zip(*map(lambda a: a.tolist(), np.nonzero(inside))))
    assert (1, 3) in ref and sum(1 for b, _ in ref if b == 0) == len(P)
    assert as_set(pairs) == ref


def test_hash_grid_edge_cases():
    P = np.zeros((5, 3))  # all points in one cell
    g = bp.build_hash_grid(P, 1.0)
    assert len(bp.hash_grid_pairs(g, P, 0.0)) == 10
    g0 = bp.build_hash_grid(np.zeros((0, 3)), 1.0)
    assert bp.hash_grid_pairs(g0, np.zeros((0, 3)), 1.0).shape == (0, 2)
    with pytest.raises(ValueError, match="cell_size"):
        bp.build_hash_grid(P, 0.0)


# ---------------------------------------------------------------------------------------------
# whole-mesh check: cloth funnel frames 227 -> 228 (CCD data set)
# ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def funnel():
    d = np.load(FUNNEL)
    V0, V1, F = d["V0"], d["V1"], d["F"]
    E = bp.mesh_edges(F)
    nv = len(V0)
    V = np.arange(nv)
    lv, hv = bp.primitive_boxes(V0, V, V1)
    le, he = bp.primitive_boxes(V0, E, V1)
    lf, hf = bp.primitive_boxes(V0, F, V1)
    bv, be, bf = bp.build_bvh(lv, hv), bp.build_bvh(le, he), bp.build_bvh(lf, hf)
    vf = bp.query_self_vf(bv, bf, F)
    ee = bp.query_self(be, E)
    return dict(d=d, V0=V0, V1=V1, F=F, E=E, boxes=(lv, hv, le, he, lf, hf), vf=vf, ee=ee)


def edge_pair_key(a, b):
    return frozenset([tuple(sorted(a)), tuple(sorted(b))])


def test_funnel_broad_phase_contains_every_collision(funnel):
    d, F, E, vf, ee = funnel["d"], funnel["F"], funnel["E"], funnel["vf"], funnel["ee"]
    assert np.array_equal(E, np.unique(np.sort(d["E"], axis=1), axis=0))
    vf_set = as_set(vf)
    ee_keys = {edge_pair_key(E[a], E[b]) for a, b in ee}
    assert len(ee_keys) == len(ee)
    vt, et = d["vf_truth"], d["ee_truth"]
    assert vt.sum() == 27 and et.sum() == 107
    for v, f in zip(d["vf_vertex"][vt], d["vf_face"][vt]):
        assert (int(v), int(f)) in vf_set
    for a, b in zip(d["ee_edge_a"][et], d["ee_edge_b"][et]):
        assert edge_pair_key(a, b) in ee_keys
    # no candidate pairs primitives that share a vertex
    assert not np.any(F[vf[:, 1]] == vf[:, :1])
    assert not np.any((E[ee[:, 0]][:, :, None] == E[ee[:, 1]][:, None, :]).any(axis=(1, 2)))
    # the data set's exhaustive swept-AABB broad phase found exactly these numbers (README)
    assert len(vf) == 7319 and len(ee) == 33770


def test_funnel_candidates_match_brute_force_sample(funnel):
    lv, hv, le, he, lf, hf = funnel["boxes"]
    F, E = funnel["F"], funnel["E"]
    rng = np.random.default_rng(8)
    vs = rng.choice(len(lv), 300, replace=False)
    es = rng.choice(len(le), 300, replace=False)
    vf = funnel["vf"]
    got = {(int(v), int(f)) for v, f in vf[np.isin(vf[:, 0], vs)]}
    m = brute_overlap(lv[vs], hv[vs], lf, hf) & ~shares_vertex(vs[:, None], F)
    i, j = np.nonzero(m)
    assert got == set(zip(vs[i].tolist(), j.tolist()))
    ee = funnel["ee"]
    sel = np.isin(ee, es)
    got = set()
    for (a, b), (sa, sb) in zip(ee, sel):
        if sa:
            got.add((int(a), int(b)))
        if sb:
            got.add((int(b), int(a)))
    m = brute_overlap(le[es], he[es], le, he) & ~shares_vertex(E[es], E)
    i, j = np.nonzero(m)
    assert got == set(zip(es[i].tolist(), j.tolist()))


@pytest.mark.slow
def test_funnel_candidates_match_full_brute_force(funnel):
    lv, hv, le, he, lf, hf = funnel["boxes"]
    F, E = funnel["F"], funnel["E"]
    ref_vf, ref_ee = set(), set()
    for s in range(0, len(lv), 500):
        m = brute_overlap(lv[s:s + 500], hv[s:s + 500], lf, hf)
        m &= ~shares_vertex(np.arange(s, min(s + 500, len(lv)))[:, None], F)
        i, j = np.nonzero(m)
        ref_vf |= set(zip((i + s).tolist(), j.tolist()))
    for s in range(0, len(le), 500):
        m = brute_overlap(le[s:s + 500], he[s:s + 500], le, he) & ~shares_vertex(E[s:s + 500], E)
        i, j = np.nonzero(m)
        keep = j > i + s
        ref_ee |= set(zip((i[keep] + s).tolist(), j[keep].tolist()))
    assert as_set(funnel["vf"]) == ref_vf
    assert as_set(funnel["ee"]) == ref_ee


def test_funnel_broad_plus_narrow_phase(funnel):
    """Broad phase + the narrow phase's CCD (zero thickness) on the whole mesh.

    The data set's truth: exactly 27 VF and 107 EE colliding pairs. A conservative CCD may add false
    positives but never miss one; every extra hit must be one of the data set's listed negative
    queries (its near misses), so a broad-phase bug that fed wrong pairs would show up here.
    """
    nph = pytest.importorskip("lokigraph.behaviors.collision.narrowphase")
    d, V0, V1, F, E, vf, ee = (funnel[k] for k in ("d", "V0", "V1", "F", "E", "vf", "ee"))
    toi_vf = np.empty(len(vf))
    toi_ee = np.empty(len(ee))
    nph.vf_ccd_batch(V0, V1, vf[:, 0], F[vf[:, 1]], 0.0, toi_vf)
    nph.ee_ccd_batch(V0, V1, E[ee[:, 0]], E[ee[:, 1]], 0.0, toi_ee)
    hit_vf = {(int(v), int(f)) for v, f in vf[np.isfinite(toi_vf)]}
    hit_ee = {edge_pair_key(E[a], E[b]) for a, b in ee[np.isfinite(toi_ee)]}
    vt, et = d["vf_truth"], d["ee_truth"]
    pos_vf = {(int(v), int(f)) for v, f in zip(d["vf_vertex"][vt], d["vf_face"][vt])}
    neg_vf = {(int(v), int(f)) for v, f in zip(d["vf_vertex"][~vt], d["vf_face"][~vt])}
    pos_ee = {edge_pair_key(a, b) for a, b in zip(d["ee_edge_a"][et], d["ee_edge_b"][et])}
    neg_ee = {edge_pair_key(a, b) for a, b in zip(d["ee_edge_a"][~et], d["ee_edge_b"][~et])}
    assert pos_vf <= hit_vf and pos_ee <= hit_ee  # no false negatives
    assert hit_vf - pos_vf <= neg_vf
    assert hit_ee - pos_ee <= neg_ee
    print(f"broad+narrow: VF {len(hit_vf)} hits (27 true), EE {len(hit_ee)} hits (107 true)")
