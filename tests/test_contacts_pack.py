"""contacts._pack: the rows of every group packed into alternating grow-only buffers hold the
values of the concatenation (``_pack_new``), and the previous detection's arrays stay intact
through the next one (callers keep views across one re-detection: the implicit solver's rows)."""

import numpy as np

from lokigraph.behaviors.collision import contacts as C


def _groups(rng, sizes, strengths):
    vf, ee = [], []
    for k, s in zip(sizes, strengths):
        vf.append((rng.integers(0, 99, (k, 4)), rng.random((k, 3)), rng.random(k), rng.random(k),
                   rng.random(k) < 0.5, s))
        ee.append((rng.integers(0, 99, (k + 3, 4)), rng.random((k + 3, 3)), rng.random(k + 3),
                   rng.random(k + 3), s))
    return vf, ee


def _arrays(d):
    return [d.vf, d.vf_n, d.vf_target, d.vf_mu, d.vf_onesided, d.strength, d.ee, d.ee_n,
            d.ee_target, d.ee_mu, d.ee_strength]


def test_pack_buffers_match_concatenation_and_keep_previous_rows():
    rng = np.random.default_rng(3)
    d = C._Contacts([], np.zeros((1, 3)))
    ref = C._Contacts([], np.zeros((1, 3)))
    prev = prev_copy = None
    for sizes in ([5, 0, 7], [40, 2, 1], [3, 3, 3], [0, 0, 0], [60, 5, 9]):
        vf, ee = _groups(rng, sizes, [0.5, 1.0, 0.25])
        C._pack(d, vf, ee)
        C._pack_new(ref, vf, ee)
        for a, b in zip(_arrays(d), _arrays(ref)):
            assert a.dtype == b.dtype and a.shape == b.shape
            assert np.array_equal(a, b)
            assert a.flags.c_contiguous
        if prev is not None:  # the previous detection's rows survive this one
            for a, b in zip(prev, prev_copy):
                assert np.array_equal(a, b)
        prev = _arrays(d)
        prev_copy = [a.copy() for a in prev]
