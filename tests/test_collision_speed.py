"""Collision speed work (#12, part 1): single-pass tree traversal, reusable BVHs, the threading
default and the peer benchmark's metrics. Exact comparisons only (no timings)."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lokigraph.behaviors.collision import broadphase as bp
from lokigraph.bench.broadphase import rolled_sheet

ROOT = Path(__file__).resolve().parents[1]


def _sheet(n, t0=0.0, t1=1.0):
    X0, F, h = rolled_sheet(n, t0)
    X1, _, _ = rolled_sheet(n, t1)
    E = bp.mesh_edges(F)
    th = np.full(len(X0), 0.1 * h)
    return X0, X1, F, E, th


def _trees(X0, X1, F, E, th):
    nv = len(X0)
    lv, hv = bp.primitive_boxes(X0, np.arange(nv), X1, th)
    le, he = bp.primitive_boxes(X0, E, X1, th)
    lf, hf = bp.primitive_boxes(X0, F, X1, th)
    return (bp.build_bvh(lv, hv), bp.build_bvh(le, he), bp.build_bvh(lf, hf)), (lv, hv, le, he,
                                                                                 lf, hf)


@pytest.mark.parametrize("expected", [1, 7, 10**6])
def test_single_pass_equals_two_pass(expected):
    """A buffer that has seen a query traverses once into its scratch; the rows (and their
    order) are exactly those of the two-pass count/fill query, also when slots overflow
    (expected=1: almost every task is traversed again) or are far too large."""
    X0, X1, F, E, th = _sheet(40)
    (bv, be, bf), _ = _trees(X0, X1, F, E, th)
    ref_vf = bp.query_self_vf(bv, bf, F).copy()
    ref_ee = bp.query_self_ee(be, E).copy()
    assert len(ref_vf) > 1000 and len(ref_ee) > 1000
    b_vf, b_ee = bp.PairBuffer(), bp.PairBuffer()
    for rep in range(3):
        b_vf.expected = b_ee.expected = expected if rep == 0 else b_vf.expected
        vf = bp.query_self_vf(bv, bf, F, out=b_vf)
        ee = bp.query_self_ee(be, E, out=b_ee)
        np.testing.assert_array_equal(vf, ref_vf)
        np.testing.assert_array_equal(ee, ref_ee)
    assert b_vf.expected == len(ref_vf) and b_ee.expected == len(ref_ee)
    # one buffer shared by two different queries (its expectation comes from the other one)
    shared = bp.PairBuffer()
    for _ in range(2):
        np.testing.assert_array_equal(bp.query_self_vf(bv, bf, F, out=shared), ref_vf)
        np.testing.assert_array_equal(bp.query_self_ee(be, E, out=shared), ref_ee)


def test_single_pass_matches_brute_force():
    """The candidate set equals the brute-force box-overlap pairs (closed boxes, pairs sharing
    a vertex skipped) on a random soup of small triangles."""
    rng = np.random.default_rng(3)
    n = 300
    X0 = rng.random((3 * n, 3))
    X0[1::3] = X0[::3] + 0.05 * rng.random((n, 3))
    X0[2::3] = X0[::3] + 0.05 * rng.random((n, 3))
    F = np.arange(3 * n).reshape(n, 3)
    F[n // 2:, 2] = F[: n - n // 2, 0]  # some triangles share a vertex
    lo, hi = bp.primitive_boxes(X0, F, None, 0.01)
    tree = bp.build_bvh(lo, hi)
    buf = bp.PairBuffer()
    for _ in range(2):  # first call two-pass, second single-pass
        got = bp.query_self(tree, F, out=buf)
        ov = ((lo[:, None, :] <= hi[None, :, :]) & (hi[:, None, :] >= lo[None, :, :])).all(-1)
        share = (F[:, None, :, None] == F[None, :, None, :]).any((-1, -2))
        i, j = np.nonzero(np.triu(ov & ~share, 1))
        assert {tuple(r) for r in got.tolist()} == set(zip(i.tolist(), j.tolist()))
        assert len(got) == len(i)


def test_bvh_cache_refits_and_rebuilds():
    """BVHCache refits a kept tree when the boxes move a little, rebuilds it when the fit has
    degraded or the size changed; a refit tree finds the same candidate set as a fresh build."""
    X0, X1, F, E, th = _sheet(30)
    X2, _, _ = rolled_sheet(30, 2.0)
    cache = bp.BVHCache()
    old = bp.BVHCache.reuse
    bp.BVHCache.reuse = True
    try:
        lo, hi = bp.primitive_boxes(X0, F, X1, th, *cache.boxes("t", len(F)))
        t1 = cache.update("t", lo, hi)
        lo2, hi2 = bp.primitive_boxes(X1, F, X2, th, *cache.boxes("t", len(F)))
        assert lo2 is lo  # the same arrays, refilled
        t2 = cache.update("t", lo2, hi2)
        assert t2 is t1 and cache.refits == 1 and cache.builds == 1
        fresh = bp.build_bvh(lo2, hi2)
        a = np.sort(bp.query_self(t2, F), axis=0)
        b = np.sort(bp.query_self(fresh, F), axis=0)
        np.testing.assert_array_equal(np.unique(a, axis=0), np.unique(b, axis=0))
        # scrambled positions: the refit tree is much worse than a new build -> rebuilt
        Xs = X0[np.random.default_rng(0).permutation(len(X0))]
        lo3, hi3 = bp.primitive_boxes(Xs, F, None, th, *cache.boxes("t", len(F)))
        t3 = cache.update("t", lo3, hi3)
        assert t3 is not t1 and cache.builds == 2
        assert bp.bvh_cost(t3) == pytest.approx(t3.build_cost)
        # off: every call builds
        bp.BVHCache.reuse = False
        assert cache.update("t", lo3, hi3) is not t3 and cache.builds == 3
    finally:
        bp.BVHCache.reuse = old
    holder = type("H", (), {})()
    assert bp.bvh_cache(holder) is bp.bvh_cache(holder)


def _env_after_import(extra):
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    env.update(extra)
    out = subprocess.run([sys.executable, "-c", "import os, lokigraph; "
                          "print(os.environ.get('OMP_WAIT_POLICY'))"],
                         env=env, capture_output=True, text=True, check=True, cwd=ROOT)
    return out.stdout.strip()


def test_threading_default_passive_wait():
    """Importing lokigraph makes OpenMP threads wait passively, unless the user chose."""
    assert _env_after_import({}) == "passive"
    assert _env_after_import({"OMP_WAIT_POLICY": "active"}) == "active"


def test_peer_collision_metrics():
    """The peer benchmark's shared counters on closed-form configurations: rest cloth (no
    strain, nothing inside, no intersection), uniformly scaled cloth (strain = scale - 1), three
    vertices moved to the sphere's centre (3 inside), a cloth triangle pushed through the
    sphere's surface (intersecting pairs > 0)."""
    sys.path.insert(0, str(ROOT / "graphs" / "bench"))
    try:
        import peer_collision as pc
    finally:
        sys.path.pop(0)
    sc = pc.ClothSphere(pc.SCENES[32])
    ball = sc.points[sc.ball_slice]
    m = sc.metrics(sc.cloth_q0, ball)
    assert m == {"finite": True, "strain": 0.0, "inside": 0, "pairs": 0}
    c = sc.cloth_q0.mean(axis=0)
    q = c + 1.1 * (sc.cloth_q0 - c)
    assert sc.metrics(q, ball)["strain"] == pytest.approx(0.1, rel=1e-12)
    q = sc.cloth_q0.copy()
    q[[0, 5, 9]] = sc.center
    assert sc.metrics(q, ball)["inside"] == 3
    # drop the whole cloth so that its middle crosses the sphere's top
    q = sc.cloth_q0.copy()
    q[:, 1] = sc.center[1] + sc.radius - 0.01
    m = sc.metrics(q, ball)
    assert m["pairs"] > 0 and m["inside"] > 0
    q[0, 0] = np.nan
    assert sc.metrics(q, ball)["finite"] is False
    # inscribed radius of the sphere mesh: below the circumscribed radius, within 1 %
    r_in = sc.inscribed_radius(ball)
    assert 0.99 * sc.radius < r_in < sc.radius
