"""Air-model kernels: wind field, isotropic and anisotropic (Ergun) drag, lift.

All arrays are float64 (elements: integer index arrays), SI units, C-contiguous:

* ``x`` particle positions [m], shape (particle_count, 3)
* ``v`` particle velocities [m/s], shape (particle_count, 3)
* ``u`` air velocity sampled at the particles [m/s], shape (particle_count, 3)
* ``m`` lumped particle masses [kg], shape (particle_count,)
* ``D`` per-particle drag matrices [kg/s], shape (particle_count, 3, 3)
* ``faces`` triangle vertex indices, shape (face_count, 3); ``edges`` rod segments, shape (edge_count, 2)
* ``De`` per-element drag matrices [kg/s], shape (element_count, 3, 3)

How a solver uses them, per substep of size ``h``::

    D[:] = 0
    accumulate_isotropic_drag(b, D)                          # paintable linear drag
    face_drag_matrices_ergun(x, v, u, faces, thickness, ergun, De)   # or *_linear
    scatter_element_matrices(faces, De, D)
    accumulate_lift(x, v, u, faces, De, xi_L, particle_f)    # explicit force
    v += h * particle_f / m[:, None]                         # the solver's explicit update
    implicit_drag_update(v, m, D, u, h)                      # drag, unconditionally stable

Drag is never applied as an explicit force. ``implicit_drag_update`` solves, per particle,

    (M_i + h D_i) v_i' = M_i v_i + h D_i u_i

(backward Euler for the drag term). For a symmetric positive semi-definite D_i it cannot increase
the kinetic energy relative to the air, ``|v' - u|_M <= |v - u|_M``, for any h, and the fixed point
of "explicit external force f, then drag update" is exactly ``v = u + D^-1 f``: the terminal
velocity of the continuous problem at every step size. The transient is first-order accurate in h.
The 3x3 systems are solved with a closed-form Cholesky factorisation (backward stable for any
h |D| / m); the result is clamped to ``|v' - u| <= |v - u|`` so that rounding cannot add energy
even for absurd stiffness with a singular D (h |D| / m >~ 1e10, where the forward error of any
float64 solve grows like eps * h |D| / m: measured < 1e-10 below 1e4, < 1e-5 below 1e8).

Anisotropic drag (Zhai et al. 2022, supplement eq. 1-3, after Fei et al. 2018)::

    C_l = 1/k_l + xi_N * 1.75 / sqrt(150 k_l) * (1 - gamma)^(-3/2) * (rho D |dv| / mu)^c,  l in {perp, par}
    1/k_l = xi_D / 1e4 * xi_l
    f_drag = -(mu V / D^2) R C R^T dv

with C = diag(C_perp, C_par, C_par) in a face frame (n, t1, t2), i.e. R C R^T = C_par I + (C_perp - C_par) n n^T,
and C = diag(C_perp, C_perp, C_par) in a rod frame whose "par" axis is the edge direction e, i.e.
R C R^T = C_perp I + (C_par - C_perp) e e^T. C is dimensionless (k_l is a permeability in units of D^2).
Element volume V: face area * ``thickness`` (material thickness [m]); rod ``length * pi * radius^2``
(``radius`` [m] of the rod's cross-section; for a rod that is one fibre, radius = D / 2, which gives
``mu V / D^2 = mu * length * pi / 4``). dv is the mean over the element's vertices of v - u.
The |dv|-dependent term is evaluated at the velocities passed in (the start of the step: lagged),
so each step's system stays linear, symmetric and positive definite.

With c = 1, xi_N = 1, gamma = 1 - porosity and 1/k = 150 gamma^2 / (1 - gamma)^3, the force per unit
volume ``(mu / D^2) C |dv|`` is exactly Ergun's (1952) pressure gradient of a packed bed.

Lift (supplement eq. 4)::

    Q = e_par x (e_par x f_drag) = -(f_drag - (e_par . f_drag) e_par)
    f_lift = -xi_L (Q - (Q . dv) / |dv|^2 dv)

so f_lift is ``xi_L`` times the part of the drag that is perpendicular to e_par (the element's normal,
"pressure" force), with its component along dv removed. e_par for a rod is the edge direction, for a
face it is the direction of dv projected into the face plane (the direction along which the flow
slides over the face). This choice makes a face behave like a flat plate: the lift comes from the
normal force, points to the side the plate deflects the flow away from (up for a nose-up plate
moving forward, with xi_L > 0), and its size goes as sin(2 alpha) in the angle of attack alpha,
zero when the face is edge-on or face-on to the flow, as in Maya Nucleus' lift. Choosing the face
normal as e_par instead would give a lift of the opposite sign built from the tangential (friction)
part of the drag. Lift is applied explicitly, as a force added to the force accumulator.

References
    X. Zhai et al. 2022, "Avatar: The Way of Hair, Cloth, and Coupled Simulation", supplemental
    document, section 2 (eq. 1-4). Y. R. Fei, C. Batty, E. Grinspun, C. Zheng 2018, "A multi-scale
    model for simulating liquid-fabric interactions", ACM TOG 37(4). S. Ergun 1952, "Fluid flow
    through packed columns", Chem. Eng. Prog. 48. J. Stam 2009, "Nucleus: towards a unified dynamics
    solver for computer graphics", section 5 (air model: drag, lift, wind direction).
    E. Drummond, M. I. Tahir 1984, Int. J. Multiphase Flow 10.

Limitations
    * The implicit update is backward Euler: terminal velocities are exact at any h, the transient
      is O(h) (e.g. 0.4 % error in v(t = 5 m/b) at h = 1/24 s for b/m = 5 /s).
    * Nonlinear (Ergun, quadratic) coefficients are lagged: a step is linear, the terminal velocity
      is still an exact fixed point, but for very stiff nonlinear drag (h * dF/dv / m >> 1) the
      approach to it is a slowly damped period-2 oscillation (contraction (1 - s)/(1 + s) per step,
      s = h * b(v_t) / m); energy relative to the air still never grows.
    * Lift is explicit: it is orthogonal to dv, so it does no work against the relative velocity in
      the continuous limit, but the explicit step rotates dv and scales |dv| by
      sqrt(1 + (h |f_lift| / (m |dv|))^2); keep h * xi_L * |D| / m modest.
    * Drag couples vertices only through the shared element |dv| (lagged); each vertex is solved with
      its own 3x3 block, element matrices are split equally to the element's vertices.
    * The wind noise is a smooth sum of sinusoids, not a solution of the flow equations (not
      divergence free, no obstacles, no air pressure model).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

__all__ = [
    "AIR_DENSITY",
    "AIR_VISCOSITY",
    "ERGUN_PARAMETER_NAMES",
    "PARALLEL_MIN_ITEMS",
    "WIND_NOISE_MODES",
    "accumulate_isotropic_drag",
    "accumulate_lift",
    "drag_force",
    "drag_power",
    "drummond_tahir_inverse_permeability",
    "edge_drag_matrices_ergun",
    "edge_drag_matrices_linear",
    "ergun_coefficients",
    "face_drag_matrices_ergun",
    "face_drag_matrices_linear",
    "implicit_drag_update",
    "implicit_drag_update_inv_mass",
    "pack_ergun_parameters",
    "scatter_element_matrices",
    "validate_ergun_parameters",
    "vertex_to_element",
    "wind_velocity",
]

AIR_DENSITY = 1.204
"""Density of air at 20 C, 1 atm [kg/m^3]."""
AIR_VISCOSITY = 1.81e-5
"""Dynamic viscosity of air at 20 C [Pa s]."""

# Columns of the packed Ergun parameter array, shape (element_count, 9).
ERGUN_MU = 0  # dynamic viscosity of the fluid [Pa s]
ERGUN_RHO = 1  # fluid density [kg/m^3]
ERGUN_DIAMETER = 2  # fibre diameter D [m]
ERGUN_GAMMA = 3  # material (solid) fraction gamma [-], 0 <= gamma < 1
ERGUN_XI_D = 4  # global drag scale xi_D [-]
ERGUN_XI_PERP = 5  # normal drag scale xi_perp [-]
ERGUN_XI_PAR = 6  # tangential drag scale xi_par [-]
ERGUN_XI_N = 7  # scale of the nonlinear (inertial) term xi_N [-]
ERGUN_C = 8  # drag degree c [-] (Ergun: 1)
ERGUN_PARAMETER_NAMES = ("mu", "rho", "diameter", "gamma", "xi_D", "xi_perp", "xi_par", "xi_N", "c")

WIND_NOISE_MODES = 6
"""Number of sinusoidal modes summed by the wind noise."""

PARALLEL_MIN_ITEMS = 4096
"""Kernels loop over vertices/elements in parallel (numba prange) from this many items on, serially
below it (a parallel launch costs ~10-50 us, more than a small hair strand's whole update)."""

_TWO_PI = 2.0 * math.pi


# ---------------------------------------------------------------------------------------------
# Wind
# ---------------------------------------------------------------------------------------------
@njit(cache=True)
def _hash_uniform(seed, index):
    """Deterministic uniform number in [0, 1) from (seed, index) (splitmix64)."""
    z = np.uint64(seed & 0x7FFFFFFFFFFFFFFF) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(index)
    z = z + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(cache=True)
def _hash_unit_vector(seed, index, out):
    z = 2.0 * _hash_uniform(seed, index) - 1.0
    phi = _TWO_PI * _hash_uniform(seed, index + 1)
    r = math.sqrt(max(0.0, 1.0 - z * z))
    out[0] = r * math.cos(phi)
    out[1] = r * math.sin(phi)
    out[2] = z


@njit(cache=True)
def _wind_item(x, i, base, kvec, avec, omega, phase, weight, t, out):
    u0 = base[0]
    u1 = base[1]
    u2 = base[2]
    for j in range(weight.shape[0]):
        s = weight[j] * math.sin(
            kvec[j, 0] * x[i, 0] + kvec[j, 1] * x[i, 1] + kvec[j, 2] * x[i, 2] - omega[j] * t + phase[j]
        )
        u0 += s * avec[j, 0]
        u1 += s * avec[j, 1]
        u2 += s * avec[j, 2]
    out[i, 0] = u0
    out[i, 1] = u1
    out[i, 2] = u2


@njit(cache=True)
def _wind_serial(x, base, kvec, avec, omega, phase, weight, t, out):
    for i in range(x.shape[0]):
        _wind_item(x, i, base, kvec, avec, omega, phase, weight, t, out)


@njit(cache=True, parallel=True)
def _wind_parallel(x, base, kvec, avec, omega, phase, weight, t, out):
    for i in prange(x.shape[0]):
        _wind_item(x, i, base, kvec, avec, omega, phase, weight, t, out)


@njit(cache=True)
def wind_velocity(x, t, direction, speed, noise, noise_scale, seed, out):
    """Air velocity [m/s] at positions ``x`` [m] (particle_count, 3) and time ``t`` [s], into ``out``.

    ``u(x, t) = speed * d + sum_j A_j a_j sin(k_j . x - omega_j t + phi_j)``, d = direction / |direction|
    (``direction`` array (3,); a zero direction gives no mean wind, only the gusts). The noise is a
    sum of ``WIND_NOISE_MODES`` plane waves: wavelengths ``noise_scale * 0.58^j`` [m] (noise_scale is
    the largest), wave directions k_j / |k_j| = normalize(d + 0.6 r_j) (gusts travel roughly
    downwind), phase speeds omega_j / |k_j| in [0.5, 1.5] * speed, amplitude directions a_j random
    unit vectors, amplitudes A_j ~ wavelength^(1/3) scaled so that the time-RMS of |u - speed d| is
    ``noise * |speed|``. r_j, a_j, phi_j and the phase speeds come from ``seed`` (integer) through a
    hash: the field is deterministic, smooth in space and time, and zero-mean in time at every point
    (omega_j != 0). ``noise`` is relative [-]; noise = 0, speed = 0 or noise_scale <= 0 give the
    uniform wind. Keyable parameters are evaluated by the caller at t; this takes scalars.
    """
    dn = math.sqrt(direction[0] ** 2 + direction[1] ** 2 + direction[2] ** 2)
    d = np.zeros(3)
    if dn > 0.0:
        for a in range(3):
            d[a] = direction[a] / dn
    base = d * speed
    amp = noise * speed
    K = WIND_NOISE_MODES
    if amp == 0.0 or not (noise_scale > 0.0) or not math.isfinite(noise_scale):
        K = 0
    kvec = np.empty((K, 3))
    avec = np.empty((K, 3))
    omega = np.empty(K)
    phase = np.empty(K)
    weight = np.empty(K)
    r = np.empty(3)
    wsum = 0.0
    for j in range(K):
        b = 16 * j
        wavelength = noise_scale * 0.58**j
        _hash_unit_vector(seed, b, r)
        kd0 = d[0] + 0.6 * r[0]
        kd1 = d[1] + 0.6 * r[1]
        kd2 = d[2] + 0.6 * r[2]
        kn = math.sqrt(kd0 * kd0 + kd1 * kd1 + kd2 * kd2)  # >= 0.4 when |d| = 1, = 0.6 when d = 0
        kmag = _TWO_PI / wavelength
        kvec[j, 0] = kd0 / kn * kmag
        kvec[j, 1] = kd1 / kn * kmag
        kvec[j, 2] = kd2 / kn * kmag
        omega[j] = kmag * speed * (0.5 + _hash_uniform(seed, b + 2))
        phase[j] = _TWO_PI * _hash_uniform(seed, b + 3)
        _hash_unit_vector(seed, b + 4, r)
        for a in range(3):
            avec[j, a] = r[a]
        weight[j] = (0.58**j) ** (1.0 / 3.0)
        wsum += weight[j] * weight[j]
    if K > 0:
        norm = amp * math.sqrt(2.0 / wsum)
        for j in range(K):
            weight[j] *= norm
    if x.shape[0] >= PARALLEL_MIN_ITEMS:
        _wind_parallel(x, base, kvec, avec, omega, phase, weight, t, out)
    else:
        _wind_serial(x, base, kvec, avec, omega, phase, weight, t, out)


# ---------------------------------------------------------------------------------------------
# Drag coefficients and element matrices
# ---------------------------------------------------------------------------------------------
@njit(cache=True)
def ergun_coefficients(dv_norm, mu, rho, diameter, gamma, xi_D, xi_perp, xi_par, xi_N, c):
    """Dimensionless Ergun drag coefficients ``(C_perp, C_par)`` at relative speed ``dv_norm`` [m/s].

    Supplement eq. (1)-(2): ``C_l = 1/k_l + xi_N 1.75 / sqrt(150 k_l) (1-gamma)^(-3/2) Re^c``,
    ``1/k_l = xi_D 1e-4 xi_l``, ``Re = rho D |dv| / mu``. ``1/sqrt(150 k_l)`` is computed as
    ``sqrt((1/k_l) / 150)``, so xi_l = 0 (infinite permeability) gives C_l = 0. Re^c at |dv| = 0 is
    0 for c > 0 and 1 for c = 0. mu [Pa s], rho [kg/m^3], diameter D [m], the rest dimensionless.
    """
    inv_k_perp = xi_D * 1e-4 * xi_perp
    inv_k_par = xi_D * 1e-4 * xi_par
    re = rho * diameter * dv_norm / mu
    if re > 0.0:
        p = re if c == 1.0 else re**c
    elif c > 0.0:
        p = 0.0
    else:
        p = 1.0
    g = xi_N * 1.75 * (1.0 - gamma) ** -1.5 * p
    c_perp = inv_k_perp + g * math.sqrt(inv_k_perp / 150.0)
    c_par = inv_k_par + g * math.sqrt(inv_k_par / 150.0)
    return c_perp, c_par


@njit(cache=True)
def _element_relative_velocity(v, u, elements, e, out):
    k = elements.shape[1]
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    for a in range(k):
        i = elements[e, a]
        for b in range(3):
            out[b] += v[i, b] - u[i, b]
    for b in range(3):
        out[b] /= k


@njit(cache=True)
def _set_axial_matrix(out_e, scale, c_iso, c_axis, n0, n1, n2):
    """out_e = scale * (c_iso I + (c_axis - c_iso) n n^T) for a unit vector n."""
    dc = c_axis - c_iso
    n = (n0, n1, n2)
    for a in range(3):
        for b in range(3):
            val = dc * n[a] * n[b]
            if a == b:
                val += c_iso
            out_e[a, b] = scale * val


@njit(cache=True)
def _face_drag_matrices_linear_item(x, faces, c_n, c_t, out, e):
    i = faces[e, 0]
    j = faces[e, 1]
    k = faces[e, 2]
    ax = x[j, 0] - x[i, 0]
    ay = x[j, 1] - x[i, 1]
    az = x[j, 2] - x[i, 2]
    bx = x[k, 0] - x[i, 0]
    by = x[k, 1] - x[i, 1]
    bz = x[k, 2] - x[i, 2]
    nx = ay * bz - az * by
    ny = az * bx - ax * bz
    nz = ax * by - ay * bx
    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
    if nn > 0.0:
        _set_axial_matrix(out[e], 0.5 * nn, c_t[e], c_n[e], nx / nn, ny / nn, nz / nn)
    else:
        out[e, :, :] = 0.0


@njit(cache=True)
def _face_drag_matrices_linear_serial(x, faces, c_n, c_t, out):
    for e in range(faces.shape[0]):
        _face_drag_matrices_linear_item(x, faces, c_n, c_t, out, e)


@njit(cache=True, parallel=True)
def _face_drag_matrices_linear_parallel(x, faces, c_n, c_t, out):
    for e in prange(faces.shape[0]):
        _face_drag_matrices_linear_item(x, faces, c_n, c_t, out, e)


@njit(cache=True)
def face_drag_matrices_linear(x, faces, c_n, c_t, out):
    """Linear anisotropic face drag matrices [kg/s] into ``out`` (face_count, 3, 3).

    ``De = A (c_n n n^T + c_t (I - n n^T))`` with A the triangle area [m^2], n its unit normal,
    ``c_n``, ``c_t`` (face_count,) drag coefficients per unit area [kg/(s m^2)] along the normal and in
    the plane. Degenerate (zero-area) triangles get a zero matrix.
    """
    if faces.shape[0] >= PARALLEL_MIN_ITEMS:
        _face_drag_matrices_linear_parallel(x, faces, c_n, c_t, out)
    else:
        _face_drag_matrices_linear_serial(x, faces, c_n, c_t, out)


@njit(cache=True)
def _edge_drag_matrices_linear_item(x, edges, c_n, c_t, out, e):
    i = edges[e, 0]
    j = edges[e, 1]
    dx = x[j, 0] - x[i, 0]
    dy = x[j, 1] - x[i, 1]
    dz = x[j, 2] - x[i, 2]
    L = math.sqrt(dx * dx + dy * dy + dz * dz)
    if L > 0.0:
        _set_axial_matrix(out[e], L, c_n[e], c_t[e], dx / L, dy / L, dz / L)
    else:
        out[e, :, :] = 0.0


@njit(cache=True)
def _edge_drag_matrices_linear_serial(x, edges, c_n, c_t, out):
    for e in range(edges.shape[0]):
        _edge_drag_matrices_linear_item(x, edges, c_n, c_t, out, e)


@njit(cache=True, parallel=True)
def _edge_drag_matrices_linear_parallel(x, edges, c_n, c_t, out):
    for e in prange(edges.shape[0]):
        _edge_drag_matrices_linear_item(x, edges, c_n, c_t, out, e)


@njit(cache=True)
def edge_drag_matrices_linear(x, edges, c_n, c_t, out):
    """Linear anisotropic rod drag matrices [kg/s] into ``out`` (edge_count, 3, 3).

    ``De = L (c_n (I - e e^T) + c_t e e^T)`` with L the edge length [m], e its unit direction,
    ``c_n`` (cross-flow) and ``c_t`` (along the rod), shape (edge_count,), per unit length [kg/(s m)].
    Zero-length edges get a zero matrix.
    """
    if edges.shape[0] >= PARALLEL_MIN_ITEMS:
        _edge_drag_matrices_linear_parallel(x, edges, c_n, c_t, out)
    else:
        _edge_drag_matrices_linear_serial(x, edges, c_n, c_t, out)


@njit(cache=True)
def _face_drag_matrices_ergun_item(x, v, u, faces, thickness, params, out, e):
    i = faces[e, 0]
    j = faces[e, 1]
    k = faces[e, 2]
    ax = x[j, 0] - x[i, 0]
    ay = x[j, 1] - x[i, 1]
    az = x[j, 2] - x[i, 2]
    bx = x[k, 0] - x[i, 0]
    by = x[k, 1] - x[i, 1]
    bz = x[k, 2] - x[i, 2]
    nx = ay * bz - az * by
    ny = az * bx - ax * bz
    nz = ax * by - ay * bx
    nn = math.sqrt(nx * nx + ny * ny + nz * nz)
    if not (nn > 0.0):
        out[e, :, :] = 0.0
        return
    dv0 = (v[i, 0] + v[j, 0] + v[k, 0] - u[i, 0] - u[j, 0] - u[k, 0]) / 3.0
    dv1 = (v[i, 1] + v[j, 1] + v[k, 1] - u[i, 1] - u[j, 1] - u[k, 1]) / 3.0
    dv2 = (v[i, 2] + v[j, 2] + v[k, 2] - u[i, 2] - u[j, 2] - u[k, 2]) / 3.0
    s = math.sqrt(dv0 * dv0 + dv1 * dv1 + dv2 * dv2)
    p = params[e]
    cp, cl = ergun_coefficients(s, p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8])
    volume = 0.5 * nn * thickness[e]
    scale = p[ERGUN_MU] * volume / (p[ERGUN_DIAMETER] * p[ERGUN_DIAMETER])
    _set_axial_matrix(out[e], scale, cl, cp, nx / nn, ny / nn, nz / nn)


@njit(cache=True)
def _face_drag_matrices_ergun_serial(x, v, u, faces, thickness, params, out):
    for e in range(faces.shape[0]):
        _face_drag_matrices_ergun_item(x, v, u, faces, thickness, params, out, e)


@njit(cache=True, parallel=True)
def _face_drag_matrices_ergun_parallel(x, v, u, faces, thickness, params, out):
    for e in prange(faces.shape[0]):
        _face_drag_matrices_ergun_item(x, v, u, faces, thickness, params, out, e)


@njit(cache=True)
def face_drag_matrices_ergun(x, v, u, faces, thickness, params, out):
    """Ergun anisotropic face drag matrices [kg/s] into ``out`` (face_count, 3, 3).

    ``De = (mu V / D^2) (C_par I + (C_perp - C_par) n n^T)`` (supplement eq. 3 with the face frame
    (n, t1, t2) and C = diag(C_perp, C_par, C_par)), V = area * ``thickness`` [m] (face_count,),
    ``params`` (face_count, 9) packed Ergun parameters (see ``pack_ergun_parameters``). C_l is
    evaluated at |dv|, dv the mean of v - u over the face's vertices (lagged). Degenerate faces: zero.
    """
    if faces.shape[0] >= PARALLEL_MIN_ITEMS:
        _face_drag_matrices_ergun_parallel(x, v, u, faces, thickness, params, out)
    else:
        _face_drag_matrices_ergun_serial(x, v, u, faces, thickness, params, out)


@njit(cache=True)
def _edge_drag_matrices_ergun_item(x, v, u, edges, radius, params, out, e):
    i = edges[e, 0]
    j = edges[e, 1]
    dx = x[j, 0] - x[i, 0]
    dy = x[j, 1] - x[i, 1]
    dz = x[j, 2] - x[i, 2]
    L = math.sqrt(dx * dx + dy * dy + dz * dz)
    if not (L > 0.0):
        out[e, :, :] = 0.0
        return
    dv0 = 0.5 * (v[i, 0] + v[j, 0] - u[i, 0] - u[j, 0])
    dv1 = 0.5 * (v[i, 1] + v[j, 1] - u[i, 1] - u[j, 1])
    dv2 = 0.5 * (v[i, 2] + v[j, 2] - u[i, 2] - u[j, 2])
    s = math.sqrt(dv0 * dv0 + dv1 * dv1 + dv2 * dv2)
    p = params[e]
    cp, cl = ergun_coefficients(s, p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8])
    volume = L * math.pi * radius[e] * radius[e]
    scale = p[ERGUN_MU] * volume / (p[ERGUN_DIAMETER] * p[ERGUN_DIAMETER])
    _set_axial_matrix(out[e], scale, cp, cl, dx / L, dy / L, dz / L)


@njit(cache=True)
def _edge_drag_matrices_ergun_serial(x, v, u, edges, radius, params, out):
    for e in range(edges.shape[0]):
        _edge_drag_matrices_ergun_item(x, v, u, edges, radius, params, out, e)


@njit(cache=True, parallel=True)
def _edge_drag_matrices_ergun_parallel(x, v, u, edges, radius, params, out):
    for e in prange(edges.shape[0]):
        _edge_drag_matrices_ergun_item(x, v, u, edges, radius, params, out, e)


@njit(cache=True)
def edge_drag_matrices_ergun(x, v, u, edges, radius, params, out):
    """Ergun anisotropic rod drag matrices [kg/s] into ``out`` (edge_count, 3, 3).

    ``De = (mu V / D^2) (C_perp I + (C_par - C_perp) e e^T)`` (supplement eq. 3 with
    C = diag(C_perp, C_perp, C_par), the edge direction e the "par" axis), V = L pi ``radius``^2,
    radius [m] (edge_count,) the rod's cross-section (D / 2 for a single fibre). ``params``
    (edge_count, 9) packed Ergun parameters. C_l at |dv| of the edge's mean relative velocity (lagged).
    """
    if edges.shape[0] >= PARALLEL_MIN_ITEMS:
        _edge_drag_matrices_ergun_parallel(x, v, u, edges, radius, params, out)
    else:
        _edge_drag_matrices_ergun_serial(x, v, u, edges, radius, params, out)


@njit(cache=True)
def scatter_element_matrices(elements, De, D):
    """Add each element matrix ``De`` (element_count, 3, 3) [kg/s], split equally over the element's
    vertices (1/3 per triangle vertex, 1/2 per edge vertex), into ``D`` (particle_count, 3, 3)."""
    k = elements.shape[1]
    w = 1.0 / k
    for e in range(elements.shape[0]):
        for a in range(k):
            i = elements[e, a]
            for r in range(3):
                for c in range(3):
                    D[i, r, c] += w * De[e, r, c]


@njit(cache=True)
def accumulate_isotropic_drag(b, D):
    """Add isotropic linear drag ``b_i I`` into ``D`` (particle_count, 3, 3); ``b`` [kg/s] per particle
    (particle_count,), paintable."""
    for i in range(D.shape[0]):
        for a in range(3):
            D[i, a, a] += b[i]


@njit(cache=True)
def vertex_to_element(values, elements, out):
    """Mean of per-vertex ``values`` (particle_count,) over each element's vertices into ``out``
    (element_count,): turns a painted per-vertex parameter into a per-element one."""
    k = elements.shape[1]
    for e in range(elements.shape[0]):
        s = 0.0
        for a in range(k):
            s += values[elements[e, a]]
        out[e] = s / k


# ---------------------------------------------------------------------------------------------
# Implicit update, force, power
# ---------------------------------------------------------------------------------------------
@njit(cache=True)
def _solve_drag_3x3(v, i, mass, D, u, h):
    """v[i] <- u_i + (mass I + h S_i)^-1 mass (v_i - u_i), S_i = (D_i + D_i^T) / 2.

    Closed-form 3x3 Cholesky of the matrix scaled to unit size (backward stable for any h |D| / m).
    Schur-complement pivots are kept >= the scaled mass (their exact-arithmetic lower bound for a PSD
    D), and the result is clamped to |v' - u| <= |v - u|, the exact-arithmetic property, so rounding
    in ill-conditioned cases (h |D| / m ~ 1e10 with a singular D) cannot add energy.
    """
    s = mass
    for r in range(3):
        for c in range(3):
            s = max(s, h * abs(D[i, r, c]))
    inv = 1.0 / s
    ms = mass * inv
    hs = h * inv
    a00 = ms + hs * D[i, 0, 0]
    a11 = ms + hs * D[i, 1, 1]
    a22 = ms + hs * D[i, 2, 2]
    a10 = 0.5 * hs * (D[i, 1, 0] + D[i, 0, 1])
    a20 = 0.5 * hs * (D[i, 2, 0] + D[i, 0, 2])
    a21 = 0.5 * hs * (D[i, 2, 1] + D[i, 1, 2])
    w0 = v[i, 0] - u[i, 0]
    w1 = v[i, 1] - u[i, 1]
    w2 = v[i, 2] - u[i, 2]
    # Cholesky A = L L^T
    l00 = math.sqrt(max(a00, ms))
    l10 = a10 / l00
    l20 = a20 / l00
    l11 = math.sqrt(max(a11 - l10 * l10, ms))
    l21 = (a21 - l20 * l10) / l11
    l22 = math.sqrt(max(a22 - l20 * l20 - l21 * l21, ms))
    # forward: L y = ms w
    y0 = ms * w0 / l00
    y1 = (ms * w1 - l10 * y0) / l11
    y2 = (ms * w2 - l20 * y0 - l21 * y1) / l22
    # backward: L^T z = y
    z2 = y2 / l22
    z1 = (y1 - l21 * z2) / l11
    z0 = (y0 - l10 * z1 - l20 * z2) / l00
    wn = w0 * w0 + w1 * w1 + w2 * w2
    zn = z0 * z0 + z1 * z1 + z2 * z2
    if zn > wn:
        f = math.sqrt(wn / zn)
        z0 *= f
        z1 *= f
        z2 *= f
    v[i, 0] = u[i, 0] + z0
    v[i, 1] = u[i, 1] + z1
    v[i, 2] = u[i, 2] + z2


@njit(cache=True)
def _implicit_drag_update_item(v, m, D, u, h, i):
    mi = m[i]
    if mi > 0.0 and mi < np.inf:
        _solve_drag_3x3(v, i, mi, D, u, h)


@njit(cache=True)
def _implicit_drag_update_serial(v, m, D, u, h):
    for i in range(v.shape[0]):
        _implicit_drag_update_item(v, m, D, u, h, i)


@njit(cache=True, parallel=True)
def _implicit_drag_update_parallel(v, m, D, u, h):
    for i in prange(v.shape[0]):
        _implicit_drag_update_item(v, m, D, u, h, i)


@njit(cache=True)
def implicit_drag_update(v, m, D, u, h):
    """In place, per particle: ``(m_i I + h D_i) v_i' = m_i v_i + h D_i u_i``.

    v [m/s] (particle_count, 3), m [kg] (particle_count,), D [kg/s] (particle_count, 3, 3), u [m/s]
    (particle_count, 3), h [s]. Solved as ``v' = u + (m I + h D)^-1 m (v - u)`` with a closed-form
    3x3 Cholesky factorisation. D must be symmetric positive semi-definite (the assembled drag
    matrices are); the solve uses its symmetric part. Particles with m_i = inf (kinematic) or
    m_i <= 0 are left unchanged.
    """
    if v.shape[0] >= PARALLEL_MIN_ITEMS:
        _implicit_drag_update_parallel(v, m, D, u, h)
    else:
        _implicit_drag_update_serial(v, m, D, u, h)


@njit(cache=True)
def _implicit_drag_update_inv_mass_item(v, inv_m, D, u, h, i):
    w = inv_m[i]
    if w > 0.0 and w < np.inf:
        _solve_drag_3x3(v, i, 1.0 / w, D, u, h)


@njit(cache=True)
def _implicit_drag_update_inv_mass_serial(v, inv_m, D, u, h):
    for i in range(v.shape[0]):
        _implicit_drag_update_inv_mass_item(v, inv_m, D, u, h, i)


@njit(cache=True, parallel=True)
def _implicit_drag_update_inv_mass_parallel(v, inv_m, D, u, h):
    for i in prange(v.shape[0]):
        _implicit_drag_update_inv_mass_item(v, inv_m, D, u, h, i)


@njit(cache=True)
def implicit_drag_update_inv_mass(v, inv_m, D, u, h):
    """As ``implicit_drag_update`` with inverse masses ``inv_m`` [1/kg] (particle_count,):
    ``(I + h w_i D_i) v_i' = v_i + h w_i D_i u_i``; w_i = 0 (pinned, kinematic) leaves v_i unchanged."""
    if v.shape[0] >= PARALLEL_MIN_ITEMS:
        _implicit_drag_update_inv_mass_parallel(v, inv_m, D, u, h)
    else:
        _implicit_drag_update_inv_mass_serial(v, inv_m, D, u, h)


@njit(cache=True)
def drag_force(v, D, u, out):
    """Drag force [N] ``f_i = -D_i (v_i - u_i)`` into ``out`` (particle_count, 3) (overwrites)."""
    for i in range(v.shape[0]):
        w0 = v[i, 0] - u[i, 0]
        w1 = v[i, 1] - u[i, 1]
        w2 = v[i, 2] - u[i, 2]
        for a in range(3):
            out[i, a] = -(D[i, a, 0] * w0 + D[i, a, 1] * w1 + D[i, a, 2] * w2)


@njit(cache=True)
def drag_power(v, D, u):
    """Mechanical power [W] of drag on the particles, ``sum_i v_i . f_i`` with f_i = -D_i (v_i - u_i).

    <= 0 in still air for PSD D (drag only removes energy); in wind it can be positive. The rate at
    which drag dissipates energy is ``sum_i dv_i^T D_i dv_i >= 0`` (``-drag_power(v, D, u)`` with
    u = 0 and v = dv).
    """
    p = 0.0
    for i in range(v.shape[0]):
        w0 = v[i, 0] - u[i, 0]
        w1 = v[i, 1] - u[i, 1]
        w2 = v[i, 2] - u[i, 2]
        for a in range(3):
            p -= v[i, a] * (D[i, a, 0] * w0 + D[i, a, 1] * w1 + D[i, a, 2] * w2)
    return p


# ---------------------------------------------------------------------------------------------
# Lift
# ---------------------------------------------------------------------------------------------
@njit(cache=True)
def accumulate_lift(x, v, u, elements, De, xi_L, f):
    """Add the explicit lift force [N] (supplement eq. 4) of each element into ``f`` (particle_count, 3).

    ``elements`` (element_count, 3) faces or (element_count, 2) rod edges, ``De`` their drag matrices
    [kg/s] (element_count, 3, 3) from the matching ``*_drag_matrices_*`` call (same v, u), ``xi_L``
    (element_count,) lift scale [-]. dv = mean of v - u over the element, f_drag = -De dv,
    ``f_lift = -xi_L (Q - (Q.dv)/|dv|^2 dv)``, ``Q = e_par x (e_par x f_drag)``; e_par = edge direction
    for rods, the in-plane direction of dv for faces (see the module docstring). The element's lift is
    split equally over its vertices. No lift (exactly zero) when |dv|^2 <= 1e-300, xi_L = 0, for a
    degenerate element, or for a face whose dv is along its normal (where the lift is zero in the limit).
    """
    k = elements.shape[1]
    w = 1.0 / k
    dv = np.empty(3)
    fd = np.empty(3)
    ep = np.empty(3)
    for e in range(elements.shape[0]):
        xl = xi_L[e]
        if xl == 0.0:
            continue
        _element_relative_velocity(v, u, elements, e, dv)
        s2 = dv[0] * dv[0] + dv[1] * dv[1] + dv[2] * dv[2]
        if not (s2 > 1e-300):
            continue
        i0 = elements[e, 0]
        i1 = elements[e, 1]
        if k == 2:
            ep[0] = x[i1, 0] - x[i0, 0]
            ep[1] = x[i1, 1] - x[i0, 1]
            ep[2] = x[i1, 2] - x[i0, 2]
        else:
            i2 = elements[e, 2]
            ax = x[i1, 0] - x[i0, 0]
            ay = x[i1, 1] - x[i0, 1]
            az = x[i1, 2] - x[i0, 2]
            bx = x[i2, 0] - x[i0, 0]
            by = x[i2, 1] - x[i0, 1]
            bz = x[i2, 2] - x[i0, 2]
            nx = ay * bz - az * by
            ny = az * bx - ax * bz
            nz = ax * by - ay * bx
            nn = math.sqrt(nx * nx + ny * ny + nz * nz)
            if not (nn > 0.0):
                continue
            nx /= nn
            ny /= nn
            nz /= nn
            dn = dv[0] * nx + dv[1] * ny + dv[2] * nz
            ep[0] = dv[0] - dn * nx
            ep[1] = dv[1] - dn * ny
            ep[2] = dv[2] - dn * nz
            if not (ep[0] * ep[0] + ep[1] * ep[1] + ep[2] * ep[2] > 1e-24 * s2):
                continue  # dv along the normal: symmetric, no lift
        el = math.sqrt(ep[0] * ep[0] + ep[1] * ep[1] + ep[2] * ep[2])
        if not (el > 0.0):
            continue
        for a in range(3):
            ep[a] /= el
        for a in range(3):
            fd[a] = -(De[e, a, 0] * dv[0] + De[e, a, 1] * dv[1] + De[e, a, 2] * dv[2])
        ef = ep[0] * fd[0] + ep[1] * fd[1] + ep[2] * fd[2]
        # Q = e x (e x f) = (e.f) e - f for unit e
        q0 = ef * ep[0] - fd[0]
        q1 = ef * ep[1] - fd[1]
        q2 = ef * ep[2] - fd[2]
        qd = (q0 * dv[0] + q1 * dv[1] + q2 * dv[2]) / s2
        l0 = -xl * (q0 - qd * dv[0]) * w
        l1 = -xl * (q1 - qd * dv[1]) * w
        l2 = -xl * (q2 - qd * dv[2]) * w
        for a in range(k):
            i = elements[e, a]
            f[i, 0] += l0
            f[i, 1] += l1
            f[i, 2] += l2


# ---------------------------------------------------------------------------------------------
# Parameters (Python level: called at compile time, not per step)
# ---------------------------------------------------------------------------------------------
def pack_ergun_parameters(
    count,
    *,
    diameter,
    gamma,
    mu=AIR_VISCOSITY,
    rho=AIR_DENSITY,
    xi_D=1.0,
    xi_perp=1.0,
    xi_par=1.0,
    xi_N=1.0,
    c=1.0,
):
    """Packed per-element Ergun parameters, float64 array (count, 9), columns ``ERGUN_PARAMETER_NAMES``.

    Each argument is a scalar or an array of shape (count,) (per element; use ``vertex_to_element``
    for painted per-vertex values). Units: mu [Pa s], rho [kg/m^3], diameter [m], the rest [-].
    Defaults: air at 20 C, all scales 1, drag degree c = 1 (Ergun). Not validated here: see
    ``validate_ergun_parameters``.
    """
    out = np.empty((count, len(ERGUN_PARAMETER_NAMES)))
    values = (mu, rho, diameter, gamma, xi_D, xi_perp, xi_par, xi_N, c)
    for col, (name, val) in enumerate(zip(ERGUN_PARAMETER_NAMES, values)):
        arr = np.asarray(val, dtype=np.float64)
        if arr.ndim not in (0, 1) or (arr.ndim == 1 and arr.shape[0] != count):
            raise ValueError(f"{name}: expected a scalar or shape ({count},), got shape {arr.shape}")
        out[:, col] = arr
    return out


def validate_ergun_parameters(params, element_kind="element"):
    """Check packed Ergun parameters (count, 9); returns a sorted list of messages (empty when valid).

    Rules: all finite; mu > 0, diameter > 0, 0 <= gamma < 1, rho, xi_D, xi_perp, xi_par, xi_N, c >= 0.
    Each message names the parameter, how many values fail and the worst index, e.g.
    ``gamma: 2 elements must satisfy 0 <= gamma < 1 (worst 1.3 at element 7)``.
    """
    params = np.asarray(params, dtype=np.float64)
    errors = []
    if params.ndim != 2 or params.shape[1] != len(ERGUN_PARAMETER_NAMES):
        return [f"ergun parameters: expected shape (count, {len(ERGUN_PARAMETER_NAMES)}), got {params.shape}"]
    for col, name in enumerate(ERGUN_PARAMETER_NAMES):
        a = params[:, col]
        if name in ("mu", "diameter"):
            bad = ~(a > 0.0) | ~np.isfinite(a)
            rule = f"{name} > 0"
            badness = np.where(np.isfinite(a), -a, np.inf)
        elif name == "gamma":
            bad = ~((a >= 0.0) & (a < 1.0))
            rule = "0 <= gamma < 1"
            badness = np.where(np.isfinite(a), np.maximum(-a, a - 1.0), np.inf)
        else:
            bad = ~(a >= 0.0) | ~np.isfinite(a)
            rule = f"{name} >= 0"
            badness = np.where(np.isfinite(a), -a, np.inf)
        if np.any(bad):
            idx = np.flatnonzero(bad)
            worst = int(idx[np.argmax(np.where(np.isnan(a[idx]), np.inf, badness[idx]))])
            errors.append(
                f"{name}: {idx.size} {element_kind}s must satisfy {rule} "
                f"(worst {float(a[worst])!r} at {element_kind} {worst})"
            )
    return sorted(errors)


def drummond_tahir_inverse_permeability(solid_fraction, c3=4.076):
    """Dimensionless inverse permeabilities ``(d^2/K_perp, d^2/K_par)`` of a square array of parallel
    fibres (Drummond & Tahir 1984), solid fraction phi in (0, ~0.4):
    ``K_par/d^2 = (-ln phi - 1.476 + 2 phi - 0.5 phi^2) / (16 phi)``,
    ``K_perp/d^2 = (-ln phi - 1.476 + 2 phi - 1.774 phi^2 + c3 phi^3) / (32 phi)``.
    A physical starting point for eq. (2): ``xi_l = 1e4 / xi_D * d^2/K_l`` (flow across the fibres of a
    rod is its "perp" direction; mapping yarn directions to a face's normal is the user's choice).
    Arrays or scalars.
    """
    phi = np.asarray(solid_fraction, dtype=np.float64)
    lp = -np.log(phi)
    k_par = (lp - 1.476 + 2.0 * phi - 0.5 * phi**2) / (16.0 * phi)
    k_perp = (lp - 1.476 + 2.0 * phi - 1.774 * phi**2 + c3 * phi**3) / (32.0 * phi)
    return 1.0 / k_perp, 1.0 / k_par
