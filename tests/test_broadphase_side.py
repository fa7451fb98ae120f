"""``column_queries``: the column grid's queries side by side give the rows of the calls one
after another, in the same order, at any thread count."""

import numba
import numpy as np
import pytest

from lokigraph.behaviors.collision import broadphase as bp
from lokigraph.bench.broadphase import _sheet


@pytest.mark.parametrize("side", [True, False])
def test_column_queries_equal_the_calls_one_after_another(monkeypatch, side):
    monkeypatch.setattr(bp, "COLUMN_SIDE_BY_SIDE", side)
    (X0, X1, _), F, _, E, verts, thick, boxes = _sheet(12000)
    lo_v, hi_v, lo_e, hi_e, lo_f, hi_f = boxes
    bp.primitive_boxes(X0, verts, X1, thick, lo_v, hi_v)
    bp.primitive_boxes(X0, E, X1, thick, lo_e, hi_e)
    bp.primitive_boxes(X0, F, X1, thick, lo_f, hi_f)
    assert min(len(lo_e), len(lo_v) + len(lo_f)) >= bp._COL_SIDE_MIN  # side by side at 2+ threads
    sv = bp.spacetime_prim_boxes(X0, verts, X1, thick)
    sf = bp.spacetime_prim_boxes(X0, F, X1, thick)
    se = bp.spacetime_prim_boxes(X0, E, X1, thick)
    ref = [bp.column_query_pairs(lo_v, hi_v, lo_f, hi_f, verts, F).copy(),
           bp.column_query_self(lo_e, hi_e, E).copy(),
           bp.column_query_pairs(lo_v, hi_v, lo_f, hi_f, verts, F, st_a=sv, st_b=sf).copy(),
           bp.column_query_self(lo_e, hi_e, E, st=se).copy()]
    assert all(len(r) > 0 for r in ref) and len(ref[2]) < len(ref[0])
    bufs = [bp.PairBuffer() for _ in range(4)]
    old = numba.get_num_threads()
    try:
        for nth in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
            numba.set_num_threads(nth)
            for rep in range(3):  # buffers fresh (count pass), then reused (one sweep)
                got = bp.column_queries(
                    (bp.column_query_pairs, (lo_v, hi_v, lo_f, hi_f, verts, F),
                     {"out": bufs[0]}),
                    (bp.column_query_self, (lo_e, hi_e, E), {"out": bufs[1]}),
                    (bp.column_query_pairs, (lo_v, hi_v, lo_f, hi_f, verts, F),
                     {"out": bufs[2], "st_a": sv, "st_b": sf}),
                    (bp.column_query_self, (lo_e, hi_e, E), {"out": bufs[3], "st": se}))
                for g, r in zip(got, ref):
                    assert np.array_equal(g, r)
            assert numba.get_num_threads() == nth  # restored on this thread
    finally:
        numba.set_num_threads(old)


def test_column_queries_raise_from_a_worker(monkeypatch):
    """An error in a query run on a worker thread reaches the caller."""
    monkeypatch.setattr(bp, "COLUMN_SIDE_BY_SIDE", True)
    monkeypatch.setattr(bp, "_COL_SIDE_MIN", 0)
    lo = np.zeros((10, 3))
    hi = np.ones((10, 3))
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        with pytest.raises(ValueError):
            bp.column_queries((bp.column_query_self, (lo, hi), {}),
                              (bp.column_query_self, (lo, hi, np.zeros((3, 2), np.int64)), {}))
    finally:
        numba.set_num_threads(old)
