"""Constraint projection kernels for the Nucleus solver (XPBD form).

Every kernel projects one kind of constraint, Gauss-Seidel in place, on the predicted positions
``p`` of one substep. Constraint ``j`` with value ``C_j(p)``, gradients ``grad_i C_j``, Lagrange
multiplier ``lam[j]`` and compliance ``alpha[j]`` takes one Newton step (Nucleus section 5, one
step per constraint) in the XPBD form:

    alpha~ = alpha / h**2
    dlam   = (-C - alpha~ * lam[j]) / (sum_i w_i |grad_i C|**2 + alpha~)
    p_i   += w_i * grad_i C * dlam          (for every vertex i of the constraint with w_i > 0)
    lam[j] += dlam

``alpha = 0`` is a hard constraint; ``alpha = inf`` switches a constraint off. Because the
multiplier carries the accumulated force, a compliance means the same stiffness (1/alpha) at any
substep size and iteration count once the iterations converge: a spring of compliance alpha
[m/N] under a load F [N] stretches by F * alpha. The solver resets ``lam`` to 0 at the start of
every substep; the constraint force on vertex i is ``grad_i C * lam / h**2`` (for a distance
constraint ``-lam / h**2`` is the tension [N]).

Array conventions
-----------------
- ``p`` positions [m], shape (n, 3), float64, modified in place. ``w`` inverse masses [1/kg],
  shape (n,); ``w == 0`` is pinned or kinematic: such a vertex is read, never written.
- Topology is int64, one constraint tuple per row. Per-constraint parameters and ``lam`` are
  float64 arrays with one entry per row (``attach`` has a 3-vector ``lam``).
- ``h`` is the substep [s].
- Colouring: rows are stored permuted by colour (:func:`lokigraph.behaviors.topology.
  color_constraints`); colour c owns rows ``color_ptr[c] .. color_ptr[c+1]-1`` and no two rows
  of a colour share a vertex with ``w > 0``. ``project_<kind>`` loops colours in order and the
  rows of a colour with ``prange`` (numba ``parallel=True``); ``project_<kind>_seq`` takes the
  same arguments and sweeps all rows in storage order on one thread. Because rows inside a colour
  are independent, both give the same result up to floating-point rounding.
- Degenerate configurations (zero-length edges, collinear corners, flat or collinear bend quads,
  zero-volume tets, coincident points) skip the constraint for that sweep: no NaN is produced.

Constraint types (Stam, Nucleus, section 5)
-------------------------------------------
- type 1, stretch: ``C = |p_i - p_j| - L`` with a stretch compliance (C > 0) and a compression
  compliance (C < 0) per edge. Applied to tet edges it is the stretch of a 3-simplex; applied to
  curve "skip-one" pairs it is the twist-free hair bend.
- type 2, angle: ``C = angle(p_a - p_o, p_b - p_o) - gamma``: shear of a triangle corner, or the
  bend of a curve at a vertex (rest near pi for straight hair).
- type 3, dihedral: signed angle across a hinge edge minus its rest angle: bend of a surface, or
  torsion of a curve centre line (quads from ``curve_torsion_quads``).
- tet volume, goal attraction, point-to-triangle attachment, global mesh volume (pressure) and
  rigid shape matching.

References
----------
J. Stam, "Nucleus: Towards a Unified Dynamics Solver for Computer Graphics", CAD/Graphics 2009.
M. Macklin, M. Mueller, N. Chentanez, "XPBD: Position-Based Simulation of Compliant Constrained
Dynamics", MIG 2016 (compliance, multiplier, damping).
R. Bridson, S. Marino, R. Fedkiw, "Simulation of Clothing with Folds and Wrinkles", SCA 2003
(dihedral angle gradients).
M. Mueller, B. Heidelberger, M. Teschner, M. Gross, "Meshless Deformations Based on Shape
Matching", SIGGRAPH 2005.

Limitations
-----------
- Type 2 and type 3 use angles: the Newton direction is undefined at exactly collinear corners
  (angle 0 or pi) and exactly degenerate triangles; such a constraint is skipped for that sweep
  (a straight hair held by an angle constraint with rest pi is already satisfied there).
- The compliance switches between stretch and compression by the sign of the current C while
  lam is accumulated; this is the exact XPBD update of the bilinear spring energy but the
  multiplier of a constraint that crosses C = 0 during a substep mixes the two regimes.
- Curves carry no material frame, so there is no material twist (see
  ``topology.curve_torsion_quads`` for the geometric torsion Nucleus calls type 3 on curves).
- The global volume constraint and shape matching are sequential (one constraint or cluster at a
  time); shape matching uses a per-iteration stiffness in [0, 1], so its effect depends on the
  iteration count (use ``project_goal`` for a compliance-based pull).
- Convergence is that of Gauss-Seidel on the constraint set, and some sets are singular where
  it matters: hard stretch on an exactly flat sheet (out-of-plane motion changes lengths only to
  second order), tet volumes alone on a Kuhn-subdivided box (the volume rows are rank
  deficient at rest), the skip-one hair bend near straight (distance changes to second order
  in the bend angle, so it barely straightens a hard-stretched strand). The angle bend with rest
  pi straightens to about 1e-9 rad and then stops (the direction is undefined at pi).
- A per-constraint compliance is resolution independent only if the caller scales it with the
  element size (e.g. a membrane of stretch modulus k [N/m] gives an edge
  ``alpha = L**2 / (k * A_edge)`` with A_edge the area the edge stands for).
- A tet (or closed mesh) that has almost collapsed to a segment still gets the Newton step on
  its volume, which can be large; only exact collapse (relative 1e-9) is skipped.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

__all__ = [
    "project_stretch", "project_stretch_seq",
    "project_stretch_damped", "project_stretch_damped_seq",
    "project_angle", "project_angle_seq",
    "project_dihedral", "project_dihedral_seq",
    "project_tet_volume", "project_tet_volume_seq",
    "project_goal", "project_goal_seq",
    "project_attach", "project_attach_seq",
    "project_mesh_volume", "mesh_volume",
    "shape_match",
    "stretch_values", "angle_values", "dihedral_values", "tet_volume_values",
    "goal_values", "attach_values", "shape_match_values",
    "residual", "residual_stretch", "residual_angle", "residual_dihedral",
    "residual_tet_volume", "residual_goal", "residual_attach", "residual_mesh_volume",
    "residual_shape_match",
    "rest_lengths", "rest_angles", "rest_dihedrals", "rest_tet_volumes",
    "bend_dropoff_scale",
]

_LEN_EPS = 1e-12     # [m] shorter edges / distances have no direction: skip
_REL_EPS = 1e-9      # relative: a triangle height below 1e-9 * edge length is degenerate
_PI = math.pi
_INF = np.inf


def _hot(fn):
    """Compile a per-constraint helper without the numba runtime (NRT).

    Called once per constraint from a sweep, a helper that takes arrays compiled with NRT
    increments and decrements the reference count of every array argument on every call (atomic
    operations that LLVM cannot remove, measured 2.7x slower on the stretch sweep; IR-level
    ``inline="always"`` does not avoid them). Without NRT the call is a plain function call that
    LLVM inlines. Helpers decorated here must not allocate.
    """
    return njit(cache=True, _nrt=False)(fn)


@_hot
def _xpbd_step(c, at, den, lam, j):
    """XPBD multiplier update of constraint j: dlam = (-C - alpha~ lam) / (sum w |grad C|^2 +
    alpha~), accumulated into lam[j]; returns dlam."""
    dl = (-c - at * lam[j]) / (den + at)
    lam[j] += dl
    return dl


@_hot
def _nudge(p, i, wi, dl, gx, gy, gz):
    """p[i] += w_i dlam grad_i C for a movable vertex (w_i > 0)."""
    if wi > 0.0:
        f = wi * dl
        p[i, 0] += f * gx
        p[i, 1] += f * gy
        p[i, 2] += f * gz


# ==============================================================================================
# type 1: stretch
# ==============================================================================================
@_hot
def _stretch_one(j, p, w, edges, rest, alpha_stretch, alpha_compress, lam, inv_h2):
    a = edges[j, 0]
    b = edges[j, 1]
    wa = w[a]
    wb = w[b]
    ws = wa + wb
    if ws <= 0.0:
        return
    dx = p[a, 0] - p[b, 0]
    dy = p[a, 1] - p[b, 1]
    dz = p[a, 2] - p[b, 2]
    ln = math.sqrt(dx * dx + dy * dy + dz * dz)
    if ln < _LEN_EPS:
        return
    c = ln - rest[j]
    alpha = alpha_stretch[j] if c >= 0.0 else alpha_compress[j]
    if not alpha < _INF:
        return
    at = alpha * inv_h2
    dl = (-c - at * lam[j]) / (ws + at)
    lam[j] += dl
    s = dl / ln
    if wa > 0.0:
        f = wa * s
        p[a, 0] += f * dx
        p[a, 1] += f * dy
        p[a, 2] += f * dz
    if wb > 0.0:
        f = wb * s
        p[b, 0] -= f * dx
        p[b, 1] -= f * dy
        p[b, 2] -= f * dz


@njit(cache=True, parallel=True)
def project_stretch(p, w, edges, rest, alpha_stretch, alpha_compress, lam, h, color_ptr):
    """Type 1 stretch, coloured parallel sweep.

    edges (m, 2) int64; rest lengths [m] (m,); alpha_stretch / alpha_compress compliance [m/N]
    (m,) used when the edge is longer / shorter than rest; lam (m,); h substep [s];
    color_ptr (ncolors + 1,).
    """
    inv_h2 = 1.0 / (h * h)
    for c in range(color_ptr.shape[0] - 1):
        for j in prange(color_ptr[c], color_ptr[c + 1]):
            _stretch_one(j, p, w, edges, rest, alpha_stretch, alpha_compress, lam, inv_h2)


@njit(cache=True)
def project_stretch_seq(p, w, edges, rest, alpha_stretch, alpha_compress, lam, h, color_ptr):
    """Type 1 stretch, sequential sweep in storage order (``color_ptr`` unused)."""
    inv_h2 = 1.0 / (h * h)
    for j in range(edges.shape[0]):
        _stretch_one(j, p, w, edges, rest, alpha_stretch, alpha_compress, lam, inv_h2)


@_hot
def _stretch_damped_one(j, p, x, w, edges, rest, alpha_stretch, alpha_compress, beta, lam, h,
                        inv_h2):
    a = edges[j, 0]
    b = edges[j, 1]
    wa = w[a]
    wb = w[b]
    ws = wa + wb
    if ws <= 0.0:
        return
    dx = p[a, 0] - p[b, 0]
    dy = p[a, 1] - p[b, 1]
    dz = p[a, 2] - p[b, 2]
    ln = math.sqrt(dx * dx + dy * dy + dz * dz)
    if ln < _LEN_EPS:
        return
    nx = dx / ln
    ny = dy / ln
    nz = dz / ln
    c = ln - rest[j]
    alpha = alpha_stretch[j] if c >= 0.0 else alpha_compress[j]
    if not alpha < _INF:
        return
    at = alpha * inv_h2
    gamma = alpha * beta[j] / h
    # grad C . (p - x): relative displacement along the edge during this substep
    vrel = (nx * ((p[a, 0] - x[a, 0]) - (p[b, 0] - x[b, 0]))
            + ny * ((p[a, 1] - x[a, 1]) - (p[b, 1] - x[b, 1]))
            + nz * ((p[a, 2] - x[a, 2]) - (p[b, 2] - x[b, 2])))
    dl = (-c - at * lam[j] - gamma * vrel) / ((1.0 + gamma) * ws + at)
    lam[j] += dl
    _nudge(p, a, wa, dl, nx, ny, nz)
    if wb > 0.0:
        f = wb * dl
        p[b, 0] -= f * nx
        p[b, 1] -= f * ny
        p[b, 2] -= f * nz


@njit(cache=True, parallel=True)
def project_stretch_damped(p, x, w, edges, rest, alpha_stretch, alpha_compress, beta, lam, h,
                           color_ptr):
    """Type 1 stretch with XPBD constraint damping, coloured parallel sweep.

    x: positions at the start of the substep [m] (n, 3), read only. beta: damping coefficient
    [N s/m] (m,); the XPBD damping ratio is ``gamma = alpha * beta / h`` and the update is
    ``dlam = (-C - alpha~ lam - gamma grad C . (p - x)) / ((1 + gamma) sum w |grad C|^2 +
    alpha~)``. beta = 0 reproduces ``project_stretch``. A hard edge (alpha = 0) gets no damping
    (it cannot oscillate). Other arguments as ``project_stretch``.
    """
    inv_h2 = 1.0 / (h * h)
    for c in range(color_ptr.shape[0] - 1):
        for j in prange(color_ptr[c], color_ptr[c + 1]):
            _stretch_damped_one(j, p, x, w, edges, rest, alpha_stretch, alpha_compress, beta,
                                lam, h, inv_h2)


@njit(cache=True)
def project_stretch_damped_seq(p, x, w, edges, rest, alpha_stretch, alpha_compress, beta, lam,
                               h, color_ptr):
    """Sequential variant of ``project_stretch_damped`` (``color_ptr`` unused)."""
    inv_h2 = 1.0 / (h * h)
    for j in range(edges.shape[0]):
        _stretch_damped_one(j, p, x, w, edges, rest, alpha_stretch, alpha_compress, beta, lam,
                            h, inv_h2)


# ==============================================================================================
# type 2: angle at a vertex (shear of a triangle corner, bend of a curve)
# ==============================================================================================
@_hot
def _angle_one(j, p, w, tri, rest, alpha, lam, inv_h2):
    o = tri[j, 0]
    a = tri[j, 1]
    b = tri[j, 2]
    wo = w[o]
    wa = w[a]
    wb = w[b]
    if wo + wa + wb <= 0.0:
        return
    ux = p[a, 0] - p[o, 0]
    uy = p[a, 1] - p[o, 1]
    uz = p[a, 2] - p[o, 2]
    vx = p[b, 0] - p[o, 0]
    vy = p[b, 1] - p[o, 1]
    vz = p[b, 2] - p[o, 2]
    lu2 = ux * ux + uy * uy + uz * uz
    lv2 = vx * vx + vy * vy + vz * vz
    if lu2 < _LEN_EPS * _LEN_EPS or lv2 < _LEN_EPS * _LEN_EPS:
        return
    iu = 1.0 / math.sqrt(lu2)
    iv = 1.0 / math.sqrt(lv2)
    ux *= iu
    uy *= iu
    uz *= iu
    vx *= iv
    vy *= iv
    vz *= iv
    cs = ux * vx + uy * vy + uz * vz
    cxx = uy * vz - uz * vy
    cxy = uz * vx - ux * vz
    cxz = ux * vy - uy * vx
    sn = math.sqrt(cxx * cxx + cxy * cxy + cxz * cxz)
    if sn < _REL_EPS:
        return  # collinear: the direction of the angle change is undefined
    al = alpha[j]
    if not al < _INF:
        return
    c = math.atan2(sn, cs) - rest[j]
    # with unit u, v: d theta / d p_a = -(v - cs u) / (|e_a| sn), d theta / d p_b =
    # -(u - cs v) / (|e_b| sn); |v - cs u| = |u - cs v| = sn
    ga = -iu / sn
    gb = -iv / sn
    gax = ga * (vx - cs * ux)
    gay = ga * (vy - cs * uy)
    gaz = ga * (vz - cs * uz)
    gbx = gb * (ux - cs * vx)
    gby = gb * (uy - cs * vy)
    gbz = gb * (uz - cs * vz)
    gox = -gax - gbx
    goy = -gay - gby
    goz = -gaz - gbz
    den = (wa * (gax * gax + gay * gay + gaz * gaz) + wb * (gbx * gbx + gby * gby + gbz * gbz)
           + wo * (gox * gox + goy * goy + goz * goz))
    if den <= 0.0:
        return
    dl = _xpbd_step(c, al * inv_h2, den, lam, j)
    _nudge(p, o, wo, dl, gox, goy, goz)
    _nudge(p, a, wa, dl, gax, gay, gaz)
    _nudge(p, b, wb, dl, gbx, gby, gbz)


@njit(cache=True, parallel=True)
def project_angle(p, w, triplets, rest, alpha, lam, h, color_ptr):
    """Type 2 angle constraint, coloured parallel sweep.

    triplets (m, 3) int64 rows ``(apex, a, b)``; rest angle gamma [rad] (m,) in [0, pi];
    alpha compliance [rad^2/J = 1/(N m)] (m,); lam (m,). ``C = angle(a - apex, b - apex) - gamma``
    with the angle in [0, pi] (Nucleus: ``acos(d_ij . d_ik) - gamma_ijk``, evaluated as
    ``atan2(|u x v|, u . v)`` for accuracy near 0 and pi).
    """
    inv_h2 = 1.0 / (h * h)
    for c in range(color_ptr.shape[0] - 1):
        for j in prange(color_ptr[c], color_ptr[c + 1]):
            _angle_one(j, p, w, triplets, rest, alpha, lam, inv_h2)


@njit(cache=True)
def project_angle_seq(p, w, triplets, rest, alpha, lam, h, color_ptr):
    """Sequential variant of ``project_angle`` (``color_ptr`` unused)."""
    inv_h2 = 1.0 / (h * h)
    for j in range(triplets.shape[0]):
        _angle_one(j, p, w, triplets, rest, alpha, lam, inv_h2)


# ==============================================================================================
# type 3: dihedral angle across a hinge (bend of a surface, torsion of a curve)
# ==============================================================================================
@njit(cache=True)
def bend_dropoff_scale(delta, dropoff):
    """Stiffness multiplier of the bend angle dropoff: ``1 + dropoff * |delta| / pi``.

    delta is the current angle minus the rest angle [rad] wrapped to (-pi, pi]; dropoff >= 0
    (0: constant stiffness). The effective compliance is ``alpha / scale``: the stiffness at the
    rest angle is unchanged and grows linearly to ``(1 + dropoff)`` times at a 180 degree fold,
    as Maya's bendAngleDropoff ("at higher values the bend resists more at high angles than when
    the surface is nearly flat").
    """
    return 1.0 + dropoff * abs(delta) / _PI


@njit(cache=True)
def _wrap_angle(d):
    if d > _PI:
        d -= 2.0 * _PI
    elif d <= -_PI:
        d += 2.0 * _PI
    return d


@_hot
def _dihedral_one(j, p, w, quads, rest, alpha, dropoff, lam, inv_h2):
    i0 = quads[j, 0]
    i1 = quads[j, 1]
    i2 = quads[j, 2]
    i3 = quads[j, 3]
    w0 = w[i0]
    w1 = w[i1]
    w2 = w[i2]
    w3 = w[i3]
    if w0 + w1 + w2 + w3 <= 0.0:
        return
    ex = p[i1, 0] - p[i0, 0]
    ey = p[i1, 1] - p[i0, 1]
    ez = p[i1, 2] - p[i0, 2]
    ax = p[i2, 0] - p[i0, 0]
    ay = p[i2, 1] - p[i0, 1]
    az = p[i2, 2] - p[i0, 2]
    bx = p[i3, 0] - p[i0, 0]
    by = p[i3, 1] - p[i0, 1]
    bz = p[i3, 2] - p[i0, 2]
    e2 = ex * ex + ey * ey + ez * ez
    if e2 < _LEN_EPS * _LEN_EPS:
        return
    el = math.sqrt(e2)
    # NA = e x a (normal of (i0, i1, i2)), NB = b x e (normal of (i1, i0, i3))
    nax = ey * az - ez * ay
    nay = ez * ax - ex * az
    naz = ex * ay - ey * ax
    nbx = by * ez - bz * ey
    nby = bz * ex - bx * ez
    nbz = bx * ey - by * ex
    na2 = nax * nax + nay * nay + naz * naz
    nb2 = nbx * nbx + nby * nby + nbz * nbz
    lim = _REL_EPS * e2
    if na2 <= lim * lim or nb2 <= lim * lim:
        return  # a triangle of the hinge has (almost) zero height
    # signed angle: atan2((NA x NB) . e_hat, NA . NB)
    cx = nay * nbz - naz * nby
    cy = naz * nbx - nax * nbz
    cz = nax * nby - nay * nbx
    al = alpha[j]
    if not al < _INF:
        return
    # both atan2 arguments scaled by |e|: saves a division
    theta = math.atan2(cx * ex + cy * ey + cz * ez, el * (nax * nbx + nay * nby + naz * nbz))
    c = _wrap_angle(theta - rest[j])
    al = al / bend_dropoff_scale(c, dropoff[j])
    # gradients (Bridson et al. 2003): g2 = -|e| NA / |NA|^2, g3 = -|e| NB / |NB|^2,
    # g1 = -(s2 g2 + s3 g3), g0 = -((1 - s2) g2 + (1 - s3) g3), s = projection on the hinge
    f2 = -el / na2
    f3 = -el / nb2
    g2x = f2 * nax
    g2y = f2 * nay
    g2z = f2 * naz
    g3x = f3 * nbx
    g3y = f3 * nby
    g3z = f3 * nbz
    ie2 = 1.0 / e2
    s2 = (ax * ex + ay * ey + az * ez) * ie2
    s3 = (bx * ex + by * ey + bz * ez) * ie2
    g1x = -(s2 * g2x + s3 * g3x)
    g1y = -(s2 * g2y + s3 * g3y)
    g1z = -(s2 * g2z + s3 * g3z)
    g0x = -(g2x + g3x) - g1x
    g0y = -(g2y + g3y) - g1y
    g0z = -(g2z + g3z) - g1z
    den = (w0 * (g0x * g0x + g0y * g0y + g0z * g0z) + w1 * (g1x * g1x + g1y * g1y + g1z * g1z)
           + w2 * (g2x * g2x + g2y * g2y + g2z * g2z) + w3 * (g3x * g3x + g3y * g3y + g3z * g3z))
    if den <= 0.0:
        return
    dl = _xpbd_step(c, al * inv_h2, den, lam, j)
    _nudge(p, i0, w0, dl, g0x, g0y, g0z)
    _nudge(p, i1, w1, dl, g1x, g1y, g1z)
    _nudge(p, i2, w2, dl, g2x, g2y, g2z)
    _nudge(p, i3, w3, dl, g3x, g3y, g3z)


@njit(cache=True, parallel=True)
def project_dihedral(p, w, quads, rest, alpha, dropoff, lam, h, color_ptr):
    """Type 3 bend (dihedral angle), coloured parallel sweep.

    quads (m, 4) int64 rows ``(i, j, k, l)``: hinge ``(i, j)``, opposite vertices k and l (see
    ``topology.bend_quads``); rest signed dihedral [rad] (m,) (``rest_dihedrals``); alpha
    compliance [1/(N m)] (m,); dropoff (m,) >= 0, see ``bend_dropoff_scale``; lam (m,).

    ``theta = atan2((N_A x N_B) . e_hat, N_A . N_B)`` with ``e = p_j - p_i``,
    ``N_A = e x (p_k - p_i)``, ``N_B = (p_l - p_i) x e``; theta is 0 for a flat hinge and lies in
    (-pi, pi]; ``C = wrap(theta - rest)``. This is Nucleus's ``acos(n_A . n_B) - theta_0`` made
    signed, so that the Newton direction is defined at the flat rest state. Sign: theta < 0 when
    the wings fold towards the side N_A points to (a valley seen from there), > 0 for a ridge.
    The effective compliance is ``alpha / bend_dropoff_scale(C, dropoff)``.
    """
    inv_h2 = 1.0 / (h * h)
    for c in range(color_ptr.shape[0] - 1):
        for j in prange(color_ptr[c], color_ptr[c + 1]):
            _dihedral_one(j, p, w, quads, rest, alpha, dropoff, lam, inv_h2)


@njit(cache=True)
def project_dihedral_seq(p, w, quads, rest, alpha, dropoff, lam, h, color_ptr):
    """Sequential variant of ``project_dihedral`` (``color_ptr`` unused)."""
    inv_h2 = 1.0 / (h * h)
    for j in range(quads.shape[0]):
        _dihedral_one(j, p, w, quads, rest, alpha, dropoff, lam, inv_h2)


# ==============================================================================================
# tetrahedron volume
# ==============================================================================================
@_hot
def _tet_volume_one(j, p, w, tets, rest, alpha, lam, inv_h2):
    i0 = tets[j, 0]
    i1 = tets[j, 1]
    i2 = tets[j, 2]
    i3 = tets[j, 3]
    w0 = w[i0]
    w1 = w[i1]
    w2 = w[i2]
    w3 = w[i3]
    if w0 + w1 + w2 + w3 <= 0.0:
        return
    ax = p[i1, 0] - p[i0, 0]
    ay = p[i1, 1] - p[i0, 1]
    az = p[i1, 2] - p[i0, 2]
    bx = p[i2, 0] - p[i0, 0]
    by = p[i2, 1] - p[i0, 1]
    bz = p[i2, 2] - p[i0, 2]
    cx = p[i3, 0] - p[i0, 0]
    cy = p[i3, 1] - p[i0, 1]
    cz = p[i3, 2] - p[i0, 2]
    s = 1.0 / 6.0
    # g1 = (b x c)/6, g2 = (c x a)/6, g3 = (a x b)/6, g0 = -(g1 + g2 + g3)
    g1x = s * (by * cz - bz * cy)
    g1y = s * (bz * cx - bx * cz)
    g1z = s * (bx * cy - by * cx)
    g2x = s * (cy * az - cz * ay)
    g2y = s * (cz * ax - cx * az)
    g2z = s * (cx * ay - cy * ax)
    g3x = s * (ay * bz - az * by)
    g3y = s * (az * bx - ax * bz)
    g3z = s * (ax * by - ay * bx)
    g0x = -(g1x + g2x + g3x)
    g0y = -(g1y + g2y + g3y)
    g0z = -(g1z + g2z + g3z)
    vol = ax * g1x + ay * g1y + az * g1z
    c = vol - rest[j]
    al = alpha[j]
    if not al < _INF:
        return
    den = (w0 * (g0x * g0x + g0y * g0y + g0z * g0z) + w1 * (g1x * g1x + g1y * g1y + g1z * g1z)
           + w2 * (g2x * g2x + g2y * g2y + g2z * g2z) + w3 * (g3x * g3x + g3y * g3y + g3z * g3z))
    # |grad V| ~ face area: a tet whose faces are all (nearly) zero relative to its squared edge
    # lengths has collapsed to a segment or a point; the Newton direction is then meaningless
    gg = (g0x * g0x + g0y * g0y + g0z * g0z + g1x * g1x + g1y * g1y + g1z * g1z
          + g2x * g2x + g2y * g2y + g2z * g2z + g3x * g3x + g3y * g3y + g3z * g3z)
    s2 = _REL_EPS * (ax * ax + ay * ay + az * az + bx * bx + by * by + bz * bz
                     + cx * cx + cy * cy + cz * cz)
    if den <= 0.0 or gg <= s2 * s2:
        return
    dl = _xpbd_step(c, al * inv_h2, den, lam, j)
    _nudge(p, i0, w0, dl, g0x, g0y, g0z)
    _nudge(p, i1, w1, dl, g1x, g1y, g1z)
    _nudge(p, i2, w2, dl, g2x, g2y, g2z)
    _nudge(p, i3, w3, dl, g3x, g3y, g3z)


@njit(cache=True, parallel=True)
def project_tet_volume(p, w, tets, rest, alpha, lam, h, color_ptr):
    """Signed tet volume, coloured parallel sweep.

    tets (m, 4) int64, positively oriented; rest volume [m^3] (m,); alpha compliance
    [m^3/Pa = m^6/J] (m,) (a bulk modulus K [Pa] gives ``alpha = rest / K``); lam (m,):
    ``lam / h**2`` is the pressure [Pa] in the tet.
    ``C = (p1-p0) . ((p2-p0) x (p3-p0)) / 6 - rest``. The edges of a tet get their stretch from
    ``project_stretch`` on ``topology.tet_edges``.
    """
    inv_h2 = 1.0 / (h * h)
    for c in range(color_ptr.shape[0] - 1):
        for j in prange(color_ptr[c], color_ptr[c + 1]):
            _tet_volume_one(j, p, w, tets, rest, alpha, lam, inv_h2)


@njit(cache=True)
def project_tet_volume_seq(p, w, tets, rest, alpha, lam, h, color_ptr):
    """Sequential variant of ``project_tet_volume`` (``color_ptr`` unused)."""
    inv_h2 = 1.0 / (h * h)
    for j in range(tets.shape[0]):
        _tet_volume_one(j, p, w, tets, rest, alpha, lam, inv_h2)


# ==============================================================================================
# goal attraction / soft pin
# ==============================================================================================
@_hot
def _goal_one(j, p, w, index, target, alpha, lam, inv_h2):
    v = index[j]
    wv = w[v]
    if wv <= 0.0:
        return
    dx = p[v, 0] - target[j, 0]
    dy = p[v, 1] - target[j, 1]
    dz = p[v, 2] - target[j, 2]
    d = math.sqrt(dx * dx + dy * dy + dz * dz)
    if d < _LEN_EPS:
        return
    al = alpha[j]
    if not al < _INF:
        return
    at = al * inv_h2
    dl = (-d - at * lam[j]) / (wv + at)
    lam[j] += dl
    f = wv * dl / d
    p[v, 0] += f * dx
    p[v, 1] += f * dy
    p[v, 2] += f * dz


@njit(cache=True, parallel=True)
def project_goal(p, w, index, target, alpha, lam, h):
    """Goal attraction / soft pin ``C = |p_v - g|``, parallel over entries.

    index (m,) int64 vertex of each entry, unique (two entries on one vertex would race);
    target g [m] (m, 3); alpha compliance [m/N] (m,) (0: hard pin to g); lam (m,). A zero-rest
    spring to a moving target: the pull is isotropic. Not momentum conserving (external).
    """
    inv_h2 = 1.0 / (h * h)
    for j in prange(index.shape[0]):
        _goal_one(j, p, w, index, target, alpha, lam, inv_h2)


@njit(cache=True)
def project_goal_seq(p, w, index, target, alpha, lam, h):
    """Sequential variant of ``project_goal`` (repeated indices allowed)."""
    inv_h2 = 1.0 / (h * h)
    for j in range(index.shape[0]):
        _goal_one(j, p, w, index, target, alpha, lam, inv_h2)


# ==============================================================================================
# point-to-triangle attachment at fixed barycentrics
# ==============================================================================================
@_hot
def _attach_one(j, p, w, attach, bary, alpha, lam, inv_h2):
    v = attach[j, 0]
    t0 = attach[j, 1]
    t1 = attach[j, 2]
    t2 = attach[j, 3]
    b0 = bary[j, 0]
    b1 = bary[j, 1]
    b2 = bary[j, 2]
    wv = w[v]
    w0 = w[t0]
    w1 = w[t1]
    w2 = w[t2]
    den = wv + b0 * b0 * w0 + b1 * b1 * w1 + b2 * b2 * w2
    if den <= 0.0:
        return
    al = alpha[j]
    if not al < _INF:
        return
    at = al * inv_h2
    inv = 1.0 / (den + at)
    for k in range(3):
        c = p[v, k] - (b0 * p[t0, k] + b1 * p[t1, k] + b2 * p[t2, k])
        dl = (-c - at * lam[j, k]) * inv
        lam[j, k] += dl
        if wv > 0.0:
            p[v, k] += wv * dl
        if w0 > 0.0:
            p[t0, k] -= w0 * b0 * dl
        if w1 > 0.0:
            p[t1, k] -= w1 * b1 * dl
        if w2 > 0.0:
            p[t2, k] -= w2 * b2 * dl


@njit(cache=True, parallel=True)
def project_attach(p, w, attach, bary, alpha, lam, h, color_ptr):
    """Point-to-triangle attachment ``C = p_v - (b0 p_t0 + b1 p_t1 + b2 p_t2)`` (3 rows).

    attach (m, 4) int64 rows ``(v, t0, t1, t2)``; bary (m, 3) fixed barycentric weights
    (summing to 1 for momentum conservation); alpha compliance [m/N] (m,); lam (m, 3). The three
    rows share one scalar denominator ``w_v + sum b_k^2 w_k``, so the 3-row step is exact.
    Coloured parallel sweep.
    """
    inv_h2 = 1.0 / (h * h)
    for c in range(color_ptr.shape[0] - 1):
        for j in prange(color_ptr[c], color_ptr[c + 1]):
            _attach_one(j, p, w, attach, bary, alpha, lam, inv_h2)


@njit(cache=True)
def project_attach_seq(p, w, attach, bary, alpha, lam, h, color_ptr):
    """Sequential variant of ``project_attach`` (``color_ptr`` unused)."""
    inv_h2 = 1.0 / (h * h)
    for j in range(attach.shape[0]):
        _attach_one(j, p, w, attach, bary, alpha, lam, inv_h2)


# ==============================================================================================
# global volume (pressure) of a triangle mesh
# ==============================================================================================
@njit(cache=True)
def mesh_volume(p, tris):
    """Volume [m^3] enclosed by a triangle mesh w.r.t. the mean of its triangle corners c:
    ``V = sum_t ((p_a - c) x (p_b - c)) . (p_c - c) / 6``. For a closed mesh this is the signed
    enclosed volume (positive for outward winding) and does not depend on c; for an open mesh
    it is the volume of the cone from c over the surface."""
    m = tris.shape[0]
    if m == 0:
        return 0.0
    cx = 0.0
    cy = 0.0
    cz = 0.0
    for t in range(m):
        for k in range(3):
            v = tris[t, k]
            cx += p[v, 0]
            cy += p[v, 1]
            cz += p[v, 2]
    inv = 1.0 / (3.0 * m)
    cx *= inv
    cy *= inv
    cz *= inv
    vol = 0.0
    for t in range(m):
        a = tris[t, 0]
        b = tris[t, 1]
        d = tris[t, 2]
        ax = p[a, 0] - cx
        ay = p[a, 1] - cy
        az = p[a, 2] - cz
        bx = p[b, 0] - cx
        by = p[b, 1] - cy
        bz = p[b, 2] - cz
        dx = p[d, 0] - cx
        dy = p[d, 1] - cy
        dz = p[d, 2] - cz
        vol += ax * (by * dz - bz * dy) + ay * (bz * dx - bx * dz) + az * (bx * dy - by * dx)
    return vol / 6.0


@njit(cache=True)
def project_mesh_volume(p, w, tris, target, alpha, lam, h, work):
    """One global volume constraint ``C = V(p) - target`` over all vertices of a triangle mesh.

    tris (T, 3) int64; target volume [m^3]; alpha compliance [m^3/Pa] (scalar); lam: (1,)
    array; work: scratch (n, 4) float64 (same n as p), contents overwritten. V as in
    ``mesh_volume`` (open meshes: w.r.t. the mean corner, whose dependence on p is included in
    the gradient, so the update conserves momentum). ``lam[0] / h**2`` is the gauge pressure
    [Pa] that holds the volume. Returns V before the update. Sequential.
    """
    m = tris.shape[0]
    if m == 0:
        return 0.0
    # pass 1: clear the rows we use, find c
    cx = 0.0
    cy = 0.0
    cz = 0.0
    sxx = 0.0
    for t in range(m):
        for k in range(3):
            v = tris[t, k]
            work[v, 0] = 0.0
            work[v, 1] = 0.0
            work[v, 2] = 0.0
            work[v, 3] = 0.0
            cx += p[v, 0]
            cy += p[v, 1]
            cz += p[v, 2]
            sxx += p[v, 0] * p[v, 0] + p[v, 1] * p[v, 1] + p[v, 2] * p[v, 2]
    inv3m = 1.0 / (3.0 * m)
    cx *= inv3m
    cy *= inv3m
    cz *= inv3m
    r2 = max(sxx * inv3m - (cx * cx + cy * cy + cz * cz), 0.0)  # mean squared radius [m^2]
    # pass 2: volume, per-vertex partial gradient (c held fixed), valence, and their sum S
    vol = 0.0
    sx = 0.0
    sy = 0.0
    sz = 0.0
    s6 = 1.0 / 6.0
    for t in range(m):
        a = tris[t, 0]
        b = tris[t, 1]
        d = tris[t, 2]
        ax = p[a, 0] - cx
        ay = p[a, 1] - cy
        az = p[a, 2] - cz
        bx = p[b, 0] - cx
        by = p[b, 1] - cy
        bz = p[b, 2] - cz
        dx = p[d, 0] - cx
        dy = p[d, 1] - cy
        dz = p[d, 2] - cz
        # b x d, d x a, a x b
        g0x = s6 * (by * dz - bz * dy)
        g0y = s6 * (bz * dx - bx * dz)
        g0z = s6 * (bx * dy - by * dx)
        g1x = s6 * (dy * az - dz * ay)
        g1y = s6 * (dz * ax - dx * az)
        g1z = s6 * (dx * ay - dy * ax)
        g2x = s6 * (ay * bz - az * by)
        g2y = s6 * (az * bx - ax * bz)
        g2z = s6 * (ax * by - ay * bx)
        vol += ax * g0x + ay * g0y + az * g0z
        work[a, 0] += g0x
        work[a, 1] += g0y
        work[a, 2] += g0z
        work[b, 0] += g1x
        work[b, 1] += g1y
        work[b, 2] += g1z
        work[d, 0] += g2x
        work[d, 1] += g2y
        work[d, 2] += g2z
        work[a, 3] += 1.0
        work[b, 3] += 1.0
        work[d, 3] += 1.0
        sx += g0x + g1x + g2x
        sy += g0y + g1y + g2y
        sz += g0z + g1z + g2z
    # pass 3: full gradient grad_v = g_v - valence_v / (3m) * S, stored in work; denominator.
    # work[v, 3] > 0 marks a vertex not yet finalised; it is negated once done.
    den = 0.0
    gg = 0.0
    for t in range(m):
        for k in range(3):
            v = tris[t, k]
            val = work[v, 3]
            if val > 0.0:
                f = val * inv3m
                gx = work[v, 0] - f * sx
                gy = work[v, 1] - f * sy
                gz = work[v, 2] - f * sz
                work[v, 0] = gx
                work[v, 1] = gy
                work[v, 2] = gz
                work[v, 3] = -val
                g2 = gx * gx + gy * gy + gz * gz
                gg += g2
                den += w[v] * g2
    al = alpha
    # a mesh collapsed to a point or a line has no volume gradient (relative to its size)
    degenerate = gg <= (_REL_EPS * r2) * (_REL_EPS * r2)
    if degenerate or den <= 0.0 or not al < _INF:
        for t in range(m):  # leave work clean (valence markers) for the next call
            for k in range(3):
                work[tris[t, k], 3] = 0.0
        return vol
    c = vol - target
    at = al / (h * h)
    dl = (-c - at * lam[0]) / (den + at)
    lam[0] += dl
    # pass 4: apply once per vertex
    for t in range(m):
        for k in range(3):
            v = tris[t, k]
            if work[v, 3] < 0.0:
                work[v, 3] = 0.0
                wv = w[v]
                if wv > 0.0:
                    f = wv * dl
                    p[v, 0] += f * work[v, 0]
                    p[v, 1] += f * work[v, 1]
                    p[v, 2] += f * work[v, 2]
    return vol


# ==============================================================================================
# rigid shape matching
# ==============================================================================================
_PINNED_MASS_SCALE = 1e9


@njit(cache=True)
def _cluster_frame(p, w, cluster_idx, cluster_rest, lo, hi):
    """Mass-weighted centres (current c, rest c0) and the optimal rotation R of one cluster."""
    # masses: 1/w; a pinned vertex (w == 0) weighs _PINNED_MASS_SCALE x the heaviest dynamic one
    mmax = 0.0
    for r in range(lo, hi):
        wv = w[cluster_idx[r]]
        if wv > 0.0 and 1.0 / wv > mmax:
            mmax = 1.0 / wv
    if mmax == 0.0:
        mmax = 1.0
    mp = _PINNED_MASS_SCALE * mmax
    c = np.zeros(3)
    c0 = np.zeros(3)
    mt = 0.0
    for r in range(lo, hi):
        v = cluster_idx[r]
        wv = w[v]
        mv = 1.0 / wv if wv > 0.0 else mp
        mt += mv
        for k in range(3):
            c[k] += mv * p[v, k]
            c0[k] += mv * cluster_rest[r, k]
    for k in range(3):
        c[k] /= mt
        c0[k] /= mt
    a = np.zeros((3, 3))
    for r in range(lo, hi):
        v = cluster_idx[r]
        wv = w[v]
        mv = 1.0 / wv if wv > 0.0 else mp
        for k in range(3):
            dk = mv * (p[v, k] - c[k])
            for l in range(3):
                a[k, l] += dk * (cluster_rest[r, l] - c0[l])
    u, _s, vt = np.linalg.svd(a)
    rot = u @ vt
    if np.linalg.det(rot) < 0.0:
        for k in range(3):
            u[k, 2] = -u[k, 2]
        rot = u @ vt
    return c, c0, rot


@njit(cache=True)
def shape_match(p, w, cluster_ptr, cluster_idx, cluster_rest, stiffness):
    """Rigid shape matching (Mueller et al. 2005), clusters one after another.

    Cluster q owns rows ``cluster_ptr[q] .. cluster_ptr[q+1]-1`` of ``cluster_idx`` (vertex,
    int64) and ``cluster_rest`` (rest position [m], (K, 3)). The goal of every member is
    ``g = c + R (q - c0)`` with c, c0 the mass-weighted current and rest centres and R the
    rotation of the polar decomposition of ``sum m (p - c)(q - c0)^T`` (via SVD, reflections
    removed); dynamic members move ``p += stiffness[q] * (g - p)``, stiffness in [0, 1] per
    iteration. Pinned members (w == 0) are not moved and weigh 1e9 x the heaviest dynamic member.
    Conserves linear momentum when every member is dynamic.
    """
    for q in range(cluster_ptr.shape[0] - 1):
        lo = cluster_ptr[q]
        hi = cluster_ptr[q + 1]
        if hi <= lo:
            continue
        c, c0, rot = _cluster_frame(p, w, cluster_idx, cluster_rest, lo, hi)
        s = stiffness[q]
        for r in range(lo, hi):
            v = cluster_idx[r]
            if w[v] <= 0.0:
                continue
            for k in range(3):
                g = c[k]
                for l in range(3):
                    g += rot[k, l] * (cluster_rest[r, l] - c0[l])
                p[v, k] += s * (g - p[v, k])


# ==============================================================================================
# constraint values, rest values and residuals
# ==============================================================================================
@njit(cache=True)
def stretch_values(p, edges, rest):
    """C = |p_i - p_j| - L for every edge, shape (m,)."""
    out = np.empty(edges.shape[0])
    for j in range(edges.shape[0]):
        a = edges[j, 0]
        b = edges[j, 1]
        d = 0.0
        for k in range(3):
            t = p[a, k] - p[b, k]
            d += t * t
        out[j] = math.sqrt(d) - rest[j]
    return out


@_hot
def _corner_angle(p, o, a, b):
    ux = p[a, 0] - p[o, 0]
    uy = p[a, 1] - p[o, 1]
    uz = p[a, 2] - p[o, 2]
    vx = p[b, 0] - p[o, 0]
    vy = p[b, 1] - p[o, 1]
    vz = p[b, 2] - p[o, 2]
    cx = uy * vz - uz * vy
    cy = uz * vx - ux * vz
    cz = ux * vy - uy * vx
    return math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), ux * vx + uy * vy + uz * vz)


@njit(cache=True)
def angle_values(p, triplets, rest):
    """C = angle at apex - rest [rad] for every triplet, shape (m,)."""
    out = np.empty(triplets.shape[0])
    for j in range(triplets.shape[0]):
        out[j] = _corner_angle(p, triplets[j, 0], triplets[j, 1], triplets[j, 2]) - rest[j]
    return out


@_hot
def _signed_dihedral(p, i0, i1, i2, i3):
    ex = p[i1, 0] - p[i0, 0]
    ey = p[i1, 1] - p[i0, 1]
    ez = p[i1, 2] - p[i0, 2]
    ax = p[i2, 0] - p[i0, 0]
    ay = p[i2, 1] - p[i0, 1]
    az = p[i2, 2] - p[i0, 2]
    bx = p[i3, 0] - p[i0, 0]
    by = p[i3, 1] - p[i0, 1]
    bz = p[i3, 2] - p[i0, 2]
    el = math.sqrt(ex * ex + ey * ey + ez * ez)
    if el < _LEN_EPS:
        return 0.0
    nax = ey * az - ez * ay
    nay = ez * ax - ex * az
    naz = ex * ay - ey * ax
    nbx = by * ez - bz * ey
    nby = bz * ex - bx * ez
    nbz = bx * ey - by * ex
    cx = nay * nbz - naz * nby
    cy = naz * nbx - nax * nbz
    cz = nax * nby - nay * nbx
    return math.atan2((cx * ex + cy * ey + cz * ez) / el, nax * nbx + nay * nby + naz * nbz)


@njit(cache=True)
def dihedral_values(p, quads, rest):
    """C = wrap(signed dihedral - rest) [rad] in (-pi, pi] for every quad, shape (m,)."""
    out = np.empty(quads.shape[0])
    for j in range(quads.shape[0]):
        th = _signed_dihedral(p, quads[j, 0], quads[j, 1], quads[j, 2], quads[j, 3])
        out[j] = _wrap_angle(th - rest[j])
    return out


@njit(cache=True)
def tet_volume_values(p, tets, rest):
    """C = signed volume - rest [m^3] for every tet, shape (m,)."""
    out = np.empty(tets.shape[0])
    for j in range(tets.shape[0]):
        i0 = tets[j, 0]
        a = p[tets[j, 1]] - p[i0]
        b = p[tets[j, 2]] - p[i0]
        c = p[tets[j, 3]] - p[i0]
        vol = (a[0] * (b[1] * c[2] - b[2] * c[1]) + a[1] * (b[2] * c[0] - b[0] * c[2])
               + a[2] * (b[0] * c[1] - b[1] * c[0])) / 6.0
        out[j] = vol - rest[j]
    return out


@njit(cache=True)
def goal_values(p, index, target):
    """C = |p_v - g| [m] per entry, shape (m,)."""
    out = np.empty(index.shape[0])
    for j in range(index.shape[0]):
        d = 0.0
        for k in range(3):
            t = p[index[j], k] - target[j, k]
            d += t * t
        out[j] = math.sqrt(d)
    return out


@njit(cache=True)
def attach_values(p, attach, bary):
    """C = p_v - sum_k b_k p_tk [m] per attachment, shape (m, 3)."""
    out = np.empty((attach.shape[0], 3))
    for j in range(attach.shape[0]):
        for k in range(3):
            out[j, k] = p[attach[j, 0], k] - (bary[j, 0] * p[attach[j, 1], k]
                                              + bary[j, 1] * p[attach[j, 2], k]
                                              + bary[j, 2] * p[attach[j, 3], k])
    return out


@njit(cache=True)
def shape_match_values(p, w, cluster_ptr, cluster_idx, cluster_rest):
    """Distance [m] of every cluster member to its rigid goal, shape (K,)."""
    out = np.empty(cluster_idx.shape[0])
    for q in range(cluster_ptr.shape[0] - 1):
        lo = cluster_ptr[q]
        hi = cluster_ptr[q + 1]
        if hi <= lo:
            continue
        c, c0, rot = _cluster_frame(p, w, cluster_idx, cluster_rest, lo, hi)
        for r in range(lo, hi):
            d = 0.0
            for k in range(3):
                g = c[k]
                for l in range(3):
                    g += rot[k, l] * (cluster_rest[r, l] - c0[l])
                t = p[cluster_idx[r], k] - g
                d += t * t
            out[r] = math.sqrt(d)
    return out


@njit(cache=True)
def residual(values):
    """``(max |C|, RMS of C)`` of an array of constraint values (rows of a 2-d array count as
    vectors: their norms). Returns (0, 0) for no constraints."""
    flat = values.reshape(values.shape[0], -1)
    n = flat.shape[0]
    if n == 0:
        return 0.0, 0.0
    mx = 0.0
    ss = 0.0
    for j in range(n):
        s = 0.0
        for k in range(flat.shape[1]):
            s += flat[j, k] * flat[j, k]
        ss += s
        a = math.sqrt(s)
        if a > mx:
            mx = a
    return mx, math.sqrt(ss / n)


def residual_stretch(p, edges, rest):
    """(max |C| [m], RMS [m]) of the stretch constraints."""
    return residual(stretch_values(p, edges, rest))


def residual_angle(p, triplets, rest):
    """(max |C| [rad], RMS [rad]) of the angle constraints."""
    return residual(angle_values(p, triplets, rest))


def residual_dihedral(p, quads, rest):
    """(max |C| [rad], RMS [rad]) of the dihedral constraints."""
    return residual(dihedral_values(p, quads, rest))


def residual_tet_volume(p, tets, rest):
    """(max |C| [m^3], RMS [m^3]) of the tet volume constraints."""
    return residual(tet_volume_values(p, tets, rest))


def residual_goal(p, index, target):
    """(max |C| [m], RMS [m]) of the goal constraints."""
    return residual(goal_values(p, index, target))


def residual_attach(p, attach, bary):
    """(max |C| [m], RMS [m]) of the attachments (|C| is the norm of the 3-vector)."""
    return residual(attach_values(p, attach, bary))


def residual_mesh_volume(p, tris, target):
    """(|C| [m^3], |C| [m^3]) of the global volume constraint."""
    c = abs(mesh_volume(p, tris) - target)
    return c, c


def residual_shape_match(p, w, cluster_ptr, cluster_idx, cluster_rest):
    """(max, RMS) distance [m] of cluster members to their rigid goals."""
    return residual(shape_match_values(p, w, cluster_ptr, cluster_idx, cluster_rest))


def rest_lengths(x, edges):
    """Rest lengths [m] of edges at positions x, shape (m,)."""
    x = np.asarray(x, dtype=np.float64)
    return np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1)


def rest_angles(x, triplets):
    """Rest corner angles [rad] at positions x, shape (m,)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    return angle_values(x, np.ascontiguousarray(triplets, dtype=np.int64),
                        np.zeros(len(triplets)))


def rest_dihedrals(x, quads):
    """Rest signed dihedral angles [rad] at positions x, shape (m,)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    return dihedral_values(x, np.ascontiguousarray(quads, dtype=np.int64),
                           np.zeros(len(quads)))


def rest_tet_volumes(x, tets):
    """Rest signed tet volumes [m^3] at positions x, shape (m,)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    return tet_volume_values(x, np.ascontiguousarray(tets, dtype=np.int64), np.zeros(len(tets)))
