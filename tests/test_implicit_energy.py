"""Implicit energies (the protocol of lokigraph.behaviors.solvers.implicit.energy): gradients
against central finite differences of the energy, Hessian blocks against finite differences of
the gradient where they are exact (springs, goals, attachments everywhere; the Gauss-Newton
energies at their rest state, where the left-out term C d2C vanishes), and every Hessian block
set positive semidefinite at random configurations."""

from __future__ import annotations

import numpy as np
import pytest

from lokigraph.behaviors.attachments.goal import goal_energy
from lokigraph.behaviors.attachments.surface import attach_energy
from lokigraph.behaviors.materials.bend import dihedral_energy, rest_dihedrals, rod_bend_energy
from lokigraph.behaviors.materials.shear import angle_energy, rest_angles
from lokigraph.behaviors.materials.stretch import spring_energy, spring_update_lam
from lokigraph.behaviors.materials.volume import rest_tet_volumes, tet_volume_energy

RNG = np.random.default_rng(7)


def _eval(fn, x, stencil, mode):
    """(E, grad (n, 3), hess (m, k, k, 3, 3)) of ``fn(x, mode, grad, hess)``."""
    m, k = stencil.shape
    g = np.zeros_like(x)
    H = np.zeros((m, k, k, 3, 3))
    E = fn(x, mode, g, H)
    return E, g, H


def _assemble(H, stencil, n):
    K = np.zeros((3 * n, 3 * n))
    m, k = stencil.shape
    for t in range(m):
        for a in range(k):
            for b in range(k):
                i, j = stencil[t, a], stencil[t, b]
                K[3 * i:3 * i + 3, 3 * j:3 * j + 3] += H[t, a, b]
    return K


def _fd_grad(fn, x, stencil, eps=1e-6):
    g = np.zeros_like(x)
    for i in range(x.shape[0]):
        for c in range(3):
            xp, xm = x.copy(), x.copy()
            xp[i, c] += eps
            xm[i, c] -= eps
            g[i, c] = (_eval(fn, xp, stencil, 0)[0] - _eval(fn, xm, stencil, 0)[0]) / (2 * eps)
    return g


def _fd_hess(fn, x, stencil, eps=1e-6):
    n = x.shape[0]
    K = np.zeros((3 * n, 3 * n))
    for i in range(n):
        for c in range(3):
            xp, xm = x.copy(), x.copy()
            xp[i, c] += eps
            xm[i, c] -= eps
            K[:, 3 * i + c] = ((_eval(fn, xp, stencil, 1)[1] - _eval(fn, xm, stencil, 1)[1])
                               .ravel() / (2 * eps))
    return K


def _check(fn, x, stencil, exact_hessian: bool, rtol=1e-5):
    E, g, H = _eval(fn, x, stencil, 2)
    gf = _fd_grad(fn, x, stencil)
    scale = max(np.abs(gf).max(), 1e-12)
    assert np.abs(g - gf).max() <= rtol * scale + 1e-9, (g, gf)
    K = _assemble(H, stencil, x.shape[0])
    assert np.allclose(K, K.T, atol=1e-12 * max(np.abs(K).max(), 1))
    ev = np.linalg.eigvalsh(K)
    assert ev.min() >= -1e-9 * max(ev.max(), 1e-300), ev.min()
    if exact_hessian:
        Kf = _fd_hess(fn, x, stencil)
        hs = max(np.abs(Kf).max(), 1e-12)
        assert np.abs(K - Kf).max() <= 1e-4 * hs, np.abs(K - Kf).max() / hs
    return E, g, K


def _rigid(x):
    """A random rotation and translation of x."""
    q, _ = np.linalg.qr(RNG.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return x @ q.T + RNG.normal(size=3)


HARD = np.full(8, 50.0)


@pytest.mark.parametrize("stretch", [1.3, 0.7])
def test_spring_energy(stretch):
    x0 = RNG.normal(size=(2, 3))
    L = np.linalg.norm(x0[1] - x0[0]) / stretch
    idx = np.array([[0, 1]])
    fn = (lambda x, mode, g, H: spring_energy(x, idx, np.array([L]), np.array([0.01]),
                                              np.array([0.02]), np.zeros(1), HARD, mode, g, H))
    E, g, K = _check(fn, x0, idx, exact_hessian=stretch > 1)
    k = 1 / 0.01 if stretch > 1 else 1 / 0.02
    assert E == pytest.approx(0.5 * k * (np.linalg.norm(x0[1] - x0[0]) - L) ** 2)
    # compressed: the transverse (negative) part is clamped, the axial stiffness stays exact
    d = (x0[0] - x0[1]) / np.linalg.norm(x0[0] - x0[1])
    assert d @ K[:3, :3] @ d == pytest.approx(k)


def test_spring_hard_row_and_zero_rest():
    x0 = RNG.normal(size=(2, 3))
    idx = np.array([[0, 1]])
    fn = (lambda x, mode, g, H: spring_energy(x, idx, np.array([0.0]), np.array([0.0]),
                                              np.array([0.0]), np.zeros(1), HARD, mode, g, H))
    E, g, K = _check(fn, x0, idx, exact_hessian=True)
    assert E == pytest.approx(0.5 * 50.0 * np.sum((x0[1] - x0[0]) ** 2))


@pytest.mark.parametrize("lam, stretch, compression", [(3.0, 1.1, 0.0), (3.0, 0.95, 0.0),
                                                       (-2.0, 0.9, 0.0), (3.0, 0.9, np.inf)])
def test_spring_augmented_lagrangian(lam, stretch, compression):
    """Hard rows: E = ((lam + k C)^2 - lam^2) / (2 k), tension only when compression is off;
    the multiplier update lam += k C moves toward the constraint force."""
    x0 = RNG.normal(size=(2, 3))
    ln = np.linalg.norm(x0[1] - x0[0])
    L = ln / stretch
    idx = np.array([[0, 1]])
    lam_a = np.array([lam])
    a2 = np.array([compression])
    fn = (lambda x, mode, g, H: spring_energy(x, idx, np.array([L]), np.array([0.0]), a2,
                                              lam_a, HARD, mode, g, H))
    f = lam + 50.0 * (ln - L)
    E, g, K = _check(fn, x0, idx, exact_hessian=f >= 0)
    if f < 0 and compression == np.inf:
        assert E == pytest.approx(-lam * lam / 100.0) and not g.any()
    else:
        assert E == pytest.approx((f * f - lam * lam) / 100.0)
    spring_update_lam(x0, idx, np.array([L]), np.array([0.0]), a2, lam_a, HARD)
    assert lam_a[0] == pytest.approx(max(f, 0.0) if compression == np.inf else f)


def test_angle_energy():
    idx = np.array([[0, 1, 2]])
    x0 = RNG.normal(size=(3, 3))
    rest = rest_angles(x0, idx)
    fn = (lambda x, mode, g, H: angle_energy(x, idx, rest, np.array([0.1]), mode, g, H))
    E, _, _ = _check(fn, _rigid(x0), idx, exact_hessian=True)  # rest state: GN exact
    assert E == pytest.approx(0.0, abs=1e-20)
    x1 = x0 + 0.2 * RNG.normal(size=x0.shape)
    _check(fn, x1, idx, exact_hessian=False)


@pytest.mark.parametrize("dropoff", [0.0, 2.0])
def test_dihedral_energy(dropoff):
    idx = np.array([[0, 1, 2, 3]])
    x0 = np.array([[0, 0, 0], [1, 0, 0], [0.4, 1, 0.2], [0.6, -1, 0.3]], float)
    rest = rest_dihedrals(x0, idx)
    fn = (lambda x, mode, g, H: dihedral_energy(x, idx, rest, np.array([0.5]),
                                                np.array([dropoff]), mode, g, H))
    _check(fn, _rigid(x0), idx, exact_hessian=True)
    x1 = x0 + 0.1 * RNG.normal(size=x0.shape)
    E, _, _ = _check(fn, x1, idx, exact_hessian=False)
    c = (rest_dihedrals(x1, idx) - rest)[0]
    assert E == pytest.approx(2.0 * (c * c / 2 + dropoff * abs(c) ** 3 / (3 * np.pi)))


@pytest.mark.parametrize("curved", [False, True])
def test_rod_bend_energy(curved):
    idx = np.array([[1, 0, 2]])  # apex, a, b
    x0 = np.array([[0, 0, 0], [1, 0, 0], [2, 0.8 if curved else 0.0, 0]], float)
    rest = rest_angles(x0, idx)
    fn = (lambda x, mode, g, H: rod_bend_energy(x, idx, rest, np.array([0.25]), mode, g, H))
    E, _, K = _check(fn, _rigid(x0), idx, exact_hessian=True)
    assert E == pytest.approx(0.0, abs=1e-20)
    if not curved:  # straight at rest: both bending directions are stiff
        assert np.linalg.matrix_rank(K, tol=1e-8 * np.abs(K).max()) == 2
    x1 = x0 + 0.15 * RNG.normal(size=x0.shape)
    E, _, _ = _check(fn, x1, idx, exact_hessian=False)
    e0, e1 = x1[1] - x1[0], x1[2] - x1[1]
    phi = np.arccos(np.clip(e0 @ e1 / np.linalg.norm(e0) / np.linalg.norm(e1), -1, 1))
    phi0 = np.pi - rest[0]
    want = 0.5 * 4.0 * (2 * np.tan(phi / 2) - 2 * np.tan(phi0 / 2)) ** 2
    assert E == pytest.approx(want)


def test_tet_volume_energy():
    idx = np.array([[0, 1, 2, 3]])
    x0 = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float) + 0.05 * RNG.normal(
        size=(4, 3))
    V0 = rest_tet_volumes(x0, idx)
    fn = (lambda x, mode, g, H: tet_volume_energy(x, idx, V0, np.array([1e-3]), mode, g, H))
    _check(fn, _rigid(x0), idx, exact_hessian=True)
    x1 = x0 * 1.1
    E, _, _ = _check(fn, x1, idx, exact_hessian=False)
    assert E == pytest.approx(0.5e3 * (V0[0] * 1.331 - V0[0]) ** 2)


def test_goal_and_attachment_energy():
    x0 = RNG.normal(size=(4, 3))
    idx = np.array([[2]])
    target = RNG.normal(size=(1, 3))
    fn = (lambda x, mode, g, H: goal_energy(x, idx[:, 0], target, np.array([0.0]), HARD, mode,
                                            g, H))  # alpha 0: the hard penalty
    E, _, _ = _check(fn, x0, idx, exact_hessian=True)
    assert E == pytest.approx(25.0 * np.sum((x0[2] - target[0]) ** 2))
    rows = np.array([[0, 1, 2, 3]])
    bary = np.array([[0.2, 0.3, 0.5]])
    fn = (lambda x, mode, g, H: attach_energy(x, rows, bary, np.array([0.5]),
                                              np.array([True]), HARD, mode, g, H))
    E, _, _ = _check(fn, x0, rows, exact_hessian=True)
    r = x0[0] - bary[0] @ x0[1:]
    assert E == pytest.approx(np.sum(r * r))
