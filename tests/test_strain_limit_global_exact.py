"""The global strain step's exact speedups (strain_limit_global.FAST_EXACT) give bitwise the
results of the code they replace: the pivots' principal submatrices (``_principal_csc``) the
arrays of scipy's ``R[idx][:, idx].tocsc()``, the serial smoothing sweeps
(``_sweeps_serial``) the positions of the parallel kernel followed by the contact planes."""

import numpy as np
import scipy.sparse as sp

from lokigraph.behaviors.materials.strain_limit import project_strain_limit
from lokigraph.behaviors.materials.strain_limit_global import (GlobalStrainStep,
                                                               _sweeps_serial, plane_project)


def _grid(n):
    """An n x n vertex grid's edges (rows, columns, one diagonal), colour-sorted so that no two
    edges of a colour share a vertex, and the colour pointers."""
    vid = np.arange(n * n).reshape(n, n)
    groups = []
    for par in (0, 1):
        groups.append(np.stack([vid[:, par:-1:2].ravel(), vid[:, 1 + par::2].ravel()], 1))
        groups.append(np.stack([vid[par:-1:2, :].ravel(), vid[1 + par::2, :].ravel()], 1))
        groups.append(np.stack([vid[par:-1:2, :-1].ravel(), vid[1 + par::2, 1:].ravel()], 1))
    edges = np.concatenate(groups).astype(np.int64)
    ptr = np.concatenate([[0], np.cumsum([len(g) for g in groups])]).astype(np.int64)
    return edges, ptr


def test_principal_submatrix_matches_scipy():
    rng = np.random.default_rng(3)
    n = 400
    B = sp.random(n, n, density=0.02, random_state=rng, format="csr")
    R = (B @ B.T + sp.diags(rng.random(n) + 0.1)).tocsr()
    g = GlobalStrainStep.__new__(GlobalStrainStep)
    g._Rc = g._sub_pos = g._sub_ind = None
    g._principal_of(R)
    for seed in range(5):
        idx = np.flatnonzero(np.random.default_rng(seed).random(n) < 0.3 + 0.1 * seed)
        ref = R[idx][:, idx].tocsc()
        got = g._principal(idx)
        assert got.shape == ref.shape
        assert np.array_equal(got.indptr, ref.indptr)
        assert np.array_equal(got.indices, ref.indices)
        assert np.array_equal(got.data, ref.data)
    # the work arrays are reset: a later extraction of a smaller set is still exact
    idx = np.arange(0, n, 7)
    assert np.array_equal(g._principal(idx).toarray(), R[idx][:, idx].toarray())


def test_serial_sweeps_bitwise_parallel_kernel():
    n = 24
    edges, ptr = _grid(n)
    rng = np.random.default_rng(0)
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    p0 = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1) * 1.05
    p0 += 0.01 * rng.standard_normal(p0.shape)
    w = np.ones(n * n)
    w[:n] = 0.0  # a pinned row
    limit = 1.01 * np.linalg.norm(p0[edges[:, 0]] / 1.05 - p0[edges[:, 1]] / 1.05, axis=1)
    vv = np.arange(0, n * n, 5, dtype=np.int64)
    nn = np.tile([0.0, 0.0, 1.0], (len(vv), 1))
    c0 = np.zeros(len(vv))
    x0 = p0[vv].copy()
    for planes in (False, True):
        a, b = p0.copy(), p0.copy()
        for _ in range(7):
            project_strain_limit(a, w, edges, limit, ptr)
            if planes:
                plane_project(a, vv, nn, c0, x0)
        _sweeps_serial(b, w, edges, limit, ptr, 7, planes, vv, nn, c0, x0)
        assert np.array_equal(a, b)
        assert not np.array_equal(a, p0)  # the sweeps did move the cloth
        if planes:
            assert (a[vv, 2] >= x0[:, 2] - 1e-15).all()
