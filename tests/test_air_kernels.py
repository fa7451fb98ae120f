"""Tests of the air-model kernels (lokigraph.behaviors.air.kernels).

Systems are integrated directly with the kernels, the way the solver uses them per substep:
external force explicitly (v += h f / m), then ``implicit_drag_update``. Reference numbers come from
tests/data/analytic/reference_values.json (closed forms computed for this project).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from lokigraph.behaviors.air import kernels as ak

G = 9.81
GRAV = np.array([0.0, -G, 0.0])
REF = json.loads((Path(__file__).parent / "data" / "analytic" / "reference_values.json").read_text())


def _fall_linear(m, b, h, n, v0=0.0):
    """Point mass from v0 (vertical, +up) under gravity and linear drag b: n steps of size h."""
    v = np.array([[0.0, v0, 0.0]])
    u = np.zeros((1, 3))
    mass = np.array([m])
    D = np.zeros((1, 3, 3))
    ak.accumulate_isotropic_drag(np.array([b]), D)
    drop = 0.0
    for _ in range(n):
        v += h * GRAV
        ak.implicit_drag_update(v, mass, D, u, h)
        drop -= h * v[0, 1]
    return v[0], drop


# ---------------------------------------------------------------------------------------------
# Isotropic linear drag: closed-form fall, terminal velocity, stiffness
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("case", REF["drag_falling"]["linear"], ids=lambda c: f"t={c['t']}")
def test_linear_drag_fall_matches_closed_form_and_converges_first_order(case):
    m, b, t = case["m"], case["b"], case["t"]
    errors = []
    for k in (1, 4, 16, 64, 256):
        n = max(1, round(t * 24 * k))
        v, drop = _fall_linear(m, b, t / n, n)
        assert abs(v[0]) == 0.0 and abs(v[2]) == 0.0
        errors.append(abs(-v[1] - case["v"]) / case["v"])
        if k >= 64 and t >= 0.2:
            assert abs(drop - case["drop"]) / case["drop"] < 5e-3
    # backward Euler: first order, error / 4 per h / 4
    for e_coarse, e_fine in zip(errors[1:-1], errors[2:]):
        assert 3.0 < e_coarse / e_fine < 5.0
    assert errors[3] < 5e-3 and errors[4] < 5e-3  # h <= 1/1536 s
    if t >= 1.0:
        assert errors[0] < 5e-3  # h = 1/24 s is already within 0.5 % at t = 5 m/b


@pytest.mark.parametrize("h", [1 / 24, 1 / 96, 1 / 384, 1 / 1536])
def test_linear_drag_terminal_velocity_exact_at_any_step(h):
    m, b = 0.01, 0.05
    v_t = REF["drag_falling"]["linear"][0]["v_t"]
    n = int(math.ceil(40 * m / b / h))  # 40 time constants
    v, _ = _fall_linear(m, b, h, n)
    assert abs(-v[1] - v_t) / v_t < 1e-12


@pytest.mark.parametrize("ratio", [4.2e2, 1e4, 1e8])
def test_stiff_linear_drag_is_stable_where_explicit_blows_up(ratio):
    m, h = 0.01, 1 / 24
    b = ratio * m / h  # b h / m = ratio >> 1
    v_t = m * G / b
    vs = []
    v = np.zeros((1, 3))
    mass, u = np.array([m]), np.zeros((1, 3))
    D = np.zeros((1, 3, 3))
    ak.accumulate_isotropic_drag(np.array([b]), D)
    for _ in range(20):
        v += h * GRAV
        ak.implicit_drag_update(v, mass, D, u, h)
        vs.append(-v[0, 1])
    vs = np.array(vs)
    assert np.all(np.isfinite(vs))
    assert np.all(np.diff(vs) >= -1e-18) and np.all(vs <= v_t * (1 + 1e-12))  # monotone, no overshoot
    assert abs(vs[0] - v_t) / v_t < 1.0 / ratio * 1.01 + 1e-12  # one step gets within 1/(1 + bh/m)
    assert abs(vs[-1] - v_t) / v_t < 1e-12
    # the same drag as an explicit force diverges: the scenario really is stiff
    ve = np.zeros((1, 3))
    f = np.zeros((1, 3))
    for _ in range(20):
        ak.drag_force(ve, D, u, f)
        ve += h * (GRAV + f / m)
    assert not np.all(np.abs(ve) < 1e3)


def test_quadratic_drag_with_lagged_coefficient():
    """F = -c |v| v through a lagged isotropic coefficient b = c |v_start|: tanh fall and terminal."""
    ref = REF["drag_falling"]["quadratic"]
    m, c = ref[0]["m"], ref[0]["c"]
    u, mass = np.zeros((1, 3)), np.array([m])
    D = np.zeros((1, 3, 3))

    def run(h, n, v0=0.0):
        v = np.array([[0.0, v0, 0.0]])
        hist = [v[0, 1]]
        y, ymax = 0.0, 0.0
        for _ in range(n):
            D[:] = 0.0
            ak.accumulate_isotropic_drag(c * np.linalg.norm(v, axis=1), D)
            v += h * GRAV
            ak.implicit_drag_update(v, mass, D, u, h)
            y += h * v[0, 1]
            ymax = max(ymax, y)
            hist.append(v[0, 1])
        return np.array(hist), ymax

    for case in ref:
        n = round(case["t"] * 24 * 256)
        hist, _ = run(case["t"] / n, n)
        assert abs(-hist[-1] - case["v"]) / case["v"] < 5e-3
    hist, _ = run(1 / 24, 48)  # coarse step: the fixed point is still the exact terminal velocity
    assert abs(-hist[-1] - ref[0]["v_t"]) / ref[0]["v_t"] < 1e-9
    up = REF["drag_falling"]["quadratic_upward"]
    h = 1 / 24 / 256
    hist, ymax = run(h, round(0.4 / h), v0=up["v0"])
    t_apex = h * np.argmax(hist <= 0.0)
    assert abs(ymax - up["h_max"]) / up["h_max"] < 5e-3
    assert abs(t_apex - up["t_apex"]) < 2 * h


# ---------------------------------------------------------------------------------------------
# Linear anisotropic drag: gliding plate
# ---------------------------------------------------------------------------------------------
def _plate(normal, rng):
    """A unit-ish square patch, 4 x 4 vertices with jittered interior, in the plane with ``normal``."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    t1 = np.cross(n, [0.0, 0.0, 1.0]) if abs(n[2]) < 0.9 else np.cross(n, [1.0, 0.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    s, t = np.meshgrid(np.linspace(0, 1, 4), np.linspace(0, 1, 4), indexing="ij")
    s, t = s.ravel(), t.ravel()
    interior = (s > 0) & (s < 1) & (t > 0) & (t < 1)
    s = s + interior * rng.uniform(-0.1, 0.1, s.size)
    t = t + interior * rng.uniform(-0.1, 0.1, t.size)
    x = np.outer(s, t1) + np.outer(t, t2) + np.array([0.3, 2.0, -0.1])
    faces = []
    for i in range(3):
        for j in range(3):
            a, b, c, d = 4 * i + j, 4 * (i + 1) + j, 4 * (i + 1) + j + 1, 4 * i + j + 1
            faces += [[a, b, c], [a, c, d]]
    faces = np.array(faces, dtype=np.int64)
    e1 = x[faces[:, 1]] - x[faces[:, 0]]
    e2 = x[faces[:, 2]] - x[faces[:, 0]]
    area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    vertex_area = np.zeros(len(x))
    np.add.at(vertex_area, faces.ravel(), np.repeat(area / 3, 3))
    return x, faces, area, vertex_area


def _glide(case, h, t_end, rot_y=0.0):
    rng = np.random.default_rng(1)
    R = np.array([[math.cos(rot_y), 0, math.sin(rot_y)], [0, 1, 0], [-math.sin(rot_y), 0, math.cos(rot_y)]])
    x, faces, area, vertex_area = _plate(R @ np.array(case["normal"]), rng)
    A = area.sum()
    mass = case["m"] * vertex_area / A  # area-lumped, sums to m
    nf = len(faces)
    c_n = np.full(nf, case["c_n"] / A)  # per unit area, totals c_n, c_t
    c_t = np.full(nf, case["c_t"] / A)
    v = np.zeros_like(x)
    u = np.zeros_like(x)
    De = np.empty((nf, 3, 3))
    D = np.empty((len(x), 3, 3))
    for _ in range(round(t_end / h)):
        D[:] = 0.0
        ak.face_drag_matrices_linear(x, faces, c_n, c_t, De)
        ak.scatter_element_matrices(faces, De, D)
        v += h * GRAV
        ak.implicit_drag_update(v, mass, D, u, h)
        x += h * v
    n = R @ np.array(case["normal"])
    C = case["c_n"] * np.outer(n, n) + case["c_t"] * (np.eye(3) - np.outer(n, n))
    np.testing.assert_allclose(D.sum(axis=0), C, atol=1e-12)  # the patch's total drag matrix
    return v, R


@pytest.mark.parametrize("h", [1 / 24, 1 / 96])
@pytest.mark.parametrize(
    "case", REF["anisotropic_linear_drag_terminal"]["cases"], ids=lambda c: f"tilt{c['normal_tilt_from_vertical_deg']}"
)
def test_tilted_plate_glides_to_anisotropic_terminal_velocity(case, h):
    v, _ = _glide(case, h, t_end=40 * case["m"] / case["c_t"])
    ref = np.array(case["terminal_velocity"])
    assert np.abs(v - v.mean(axis=0)).max() < 1e-12  # moves rigidly (D_i / m_i equal on all vertices)
    err = np.linalg.norm(v.mean(axis=0) - ref) / np.linalg.norm(ref)
    assert err < 5e-3
    assert err < 1e-9  # the fixed point is exact, independent of h
    vm = v.mean(axis=0)
    glide = math.degrees(math.atan2(math.hypot(vm[0], vm[2]), -vm[1]))
    assert abs(glide - case["glide_angle_from_vertical_deg"]) < 1e-6


def test_plate_glide_is_frame_invariant_about_vertical():
    case = REF["anisotropic_linear_drag_terminal"]["cases"][2]  # 45 degrees
    v, R = _glide(case, 1 / 24, t_end=4.0, rot_y=0.7)
    ref = R @ np.array(case["terminal_velocity"])
    assert np.linalg.norm(v.mean(axis=0) - ref) / np.linalg.norm(ref) < 1e-9
    assert abs(ref[2]) > 0.1  # the rotation really moved the glide out of the xy-plane


# ---------------------------------------------------------------------------------------------
# Implicit update: energy, wind, residual, pinned particles
# ---------------------------------------------------------------------------------------------
def _random_spd(rng, n):
    A = rng.normal(size=(n, 3, 3))
    D = A @ np.transpose(A, (0, 2, 1))
    rank1 = rng.random(n) < 0.2  # singular (rod-like) matrices too
    w = rng.normal(size=(n, 3))
    D[rank1] = w[rank1, :, None] * w[rank1, None, :]
    return D * 10.0 ** rng.uniform(-6, 4, size=(n, 1, 1))


@pytest.mark.parametrize("seed", range(8))
def test_implicit_update_never_adds_energy(seed):
    rng = np.random.default_rng(seed)
    n = 2000
    h = 10.0 ** rng.uniform(-5, 2)
    m = 10.0 ** rng.uniform(-5, 1, size=n)
    D = _random_spd(rng, n)
    v0 = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-3, 2, size=(n, 1))
    # still air: kinetic energy per particle does not grow
    v = v0.copy()
    ak.implicit_drag_update(v, m, D, np.zeros((n, 3)), h)
    ke0 = 0.5 * m * (v0**2).sum(1)
    ke1 = 0.5 * m * (v**2).sum(1)
    assert np.all(ke1 <= ke0 * (1 + 1e-12))
    assert ke1.sum() < ke0.sum()
    # wind: |v' - u| <= |v - u| per particle (M-norm), and the linear system is solved
    u = rng.normal(size=(n, 3)) * 5.0
    v = v0.copy()
    ak.implicit_drag_update(v, m, D, u, h)
    assert np.all(((v - u) ** 2).sum(1) <= ((v0 - u) ** 2).sum(1) * (1 + 1e-12))
    z, w = v - u, v0 - u  # (m I + h D) z = m w, checked as a backward error
    lhs = m[:, None] * z + h * np.einsum("nij,nj->ni", D, z)
    rhs = m[:, None] * w
    scale = m[:, None] * (np.abs(z) + np.abs(w)) + h * np.einsum("nij,nj->ni", np.abs(D), np.abs(z))
    scale += (m[:, None] + h * np.abs(D).sum(2)) * np.abs(u)  # rounding of v - u in this check
    assert np.all(np.abs(lhs - rhs) <= 1e-14 * scale.max(axis=1, keepdims=True))
    # an explicit force step would have added energy in this set-up (the test can fail)
    ve = v0 - h / m[:, None] * np.einsum("nij,nj->ni", D, v0)
    assert np.any((ve**2).sum(1) > (v0**2).sum(1)) or h * (D.max() / m.min()) < 2


def test_implicit_update_extreme_stiffness_never_adds_energy_and_stays_accurate():
    """Singular D (rank 1-2) with h |D| / m from 1 to 1e18: beyond ~1/eps rounding decides the soft
    direction, but the update must still never add energy (and be accurate where the problem is)."""
    rng = np.random.default_rng(12)
    n = 20000
    w, w2 = rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    rank2 = rng.random((n, 1, 1)) < 0.5
    ratio = 10.0 ** rng.uniform(0, 18, n)
    D = (w[:, :, None] * w[:, None, :] + rank2 * w2[:, :, None] * w2[:, None, :]) * ratio[:, None, None]
    m = np.ones(n)
    v0 = rng.normal(size=(n, 3))
    v = v0.copy()
    ak.implicit_drag_update(v, m, D, np.zeros((n, 3)), 1.0)
    assert np.all(np.isfinite(v))
    assert np.all((v**2).sum(1) <= (v0**2).sum(1) * (1 + 1e-13))  # up to rounding of the norms
    lam, Q = np.linalg.eigh(D)
    exact = np.einsum("nij,nj->ni", Q, np.einsum("nji,nj->ni", Q, v0) / (1.0 + np.maximum(lam, 0.0)))
    err = np.linalg.norm(v - exact, axis=1) / np.linalg.norm(v0, axis=1)
    assert err[ratio < 1e4].max() < 1e-10
    assert err[ratio < 1e8].max() < 1e-5


def test_inverse_mass_variant_and_kinematic_particles():
    rng = np.random.default_rng(3)
    n = 50
    m = rng.uniform(0.1, 2.0, n)
    m[:5] = np.inf
    D = _random_spd(rng, n)
    v0 = rng.normal(size=(n, 3))
    u = rng.normal(size=(n, 3))
    va, vb = v0.copy(), v0.copy()
    ak.implicit_drag_update(va, m, D, u, 0.05)
    inv_m = 1.0 / m  # 0 for the kinematic ones
    ak.implicit_drag_update_inv_mass(vb, inv_m, D, u, 0.05)
    np.testing.assert_allclose(va, vb, rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(va[:5], v0[:5])
    assert not np.allclose(va[5:], v0[5:])


def test_extreme_drag_stays_finite_and_hits_air_velocity():
    v = np.array([[1.0, 2.0, 3.0]])
    u = np.array([[-0.5, 0.25, 4.0]])
    D = np.zeros((1, 3, 3))
    ak.accumulate_isotropic_drag(np.array([1e200]), D)
    ak.implicit_drag_update(v, np.array([1e-6]), D, u, 1.0)
    np.testing.assert_allclose(v, u, rtol=1e-12)


def test_drag_force_and_power():
    rng = np.random.default_rng(4)
    n = 40
    D = _random_spd(rng, n)
    v = rng.normal(size=(n, 3))
    u = rng.normal(size=(n, 3))
    f = np.empty((n, 3))
    ak.drag_force(v, D, u, f)
    np.testing.assert_allclose(f, -np.einsum("nij,nj->ni", D, v - u), rtol=1e-13, atol=1e-300)
    assert ak.drag_power(v, D, u) == pytest.approx(float((v * f).sum()), rel=1e-12)
    assert ak.drag_power(v, D, np.zeros_like(u)) < 0.0


# ---------------------------------------------------------------------------------------------
# Ergun anisotropic drag
# ---------------------------------------------------------------------------------------------
PARAMS = dict(mu=1.81e-5, rho=1.204, diameter=2e-4, gamma=0.3, xi_D=1.5, xi_perp=3e3, xi_par=800.0, xi_N=0.7)


def _coef(s, c=1.0, **kw):
    p = {**PARAMS, **kw}
    return ak.ergun_coefficients(
        s, p["mu"], p["rho"], p["diameter"], p["gamma"], p["xi_D"], p["xi_perp"], p["xi_par"], p["xi_N"], c
    )


def test_ergun_coefficient_at_rest_is_inverse_permeability():
    cp, cl = _coef(0.0)
    assert cp == pytest.approx(PARAMS["xi_D"] * 1e-4 * PARAMS["xi_perp"], rel=1e-14)
    assert cl == pytest.approx(PARAMS["xi_D"] * 1e-4 * PARAMS["xi_par"], rel=1e-14)
    assert _coef(0.0, c=0.0)[0] > cp  # Re^0 = 1: the "nonlinear" term is a constant then
    assert _coef(0.0, xi_perp=0.0)[0] == 0.0  # infinite permeability: no drag


@pytest.mark.parametrize("c", [0.5, 1.0, 1.7, 2.0])
def test_ergun_nonlinear_term_scales_as_speed_to_c(c):
    c0 = np.array(_coef(0.0, c=c))
    for s in (0.01, 0.3, 7.0):
        r = (np.array(_coef(2 * s, c=c)) - c0) / (np.array(_coef(s, c=c)) - c0)
        np.testing.assert_allclose(r, 2.0**c, rtol=1e-12)
    # and its size: xi_N 1.75 sqrt((1/k)/150) (1-gamma)^-1.5 Re^c
    s = 0.4
    re = PARAMS["rho"] * PARAMS["diameter"] * s / PARAMS["mu"]
    inv_k = PARAMS["xi_D"] * 1e-4 * PARAMS["xi_perp"]
    expect = PARAMS["xi_N"] * 1.75 / math.sqrt(150 / inv_k) * (1 - PARAMS["gamma"]) ** -1.5 * re**c
    assert _coef(s, c=c)[0] - c0[0] == pytest.approx(expect, rel=1e-12)


@pytest.mark.parametrize("case", REF["ergun"]["cases"], ids=lambda c: f"U={c['U_superficial']}-mu={c['mu']}")
def test_ergun_face_reproduces_packed_bed_pressure_gradient(case):
    """c = 1, xi_N = 1, gamma = 1 - eps, 1/k = 150 gamma^2 / eps^3: force / volume = Ergun's dP/L."""
    eps, d, U, mu, rho = case["porosity"], case["d_p"], case["U_superficial"], case["mu"], case["rho"]
    gamma = 1.0 - eps
    inv_k = 150 * gamma**2 / eps**3
    params = ak.pack_ergun_parameters(1, mu=mu, rho=rho, diameter=d, gamma=gamma, xi_perp=inv_k * 1e4, xi_par=1.0)
    assert ak.validate_ergun_parameters(params) == []
    x = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.0, 0.1]])  # normal along -y, area 0.01
    faces = np.array([[0, 1, 2]])
    thickness = np.array([0.03])
    v = np.tile([0.0, -U, 0.0], (3, 1))
    u = np.zeros((3, 3))
    De = np.empty((1, 3, 3))
    ak.face_drag_matrices_ergun(x, v, u, faces, thickness, params, De)
    force = -De[0] @ v[0]
    volume = 0.01 * 0.03
    assert np.abs(force[[0, 2]]).max() < 1e-12 * abs(force[1])
    assert force[1] / volume == pytest.approx(case["dPdL_total"], rel=1e-10)
    cv = ak.ergun_coefficients(0.0, mu, rho, d, gamma, 1.0, inv_k * 1e4, 1.0, 1.0, 1.0)[0]
    assert mu / d**2 * cv * U == pytest.approx(case["dPdL_viscous"], rel=1e-10)


def _random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def test_ergun_face_and_rod_axis_assignment_and_volume():
    params = ak.pack_ergun_parameters(1, **PARAMS)
    # face in the xz-plane: normal along y, area 0.5 * 0.3 * 0.2
    x = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.3], [0.2, 0.0, 0.0]])
    dv = np.array([0.3, -0.4, 1.2])
    v = np.tile(dv, (3, 1))
    u = np.zeros((3, 3))
    thickness = np.array([2e-3])
    De = np.empty((1, 3, 3))
    ak.face_drag_matrices_ergun(x, v, u, np.array([[0, 1, 2]]), thickness, params, De)
    cp, cl = _coef(np.linalg.norm(dv))
    scale = PARAMS["mu"] * 0.03 * 2e-3 / PARAMS["diameter"] ** 2
    np.testing.assert_allclose(De[0] @ [0, 1, 0], scale * cp * np.array([0, 1, 0]), atol=1e-15 * scale)
    np.testing.assert_allclose(De[0] @ [1, 0, 0], scale * cl * np.array([1, 0, 0]), atol=1e-15 * scale)
    np.testing.assert_allclose(De[0] @ [0, 0, 1], scale * cl * np.array([0, 0, 1]), atol=1e-15 * scale)
    assert cp > 2 * cl  # the test distinguishes the axes
    # rod along x, length 0.5, radius r: V = L pi r^2; the edge is the "par" axis
    xr = np.array([[0.1, 0.0, 0.0], [0.6, 0.0, 0.0]])
    vr = np.tile(dv, (2, 1))
    radius = np.array([3e-4])
    Dr = np.empty((1, 3, 3))
    ak.edge_drag_matrices_ergun(xr, vr, np.zeros((2, 3)), np.array([[0, 1]]), radius, params, Dr)
    scale = PARAMS["mu"] * 0.5 * math.pi * 3e-4**2 / PARAMS["diameter"] ** 2
    np.testing.assert_allclose(Dr[0], scale * np.diag([cl, cp, cp]), rtol=1e-12, atol=1e-15 * scale)
    # linear modes
    ak.face_drag_matrices_linear(x, np.array([[0, 1, 2]]), np.array([5.0]), np.array([0.5]), De)
    np.testing.assert_allclose(De[0], 0.03 * np.diag([0.5, 5.0, 0.5]), atol=1e-15)
    ak.edge_drag_matrices_linear(xr, np.array([[0, 1]]), np.array([5.0]), np.array([0.5]), Dr)
    np.testing.assert_allclose(Dr[0], 0.5 * np.diag([0.5, 5.0, 5.0]), atol=1e-15)


@pytest.mark.parametrize("kind", ["face", "rod"])
def test_ergun_drag_is_frame_invariant(kind):
    rng = np.random.default_rng(11)
    ne = 30
    k = 3 if kind == "face" else 2
    elements = np.arange(ne * k).reshape(ne, k)
    x = rng.normal(size=(ne * k, 3))
    v = rng.normal(size=(ne * k, 3))
    u = rng.normal(size=(ne * k, 3)) * 0.3
    size = rng.uniform(1e-4, 1e-3, ne)
    params = ak.pack_ergun_parameters(
        ne, **{**PARAMS, "diameter": rng.uniform(5e-5, 2e-4, ne), "gamma": rng.uniform(0.05, 0.5, ne)}
    )
    kern = ak.face_drag_matrices_ergun if kind == "face" else ak.edge_drag_matrices_ergun
    De = np.empty((ne, 3, 3))
    kern(x, v, u, elements, size, params, De)
    R = _random_rotation(rng)
    Dr = np.empty((ne, 3, 3))
    kern(x @ R.T + 5.0, v @ R.T, u @ R.T, elements, size, params, Dr)
    np.testing.assert_allclose(Dr, R @ De @ R.T, rtol=1e-10, atol=1e-12 * np.abs(De).max())
    dv = (v - u)[elements].mean(axis=1)
    f = -np.einsum("eij,ej->ei", De, dv)
    fr = -np.einsum("eij,ej->ei", Dr, dv @ R.T)
    np.testing.assert_allclose(fr, f @ R.T, rtol=1e-10, atol=1e-12 * np.abs(f).max())
    assert np.allclose(De, np.transpose(De, (0, 2, 1)))
    assert np.all(np.linalg.eigvalsh(De) > 0)


def test_scatter_distributes_equal_shares():
    rng = np.random.default_rng(2)
    faces = np.array([[0, 1, 2], [1, 2, 3]])
    edges = np.array([[3, 4]])
    Df = _random_spd(rng, 2)
    Dr = _random_spd(rng, 1)
    D = np.zeros((5, 3, 3))
    ak.scatter_element_matrices(faces, Df, D)
    ak.scatter_element_matrices(edges, Dr, D)
    np.testing.assert_allclose(D[0], Df[0] / 3)
    np.testing.assert_allclose(D[1], (Df[0] + Df[1]) / 3)
    np.testing.assert_allclose(D[3], Df[1] / 3 + Dr[0] / 2)
    np.testing.assert_allclose(D[4], Dr[0] / 2)
    np.testing.assert_allclose(D.sum(0), Df.sum(0) + Dr.sum(0))
    vals = np.arange(5.0)
    out = np.empty(2)
    ak.vertex_to_element(vals, faces, out)
    np.testing.assert_allclose(out, [1.0, 2.0])


def test_ergun_face_falls_to_nonlinear_terminal_velocity():
    """A horizontal face (lagged nonlinear coefficient) reaches the root of m g = (mu V / D^2) C(v) v."""
    p = dict(mu=1.81e-5, rho=1.204, diameter=1e-4, gamma=0.3, xi_D=1.0, xi_perp=1e4, xi_par=2e3, xi_N=1.0, c=1.0)
    params = ak.pack_ergun_parameters(1, **p)
    x = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.2], [0.1, 0.0, 0.0]])  # area 0.01, normal along y
    faces = np.array([[0, 1, 2]])
    thickness = np.array([1e-3])
    m_total = 0.002
    mass = np.full(3, m_total / 3)
    scale = p["mu"] * 0.01 * 1e-3 / p["diameter"] ** 2

    def residual(s):
        return scale * _coef(s, c=1.0, **{k: p[k] for k in PARAMS})[0] * s - m_total * G

    v_t = brentq(residual, 1e-6, 100.0, xtol=1e-14)
    assert 0.3 < (_coef(v_t, **{k: p[k] for k in PARAMS})[0] - 1.0) < 3.0  # the nonlinear term matters
    for h in (1 / 24, 1 / 240):
        v = np.zeros((3, 3))
        u = np.zeros((3, 3))
        De = np.empty((1, 3, 3))
        D = np.empty((3, 3, 3))
        for _ in range(round(3.0 / h)):
            ak.face_drag_matrices_ergun(x, v, u, faces, thickness, params, De)
            D[:] = 0.0
            ak.scatter_element_matrices(faces, De, D)
            v += h * GRAV
            ak.implicit_drag_update(v, mass, D, u, h)
        assert abs(-v[0, 1] - v_t) / v_t < 5e-3
        assert abs(-v[0, 1] - v_t) / v_t < 1e-9
        assert np.abs(v - v[0]).max() < 1e-14


@pytest.mark.parametrize("case", REF["fibrous_permeability"]["cases"][:5], ids=lambda c: f"phi={c['solid_fraction']}")
def test_drummond_tahir_inverse_permeability(case):
    inv_perp, inv_par = ak.drummond_tahir_inverse_permeability(case["solid_fraction"])
    assert 1.0 / inv_par == pytest.approx(case["drummond_tahir_parallel_K_over_d2"], rel=1e-12)
    assert 1.0 / inv_perp == pytest.approx(case["drummond_tahir_perp_K_over_d2_c3_4p076"], rel=1e-12)
    inv_perp78, _ = ak.drummond_tahir_inverse_permeability(case["solid_fraction"], c3=4.078)
    assert 1.0 / inv_perp78 == pytest.approx(case["drummond_tahir_perp_K_over_d2_c3_4p078"], rel=1e-12)
    assert inv_perp > inv_par  # flow across fibres is harder (dilute range)


def test_ergun_parameter_validation_messages():
    good = ak.pack_ergun_parameters(4, diameter=1e-4, gamma=0.2)
    assert ak.validate_ergun_parameters(good) == []
    bad = ak.pack_ergun_parameters(4, diameter=[1e-4, -2.0, 0.0, 1e-4], gamma=[0.2, 0.2, 1.5, 1.2], mu=0.0)
    errs = ak.validate_ergun_parameters(bad, element_kind="face")
    assert errs == sorted(errs) and len(errs) == 3
    assert errs[0] == "diameter: 2 faces must satisfy diameter > 0 (worst -2.0 at face 1)"
    assert errs[1] == "gamma: 2 faces must satisfy 0 <= gamma < 1 (worst 1.5 at face 2)"
    assert errs[2].startswith("mu: 4 faces must satisfy mu > 0")
    with pytest.raises(ValueError, match=r"xi_N: expected a scalar or shape \(4,\)"):
        ak.pack_ergun_parameters(4, diameter=1e-4, gamma=0.2, xi_N=np.ones(3))


# ---------------------------------------------------------------------------------------------
# Lift
# ---------------------------------------------------------------------------------------------
def _lift_reference(x, v, u, elements, De, xi_L):
    """Eq. (4) written with np.cross, per element (independent of the kernel's algebra)."""
    dv = (v - u)[elements].mean(axis=1)
    fd = -np.einsum("eij,ej->ei", De, dv)
    if elements.shape[1] == 2:
        e = x[elements[:, 1]] - x[elements[:, 0]]
    else:
        nrm = np.cross(x[elements[:, 1]] - x[elements[:, 0]], x[elements[:, 2]] - x[elements[:, 0]])
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        e = dv - (dv * nrm).sum(1, keepdims=True) * nrm
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    Q = np.cross(e, np.cross(e, fd))
    s2 = (dv * dv).sum(1, keepdims=True)
    return -xi_L[:, None] * (Q - (Q * dv).sum(1, keepdims=True) / s2 * dv), dv


@pytest.mark.parametrize("kind", ["face", "rod"])
def test_lift_orthogonal_to_relative_velocity_and_matches_eq4(kind):
    rng = np.random.default_rng(5)
    ne = 40
    k = 3 if kind == "face" else 2
    elements = np.arange(ne * k).reshape(ne, k)  # disjoint: per-element lift = k * vertex force
    x = rng.normal(size=(ne * k, 3))
    v = rng.normal(size=(ne * k, 3))
    u = rng.normal(size=(ne * k, 3)) * 0.5
    params = ak.pack_ergun_parameters(ne, **PARAMS)
    De = np.empty((ne, 3, 3))
    size = np.full(ne, 1e-3)
    kern = ak.face_drag_matrices_ergun if kind == "face" else ak.edge_drag_matrices_ergun
    kern(x, v, u, elements, size, params, De)
    xi_L = rng.uniform(0.1, 2.0, ne)
    f = np.zeros_like(x)
    ak.accumulate_lift(x, v, u, elements, De, xi_L, f)
    lift = f[elements].sum(axis=1)
    np.testing.assert_allclose(f[elements], np.repeat(lift[:, None, :] / k, k, axis=1), rtol=1e-13)
    ref, dv = _lift_reference(x, v, u, elements, De, xi_L)
    np.testing.assert_allclose(lift, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
    cosang = np.abs((lift * dv).sum(1)) / (np.linalg.norm(lift, axis=1) * np.linalg.norm(dv, axis=1))
    assert np.all(cosang < 1e-12)
    assert np.all(np.linalg.norm(lift, axis=1) > 1e-6 * np.linalg.norm(-np.einsum("eij,ej->ei", De, dv), axis=1))
    # xi_L = 0: exactly nothing
    f0 = np.zeros_like(x)
    ak.accumulate_lift(x, v, u, elements, De, np.zeros(ne), f0)
    assert np.all(f0 == 0.0)


def test_lift_vanishes_for_flow_along_e_par_and_at_rest():
    rng = np.random.default_rng(6)
    De = _random_spd(rng, 1)
    # rod along a random direction, dv parallel to it; with an axially symmetric De (as built)
    xr = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 0.5]])
    params = ak.pack_ergun_parameters(1, **PARAMS)
    for dv in (xr[1] * 2.0, -xr[1] * 0.01):
        v = np.tile(dv, (2, 1))
        Dr = np.empty((1, 3, 3))
        ak.edge_drag_matrices_ergun(xr, v, np.zeros((2, 3)), np.array([[0, 1]]), np.array([1e-3]), params, Dr)
        f = np.zeros((2, 3))
        ak.accumulate_lift(xr, v, np.zeros((2, 3)), np.array([[0, 1]]), Dr, np.array([1.0]), f)
        assert np.abs(f).max() <= 1e-14 * np.abs(Dr[0] @ dv).max()
    # face: dv in its plane, and dv along its normal
    xf = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    for dv in ([0.3, -0.7, 0.0], [0.0, 0.0, 2.0]):
        v = np.tile(dv, (3, 1))
        Df = np.empty((1, 3, 3))
        ak.face_drag_matrices_linear(xf, np.array([[0, 1, 2]]), np.array([3.0]), np.array([0.2]), Df)
        f = np.zeros((3, 3))
        ak.accumulate_lift(xf, v, np.zeros((3, 3)), np.array([[0, 1, 2]]), Df, np.array([1.0]), f)
        assert np.abs(f).max() <= 1e-14
    # dv = 0, even with a non-axial matrix: zero and finite
    for elements, xx in ((np.array([[0, 1]]), xr), (np.array([[0, 1, 2]]), xf)):
        n = len(xx)
        f = np.zeros((n, 3))
        ak.accumulate_lift(xx, np.ones((n, 3)), np.ones((n, 3)), elements, De, np.array([1.0]), f)
        assert np.all(f == 0.0)


@pytest.mark.parametrize("alpha_deg", [10.0, 30.0, 45.0, 60.0, 80.0])
def test_face_lift_is_flat_plate_like(alpha_deg):
    """A nose-up plate moving along +x: lift points up (+y), |lift| = xi_L c A |dv| sin(a) cos(a)."""
    a = math.radians(alpha_deg)
    t1 = np.array([math.cos(a), math.sin(a), 0.0])  # chord, nose up
    x = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], t1])  # normal = z x t1 -> (-sin a, cos a, 0)
    A = 0.5
    c, xi_L, speed = 2.0, 0.8, 3.0
    v = np.tile([speed, 0.0, 0.0], (3, 1))
    u = np.zeros((3, 3))
    De = np.empty((1, 3, 3))
    ak.face_drag_matrices_linear(x, np.array([[0, 1, 2]]), np.array([c / A]), np.array([c / A]), De)
    f = np.zeros((3, 3))
    ak.accumulate_lift(x, v, u, np.array([[0, 1, 2]]), De, np.array([xi_L]), f)
    lift = f.sum(0)
    assert lift[1] > 0.0
    assert abs(lift[0]) < 1e-14 and abs(lift[2]) < 1e-14
    assert lift[1] == pytest.approx(xi_L * c * speed * math.sin(a) * math.cos(a), rel=1e-12)
    # with anisotropic drag the lift is xi_L times the part of the normal (pressure) force across dv
    ak.face_drag_matrices_linear(x, np.array([[0, 1, 2]]), np.array([c / A]), np.array([0.1 * c / A]), De)
    f[:] = 0.0
    ak.accumulate_lift(x, v, u, np.array([[0, 1, 2]]), De, np.array([xi_L]), f)
    assert f.sum(0)[1] == pytest.approx(xi_L * c * speed * math.sin(a) * math.cos(a), rel=1e-12)


def test_rod_lift_follows_cross_flow_principle():
    """Yawed cylinder: lift = xi_L x (normal force component across dv), size c_n L |dv| sin b cos b."""
    b = math.radians(35.0)
    L, c_n, c_t, xi_L, speed = 0.4, 3.0, 0.3, 1.3, 2.0
    x = np.array([[0.0, 0.0, 0.0], [L * math.cos(b), L * math.sin(b), 0.0]])
    v = np.tile([speed, 0.0, 0.0], (2, 1))
    Dr = np.empty((1, 3, 3))
    ak.edge_drag_matrices_linear(x, np.array([[0, 1]]), np.array([c_n]), np.array([c_t]), Dr)
    f = np.zeros((2, 3))
    ak.accumulate_lift(x, v, np.zeros((2, 3)), np.array([[0, 1]]), Dr, np.array([xi_L]), f)
    lift = f.sum(0)
    assert lift[0] == pytest.approx(0.0, abs=1e-14)
    # rod rising along +x, moving along +x: the cross-flow (normal) force pushes it up
    assert lift[1] == pytest.approx(xi_L * c_n * L * speed * math.sin(b) * math.cos(b), rel=1e-12)


# ---------------------------------------------------------------------------------------------
# Wind
# ---------------------------------------------------------------------------------------------
def test_wind_without_noise_is_uniform():
    x = np.random.default_rng(0).normal(size=(7, 3)) * 10
    out = np.empty((7, 3))
    ak.wind_velocity(x, 3.3, np.array([0.0, 0.0, 2.0]), 4.0, 0.0, 1.0, 1, out)
    np.testing.assert_array_equal(out, np.tile([0.0, 0.0, 4.0], (7, 1)))
    ak.wind_velocity(x, 3.3, np.array([0.0, 0.0, 0.0]), 4.0, 0.0, 1.0, 1, out)
    np.testing.assert_array_equal(out, 0.0)  # zero direction: no mean wind
    ak.wind_velocity(x, 3.3, np.array([0.0, 0.0, 0.0]), 4.0, 0.5, 1.0, 1, out)
    assert np.all(np.isfinite(out)) and np.abs(out).max() > 0.0  # ... but gusts of rms 0.5 * 4 m/s
    ak.wind_velocity(x, 3.3, np.array([1.0, 0.0, 0.0]), 4.0, 0.5, 0.0, 1, out)
    np.testing.assert_array_equal(out, np.tile([4.0, 0.0, 0.0], (7, 1)))  # noise_scale <= 0: no noise


def test_wind_noise_is_zero_mean_deterministic_and_smooth():
    rng = np.random.default_rng(8)
    pts = rng.uniform(-3, 3, size=(5, 3))
    direction = np.array([1.0, 0.2, -0.5])
    d = direction / np.linalg.norm(direction)
    speed, noise, scale = 4.0, 0.5, 3.0
    ts = np.arange(0.0, 400.0, 0.0137)
    samples = np.empty((ts.size, 5, 3))
    out = np.empty((5, 3))
    for j, t in enumerate(ts):
        ak.wind_velocity(pts, t, direction, speed, noise, scale, 42, out)
        samples[j] = out
    mean = samples.mean(axis=0)
    assert np.abs(mean - speed * d).max() < 0.01 * speed
    rms = np.sqrt(((samples - speed * d) ** 2).sum(-1).mean(0))
    np.testing.assert_allclose(rms, noise * speed, rtol=0.1)  # documented amplitude
    assert samples.std(axis=0).min() > 0.05 * noise * speed  # the noise is there, in every component
    # deterministic for a seed, different for another seed
    a, b, c = np.empty((5, 3)), np.empty((5, 3)), np.empty((5, 3))
    ak.wind_velocity(pts, 1.25, direction, speed, noise, scale, 42, a)
    ak.wind_velocity(pts, 1.25, direction, speed, noise, scale, 42, b)
    ak.wind_velocity(pts, 1.25, direction, speed, noise, scale, 43, c)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 1e-3
    # smooth: a 1 mm move changes the wind by at most amplitude * |k_max| * 1 mm (times a margin)
    ak.wind_velocity(pts + 1e-3, 1.25, direction, speed, noise, scale, 42, c)
    k_max = 2 * math.pi / (scale * 0.58 ** (ak.WIND_NOISE_MODES - 1))
    assert np.abs(a - c).max() < 3 * noise * speed * k_max * 1e-3 * math.sqrt(3)


# ---------------------------------------------------------------------------------------------
# Parallel path (large inputs) agrees with the serial path
# ---------------------------------------------------------------------------------------------
def test_parallel_and_serial_paths_agree():
    rng = np.random.default_rng(9)
    n = ak.PARALLEL_MIN_ITEMS + 17
    x = rng.normal(size=(n, 3))
    v = rng.normal(size=(n, 3))
    u = rng.normal(size=(n, 3)) * 0.3
    faces = rng.integers(0, n, size=(n, 3))
    edges = rng.integers(0, n, size=(n, 2))
    params = ak.pack_ergun_parameters(n, **PARAMS)
    size = rng.uniform(1e-4, 1e-3, n)
    c_n, c_t = rng.uniform(0.5, 2.0, n), rng.uniform(0.0, 0.5, n)
    cases = [
        (ak.face_drag_matrices_linear, ak._face_drag_matrices_linear_serial, (x, faces, c_n, c_t), (n, 3, 3)),
        (ak.edge_drag_matrices_linear, ak._edge_drag_matrices_linear_serial, (x, edges, c_n, c_t), (n, 3, 3)),
        (ak.face_drag_matrices_ergun, ak._face_drag_matrices_ergun_serial, (x, v, u, faces, size, params), (n, 3, 3)),
        (ak.edge_drag_matrices_ergun, ak._edge_drag_matrices_ergun_serial, (x, v, u, edges, size, params), (n, 3, 3)),
    ]
    for par, ser, args, shape in cases:
        a, b = np.full(shape, np.nan), np.full(shape, np.nan)
        par(*args, a)
        ser(*args, b)
        np.testing.assert_array_equal(a, b)
    D = _random_spd(rng, n)
    m = rng.uniform(0.1, 1.0, n)
    for par, ser, mass in (
        (ak.implicit_drag_update, ak._implicit_drag_update_serial, m),
        (ak.implicit_drag_update_inv_mass, ak._implicit_drag_update_inv_mass_serial, 1.0 / m),
    ):
        va, vb = v.copy(), v.copy()
        par(va, mass, D, u, 0.1)
        ser(vb, mass, D, u, 0.1)
        np.testing.assert_array_equal(va, vb)
        assert not np.array_equal(va, v)
    a, b = np.empty((n, 3)), np.empty((n, 3))
    ak.wind_velocity(x, 0.7, np.array([0.0, 1.0, 0.0]), 3.0, 0.4, 2.0, 5, a)
    ak.wind_velocity(x[:100], 0.7, np.array([0.0, 1.0, 0.0]), 3.0, 0.4, 2.0, 5, b[:100])
    np.testing.assert_array_equal(a[:100], b[:100])
