"""Contacts with analytic colliders (``ShapeCollider``: plane, sphere, capsule) inside the
implicit Newton solve, with smoothed Coulomb friction lagged from the previous Newton iterate.

For every free vertex i and shape s, with d_is(x) the signed distance of x_i to the shape's
surface pushed out by the collider's thickness (the radii ``ShapeCollisionConstraint`` binds)
and n_is its outward normal, the incremental potential gets

    penalty   P = k_i / 2 * min(d_is(x), 0)^2,          k_i = contact_stiffness * m_i / h^2
    friction  F = mu_s * lam_is * f0(|u_is|),           u_is = (I - n n^T) (x_i - x_i^n)

(IPC's smoothed friction, Li et al. 2020 eq. 14-16): ``lam_is = k_i * max(-d_is, 0)`` and
``n_is`` are taken at the previous Newton iterate (lagged, so F is a potential within one
Newton iteration and its line search), and f0 is C1 with f0'(y) = f1(y) = 2 y / eps - y^2 /
eps^2 below ``eps = friction_velocity * h`` and 1 above: the friction force
-mu lam f1(|u|) u / |u| is exact Coulomb for tangential speeds above ``friction_velocity`` and a
stiff viscous stick below it. Hessian blocks (3x3, per vertex, so on the diagonal of the Newton
matrix): the penalty's Gauss-Newton ``k n n^T`` (the curvature term of a sphere / capsule,
negative inside, is dropped) and the friction's exact tangential Hessian, which is PSD for f1
as above (eigenvalues mu lam (2/eps - 2y/eps^2) along u and mu lam f1(y)/y across).

Augmented Lagrangian (``contact_multipliers``, the default; ``contact_energy_al``): the
penalty carries a multiplier M_is [N] over from one substep to the next, P = ((M - k d)_+^2 -
M^2) / (2 k) with the normal force lam = (M - k d)_+, updated after every substep by
``update_contact_multipliers`` (M <- (M - k d)_+ at the solved positions, before the safety
projection). At rest M converges to the normal force and d to 0, whatever load presses the
vertex: the plain penalty's penetration is load / k with k from the vertex's *own* mass, up to
0.5 mm for a light rope vertex wrapped round a drum under the tension of a heavy weight
(tests/test_implicit_capstan.py, where the sticking rope then creeps by 0.7 mm over 1.5 s
instead of 0.012 mm, in 19 Newton iterations per substep instead of 6: graphs/bench/capstan.py
ablation); with M = 0 (no contact last substep) it is the plain penalty, bitwise.

A vertex that ends the Newton solve inside a shape (the penalty leaves a small penetration,
~ m g / k at rest without multipliers) is pushed out along the normal by ``safety_project``
(no friction), and the solver reports the largest such move.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ...collision.narrowphase import row_coefficients


@njit(cache=True)
def _friction_f0(y, eps):
    """IPC's smoothed friction at tangential displacement y: (f0(y), f1(y) / y), with
    f0 = -y^3 / (3 eps^2) + y^2 / eps + eps / 3 below eps and y above (energy = mu lam f0)."""
    if y < eps:
        return -y * y * y / (3.0 * eps * eps) + y * y / eps + eps / 3.0, 2.0 / eps - y / (eps * eps)
    return y, 1.0 / y


@njit(cache=True)
def _friction_cu(y, eps, ml, floor):
    """Coefficient of the -u u^T term of the friction Hessian block; ml = mu lam. ``floor``
    in [0, 1]: the block's curvature along u is kept at least ``floor`` times its curvature
    across u (mu lam f1(y) / y): 0 is IPC's exact PSD block (0 along u while sliding), 1 the
    IRLS majorizer (``friction_hessian: irls``, no -u u^T term)."""
    if floor >= 1.0:
        return 0.0
    if y < eps:
        cu = ml / (eps * eps * y) if y > 0.0 else 0.0
    else:
        cu = ml / (y * y * y)
    if floor > 0.0 and y > 0.0:
        f1y = 2.0 / eps - y / (eps * eps) if y < eps else 1.0 / y
        cu = min(cu, (1.0 - floor) * ml * f1y / (y * y))
    return cu

_PLANE, _SPHERE, _CAPSULE = 0, 1, 2  # as behaviors/collision/shapes.py


@njit(cache=True)
def _dist(x, i, s, kinds, centers, dirs, radii, lengths, n_out):
    """Signed distance of vertex i to shape s minus its radius (+ thickness); the outward normal
    into n_out. Returns 1e300 where the normal is undefined (on a sphere's centre)."""
    px, py, pz = x[i, 0], x[i, 1], x[i, 2]
    cx, cy, cz = centers[s, 0], centers[s, 1], centers[s, 2]
    if kinds[s] == _PLANE:
        nx, ny, nz = dirs[s, 0], dirs[s, 1], dirs[s, 2]
        n_out[0], n_out[1], n_out[2] = nx, ny, nz
        return (px - cx) * nx + (py - cy) * ny + (pz - cz) * nz - radii[s]
    qx, qy, qz = cx, cy, cz
    if kinds[s] == _CAPSULE:
        ax, ay, az = dirs[s, 0], dirs[s, 1], dirs[s, 2]
        t = (px - cx) * ax + (py - cy) * ay + (pz - cz) * az
        hl = 0.5 * lengths[s]
        t = min(max(t, -hl), hl)
        qx, qy, qz = cx + t * ax, cy + t * ay, cz + t * az
    rx, ry, rz = px - qx, py - qy, pz - qz
    r = np.sqrt(rx * rx + ry * ry + rz * rz)
    if r < 1e-15:
        return 1e300
    n_out[0], n_out[1], n_out[2] = rx / r, ry / r, rz / r
    return r - radii[s]


@njit(cache=True)
def lag_contacts(x, fixed, kinds, centers, dirs, radii, lengths, kc, lam, nrm):
    """Normal forces lam[i, s] = k_i max(-d, 0) and normals nrm[i, s] at x (the lagged values
    of the friction). Returns the number of active (vertex, shape) contacts."""
    return lag_contacts_al(x, fixed, kinds, centers, dirs, radii, lengths, kc,
                           np.zeros_like(lam), lam, nrm)


@njit(cache=True)
def lag_contacts_al(x, fixed, kinds, centers, dirs, radii, lengths, kc, mult, lam, nrm):
    """Normal forces lam[i, s] = max(mult[i, s] - k_i d, 0) (augmented Lagrangian with the
    multipliers ``mult`` [N] carried over from the last substep; k_i max(-d, 0) without) and
    normals nrm[i, s] at x (the lagged values of the friction). Returns the number of active
    (vertex, shape) contacts."""
    n = x.shape[0]
    ns = kinds.shape[0]
    nb = np.zeros(3)
    count = 0
    for i in range(n):
        for s in range(ns):
            lam[i, s] = 0.0
            if fixed[i]:
                continue
            d = _dist(x, i, s, kinds, centers, dirs, radii, lengths, nb)
            L = mult[i, s]
            if L > 0.0:
                f = L - kc[i] * d
                if f > 0.0:
                    lam[i, s] = f
                    nrm[i, s, 0], nrm[i, s, 1], nrm[i, s, 2] = nb[0], nb[1], nb[2]
                    count += 1
            elif d < 0.0:
                lam[i, s] = -kc[i] * d
                nrm[i, s, 0], nrm[i, s, 1], nrm[i, s, 2] = nb[0], nb[1], nb[2]
                count += 1
    return count


@njit(cache=True)
def update_contact_multipliers(x, fixed, kinds, centers, dirs, radii, lengths, kc, mult):
    """After a substep's Newton solve (before the safety projection): mult <- max(mult - k d,
    0), the augmented Lagrangian update; mult converges to the normal force of a resting
    contact and its penetration to 0."""
    n = x.shape[0]
    ns = kinds.shape[0]
    nb = np.zeros(3)
    for i in range(n):
        for s in range(ns):
            if fixed[i]:
                mult[i, s] = 0.0
                continue
            d = _dist(x, i, s, kinds, centers, dirs, radii, lengths, nb)
            f = mult[i, s] - kc[i] * d
            mult[i, s] = f if f > 0.0 else 0.0


@njit(cache=True)
def contact_energy(x, x0, fixed, kinds, centers, dirs, radii, lengths, mus, kc, lam, nrm, eps,
                   mode, grad, A, diag, floor):
    """Penalty + lagged friction energy at x (module docstring); mode >= 1 adds the gradient
    into grad, mode >= 2 adds the 3x3 Hessian blocks into A[diag[i]]; ``floor``: the friction
    block's curvature along the slip (``_friction_cu``: 0 exact, 1 IRLS)."""
    return contact_energy_al(x, x0, fixed, kinds, centers, dirs, radii, lengths, mus, kc,
                             np.zeros_like(lam), lam, nrm, eps, mode, grad, A, diag, floor)


@njit(cache=True)
def contact_energy_al(x, x0, fixed, kinds, centers, dirs, radii, lengths, mus, kc, mult, lam,
                      nrm, eps, mode, grad, A, diag, floor):
    """``contact_energy`` with the augmented Lagrangian multipliers ``mult`` [N]: where
    mult[i, s] > 0 the penalty is ((mult - k d)_+^2 - mult^2) / (2 k) (force (mult - k d)_+
    along the normal, Hessian k n n^T while it pushes); where it is 0, k / 2 min(d, 0)^2."""
    n = x.shape[0]
    ns = kinds.shape[0]
    nb = np.zeros(3)
    u = np.zeros(3)
    E = 0.0
    for i in range(n):
        if fixed[i]:
            continue
        for s in range(ns):
            d = _dist(x, i, s, kinds, centers, dirs, radii, lengths, nb)
            M = mult[i, s]
            if M > 0.0:
                k = kc[i]
                f = M - k * d
                if f > 0.0:
                    E += 0.5 * (f * f - M * M) / k
                    if mode >= 1:
                        for r in range(3):
                            grad[i, r] -= f * nb[r]
                    if mode >= 2:
                        b = diag[i]
                        for r in range(3):
                            for c in range(3):
                                A[b, r, c] += k * nb[r] * nb[c]
                else:
                    E -= 0.5 * M * M / k
            elif d < 0.0:
                k = kc[i]
                E += 0.5 * k * d * d
                if mode >= 1:
                    for r in range(3):
                        grad[i, r] += k * d * nb[r]
                if mode >= 2:
                    b = diag[i]
                    for r in range(3):
                        for c in range(3):
                            A[b, r, c] += k * nb[r] * nb[c]
            L = lam[i, s]
            mu = mus[s]
            if L <= 0.0 or mu <= 0.0:
                continue
            ml = mu * L
            # tangential displacement of the substep with the lagged normal
            n0, n1, n2 = nrm[i, s, 0], nrm[i, s, 1], nrm[i, s, 2]
            dx0 = x[i, 0] - x0[i, 0]
            dx1 = x[i, 1] - x0[i, 1]
            dx2 = x[i, 2] - x0[i, 2]
            dn = dx0 * n0 + dx1 * n1 + dx2 * n2
            u[0], u[1], u[2] = dx0 - dn * n0, dx1 - dn * n1, dx2 - dn * n2
            y = np.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
            f0, f1y = _friction_f0(y, eps)
            E += ml * f0
            if mode >= 1:
                for r in range(3):
                    grad[i, r] += ml * f1y * u[r]
            if mode >= 2:
                b = diag[i]
                cu = _friction_cu(y, eps, ml, floor)
                for r in range(3):
                    for c in range(3):
                        p = (1.0 if r == c else 0.0) - nrm[i, s, r] * nrm[i, s, c]
                        A[b, r, c] += ml * f1y * p - cu * u[r] * u[c]
    return E


@njit(cache=True)
def safety_project(x, fixed, kinds, centers, dirs, radii, lengths):
    """Push every free vertex inside a shape out along its normal; returns the largest move."""
    n = x.shape[0]
    ns = kinds.shape[0]
    nb = np.zeros(3)
    worst = 0.0
    for _ in range(2):  # a second pass for vertices pushed into another shape
        for i in range(n):
            if fixed[i]:
                continue
            for s in range(ns):
                d = _dist(x, i, s, kinds, centers, dirs, radii, lengths, nb)
                if d < 0.0:
                    for r in range(3):
                        x[i, r] -= d * nb[r]
                    if -d > worst:
                        worst = -d
    return worst


# -- contact rows of the collision pipeline (CollisionDetect's vertex-face / edge-edge sets) --
#
# A row r couples 4 vertices with coefficients c[r] (vertex-face: 1, -b0, -b1, -b2 with the
# closest point's barycentrics; edge-edge: 1 - s, s, -(1 - t), -t) along the contact normal n_r
# the detection took at the start of the substep: gap C_r = n_r . sum_a c_a x_a - target_r.
# Energy: k_r / 2 min(C_r, 0)^2 + mu_r lam_r f0(|u_r|), u_r = (I - n n^T) sum_a c_a (x_a - x_a^n),
# with c, lam_r = k_r max(-C_r, 0) lagged from the previous Newton iterate (so the energy is
# exactly what its gradient says within one Newton iteration). Hessian: the diagonal 3x3 blocks
# c_a^2 (k n n^T + friction block) of the rank-structured row Hessian only (the block diagonal
# of a PSD matrix is PSD; the pattern of the Newton matrix stays fixed): a quasi-Newton
# direction, exact for a vertex against a kinematic collider.


#: ``implicit_solver.edge_endpoint_rows`` as the mode of the vertices of triangle meshes in the
#: lag kernels' ``endpoints`` array (per vertex; 0 at the vertices of curves, which have no
#: faces whose vertex-face rows could hold an end's contact)
ENDPOINTS = {"keep": 0, "skip": 1, "skip_collider": 2}
#: no ``endpoints`` array: every row kept
NO_ENDPOINTS = np.zeros(0, np.int8)


@njit(cache=True, inline="always")
def _endpoint_row(fixed, rows, coef, r, endpoints):
    """Is edge-edge row r (coefficients 1 - s, s, -(1 - t), -t lagged) one that
    ``edge_endpoint_rows`` leaves out? Its mode is the smallest of its four vertices'
    ``endpoints``: 1 its closest point is an end of either edge (s or t is 0 or 1; the
    vertex-face rows of that end hold the same contact), 2 only where that end is a collider's
    (both vertices of the clamped edge Dirichlet) and the closest point on the other edge is
    inside it (a collider's vertex against the inside of an edge: the rows of that vertex
    against the edge's faces hold it), 0 none."""
    mode = min(min(endpoints[rows[r, 0]], endpoints[rows[r, 1]]),
               min(endpoints[rows[r, 2]], endpoints[rows[r, 3]]))
    if mode == 0:
        return False
    ca = coef[r, 0] == 0.0 or coef[r, 1] == 0.0
    cb = coef[r, 2] == 0.0 or coef[r, 3] == 0.0
    if mode == 1:
        return ca or cb
    if cb and not ca and fixed[rows[r, 2]] and fixed[rows[r, 3]]:
        return True
    return ca and not cb and fixed[rows[r, 0]] and fixed[rows[r, 1]]


@njit(cache=True, inline="always")
def _lag_row(x, fixed, mass, h2k, rows, nrm, target, is_vf, coef, kr, lam, r,
             endpoints=NO_ENDPOINTS):
    """``lag_rows`` for row r; returns 1 where the row is active (C < 0, a free vertex).
    ``endpoints`` (int8 per vertex, ``ENDPOINTS``; empty: none): edge-edge rows left out of the
    energy (stiffness 0)."""
    _, coef[r, 0], coef[r, 1], coef[r, 2], coef[r, 3] = row_coefficients(x, rows, is_vf, r)
    mk = 0.0
    for j in range(4):
        a = rows[r, j]
        if not fixed[a] and coef[r, j] != 0.0 and mass[a] > mk:
            mk = mass[a]
    if endpoints.shape[0] and not is_vf and _endpoint_row(fixed, rows, coef, r, endpoints):
        mk = 0.0
    kr[r] = h2k * mk
    C = -target[r]
    for j in range(4):
        a = rows[r, j]
        for q in range(3):
            C += coef[r, j] * x[a, q] * nrm[r, q]
    lam[r] = -kr[r] * C if C < 0.0 else 0.0
    return 1 if (C < 0.0 and mk > 0.0) else 0


@njit(cache=True)
def lag_rows(x, fixed, mass, h2k, rows, nrm, target, is_vf, coef, kr, lam,
             endpoints=NO_ENDPOINTS):
    """Coefficients coef[r] (closest points at x), row stiffness kr[r] = h2k * the largest
    mass of its free vertices (0 for the rows ``endpoints`` leaves out, ``_endpoint_row``), and
    the normal forces lam[r] at x. Returns the active count."""
    count = 0
    for r in range(rows.shape[0]):
        count += _lag_row(x, fixed, mass, h2k, rows, nrm, target, is_vf, coef, kr, lam, r,
                          endpoints)
    return count


#: slack [m] of the live-row test against the rounding of the gap sums (~1e-15 m)
LIVE_SLACK = 1e-10


@njit(cache=True, inline="always")
def _gap_bound(x, rows, nrm, target, is_vf, r):
    """A lower bound of the gap C_r = n_r . sum_a c_a x_a - target_r over every closest-point
    coefficient vector c (convex on each side: vertex-face 1, -b with b barycentric; edge-edge
    1 - s, s, -(1 - t), -t with s, t in [0, 1]): the smallest n . x of side one minus the
    largest of side two. A min of linear functions of x, so concave: where it is >= 0 at both
    ends of a segment, C is >= 0 all along it, whatever coefficients the row is lagged with."""
    n0, n1, n2 = nrm[r, 0], nrm[r, 1], nrm[r, 2]
    a, b, c, e = rows[r, 0], rows[r, 1], rows[r, 2], rows[r, 3]
    p0 = x[a, 0] * n0 + x[a, 1] * n1 + x[a, 2] * n2
    p1 = x[b, 0] * n0 + x[b, 1] * n1 + x[b, 2] * n2
    p2 = x[c, 0] * n0 + x[c, 1] * n1 + x[c, 2] * n2
    p3 = x[e, 0] * n0 + x[e, 1] * n1 + x[e, 2] * n2
    if is_vf:
        return p0 - max(p1, max(p2, p3)) - target[r]
    return min(p0, p1) - max(p2, p3) - target[r]


@njit(cache=True, inline="always")
def _live_row(x, fixed, mass, h2k, rows, nrm, target, is_vf, coef, kr, lam, reach, mark, sel, r,
              count, ns, dl, top, dgap, endpoints):
    """The visit of row r by ``lag_rows_live`` / ``lag_rows_sel``: a live row (normal force
    > 0, or gap bound below ``reach`` + ``LIVE_SLACK``) is lagged, marked and appended to
    ``sel`` at ``ns``; any other gets lam 0 and is unmarked. Returns the running (active
    count, live count, largest |change| of a normal force, largest normal force, largest
    change over stiffness)."""
    old = lam[r]
    if old > 0.0 or _gap_bound(x, rows, nrm, target, is_vf, r) < reach + LIVE_SLACK:
        count += _lag_row(x, fixed, mass, h2k, rows, nrm, target, is_vf, coef, kr, lam, r,
                          endpoints)
        mark[r] = 1
        sel[ns] = r
        ns += 1
        d = abs(lam[r] - old)
        dl = max(dl, d)
        top = max(top, lam[r])
        if kr[r] > 0.0:
            dgap = max(dgap, d / kr[r])
    else:
        lam[r] = 0.0
        mark[r] = 0
    return count, ns, dl, top, dgap


@njit(cache=True)
def lag_rows_live(x, fixed, mass, h2k, rows, nrm, target, is_vf, coef, kr, lam, reach, mark,
                  sel, endpoints=NO_ENDPOINTS):
    """``lag_rows`` for the live rows at x only: a row whose gap bound (``_gap_bound``) is at
    least ``reach`` (+ ``LIVE_SLACK``) at x and whose normal force ``lam`` was 0 gets lam = 0
    and keeps its coefficients (it is inactive at x with any: no energy, gradient or Hessian,
    exactly what ``lag_rows`` would give it); the others are lagged as ``lag_rows`` lags them,
    flagged in ``mark`` and listed in ascending order in ``sel``. Returns (active count, number of live rows, largest |change|
    of a normal force [N], largest normal force [N], largest |change| of a normal force over
    its row's stiffness where that is > 0 [m]): the rows left out have lam 0 before and after.
    """
    count = 0
    ns = 0
    dl, top, dgap = 0.0, 0.0, 0.0
    for r in range(rows.shape[0]):
        count, ns, dl, top, dgap = _live_row(x, fixed, mass, h2k, rows, nrm, target, is_vf,
                                             coef, kr, lam, reach, mark, sel, r, count, ns, dl,
                                             top, dgap, endpoints)
    return count, ns, dl, top, dgap


@njit(cache=True)
def lag_rows_sel(x, fixed, mass, h2k, rows, nrm, target, is_vf, coef, kr, lam, reach, mark,
                 sel, ns_in, endpoints=NO_ENDPOINTS):
    """``lag_rows_live`` visiting only the rows listed in ``sel[:ns_in]`` (ascending), with the
    same results, when x lies on a segment over which ``extend_live`` has just marked every row
    whose gap bound drops below ``LIVE_SLACK`` (``reach`` 0): an unmarked row has lam 0 and a
    gap bound of at least ``LIVE_SLACK`` at both ends of the segment, so, the bound being
    concave (``_gap_bound``), all along it, and ``lag_rows_live`` would leave it as it is (lam 0,
    unmarked). The Newton loop's lag after a line search: one pass over the live rows instead of
    one over every row. Returns what ``lag_rows_live`` returns."""
    count = 0
    ns = 0
    dl, top, dgap = 0.0, 0.0, 0.0
    for i in range(ns_in):
        r = sel[i]
        count, ns, dl, top, dgap = _live_row(x, fixed, mass, h2k, rows, nrm, target, is_vf,
                                             coef, kr, lam, reach, mark, sel, r, count, ns, dl,
                                             top, dgap, endpoints)
    return count, ns, dl, top, dgap


_ALL_MOVED = np.zeros(0, np.bool_)  # ``extend_live``: no ``moved`` flags, every row tested


@njit(cache=True)
def extend_live(xb, x, fixed, mass, h2k, rows, nrm, target, is_vf, coef, kr, lam, mark, sel,
                moved=_ALL_MOVED, endpoints=NO_ENDPOINTS):
    """Before a line search from x toward xb (or an energy evaluation at xb with the rows
    lagged at x): the rows not live at x (``mark`` 0) whose gap bound is below
    ``LIVE_SLACK`` at xb join the live rows, lagged at x (their normal force there is 0);
    ``sel`` is rebuilt in ascending row order (the order of the sums of ``row_energy``). Rows
    still not live have C >= 0 on the whole segment (``_gap_bound``). Returns the number of
    live rows.

    ``moved`` (bool per vertex, or empty: all): xb differs from x only at the flagged
    vertices, and every row not live has a gap bound of at least ``LIVE_SLACK`` at x (as after
    ``lag_rows_live`` or this at x); a row none of whose vertices moved then has bitwise the
    same gap bound at xb as at x and stays out without its bound being formed. The same
    marks, lags and ``sel`` as without ``moved``."""
    ns = 0
    some = moved.shape[0] > 0
    for r in range(rows.shape[0]):
        if mark[r] == 0 and (not some or moved[rows[r, 0]] or moved[rows[r, 1]]
                             or moved[rows[r, 2]] or moved[rows[r, 3]]):
            if _gap_bound(xb, rows, nrm, target, is_vf, r) < LIVE_SLACK:
                _lag_row(x, fixed, mass, h2k, rows, nrm, target, is_vf, coef, kr, lam, r,
                         endpoints)
                mark[r] = 1
        if mark[r]:
            sel[ns] = r
            ns += 1
    return ns


@njit(cache=True)
def start_targets(x, rows, nrm, target, coef, out, sel):
    """``start_targets_on`` for every row in ``sel``."""
    return start_targets_on(x, rows, nrm, target, coef, out, sel,
                            np.ones(x.shape[0], dtype=np.bool_))


@njit(cache=True)
def start_targets_on(x, rows, nrm, target, coef, out, sel, on):
    """The targets of the contact rows in the Newton solve: ``min(target, gap)`` with ``gap``
    the row's signed gap along its normal at x (the start of the substep, coefficients
    ``coef`` lagged there). A row its pair already violates at the start (a crossed pair's
    "back toward the remembered side" row, a pair pressed inside its thickness) only stops
    approaching in the solve: its penalty holds no energy at the start that the solve would
    turn into motion; the recovery push stays with CollisionConstraint's projection pass,
    as Nucleus applies it. Only the rows in ``sel`` are visited (the live rows at x: the
    others have gap > target with any coefficients, ``_gap_bound``, and keep it). Only rows
    with a vertex flagged in ``on`` are lowered (``violated_rows: hold_kinematic``: the rows
    against kinematic vertices); the others keep their target. Returns the number of rows
    lowered."""
    low = 0
    for i in range(sel.shape[0]):
        r = sel[i]
        if not (on[rows[r, 0]] or on[rows[r, 1]] or on[rows[r, 2]] or on[rows[r, 3]]):
            out[r] = target[r]
            continue
        g = 0.0
        for j in range(4):
            a = rows[r, j]
            for q in range(3):
                g += coef[r, j] * x[a, q] * nrm[r, q]
        if g < target[r]:
            out[r] = g
            low += 1
        else:
            out[r] = target[r]
    return low


@njit(cache=True)
def row_energy(x, x0, fixed, rows, nrm, target, coef, kr, lam, mu, eps, mode, grad, A, diag,
               irls, reach, xf, nofric, sel):
    """``row_energy_coupled`` with the block-diagonal Hessian (``coupled`` False)."""
    z = np.zeros(1, dtype=np.int32)
    return row_energy_coupled(x, x0, fixed, rows, nrm, target, coef, kr, lam, mu, eps, mode,
                              grad, A, diag, irls, reach, xf, nofric, sel, z, z, False,
                              np.zeros(rows.shape[0], dtype=np.uint8))


@njit(cache=True, inline="always")
def _block_at(indptr, indices, a, b):
    """The index of block (a, b) in a BSR pattern with sorted column indices; -1 if absent."""
    lo, hi = indptr[a], indptr[a + 1]
    while lo < hi:
        mid = (lo + hi) // 2
        c = indices[mid]
        if c < b:
            lo = mid + 1
        elif c > b:
            hi = mid
        else:
            return mid
    return -1


@njit(cache=True)
def row_energy_coupled(x, x0, fixed, rows, nrm, target, coef, kr, lam, mu, eps, mode, grad, A,
                       diag, irls, reach, xf, nofric, sel, indptr, indices, coupled, hot):
    """Penalty + lagged friction energy of the contact rows at x (see above); gradient and
    block-diagonal Hessian as ``contact_energy``. With mode 2 a row not active at x but within
    ``reach`` [m] of its target (0 <= C < reach) still writes its penalty block k n n^T: the
    Newton model then sees the contacts a step is about to close (the energy and gradient are
    unchanged; the matrix stays positive definite, so CG and the line search apply).
    Vertices flagged ``nofric`` (compliant kinematic vertices) take no friction: their
    displacement in the row's tangential motion u is the fixed ``xf - x0`` (their animation's
    step), and the friction term adds no gradient or Hessian to them (the penalty does).
    Only the rows listed in ``sel`` are visited (the live rows of ``lag_rows_live`` /
    ``extend_live``: every other row is inactive here, adding nothing), in its order.

    With ``coupled`` (``contact_hessian: coupled``) the Hessian is the row's whole
    Gauss-Newton block c c^T (x) (k n n^T) + c_f c_f^T (x) friction block (c_f: c with 0 at
    ``nofric`` vertices) wherever the BSR pattern (``indptr``, ``indices``) holds the block of
    a pair of the row's free vertices (cloth against a kinematic body: the cloth vertices of a
    row share a triangle or an edge); a pair the pattern lacks (self contact between distant
    vertices) puts |c_a c_b| times its block on both diagonals instead, which bounds the
    dropped off-diagonal pair from above (+-(E_ab + E_ba) <= E_aa + E_bb): a PSD majorizer of
    the row's curvature. The block-diagonal Hessian (False) is neither: it drops the
    off-diagonal blocks, which under-estimates a cloth triangle's curvature against a
    kinematic vertex by up to 3x along a common motion of its vertices (sum b^2 >= 1/3).
    A row flagged in ``hot`` (uint8 per row; ``contact_sticky``: active at an earlier Newton
    iterate of the substep) writes its penalty curvature even where inactive, as a row within
    ``reach`` does."""
    g = np.zeros(3)
    u = np.zeros(3)
    blk = np.zeros((3, 3))
    blf = np.zeros((3, 3))
    E = 0.0
    for i in range(sel.shape[0]):
        r = sel[i]
        k = kr[r]
        if k <= 0.0:
            continue
        n0, n1, n2 = nrm[r, 0], nrm[r, 1], nrm[r, 2]
        C = -target[r]
        for j in range(4):
            a = rows[r, j]
            C += coef[r, j] * (x[a, 0] * n0 + x[a, 1] * n1 + x[a, 2] * n2)
        _row_motion(x, x0, xf, nofric, rows, coef, r, u)
        blk[:, :] = 0.0
        blf[:, :] = 0.0
        have = False
        gC = 0.0
        if C < 0.0:
            E += 0.5 * k * C * C
            gC = k * C
            if mode >= 2:
                for p in range(3):
                    for q in range(3):
                        blk[p, q] = k * nrm[r, p] * nrm[r, q]
            have = True
        elif mode >= 2 and (C < reach or hot[r]):  # inactive but near (or active at an
            # earlier Newton iterate, ``hot``): its curvature in the Newton model
            for p in range(3):
                for q in range(3):
                    blk[p, q] = k * nrm[r, p] * nrm[r, q]
            have = True
        L = lam[r]
        m = mu[r]
        g[:] = 0.0
        if L > 0.0 and m > 0.0:
            ml = m * L
            un = u[0] * n0 + u[1] * n1 + u[2] * n2
            u[0] -= un * n0
            u[1] -= un * n1
            u[2] -= un * n2
            y = np.sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
            f0, f1y = _friction_f0(y, eps)
            E += ml * f0
            for q in range(3):
                g[q] = ml * f1y * u[q]
            if mode >= 2:
                cu = _friction_cu(y, eps, ml, 1.0 if irls else 0.0)
                for p in range(3):
                    for q in range(3):
                        pp = (1.0 if p == q else 0.0) - nrm[r, p] * nrm[r, q]
                        blf[p, q] = ml * f1y * pp - cu * u[p] * u[q]
            have = True
        if not have:
            continue
        for j in range(4):
            a = rows[r, j]
            cj = coef[r, j]
            if fixed[a] or cj == 0.0:
                continue
            fr = 0.0 if nofric[a] else 1.0
            if mode >= 1:
                grad[a, 0] += cj * (gC * n0 + fr * g[0])
                grad[a, 1] += cj * (gC * n1 + fr * g[1])
                grad[a, 2] += cj * (gC * n2 + fr * g[2])
            if mode >= 2:
                b = diag[a]
                for p in range(3):
                    for q in range(3):
                        A[b, p, q] += cj * cj * (blk[p, q] + fr * blf[p, q])
                if coupled:
                    for l in range(j + 1, 4):
                        e = rows[r, l]
                        cl = coef[r, l]
                        if fixed[e] or cl == 0.0:
                            continue
                        ff = fr * (0.0 if nofric[e] else 1.0)
                        w = cj * cl
                        bo = _block_at(indptr, indices, a, e)
                        if bo >= 0:
                            bt = _block_at(indptr, indices, e, a)
                            for p in range(3):
                                for q in range(3):
                                    t = w * (blk[p, q] + ff * blf[p, q])
                                    A[bo, p, q] += t
                                    A[bt, p, q] += t
                        else:  # the pattern lacks (a, e): majorize on the diagonals
                            w = abs(w)
                            b2 = diag[e]
                            for p in range(3):
                                for q in range(3):
                                    t = w * (blk[p, q] + ff * blf[p, q])
                                    A[b, p, q] += t
                                    A[b2, p, q] += t
    return E


@njit(cache=True, inline="always")
def _row_motion(x, x0, xf, nofric, rows, coef, r, u):
    """The motion of row r over the substep into ``u``: sum_a c_a (x_a - x0_a), with the fixed
    ``xf - x0`` (the animation's step) at vertices flagged ``nofric`` (compliant kinematic
    vertices, which take no friction)."""
    u[:] = 0.0
    for j in range(4):
        a = rows[r, j]
        cj = coef[r, j]
        if nofric[a]:
            for q in range(3):
                u[q] += cj * (xf[a, q] - x0[a, q])
        else:
            for q in range(3):
                u[q] += cj * (x[a, q] - x0[a, q])


@njit(cache=True)
def row_residuals(x, x0, fixed, rows, nrm, target, coef, kr, lam, mu, eps, xf, nofric, sel):
    """Complementarity residuals of the contact rows at x (the end of a Newton solve), with the
    gaps C_r = n_r . sum_a c_a x_a - target_r (summed as ``lag_rows`` sums them) and the rows'
    normal forces lam_r [N] as the solve lagged them at x. Returns (normal, cone):

    - normal [m]: max over rows of |min(C_r, lam_r / k_r)|, the residual of C >= 0, lam >= 0,
      C lam = 0 (0 at an exact complementary pair; for the penalty rows, whose force is
      k max(-C, 0), it is the largest penetration);
    - cone [N]: max(|f_t| - mu lam, 0) over rows, the Coulomb cone violation of the smoothed
      friction force f_t = mu lam f1(|u|) u / |u| (u the tangential displacement of the
      substep, ``row_energy``; IPC's f1 <= 1 keeps it 0 up to rounding).

    Rows without a free vertex (k_r = 0) are skipped, and so are rows not in ``sel`` (not
    live at x, ``lag_rows_live``: C >= 0 and lam = 0, a zero residual)."""
    normal, cone = 0.0, 0.0
    u = np.zeros(3)
    for i in range(sel.shape[0]):
        r = sel[i]
        k = kr[r]
        if k <= 0.0:
            continue
        C = -target[r]
        for j in range(4):
            a = rows[r, j]
            for q in range(3):
                C += coef[r, j] * x[a, q] * nrm[r, q]
        _row_motion(x, x0, xf, nofric, rows, coef, r, u)
        L = lam[r]
        res = abs(min(C, L / k))
        if res > normal:
            normal = res
        if L > 0.0 and mu[r] > 0.0:
            un = u[0] * nrm[r, 0] + u[1] * nrm[r, 1] + u[2] * nrm[r, 2]
            y = 0.0
            for q in range(3):
                t = u[q] - un * nrm[r, q]
                y += t * t
            y = np.sqrt(y)
            _, f1y = _friction_f0(y, eps)
            over = mu[r] * L * f1y * y - mu[r] * L
            if over > cone:
                cone = over
    return normal, cone


@njit(cache=True)
def mark_closing(x, rows, nrm, target, coef, kr, sel, hot):
    """``contact_sticky``: flag in ``hot`` the rows listed in ``sel`` whose gap (coefficients
    as lagged) is negative at x (the full Newton step's end, before the line search cuts it),
    so that the next Newton matrix holds their curvature although the cut step left them
    open. Returns the number of rows newly flagged."""
    new = 0
    for i in range(sel.shape[0]):
        r = sel[i]
        if hot[r] or kr[r] <= 0.0:
            continue
        C = -target[r]
        for j in range(4):
            a = rows[r, j]
            C += coef[r, j] * (x[a, 0] * nrm[r, 0] + x[a, 1] * nrm[r, 1] + x[a, 2] * nrm[r, 2])
        if C < 0.0:
            hot[r] = 1
            new += 1
    return new
