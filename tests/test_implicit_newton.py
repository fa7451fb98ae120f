"""The contact rows' Newton-matrix blocks (issue #11, Newton at contact;
graphs/bench/implicit_newton.py): ``contact_hessian: coupled`` gives a row's exact Gauss-Newton
Hessian where the pattern holds its vertex pairs and a PSD majorizer of it where it does not;
the block-diagonal default is neither (the test shows where it falls short)."""

from __future__ import annotations

import numpy as np

from lokigraph.behaviors.solvers.implicit.contact import (lag_rows, mark_closing,
                                                          row_energy_coupled)
from lokigraph.behaviors.solvers.implicit.energy import build_pattern


def _dense(n, indptr, indices, data):
    A = np.zeros((3 * n, 3 * n))
    for a in range(n):
        for k in range(indptr[a], indptr[a + 1]):
            b = indices[k]
            A[3 * a:3 * a + 3, 3 * b:3 * b + 3] = data[k]
    return A


def _scene(is_vf):
    """A kinematic vertex (0) pressed into a free cloth triangle (1, 2, 3), or a kinematic edge
    (0, 1) across a free cloth edge (2, 3): one row, violated at x."""
    if is_vf:
        x = np.array([[0.3, -0.001, 0.2], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        fixed = np.array([True, False, False, False])
        rows = np.array([[0, 1, 2, 3]])
        nrm = np.array([[0.0, -1.0, 0.0]])  # the vertex's side of the triangle is below
    else:
        x = np.array([[-0.5, -0.001, 0.3], [0.5, -0.001, 0.3], [0.3, 0.0, -0.5],
                      [0.3, 0.0, 0.5]])
        fixed = np.array([True, True, False, False])
        rows = np.array([[0, 1, 2, 3]])
        nrm = np.array([[0.0, -1.0, 0.0]])
    return x, fixed, rows, nrm


def _hessians(is_vf, stencils):
    x, fixed, rows, nrm = _scene(is_vf)
    n, m = len(x), 1
    mass = np.full(n, 1e-3)
    tgt = np.full(m, 0.002)
    coef, kr, lam = np.zeros((m, 4)), np.zeros(m), np.zeros(m)
    assert lag_rows(x, fixed, mass, 1e4, rows, nrm, tgt, is_vf, coef, kr, lam) == 1
    indptr, indices, diag, _ = build_pattern(n, stencils)
    out = {}
    for coupled in (False, True):
        data = np.zeros((len(indices), 3, 3))
        g = np.zeros((n, 3))
        row_energy_coupled(x, x, fixed, rows, nrm, tgt, coef, kr, lam, np.zeros(m), 1e-7, 2, g,
                           data, diag, False, 0.0, x, np.zeros(n, bool), np.arange(m), indptr,
                           indices, coupled, np.zeros(m, np.uint8))
        out[coupled] = _dense(n, indptr, indices, data)

    def grad(xe):
        g = np.zeros((n, 3))
        row_energy_coupled(xe, x, fixed, rows, nrm, tgt, coef, kr, lam, np.zeros(m), 1e-7, 1,
                           g, np.zeros((1, 3, 3)), diag, False, 0.0, x, np.zeros(n, bool),
                           np.arange(m), indptr, indices, False, np.zeros(m, np.uint8))
        return g.ravel()

    # the penalty's Hessian by central differences of its gradient (coefficients lagged: the
    # energy is quadratic where the row is active, so this is exact up to rounding)
    H = np.zeros((3 * n, 3 * n))
    h = 1e-7
    for j in range(3 * n):
        e = np.zeros(3 * n)
        e[j] = h
        H[:, j] = (grad(x.ravel().__add__(e).reshape(n, 3))
                   - grad(x.ravel().__sub__(e).reshape(n, 3))) / (2 * h)
    free = np.repeat(~fixed, 3)
    sub = np.ix_(free, free)
    return H[sub], out[False][sub], out[True][sub], kr[0]


def test_coupled_blocks_are_the_rows_hessian_where_the_pattern_has_them():
    """Cloth triangle / cloth edge against a kinematic body, the row's free vertices sharing a
    stencil: the coupled blocks equal the penalty's Hessian (central differences) to 1e-6 of
    the row stiffness; the block-diagonal ones miss its off-diagonal blocks (the test can
    fail: they differ by more than 10 % of the stiffness)."""
    for is_vf, st in ((True, [np.array([[1, 2, 3]])]), (False, [np.array([[2, 3]])])):
        H, Hd, Hc, k = _hessians(is_vf, st)
        assert np.abs(H).max() > 0.1 * k
        assert np.abs(Hc - H).max() < 1e-6 * k
        assert np.abs(Hd - H).max() > 0.1 * k


def test_coupled_majorizes_where_the_pattern_lacks_the_pairs():
    """With a diagonal-only pattern (a self contact between distant vertices) the coupled
    blocks bound the row's Hessian from above (Hc - H PSD) and stay PSD, while the
    block-diagonal ones under-estimate it along a common motion of the row's vertices
    (Hd - H has a negative eigenvalue below -10 % of the stiffness)."""
    for is_vf in (True, False):
        H, Hd, Hc, k = _hessians(is_vf, [])
        assert np.linalg.eigvalsh(Hc - H).min() > -1e-6 * k
        assert np.linalg.eigvalsh(Hc).min() > -1e-6 * k
        assert np.linalg.eigvalsh(Hd - H).min() < -0.1 * k


def test_mark_closing_flags_the_rows_a_step_closes():
    """``contact_sticky``: a row open at x that the full step closes is flagged, one that
    stays open is not, and a flagged row is not counted twice."""
    x, fixed, rows, nrm = _scene(True)
    rows = np.array([[0, 1, 2, 3], [0, 1, 2, 3]])
    nrm = np.array([[0.0, -1.0, 0.0], [0.0, -1.0, 0.0]])
    tgt = np.array([-0.01, -0.0005])  # both open at x (gap 1 mm above -target)
    coef, kr, lam = np.zeros((2, 4)), np.zeros(2), np.zeros(2)
    mass = np.full(4, 1e-3)
    assert lag_rows(x, fixed, mass, 1e4, rows, nrm, tgt, True, coef, kr, lam) == 0
    xe = x.copy()
    xe[1:, 1] -= 0.002  # the triangle moves 2 mm toward the vertex: gap 1 mm -> -1 mm
    hot = np.zeros(2, np.uint8)
    assert mark_closing(xe, rows, nrm, tgt, coef, kr, np.arange(2), hot) == 1
    assert hot.tolist() == [0, 1]
    assert mark_closing(xe, rows, nrm, tgt, coef, kr, np.arange(2), hot) == 0
