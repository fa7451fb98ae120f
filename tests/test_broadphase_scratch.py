"""The column grid's scratch buffers stay bounded when their trailing dimensions change."""

import types

import numpy as np

from lokigraph.behaviors.collision.broadphase import _col_work


def test_col_work_does_not_grow_when_trailing_dimensions_change():
    # the per-thread histogram (threads, 2, columns) changes its column count nearly every
    # query; a buffer grown by half per change asked for 24.8 GiB after 40 calls
    out = types.SimpleNamespace()
    for n in range(100, 140):
        a = _col_work(out, "hist", (2, 2, n), np.int64)
        assert a.shape == (2, 2, n) and a.flags.c_contiguous
    assert out._col_ws["hist"].size <= 1.5 * 2 * 2 * 139
    b = _col_work(out, "hist", (3, 2, 50), np.int64)
    assert b.shape == (3, 2, 50) and np.shares_memory(b, out._col_ws["hist"])
