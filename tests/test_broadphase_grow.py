"""Grow-only buffers take headroom over what a query needs (``broadphase.GROW_HEADROOM``)."""

import numpy as np
import pytest

from lokigraph.behaviors.collision import broadphase as bp


@pytest.fixture
def headroom():
    keep = bp.GROW_HEADROOM
    yield
    bp.GROW_HEADROOM = keep


def test_grown_size_headroom_over_need(headroom):
    bp.GROW_HEADROOM = 2.0
    assert bp.grown_size(1000, 10) == 2000  # a jump: twice what is needed, not exactly it
    assert bp.grown_size(1000, 900) == 2000
    bp.GROW_HEADROOM = 0.0  # the former rule
    assert bp.grown_size(1000, 10) == 1000
    assert bp.grown_size(1000, 900) == 1350


def test_pair_buffer_climbing_count_reallocates_rarely(headroom):
    """A count climbing by 30 % a query (the rows of a landing cloth) reallocates the buffer
    (fresh pages to fault in) in 4 of 12 queries with headroom 2, in 9 with the former rule."""
    counts = [int(1000 * 1.3 ** i) for i in range(12)]
    allocs = {}
    for h in (0.0, 2.0):
        bp.GROW_HEADROOM = h
        buf = bp.PairBuffer(100)
        n = 0
        for c in counts:
            before = buf.data.__array_interface__["data"][0]
            v = buf.reserve(c)
            assert v.shape == (c, 2)
            n += buf.data.__array_interface__["data"][0] != before
        allocs[h] = n
    assert allocs[2.0] <= 4 and allocs[0.0] >= 8
