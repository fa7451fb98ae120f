"""Cheaper collision candidates (issue #12): the broad phase's space-time boxes
(``broadphase.spacetime_boxes``) must keep every pair that comes within the inflation along
the linear motion (checked against brute force at sampled times) and drop only pairs that
cannot; the vertex-normal kernel and the reused pair buffer of the intersection check give
what they replaced."""

import numpy as np
import pytest

from lokigraph.behaviors.collision import broadphase as bp
from lokigraph.behaviors.collision import contacts as C
from lokigraph.behaviors.collision.intersect import find_intersections
from lokigraph.behaviors.collision.narrowphase import _pt_tri_sq, _seg_seg_sq


def _grid(n, jitter, rng):
    """An n x n triangulated sheet in the xz plane (1 m), vertices jittered by ``jitter`` [m]."""
    u = np.linspace(0.0, 1.0, n)
    X = np.stack(np.meshgrid(u, u, indexing="ij"), -1).reshape(-1, 2)
    V = np.column_stack([X[:, 0], np.zeros(len(X)), X[:, 1]]) + rng.normal(0, jitter, (n * n, 3))
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    F = np.concatenate([np.stack([a, a + n, a + 1], 1), np.stack([a + 1, a + n, a + n + 1], 1)])
    return V, F.astype(np.int64)


def _motion(V, rng, common, relative):
    """End positions: a common translation plus random per-vertex displacements [m]."""
    return V + np.asarray(common) + rng.normal(0, relative, V.shape)


def _min_dist_sampled(x0, x1, a, b, kind, ts):
    """Smallest distance [m] of primitives a and b over the sampled times of x0 -> x1."""
    best = np.inf
    for t in ts:
        x = x0 + t * (x1 - x0)
        if kind == "ee":
            d2 = _seg_seg_sq(*x[a[0]], *x[a[1]], *x[b[0]], *x[b[1]])[0]
        else:
            d2 = _pt_tri_sq(*x[a[0]], *x[b[0]], *x[b[1]], *x[b[2]])[0]
        best = min(best, d2)
    return np.sqrt(best)


@pytest.mark.parametrize("common", [(0.2, -0.06, 0.0), (0.15, 0.02, -0.12)])
def test_spacetime_pairs_are_swept_pairs_minus_common_motion(common):
    """A sheet translating as a whole: the space-time query gives exactly the pairs of the
    resting sheet (the translation cancels), a subset of the swept-box pairs, which are many
    more; with relative motion it stays a subset that holds every pair that actually comes
    within the inflation at a sampled time."""
    rng = np.random.default_rng(3)
    V, F = _grid(14, 0.004, rng)
    E = bp.mesh_edges(F)
    r = 0.004
    X1 = V + np.asarray(common)
    lo, hi = bp.primitive_boxes(V, E, X1, r)
    tree = bp.build_bvh(lo, hi)
    st = bp.spacetime_boxes(tree, V, E, X1, r)
    swept = {tuple(p) for p in bp.query_self(tree, E).tolist()}
    spt = {tuple(p) for p in bp.query_self(tree, E, st=st).tolist()}
    lo0, hi0 = bp.primitive_boxes(V, E, None, r)
    static = {tuple(p) for p in bp.query_self(bp.build_bvh(lo0, hi0), E).tolist()}
    assert spt == static
    assert spt < swept and len(swept) > 1.5 * len(spt)

    X1 = _motion(V, rng, common, 0.03)
    r = 0.01
    lo, hi = bp.primitive_boxes(V, E, X1, r)
    tree = bp.build_bvh(lo, hi)
    st = bp.spacetime_boxes(tree, V, E, X1, r)
    swept = {tuple(p) for p in bp.query_self(tree, E).tolist()}
    spt = {tuple(p) for p in bp.query_self(tree, E, st=st).tolist()}
    assert spt <= swept and len(spt) < len(swept)
    ts = np.linspace(0.0, 1.0, 41)
    near = {(i, j) for i, j in swept
            if _min_dist_sampled(V, X1, E[i], E[j], "ee", ts) <= 2 * r}
    assert near and near <= spt


def test_spacetime_two_trees_and_inactive_subtrees():
    """Vertices against triangles (two trees): the space-time pairs are a subset of the swept
    ones holding every pair that comes within the inflation; pairs of two inactive primitives
    are never reported, and only those are dropped by the flags."""
    rng = np.random.default_rng(5)
    V, F = _grid(12, 0.003, rng)
    X1 = _motion(V, rng, (0.15, -0.04, 0.05), 0.03)
    r = 0.01
    verts = np.arange(len(V))
    lo_v, hi_v = bp.primitive_boxes(V, verts, X1, r)
    lo_t, hi_t = bp.primitive_boxes(V, F, X1, r)
    bv, bt = bp.build_bvh(lo_v, hi_v), bp.build_bvh(lo_t, hi_t)
    sv = bp.spacetime_boxes(bv, V, verts, X1, r)
    stt = bp.spacetime_boxes(bt, V, F, X1, r)
    swept = {tuple(p) for p in bp.query_pairs(bv, bt, verts, F).tolist()}
    spt = {tuple(p) for p in bp.query_pairs(bv, bt, verts, F, st_a=sv, st_b=stt).tolist()}
    assert spt <= swept and len(spt) < len(swept)
    ts = np.linspace(0.0, 1.0, 41)
    near = {(v, t) for v, t in swept
            if _min_dist_sampled(V, X1, [v], F[t], "vf", ts) <= 2 * r}
    assert near and near <= spt
    # inactive: the vertices of the left half and the triangles of the left half
    act_v = V[:, 0] > 0.5
    act_t = V[F].mean(1)[:, 0] > 0.5
    sv2 = bp.spacetime_boxes(bv, V, verts, X1, r, active=act_v)
    st2 = bp.spacetime_boxes(bt, V, F, X1, r, active=act_t)
    got = {tuple(p) for p in bp.query_pairs(bv, bt, verts, F, st_a=sv2, st_b=st2).tolist()}
    want = {(v, t) for v, t in spt if act_v[v] or act_t[t]}
    assert got == want and len(want) < len(spt)
    # groups: only pairs within one group are tested in space-time, the others keep their
    # swept-box pairs (objects pushing each other)
    gv = (V[:, 2] > 0.5).astype(np.int64)
    gt = (V[F].mean(1)[:, 2] > 0.5).astype(np.int64)
    sv3 = bp.spacetime_boxes(bv, V, verts, X1, r, group=gv)
    st3 = bp.spacetime_boxes(bt, V, F, X1, r, group=gt)
    got = {tuple(p) for p in bp.query_pairs(bv, bt, verts, F, st_a=sv3, st_b=st3).tolist()}
    want = {(v, t) for v, t in swept if gv[v] != gt[t] or (v, t) in spt}
    assert got == want and len(spt) < len(want) < len(swept)


def test_vertex_normals_kernel_matches_numpy():
    """The vertex-normal kernel gives bitwise the former numpy computation (np.add.at per
    corner)."""
    rng = np.random.default_rng(2)
    V, F = _grid(9, 0.01, rng)

    class G:
        tris = F

    n = np.zeros((len(V), 3))
    P = V[F]
    fn = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    for k in range(3):
        np.add.at(n, F[:, k], fn)
    ln = np.linalg.norm(n, axis=1)
    n[ln > 0] /= ln[ln > 0][:, None]
    assert np.array_equal(C._vertex_normals(V, G), n)


def test_intersections_with_reused_buffer():
    """find_intersections with a reused pair buffer (single-pass traversal) reports what it
    reports without one, every call."""
    rng = np.random.default_rng(4)
    A, FA = _grid(10, 0.0, rng)
    B = np.column_stack([A[:, 0] + 0.03, A[:, 2] - 0.5, np.full(len(A), 0.5)])
    F = np.concatenate([FA, FA + len(A)])
    V2 = np.concatenate([A, B])  # two sheets crossing along z = 0.5
    V = np.concatenate([A, B + [0.0, 0.0, 0.7]])  # apart
    buf = bp.PairBuffer(0)
    for X in (V2, V, V2):
        a = find_intersections(X, F, touching=False)
        b = find_intersections(X, F, touching=False, out=buf)
        assert a.count == b.count
        assert np.array_equal(a.tri_pairs, b.tri_pairs)
    assert a.count > 0
