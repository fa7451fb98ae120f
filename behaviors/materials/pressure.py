"""Pressure of a closed triangle mesh: the enclosed volume held at ``volume_scale`` x its rest
volume (a global constraint, ``mode: volume``), or a gauge pressure force p A n
(``mode: pressure``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numba import njit
from pydantic import Field

from lokigraph.behavior import Behavior, ConstraintBehavior, ConstraintParams
from lokigraph.components.core import Dynamic
from lokigraph.components.materials import Pressure

from ..solvers.nucleus.xpbd import _INF, _REL_EPS, _hot


# ==============================================================================================
# XPBD kernels: global volume of a triangle mesh
# ==============================================================================================
@_hot
def _corners(p, a, b, d, cx, cy, cz):
    """The corners a, b, d of a triangle relative to the point c (9 floats)."""
    return (p[a, 0] - cx, p[a, 1] - cy, p[a, 2] - cz, p[b, 0] - cx, p[b, 1] - cy, p[b, 2] - cz,
            p[d, 0] - cx, p[d, 1] - cy, p[d, 2] - cz)


@_hot
def _tri_gradient(ax, ay, az, bx, by, bz, dx, dy, dz):
    """d/d(a, b, d) of the triangle's signed cone volume (a x b) . d / 6 about the point the
    corners are taken from: (b x d, d x a, a x b) / 6 (9 floats)."""
    s6 = 1.0 / 6.0
    return (s6 * (by * dz - bz * dy), s6 * (bz * dx - bx * dz), s6 * (bx * dy - by * dx),
            s6 * (dy * az - dz * ay), s6 * (dz * ax - dx * az), s6 * (dx * ay - dy * ax),
            s6 * (ay * bz - az * by), s6 * (az * bx - ax * bz), s6 * (ax * by - ay * bx))


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
        ax, ay, az, bx, by, bz, dx, dy, dz = _corners(p, a, b, d, cx, cy, cz)
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
    for t in range(m):
        a = tris[t, 0]
        b = tris[t, 1]
        d = tris[t, 2]
        ax, ay, az, bx, by, bz, dx, dy, dz = _corners(p, a, b, d, cx, cy, cz)
        g0x, g0y, g0z, g1x, g1y, g1z, g2x, g2y, g2z = _tri_gradient(ax, ay, az, bx, by, bz,
                                                                   dx, dy, dz)
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


def residual_mesh_volume(p, tris, target):
    """(|C| [m^3], |C| [m^3]) of the global volume constraint."""
    c = abs(mesh_volume(p, tris) - target)
    return c, c


# ------------------------------------------- Nucleus constraint behavior and the pressure force


class PressureParams(ConstraintParams):
    implicit: Literal["energy", "projection"] = Field(
        "energy", description="With solver: implicit: 'energy' makes the volume constraint "
        "C = V(x) - V_target of every closed mesh a row of the Newton solve itself (an "
        "augmented Lagrangian row, force lam + k C along g = dV/dx, k = the solver's "
        "hard_stiffness times the inertia along g; compliance > 0: the energy C^2 / (2 "
        "compliance)), so the pressure pushes back on the elastic and contact terms of the same "
        "solve; its dense rank-one Hessian k g g^T is applied in the CG product, its per-vertex "
        "diagonal blocks are in the Newton matrix (so every preconditioner sees them); the "
        "projection pass after the solve stays as a safety projection. 'projection': the "
        "volume is projected after the solve only (before). Open meshes stay projected.")
    implicit_stiffness: float | None = Field(
        None, gt=0, description="implicit: energy, a hard volume (compliance 0): the penalty k "
        "as a multiple of the inertia along g, k = s / (h^2 sum_i w_i |g_i|^2) [-] (None: the "
        "implicit solver's hard_stiffness).")
    implicit_hessian: Literal["gauss_newton", "projected"] = Field(
        "gauss_newton", description="implicit: energy: the sparse part (lam + k C) d2V/dx2 of "
        "the row's Hessian (per triangle, indefinite): 'gauss_newton' leaves it out, "
        "'projected' adds each triangle's 9x9 block clamped to its positive eigenvalues.")


@dataclass
class _Volumes:
    items: list  # (global tris, target volume, compliance, lam (1,), work)
    lam: None = None
    #: ``implicit: energy``: the rows of the Newton solve (``_Row``), none otherwise
    rows: list = field(default_factory=list)
    implicit: bool = False  # the scene runs the implicit solver


@dataclass
class _Row:
    """A closed mesh's volume row of the implicit solve."""

    tris: np.ndarray  # (m, 3) global
    verts: np.ndarray  # its vertices (global)
    target: float  # [m^3]
    alpha: float  # compliance [m^3/Pa]; 0: hard (augmented Lagrangian)
    mult: np.ndarray  # (1,) the multiplier lam [Pa], carried between substeps (checkpointed)
    g: np.ndarray  # (n, 3) dV/dx at the last evaluation (0 off the mesh)
    c0: np.ndarray  # (3,) reference point of V this substep (the mean vertex at x^n)
    k: np.ndarray  # (1,) this substep's penalty [Pa/m^3]
    s: np.ndarray  # (1,) sum_i w_i |g_i|^2 at x^n [m^4/kg]


def _closed(tris) -> bool:
    """Every edge of the mesh is shared by exactly two triangles."""
    e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    _, cnt = np.unique(e, axis=0, return_counts=True)
    return bool((cnt == 2).all())


class PressureConstraint(ConstraintBehavior):
    """Holds the enclosed volume of a triangle mesh at volume_scale x rest volume."""

    ParamsModel = PressureParams
    requires = (Dynamic, Pressure)
    # after stretch (30) and before collisions (50), in every iteration: a hard target then holds
    # within 0.1 % through impact (measured on pressure_ball: 0.07 % worst frame, against 0.44 %
    # at importance 0.5 before stretch); after collisions it would push vertices into colliders
    default_importance = 1.0
    default_order = 49

    def bind(self, ctx, elements):
        items = []
        n = ctx.model.particle_count
        for e in elements:
            c = e.get(Pressure)
            if c.mode != "volume":
                continue
            if not len(e.geometry.triangles):
                ctx.error(e, "Pressure", "needs triangles")
                continue
            tris = e.geometry.triangles + e.vertex_offset
            V0 = mesh_volume(ctx.model.particle_rest, tris)
            items.append((tris, V0 * c.volume_scale, c.compliance, np.zeros(1), np.zeros((n, 4))))
        if not items:
            return None
        d = _Volumes(items)
        d.implicit = getattr(ctx.scene.spec, "solver", "nucleus") == "implicit"
        if d.implicit and self.params.implicit == "energy":
            for tris, target, alpha, _lam, _work in items:
                if _closed(tris):
                    d.rows.append(_Row(np.ascontiguousarray(tris, dtype=np.int64),
                                       np.unique(tris).astype(np.int64), float(target),
                                       float(alpha), np.zeros(1), np.zeros((n, 3)), np.zeros(3),
                                       np.zeros(1), np.zeros(1)))
        return d

    def begin_substep(self, ctx, d):
        for it in d.items:
            it[3][:] = 0.0
        for r in d.rows:  # the reference point and the inertia along g at x^n
            x = ctx.state.particle_q
            r.c0[:] = x[r.verts].mean(axis=0)
            volume_gradient(x, r.tris, r.verts, r.c0, r.g)
            gv = r.g[r.verts]
            r.s[0] = float(np.dot(ctx.model.particle_inv_mass[r.verts],
                                  np.einsum("ij,ij->i", gv, gv)))

    def project(self, ctx, d, p):
        for tris, target, alpha, lam, work in d.items:  # loop over elements, not vertices
            project_mesh_volume(p, ctx.model.particle_inv_mass, tris, target, alpha, lam,
                                  ctx.dt, work)

    def residual(self, ctx, d, p):
        return max(abs(mesh_volume(p, t) - v) / max(abs(v), 1e-300)
                   for t, v, *_ in d.items)

    def describe(self, d):
        return (f"{len(d.items)} volumes" + (f" ({len(d.rows)} in the implicit solve)"
                                             if d.rows else "")) if d else ""


class PressureForce(Behavior):
    """Gauge pressure p [Pa] on a triangle mesh: f = p * area * normal, spread to corners."""

    stage = "forces"
    requires = (Dynamic, Pressure)
    accumulates = ("particle_f",)

    def bind(self, ctx, elements):
        tris, pres = [], []
        for e in elements:
            c = e.get(Pressure)
            if c.mode == "pressure" and c.pressure != 0 and len(e.geometry.triangles):
                tris.append(e.geometry.triangles + e.vertex_offset)
                pres.append(np.full(len(e.geometry.triangles), c.pressure))
        if not tris:
            return None
        return (np.concatenate(tris), np.concatenate(pres))

    def step(self, ctx, data):
        if data is None:
            return
        tris, pres = data
        x = ctx.state.particle_q
        P = x[tris]
        fn = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]) * (pres / 6.0)[:, None]  # p A n / 3
        f = ctx.state.particle_f
        for k in range(3):
            np.add.at(f, tris[:, k], fn)


# ==============================================================================================
# Implicit energy (behaviors/solvers/implicit/energy.py has the protocol)
# ==============================================================================================
# With ``PressureParams.implicit`` 'energy' the volume constraint ``C = V(x) - V_target`` of a
# closed mesh is a row of the Newton solve: hard (compliance 0) an augmented Lagrangian term
# ``E = ((lam + k C)^2 - lam^2) / (2 k)``, force ``f = lam + k C`` along ``g = dV/dx``, ``lam``
# [Pa] carried between substeps (``lam += k C`` after a substep, checkpointed); with compliance
# alpha > 0 the energy ``C^2 / (2 alpha)`` (f = C / alpha). ``k = hard_stiffness / (h^2 sum_i
# w_i |g_i|^2)`` (g at x^n): the curvature k g g^T along g is hard_stiffness times the inertia
# there, as the hard distance rows' penalty hard_stiffness m / h^2. The Hessian is
# ``k g g^T + f d2V/dx2``: the first is dense over the mesh's vertices (rank one): the solver
# applies it in the CG product as k g (g . v) and puts its per-vertex diagonal blocks
# k g_i g_i^T into the Newton matrix (``energy_lowrank``); the second is sparse (per triangle)
# and indefinite: left out ('gauss_newton') or clamped per triangle ('projected').
# V is taken about c0, the mean vertex at the start of the substep (for a closed mesh V does not
# depend on it).
from ..solvers.implicit.energy import hess_or_dummy  # noqa: E402


@njit(cache=True)
def volume_gradient(x, tris, verts, c, g):
    """V of the mesh about the point c [m^3]; g (n, 3) = dV/dx at its vertices ``verts`` (their
    rows zeroed first; other rows untouched)."""
    for v in verts:
        g[v, 0] = 0.0
        g[v, 1] = 0.0
        g[v, 2] = 0.0
    vol = 0.0
    for t in range(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        d = tris[t, 2]
        ax, ay, az, bx, by, bz, dx, dy, dz = _corners(x, a, b, d, c[0], c[1], c[2])
        g0x, g0y, g0z, g1x, g1y, g1z, g2x, g2y, g2z = _tri_gradient(ax, ay, az, bx, by, bz,
                                                                   dx, dy, dz)
        vol += ax * g0x + ay * g0y + az * g0z
        g[a, 0] += g0x
        g[a, 1] += g0y
        g[a, 2] += g0z
        g[b, 0] += g1x
        g[b, 1] += g1y
        g[b, 2] += g1z
        g[d, 0] += g2x
        g[d, 1] += g2y
        g[d, 2] += g2z
    return vol


@njit(cache=True)
def volume_hessian_projected(x, tris, c, f, hess):
    """hess[t] (m, 3, 3, 3, 3) = triangle t's part of f d2V/dx2 (V about c), clamped to its
    positive eigenvalues (PSD). Block (a, b) of a.(b x d) / 6 is -[d]x / 6, (a, d) [b]x / 6,
    (b, d) -[a]x / 6, their transposes below the diagonal, zero diagonal blocks."""
    H = np.zeros((9, 9))
    s = f / 6.0
    for t in range(tris.shape[0]):
        p = np.empty((3, 3))
        for k in range(3):
            for r in range(3):
                p[k, r] = x[tris[t, k], r] - c[r]
        H[:] = 0.0
        # (i, j, l): block (i, j) = s [p_l]x with the sign of the cyclic order
        for i, j, l, sg in ((0, 1, 2, -1.0), (0, 2, 1, 1.0), (1, 2, 0, -1.0)):
            vx, vy, vz = p[l, 0], p[l, 1], p[l, 2]
            cr = np.array([[0.0, -vz, vy], [vz, 0.0, -vx], [-vy, vx, 0.0]]) * (sg * s)
            for r in range(3):
                for q in range(3):
                    H[3 * i + r, 3 * j + q] = cr[r, q]
                    H[3 * j + q, 3 * i + r] = cr[r, q]
        w, U = np.linalg.eigh(H)
        for e in range(9):
            if w[e] < 0.0:
                w[e] = 0.0
        Hp = (U * w) @ U.T
        for a in range(3):
            for b in range(3):
                for r in range(3):
                    for q in range(3):
                        hess[t, a, b, r, q] = Hp[3 * a + r, 3 * b + q]


def _row_k(self, ctx, r, opts):
    """The row's curvature d2E/dC2 [Pa/m^3]: 1 / compliance, or the hard penalty
    hard_stiffness / (h^2 sum w |g|^2) (``opts.hard_k`` = hard_stiffness m / h^2)."""
    if r.alpha > 0.0:
        return 1.0 / r.alpha if np.isfinite(r.alpha) else 0.0
    m = ctx.model.particle_mass[r.verts]
    i = int(np.argmax(m))
    if m[i] <= 0.0 or r.s[0] <= 0.0:
        return 0.0
    s = self.params.implicit_stiffness
    hs_h2 = (float(opts.hard_k[r.verts[i]] / m[i]) if s is None else s / (opts.h * opts.h))
    return hs_h2 / r.s[0]


def pressure_energy_stencils(self, ctx, d):
    """The triangles of the closed meshes whose volume is a row of the solve (``implicit``
    'energy'), else none (the solver then projects the volume after the solve)."""
    return [r.tris for r in d.rows] if d is not None else []


def pressure_energy(self, ctx, d, x, grad, hess, opts):
    """E of the volume rows at x; gradient f g; with mode 2 and 'projected' the clamped
    per-triangle blocks of f d2V/dx2 (the rank-one k g g^T: ``pressure_energy_lowrank``)."""
    if d is None or not d.rows:
        return 0.0
    E = 0.0
    for s, r in enumerate(d.rows):
        V = volume_gradient(x, r.tris, r.verts, r.c0, r.g)
        k = _row_k(self, ctx, r, opts)
        r.k[0] = k
        if k == 0.0:
            continue
        c = V - r.target
        lam = r.mult[0] if r.alpha == 0.0 else 0.0
        f = lam + k * c
        E += 0.5 * (f * f - lam * lam) / k
        if opts.mode >= 1 and grad is not None:
            grad[r.verts] += f * r.g[r.verts]
        if opts.mode >= 2 and self.params.implicit_hessian == "projected":
            volume_hessian_projected(x, r.tris, r.c0, f, hess_or_dummy(hess, s, opts))
    return E


def pressure_energy_lowrank(self, d):
    """The rank-one terms (k, g) of the rows' Hessians at the last mode-2 evaluation: the
    solver adds k g (g . v) to its CG product (and k g_i g_i^T to the diagonal blocks)."""
    return [(float(r.k[0]), r.g) for r in d.rows] if d is not None else []


def pressure_update_multipliers(self, ctx, d, x, opts):
    """After a substep: lam += k C (hard rows)."""
    if d is None:
        return
    for r in d.rows:
        if r.alpha == 0.0 and r.k[0] > 0.0:
            r.mult[0] += r.k[0] * (volume_gradient(x, r.tris, r.verts, r.c0, r.g) - r.target)


def pressure_multipliers(self, d):
    return np.array([r.mult[0] for r in d.rows]) if d is not None else np.zeros(0)


def _volume_error(d, x):
    return max(abs(mesh_volume(x, t) / v - 1.0) for t, v, *_ in d.items)


def pressure_implicit_solved(self, ctx, d, x):
    """run.json: ``max_volume_error_solve``, the largest relative volume error at the Newton
    solution (before the projection pass) [-] (implicit solver, either setting)."""
    if d is not None:
        s = ctx.stats
        s["max_volume_error_solve"] = max(s.get("max_volume_error_solve", 0.0),
                                          _volume_error(d, x))


def pressure_implicit_end_substep(self, ctx, d, x):
    """run.json: ``max_volume_error``, the largest relative volume error at the end of a
    substep (after every projection) [-], and with rows in the solve ``max_pressure_lam``, the
    largest multiplier [Pa]."""
    if d is None:
        return
    s = ctx.stats
    s["max_volume_error"] = max(s.get("max_volume_error", 0.0), _volume_error(d, x))
    if d.rows:
        s["max_pressure_lam"] = max(s.get("max_pressure_lam", 0.0),
                                    max(abs(r.mult[0]) for r in d.rows))


def pressure_state_arrays(self, d):
    """Checkpointed run state: the volume rows' multipliers (none without rows)."""
    return {"implicit_lam": pressure_multipliers(self, d)} if d is not None and d.rows else {}


def pressure_load_state_arrays(self, d, arrays):
    if d is not None and d.rows and "implicit_lam" in arrays:
        for r, v in zip(d.rows, arrays["implicit_lam"]):
            r.mult[0] = v


PressureConstraint.energy_stencils = pressure_energy_stencils
PressureConstraint.energy = pressure_energy
PressureConstraint.energy_lowrank = pressure_energy_lowrank
PressureConstraint.energy_update_multipliers = pressure_update_multipliers
PressureConstraint.energy_multipliers = pressure_multipliers
PressureConstraint.implicit_solved = pressure_implicit_solved
PressureConstraint.implicit_end_substep = pressure_implicit_end_substep
PressureConstraint.state_arrays = pressure_state_arrays
PressureConstraint.load_state_arrays = pressure_load_state_arrays
