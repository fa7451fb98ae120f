"""A staggered (MAC) grid for incompressible air or water: advection, forces, pressure projection.

Layout. ``n = (nx, ny, nz)`` cells of size ``h = (hx, hy, hz)`` [m] from ``origin`` [m]. The
x-velocity ``u`` [m/s] lives on the x-faces, shape (nx + 1, ny, nz), face (i, j, k) at
``origin + (i, j + 1/2, k + 1/2) * h``; ``v`` on the y-faces (nx, ny + 1, nz) and ``w`` on the
z-faces (nx, ny, nz + 1) likewise. The pressure ``p`` [Pa] lives at cell centres (nx, ny, nz).
Each face of the box is a ``wall`` (no flow through it), ``open`` (p = 0 outside, the flow leaves
or enters freely) or ``inflow`` (a prescribed normal velocity into the box).

Per time step ``dt`` (what :class:`MacGrid` offers; the coupling behavior calls them in the order
of the Avatar supplement, Figure 2)::

    grid.sample(x, out)                 # velocity at points (trilinear on each face grid)
    grid.splat(x, impulse)              # add impulses [N s] to the faces: the exact transpose
    grid.add_body_acceleration(g, dt)   # gravity on the fluid (buoyancy comes from the pressure)
    grid.project(dt)                    # incompressible: u -= dt / rho grad p, div u = 0
    grid.advect(dt)                     # semi-Lagrangian or MacCormack self-advection

Pressure projection. With the face gradient ``G`` (faces x cells; rows of wall and inflow faces
are empty, an open face has its single interior cell) and the open fraction ``a = 1 - phi_s`` of
every face (phi_s: the solid face fraction; faces inside a solid carry the solid's velocity
``u_s``), the scaled pressure ``q = p dt / rho`` solves ``(G^T diag(a) G) q = -div(a u + (1 - a)
u_s)``, then ``u -= G q``. The matrix is assembled once (scipy.sparse) and its preconditioner
built once; it is rebuilt only when the solid fractions change. The solve is conjugate gradients
preconditioned by one V-cycle of pyamg smoothed aggregation (``amg``), or plain / Jacobi CG for
comparison (``cg``, ``jacobi``); the previous pressure is the initial guess. Measured on a
64^3 box (walls, open top, random field, rtol 1e-8, zero initial guess; 2 busy cores,
``lokigraph bench --fluid 64``): amg 10-13 iterations, 0.19-0.21 s CPU per solve
after a one-off 4-5 s setup; Jacobi-CG 417 iterations, 1.04 s; plain CG 420, 1.05 s. A box of walls only
(pure Neumann) has the constants as null space: one diagonal entry is doubled, which leaves the
gradient of the solution of the consistent system unchanged.

Momentum. :meth:`sample` and :meth:`splat` use the same trilinear weights (which sum to 1 inside
the box), so the momentum removed from the solids by drag is put into the fluid exactly
(``sum_faces m_f du_f = sum_i J_i``, m_f = rho * cell volume). The projection changes the fluid's
momentum by exactly the pressure force on the box walls (:meth:`wall_impulse`). Semi-Lagrangian
advection does not conserve momentum exactly (interpolation); its change is reported apart.

Limitations: uniform grid, first-order time splitting; the viscosity term is explicit (checked
against its stability limit); the solid face fractions of thin cloth and hair are neglected
(phi_s ~ gamma * thickness / h << 1): they act on the fluid through drag only. No free surface.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from numba import njit, prange

FACES = ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max")
WALL, OPEN, INFLOW = 0, 1, 2
KINDS = {"wall": WALL, "open": OPEN, "inflow": INFLOW}
PRESSURE_SOLVERS = ("amg", "jacobi", "cg")
MAX_CELLS = 256 ** 3
"""Most cells of one grid."""


# ---------------------------------------------------------------------------------------------
# point <-> face-grid interpolation (trilinear; splat is the exact transpose of sample)
# ---------------------------------------------------------------------------------------------
@njit(cache=True)
def _axis(xa, o, h, off, n):
    """Fractional index of coordinate ``xa`` on an axis of ``n`` samples at o + (i + off) h,
    clamped into the samples; returns (i0, f) with weights (1 - f, f) on (i0, i0 + 1)."""
    g = (xa - o) / h - off
    if g < 0.0:
        g = 0.0
    top = n - 1.0
    if g > top:
        g = top
    if n < 2:
        return 0, 0.0
    i0 = int(g)
    if i0 > n - 2:
        i0 = n - 2
    return i0, g - i0


@njit(cache=True)
def _inside(p, origin, size):
    return (p[0] >= origin[0] and p[1] >= origin[1] and p[2] >= origin[2]
            and p[0] <= origin[0] + size[0] and p[1] <= origin[1] + size[1]
            and p[2] <= origin[2] + size[2])


@njit(cache=True)
def _interp(q, px, py, pz, origin, h, ox, oy, oz):
    """Trilinear value of the face array ``q`` (staggering offsets ox, oy, oz in cells)."""
    i0, fx = _axis(px, origin[0], h[0], ox, q.shape[0])
    j0, fy = _axis(py, origin[1], h[1], oy, q.shape[1])
    k0, fz = _axis(pz, origin[2], h[2], oz, q.shape[2])
    i1 = min(i0 + 1, q.shape[0] - 1)
    j1 = min(j0 + 1, q.shape[1] - 1)
    k1 = min(k0 + 1, q.shape[2] - 1)
    c00 = q[i0, j0, k0] * (1 - fz) + q[i0, j0, k1] * fz
    c01 = q[i0, j1, k0] * (1 - fz) + q[i0, j1, k1] * fz
    c10 = q[i1, j0, k0] * (1 - fz) + q[i1, j0, k1] * fz
    c11 = q[i1, j1, k0] * (1 - fz) + q[i1, j1, k1] * fz
    return (c00 * (1 - fy) + c01 * fy) * (1 - fx) + (c10 * (1 - fy) + c11 * fy) * fx


@njit(cache=True)
def _interp_minmax(q, px, py, pz, origin, h, ox, oy, oz):
    """Min and max of the 8 samples ``_interp`` blends (MacCormack's limiter)."""
    i0, fx = _axis(px, origin[0], h[0], ox, q.shape[0])
    j0, fy = _axis(py, origin[1], h[1], oy, q.shape[1])
    k0, fz = _axis(pz, origin[2], h[2], oz, q.shape[2])
    lo = np.inf
    hi = -np.inf
    for a in range(2):
        for b in range(2):
            for c in range(2):
                val = q[min(i0 + a, q.shape[0] - 1), min(j0 + b, q.shape[1] - 1),
                        min(k0 + c, q.shape[2] - 1)]
                lo = min(lo, val)
                hi = max(hi, val)
    return lo, hi


@njit(cache=True)
def _splat1(q, px, py, pz, origin, h, ox, oy, oz, value):
    i0, fx = _axis(px, origin[0], h[0], ox, q.shape[0])
    j0, fy = _axis(py, origin[1], h[1], oy, q.shape[1])
    k0, fz = _axis(pz, origin[2], h[2], oz, q.shape[2])
    i1 = min(i0 + 1, q.shape[0] - 1)
    j1 = min(j0 + 1, q.shape[1] - 1)
    k1 = min(k0 + 1, q.shape[2] - 1)
    q[i0, j0, k0] += value * (1 - fx) * (1 - fy) * (1 - fz)
    q[i0, j0, k1] += value * (1 - fx) * (1 - fy) * fz
    q[i0, j1, k0] += value * (1 - fx) * fy * (1 - fz)
    q[i0, j1, k1] += value * (1 - fx) * fy * fz
    q[i1, j0, k0] += value * fx * (1 - fy) * (1 - fz)
    q[i1, j0, k1] += value * fx * (1 - fy) * fz
    q[i1, j1, k0] += value * fx * fy * (1 - fz)
    q[i1, j1, k1] += value * fx * fy * fz


PARALLEL_MIN_ITEMS = 32768
"""Grid loops run in parallel (numba prange) from this many items on, serially below (a
parallel launch costs more than a small grid's whole loop on a busy machine)."""


@njit(cache=True)
def _sample_item(x, u, v, w, origin, size, h, out, i):
    p = x[i]
    if not _inside(p, origin, size):
        out[i, 0] = 0.0
        out[i, 1] = 0.0
        out[i, 2] = 0.0
        return
    out[i, 0] = _interp(u, p[0], p[1], p[2], origin, h, 0.0, 0.5, 0.5)
    out[i, 1] = _interp(v, p[0], p[1], p[2], origin, h, 0.5, 0.0, 0.5)
    out[i, 2] = _interp(w, p[0], p[1], p[2], origin, h, 0.5, 0.5, 0.0)


@njit(cache=True)
def _sample_serial(x, u, v, w, origin, size, h, out):
    for i in range(x.shape[0]):
        _sample_item(x, u, v, w, origin, size, h, out, i)


@njit(cache=True, parallel=True)
def _sample_parallel(x, u, v, w, origin, size, h, out):
    for i in prange(x.shape[0]):
        _sample_item(x, u, v, w, origin, size, h, out, i)


def sample_mac(x, u, v, w, origin, size, h, out):
    """Set ``out[i]`` to the fluid velocity at ``x[i]``; points outside the box get 0."""
    if x.shape[0] >= PARALLEL_MIN_ITEMS:
        _sample_parallel(x, u, v, w, origin, size, h, out)
    else:
        _sample_serial(x, u, v, w, origin, size, h, out)


@njit(cache=True)
def splat_mac(x, value, u, v, w, origin, size, h, scale):
    """Add ``scale * value[i]`` (3 components) to the face arrays with the weights of
    :func:`sample_mac` (its transpose; serial: neighbouring points share faces). Returns the
    number of points inside the box."""
    count = 0
    for i in range(x.shape[0]):
        p = x[i]
        if not _inside(p, origin, size):
            continue
        count += 1
        _splat1(u, p[0], p[1], p[2], origin, h, 0.0, 0.5, 0.5, scale * value[i, 0])
        _splat1(v, p[0], p[1], p[2], origin, h, 0.5, 0.0, 0.5, scale * value[i, 1])
        _splat1(w, p[0], p[1], p[2], origin, h, 0.5, 0.5, 0.0, scale * value[i, 2])
    return count


# ---------------------------------------------------------------------------------------------
# advection
# ---------------------------------------------------------------------------------------------
@njit(cache=True)
def _velocity_at(u, v, w, px, py, pz, origin, h):
    return (_interp(u, px, py, pz, origin, h, 0.0, 0.5, 0.5),
            _interp(v, px, py, pz, origin, h, 0.5, 0.0, 0.5),
            _interp(w, px, py, pz, origin, h, 0.5, 0.5, 0.0))


@njit(cache=True)
def _backtrace(u, v, w, px, py, pz, origin, h, dt):
    """Departure point of the characteristic ending at p after dt (explicit midpoint, RK2)."""
    a0, a1, a2 = _velocity_at(u, v, w, px, py, pz, origin, h)
    mx = px - 0.5 * dt * a0
    my = py - 0.5 * dt * a1
    mz = pz - 0.5 * dt * a2
    b0, b1, b2 = _velocity_at(u, v, w, mx, my, mz, origin, h)
    return px - dt * b0, py - dt * b1, pz - dt * b2


@njit(cache=True)
def _advect_slab(q, ox, oy, oz, u, v, w, origin, h, dt, out, lo, hi, i):
    for j in range(q.shape[1]):
        for k in range(q.shape[2]):
            px = origin[0] + (i + ox) * h[0]
            py = origin[1] + (j + oy) * h[1]
            pz = origin[2] + (k + oz) * h[2]
            dx, dy, dz = _backtrace(u, v, w, px, py, pz, origin, h, dt)
            out[i, j, k] = _interp(q, dx, dy, dz, origin, h, ox, oy, oz)
            a, b = _interp_minmax(q, dx, dy, dz, origin, h, ox, oy, oz)
            lo[i, j, k] = a
            hi[i, j, k] = b


@njit(cache=True)
def _advect_serial(q, ox, oy, oz, u, v, w, origin, h, dt, out, lo, hi):
    for i in range(q.shape[0]):
        _advect_slab(q, ox, oy, oz, u, v, w, origin, h, dt, out, lo, hi, i)


@njit(cache=True, parallel=True)
def _advect_parallel(q, ox, oy, oz, u, v, w, origin, h, dt, out, lo, hi):
    for i in prange(q.shape[0]):
        _advect_slab(q, ox, oy, oz, u, v, w, origin, h, dt, out, lo, hi, i)


def advect_component(q, ox, oy, oz, u, v, w, origin, h, dt, out, lo, hi):
    """Semi-Lagrangian advection of the face array ``q`` (offsets ox, oy, oz) by (u, v, w)
    over ``dt``: out = q(departure point); ``lo``/``hi`` get the min/max of the 8 samples
    blended (for MacCormack's limiter). Departure points are clamped into the box."""
    if q.size >= PARALLEL_MIN_ITEMS:
        _advect_parallel(q, ox, oy, oz, u, v, w, origin, h, dt, out, lo, hi)
    else:
        _advect_serial(q, ox, oy, oz, u, v, w, origin, h, dt, out, lo, hi)


@njit(cache=True)
def maccormack_correct(q, fwd, back, lo, hi, out):
    """out = fwd + (q - back) / 2, clamped to [lo, hi] (Selle et al. 2008: no new extrema)."""
    for i in range(q.shape[0]):
        for j in range(q.shape[1]):
            for k in range(q.shape[2]):
                c = fwd[i, j, k] + 0.5 * (q[i, j, k] - back[i, j, k])
                out[i, j, k] = min(max(c, lo[i, j, k]), hi[i, j, k])


# ---------------------------------------------------------------------------------------------
# preconditioned conjugate gradients (numba vector kernels: no BLAS threads, which on a busy
# machine cost 10-100x for vectors of this size)
# ---------------------------------------------------------------------------------------------
@njit(cache=True)
def _dot(a, b):
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * b[i]
    return s


@njit(cache=True)
def _axpy(alpha, x, y):
    """y += alpha x"""
    for i in range(x.shape[0]):
        y[i] += alpha * x[i]


@njit(cache=True)
def _xpby(x, beta, y):
    """y = x + beta y"""
    for i in range(x.shape[0]):
        y[i] = x[i] + beta * y[i]


@njit(cache=True)
def csr_matvec(indptr, indices, data, x, out, accumulate):
    """out = A x (or out += A x with ``accumulate``) for a CSR matrix, into ``out`` (no
    allocation; the same summation order as scipy's)."""
    for i in range(out.shape[0]):
        s = 0.0
        for jj in range(indptr[i], indptr[i + 1]):
            s += data[jj] * x[indices[jj]]
        if accumulate:
            out[i] += s
        else:
            out[i] = s


def _mv(A, x, out, accumulate=False):
    csr_matvec(A.indptr, A.indices, A.data, x, out, accumulate)
    return out


class _AMGPreconditioner:
    """One V-cycle of a pyamg smoothed-aggregation hierarchy from x = 0: a forward Gauss-Seidel
    sweep before and a backward one after (a symmetric cycle; CSR on every level), the
    coarsest level solved by a sparse LU computed once. Symmetric, so valid inside CG.
    (pyamg's own cycle computes residual norms with BLAS, keeps the coarse levels in BSR and
    applies a dense pseudo-inverse on the coarsest: 10-100x slower per cycle here.) Work
    vectors of every level are allocated once; the returned vector is one of them (valid until
    the next call)."""

    def __init__(self, L):
        import pyamg
        from pyamg.relaxation.relaxation import gauss_seidel
        from scipy.sparse.linalg import factorized

        # pyamg estimates spectral radii from numpy's global random generator: seed it for
        # reproducible runs (bit-identical resumes), then give the caller's state back
        rng_state = np.random.get_state()
        np.random.seed(12345)
        try:
            ml = pyamg.smoothed_aggregation_solver(L, symmetry="symmetric", max_coarse=500,
                                                   improve_candidates=None)
        finally:
            np.random.set_state(rng_state)
        self.A = [sp.csr_matrix(lev.A) for lev in ml.levels]
        self.P = [sp.csr_matrix(lev.P) for lev in ml.levels[:-1]]
        self.R = [sp.csr_matrix(lev.R) for lev in ml.levels[:-1]]
        self.levels = len(ml.levels)
        self._gs = gauss_seidel
        self._coarse = factorized(sp.csc_matrix(self.A[-1]))
        self._x = [np.zeros(A.shape[0]) for A in self.A]
        self._r = [np.zeros(A.shape[0]) for A in self.A]
        self._b = [np.zeros(A.shape[0]) for A in self.A]

    def _cycle(self, lvl, b):
        x = self._x[lvl]
        if lvl == self.levels - 1:
            x[:] = self._coarse(b)
            return x
        A = self.A[lvl]
        x[:] = 0.0
        self._gs(A, x, b, iterations=1, sweep="forward")
        r = _mv(A, x, self._r[lvl])
        np.subtract(b, r, out=r)
        xc = self._cycle(lvl + 1, _mv(self.R[lvl], r, self._b[lvl + 1]))
        _mv(self.P[lvl], xc, x, accumulate=True)
        self._gs(A, x, b, iterations=1, sweep="backward")
        return x

    def __call__(self, r):
        return self._cycle(0, r)


class PCGWork:
    """Work vectors of :func:`pcg` for systems of size n (allocated once)."""

    def __init__(self, n):
        self.r = np.zeros(n)
        self.p = np.zeros(n)
        self.Ap = np.zeros(n)


def pcg(A, b, x, precond, rtol, maxiter, work=None):
    """Solve A x = b (SPD, CSR) from the initial guess ``x`` (updated in place) to
    |b - A x| <= rtol |b|; ``precond(r)`` returns M^-1 r or None for plain CG; ``work``: a
    :class:`PCGWork` (else allocated here). Returns (iterations, relative residual)."""
    nb = math.sqrt(_dot(b, b))
    if nb == 0.0:
        x[:] = 0.0
        return 0, 0.0
    wk = work if work is not None else PCGWork(b.shape[0])
    r, p, Ap = wk.r, wk.p, wk.Ap
    _mv(A, x, r)
    np.subtract(b, r, out=r)
    nr = math.sqrt(_dot(r, r))
    if nr <= rtol * nb:
        return 0, nr / nb
    p[:] = precond(r) if precond is not None else r
    rz = _dot(r, p)
    it = 0
    while it < maxiter:
        it += 1
        _mv(A, p, Ap)
        alpha = rz / _dot(p, Ap)
        _axpy(alpha, p, x)
        _axpy(-alpha, Ap, r)
        nr = math.sqrt(_dot(r, r))
        if nr <= rtol * nb:
            break
        z = precond(r) if precond is not None else r
        rz_new = _dot(r, z)
        _xpby(z, rz_new / rz, p)
        rz = rz_new
    return it, nr / nb


@njit(cache=True)
def assemble_faces(pos, coef, a, diag, open_diag, data, pin):
    """L.data of G^T diag(a) G from each face's precomputed entry positions ``pos`` (F, 4; -1
    unused) and products g_i g_j ``coef``; cells closed on every face (q = 0 there) get the
    diagonal they have with every face open, ``open_diag`` (the scale the preconditioner of
    the open grid expects: measured 35 CG iterations against 79 with a unit diagonal);
    ``pin`` doubles the first diagonal (pure Neumann box)."""
    data[:] = 0.0
    for f in range(pos.shape[0]):
        af = a[f]
        if af == 0.0:
            continue
        for k in range(4):
            if pos[f, k] >= 0:
                data[pos[f, k]] += af * coef[f, k]
    for c in range(diag.shape[0]):
        if data[diag[c]] <= 0.0:
            data[diag[c]] = open_diag[c]
    if pin:
        data[diag[0]] *= 2.0


@njit(cache=True)
def divergence_into(u, v, w, h, out):
    """Cell divergence [1/s] of face velocities into ``out`` (nx, ny, nz)."""
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            for k in range(out.shape[2]):
                out[i, j, k] = ((u[i + 1, j, k] - u[i, j, k]) / h[0]
                                + (v[i, j + 1, k] - v[i, j, k]) / h[1]
                                + (w[i, j, k + 1] - w[i, j, k]) / h[2])


# ---------------------------------------------------------------------------------------------
# the grid
# ---------------------------------------------------------------------------------------------
@dataclass
class ProjectionStats:
    iterations: int = 0
    residual: float = 0.0  # relative residual |b - A q| / |b|
    seconds: float = 0.0  # CPU seconds (process time)
    max_divergence: float = 0.0  # max |div u| after the projection [1/s]


@dataclass
class MacGrid:
    """One simulated fluid box (see the module docstring)."""

    origin: np.ndarray
    n: tuple
    h: np.ndarray
    density: float
    kinds: np.ndarray  # (6,) WALL / OPEN / INFLOW per box face, in FACES order
    inflow: np.ndarray  # (6,) inflow speed into the box [m/s] per face (INFLOW faces)
    viscosity: float = 0.0  # dynamic viscosity [Pa s]
    advection: str = "maccormack"
    solver: str = "amg"
    tolerance: float = 1e-8
    max_iterations: int = 500
    #: optional (phi_s, solid velocity), flat over the u, v, w faces: assembled with the matrix
    solid: tuple | None = None
    u: np.ndarray = field(default=None)
    v: np.ndarray = field(default=None)
    w: np.ndarray = field(default=None)
    p: np.ndarray = field(default=None)  # pressure [Pa]
    stats: ProjectionStats = field(default_factory=ProjectionStats)

    def __post_init__(self):
        nx, ny, nz = self.n
        self.origin = np.asarray(self.origin, np.float64)
        self.h = np.asarray(self.h, np.float64)
        self.size = self.h * np.asarray(self.n, np.float64)
        self.kinds = np.asarray(self.kinds, np.int64)
        self.inflow = np.asarray(self.inflow, np.float64)
        # u, v, w are views of one flat face vector (the order of :meth:`flat`)
        shapes = ((nx + 1, ny, nz), (nx, ny + 1, nz), (nx, ny, nz + 1))
        sizes = [int(np.prod(s)) for s in shapes]
        self._vel = np.zeros(sum(sizes))
        given = (self.u, self.v, self.w)
        views = []
        start = 0
        for sh, sz, g in zip(shapes, sizes, given):
            view = self._vel[start:start + sz].reshape(sh)
            if g is not None:
                view[...] = g
            views.append(view)
            start += sz
        self.u, self.v, self.w = views
        self.p = (np.zeros((nx, ny, nz)) if self.p is None
                  else np.ascontiguousarray(self.p, np.float64))
        self.cell_volume = float(np.prod(self.h))
        self.face_mass = self.density * self.cell_volume
        # scratch, allocated once
        self._scr = [np.zeros_like(a) for a in (self.u, self.v, self.w) for _ in range(4)]
        self._scr2 = [(np.zeros_like(a), np.zeros_like(a)) for a in (self.u, self.v, self.w)]
        self._f0 = np.zeros_like(self._vel)
        self._gq = np.zeros_like(self._vel)
        self._b = np.zeros(nx * ny * nz)
        self._pcg = PCGWork(nx * ny * nz)
        self._solid = None  # (open fraction a, solid velocity u_s), flat over faces
        self._pattern = None  # fast re-assembly of L for moving solids (built on first use)
        self._q = np.zeros(nx * ny * nz)
        self.G = self._gradient_matrix()
        if self.solid is not None:
            self._check_solid(*self.solid)
        self._assemble()
        self.apply_boundaries()

    # -- boundary conditions -----------------------------------------------------------
    def apply_boundaries(self):
        """Wall faces: no normal flow; inflow faces: the inflow speed along the inward
        normal; open faces are left free; faces inside a solid take its velocity."""
        if self._solid is not None:
            blk = self._blocked_idx  # u, v, w are views of the flat _vel
            self._vel[blk] = self._solid[1][blk]
        for f, arr, idx, sign in ((0, self.u, 0, 1.0), (1, self.u, -1, -1.0),
                                  (2, self.v, 0, 1.0), (3, self.v, -1, -1.0),
                                  (4, self.w, 0, 1.0), (5, self.w, -1, -1.0)):
            sl = [slice(None)] * 3
            sl[f // 2] = idx
            if self.kinds[f] == WALL:
                arr[tuple(sl)] = 0.0
            elif self.kinds[f] == INFLOW:
                arr[tuple(sl)] = sign * self.inflow[f]

    def set_velocity(self, vel):
        """Uniform velocity [m/s] everywhere (then the boundary conditions)."""
        self.u[...] = vel[0]
        self.v[...] = vel[1]
        self.w[...] = vel[2]
        self.apply_boundaries()

    # -- pressure matrix ------------------------------------------------------------------
    def _gradient_matrix(self):
        nx, ny, nz = self.n
        cells = np.arange(nx * ny * nz).reshape(nx, ny, nz)
        rows, cols, vals = [], [], []
        offset = 0
        for ax, shape in enumerate(((nx + 1, ny, nz), (nx, ny + 1, nz), (nx, ny, nz + 1))):
            fid = offset + np.arange(int(np.prod(shape))).reshape(shape)
            inv = 1.0 / self.h[ax]
            m = shape[ax]
            # interior faces: right cell +1/h, left cell -1/h
            sl_int = [slice(None)] * 3
            sl_int[ax] = slice(1, m - 1)
            sl_r = [slice(None)] * 3
            sl_r[ax] = slice(1, None)
            sl_l = [slice(None)] * 3
            sl_l[ax] = slice(0, -1)
            f_int = fid[tuple(sl_int)].ravel()
            rows += [f_int, f_int]
            cols += [cells[tuple(sl_r)].ravel(), cells[tuple(sl_l)].ravel()]
            vals += [np.full(f_int.size, inv), np.full(f_int.size, -inv)]
            for side, (fi, ci, sgn) in enumerate(((0, 0, inv), (m - 1, m - 2, -inv))):
                if self.kinds[2 * ax + side] != OPEN:
                    continue  # wall / inflow: prescribed normal velocity, no pressure row
                sf = [slice(None)] * 3
                sf[ax] = fi
                sc = [slice(None)] * 3
                sc[ax] = ci
                fb = fid[tuple(sf)].ravel()
                rows.append(fb)
                cols.append(cells[tuple(sc)].ravel())
                vals.append(np.full(fb.size, sgn))
            offset += int(np.prod(shape))
        self.face_count = offset
        G = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(offset, nx * ny * nz))
        return G

    def _assemble(self):
        """Assemble L = G^T diag(a) G and its preconditioner (once; again only when the static
        solid fractions change)."""
        t0 = time.process_time()
        a = np.ones(self.face_count) if self._solid is None else self._solid[0]
        L = (self.G.T @ sp.diags(a) @ self.G).tocsr()
        empty = L.diagonal() <= 0  # cells closed on every face (inside a solid): q = 0 there
        if empty.any():
            L = (L + sp.diags(empty.astype(np.float64))).tocsr()
        self.neumann = not (self.kinds == OPEN).any()
        if self.neumann:  # pin the constant (see the module docstring)
            L = L.tolil()
            L[0, 0] = 2.0 * L[0, 0]
            L = L.tocsr()
        L.sort_indices()
        self.L = L
        self._prec = None
        if self.solver == "amg":
            self._prec = _AMGPreconditioner(L)
            self.amg_levels = self._prec.levels
        elif self.solver == "jacobi":
            d = 1.0 / L.diagonal()
            self._prec = lambda r: d * r
        self.assemble_seconds = time.process_time() - t0

    def set_solid_fractions(self, phi, solid_velocity):
        """Solid face fractions phi_s in [0, 1] (flat over u, v, w faces) and the solids'
        face velocities [m/s]; the pressure matrix and preconditioner are rebuilt."""
        self._check_solid(phi, solid_velocity)
        self._assemble()

    def set_moving_solid(self, phi, solid_velocity):
        """Solid face fractions and velocities of solids that move every step: the matrix is
        re-assembled in place on the sparsity pattern of the solid-free one (a numba scatter,
        no sparse products) and the preconditioner built at construction is kept (it stays
        symmetric positive definite, so CG still converges; the iteration counts are in the
        projection statistics). The caller passes every solid, static ones included (e.g.
        the face-wise maximum of the static and the moving fractions)."""
        self._check_solid(phi, solid_velocity)
        if self._pattern is None:
            self._build_pattern()
        pos, coef, diag, open_diag = self._pattern
        L = self._Lm
        assemble_faces(pos, coef, self._solid[0], diag, open_diag, L.data, self.neumann)
        self.L = L

    def _build_pattern(self):
        """Positions in L.data of every face's (up to 4) contributions a_f g_i g_j, on the
        pattern of G^T G (every face open)."""
        L0 = (self.G.T @ self.G).tocsr()
        L0.sort_indices()
        nnz = L0.nnz
        look = sp.csr_matrix((np.arange(1, nnz + 1, dtype=np.float64), L0.indices, L0.indptr),
                             shape=L0.shape)
        G = self.G.tocsr()
        G.sort_indices()
        cnt = np.diff(G.indptr)
        F = G.shape[0]
        pos = np.full((F, 4), -1, np.int64)
        coef = np.zeros((F, 4))
        first = G.indptr[:-1]
        # faces with one cell (open boundary): (c, c); with two: (c1,c1), (c2,c2), (c1,c2), (c2,c1)
        one = cnt == 1
        two = cnt == 2
        c1 = np.where(cnt >= 1, G.indices[np.minimum(first, max(G.nnz - 1, 0))], 0)
        g1 = np.where(cnt >= 1, G.data[np.minimum(first, max(G.nnz - 1, 0))], 0.0)
        c2 = np.where(two, G.indices[np.minimum(first + 1, max(G.nnz - 1, 0))], 0)
        g2 = np.where(two, G.data[np.minimum(first + 1, max(G.nnz - 1, 0))], 0.0)
        sel = one | two
        f = np.flatnonzero(sel)
        pos[f, 0] = np.asarray(look[c1[f], c1[f]]).ravel().astype(np.int64) - 1
        coef[f, 0] = g1[f] * g1[f]
        f = np.flatnonzero(two)
        pos[f, 1] = np.asarray(look[c2[f], c2[f]]).ravel().astype(np.int64) - 1
        coef[f, 1] = g2[f] * g2[f]
        pos[f, 2] = np.asarray(look[c1[f], c2[f]]).ravel().astype(np.int64) - 1
        coef[f, 2] = g1[f] * g2[f]
        pos[f, 3] = np.asarray(look[c2[f], c1[f]]).ravel().astype(np.int64) - 1
        coef[f, 3] = g1[f] * g2[f]
        diag = (np.asarray(look.diagonal()).astype(np.int64) - 1)
        self._pattern = (pos, coef, diag, np.ascontiguousarray(L0.diagonal()))
        self._Lm = sp.csr_matrix((np.zeros(nnz), L0.indices.copy(), L0.indptr.copy()),
                                 shape=L0.shape)

    def _check_solid(self, phi, solid_velocity):
        nf = self.u.size + self.v.size + self.w.size
        phi = np.asarray(phi, np.float64).ravel()
        if phi.size != nf or (phi < 0).any() or (phi > 1).any():
            raise ValueError(f"solid fractions need {nf} values in [0, 1]")
        self._solid = (1.0 - phi, np.asarray(solid_velocity, np.float64).ravel())
        a, us = self._solid
        self._solid_flux = (1.0 - a) * us
        self._blocked_idx = np.flatnonzero(a <= 0)  # faces fully inside a solid

    def face_centers(self):
        """Positions [m] of the u, v, w faces, flat in the order of :meth:`flat`, (F, 3)."""
        out = []
        for ax, q in enumerate((self.u, self.v, self.w)):
            off = np.full(3, 0.5)
            off[ax] = 0.0
            idx = np.stack(np.meshgrid(*[np.arange(m) for m in q.shape], indexing="ij"), -1)
            out.append((self.origin + (idx.reshape(-1, 3) + off) * self.h))
        return np.concatenate(out)

    # -- operators ----------------------------------------------------------------------
    def flat(self):
        return np.concatenate([self.u.ravel(), self.v.ravel(), self.w.ravel()])

    def set_flat(self, f):
        a, b = self.u.size, self.u.size + self.v.size
        self.u[...] = f[:a].reshape(self.u.shape)
        self.v[...] = f[a:b].reshape(self.v.shape)
        self.w[...] = f[b:].reshape(self.w.shape)

    def divergence(self, u=None, v=None, w=None):
        """Cell divergence [1/s], shape n."""
        u = self.u if u is None else u
        v = self.v if v is None else v
        w = self.w if w is None else w
        return (np.diff(u, axis=0) / self.h[0] + np.diff(v, axis=1) / self.h[1]
                + np.diff(w, axis=2) / self.h[2])

    def fluid_divergence(self):
        """Divergence [1/s] of the volume flux a u + (1 - a) u_s (= divergence without
        solids): what the projection makes zero (into a buffer reused by every call)."""
        out = self._b.reshape(self.n)
        if self._solid is None:
            divergence_into(self.u, self.v, self.w, self.h, out)
            return out
        f = self._f0
        np.multiply(self._solid[0], self._vel, out=f)
        f += self._solid_flux
        nu, nv = self.u.size, self.v.size
        divergence_into(f[:nu].reshape(self.u.shape), f[nu:nu + nv].reshape(self.v.shape),
                        f[nu + nv:].reshape(self.w.shape), self.h, out)
        return out

    def project(self, dt):
        """Make the velocity divergence free (with the solids' prescribed face velocities);
        sets ``p`` [Pa] and ``stats``. Returns the stats. Works in buffers allocated once."""
        t0 = time.process_time()
        vel, f0 = self._vel, self._f0
        f0[:] = vel
        if self._solid is not None:
            a, us = self._solid
            np.multiply(a, f0, out=vel)
            vel += self._solid_flux
        b = self._b
        divergence_into(self.u, self.v, self.w, self.h, b.reshape(self.n))
        np.negative(b, out=b)
        if self.neumann:
            b -= b.mean()
        iters, res = pcg(self.L, b, self._q, self._prec, self.tolerance, self.max_iterations,
                         self._pcg)
        q = self._q
        gq = _mv(self.G, q, self._gq)
        np.subtract(f0, gq, out=vel)
        self.apply_boundaries()  # faces inside a solid take its velocity there
        np.multiply(q, self.density / dt, out=self.p.reshape(-1))
        s = self.stats
        s.iterations = iters
        s.residual = res
        s.max_divergence = float(np.abs(self.fluid_divergence()).max())
        s.seconds = time.process_time() - t0
        return s

    def wall_impulse(self, dt):
        """Momentum [N s] the box faces gave the fluid in the last projection: minus the
        pressure force on the wall and inflow faces (cell-centre pressure of the adjacent
        cell, as the discrete gradient sees it) times dt. Open faces: p = 0 outside, their
        pressure force on the fluid is counted too (it is a force from outside the box)."""
        p = self.p
        A = (self.h[1] * self.h[2], self.h[0] * self.h[2], self.h[0] * self.h[1])
        out = np.zeros(3)
        for ax in range(3):
            lo = np.take(p, 0, axis=ax).sum()
            hi = np.take(p, -1, axis=ax).sum()
            out[ax] = dt * A[ax] * (lo - hi)
        return out

    def momentum(self):
        """Fluid momentum [kg m/s]: rho * cell volume * sum of the face velocities (faces of
        walls excluded: they carry no fluid)."""
        m = self.face_mass
        return np.array([m * self._interior(self.u, 0).sum(), m * self._interior(self.v, 1).sum(),
                         m * self._interior(self.w, 2).sum()])

    def kinetic_energy(self):
        """Fluid kinetic energy [J] (interior faces at full cell mass, boundary faces half)."""
        m = self.face_mass
        e = 0.0
        for ax, q in enumerate((self.u, self.v, self.w)):
            e += 0.5 * m * float((self._interior(q, ax) ** 2).sum())
        return e

    @staticmethod
    def _interior(q, ax):
        sl = [slice(None)] * 3
        sl[ax] = slice(1, q.shape[ax] - 1)
        return q[tuple(sl)]

    def add_body_acceleration(self, g, dt):
        """u += g dt on the fluid faces (then the boundary conditions)."""
        if g[0]:
            self.u += g[0] * dt
        if g[1]:
            self.v += g[1] * dt
        if g[2]:
            self.w += g[2] * dt
        self.apply_boundaries()

    def diffuse(self, dt):
        """Explicit viscous diffusion u += dt nu lap(u), with zero-gradient (free-slip) ghost
        values at the box faces; stable for nu dt sum(2 / h^2) <= 1 (checked at bind)."""
        if self.viscosity <= 0:
            return
        nu = self.viscosity / self.density
        for q in (self.u, self.v, self.w):
            lap = np.zeros_like(q)
            for ax in range(3):
                if q.shape[ax] < 2:
                    continue
                d = np.diff(q, axis=ax) / self.h[ax] ** 2
                lo = [slice(None)] * 3
                hi = [slice(None)] * 3
                lo[ax] = slice(0, -1)
                hi[ax] = slice(1, None)
                lap[tuple(lo)] += d
                lap[tuple(hi)] -= d
            q += nu * dt * lap
        self.apply_boundaries()

    def advect(self, dt):
        """Self-advection over dt: semi-Lagrangian (RK2 backtrace, trilinear), or MacCormack
        (forward + backward semi-Lagrangian, error-corrected, limited to the local extrema)."""
        o, h = self.origin, self.h
        U, V, W = self.u, self.v, self.w
        offs = ((0.0, 0.5, 0.5), (0.5, 0.0, 0.5), (0.5, 0.5, 0.0))
        outs = []
        for c, q in enumerate((U, V, W)):
            fwd, back, lo, hi = self._scr[4 * c: 4 * c + 4]
            advect_component(q, *offs[c], U, V, W, o, h, dt, fwd, lo, hi)
            outs.append((q, fwd, back, lo, hi))
        if self.advection == "maccormack":
            for c, (q, fwd, back, lo, hi) in enumerate(outs):
                t_lo, t_hi = self._scr2[c]
                advect_component(fwd, *offs[c], U, V, W, o, h, -dt, back, t_lo, t_hi)
            for q, fwd, back, lo, hi in outs:
                maccormack_correct(q, fwd, back, lo, hi, back)
                q[...] = back
        else:
            for q, fwd, back, lo, hi in outs:
                q[...] = fwd
        self.apply_boundaries()

    def sample(self, x, out):
        sample_mac(x, self.u, self.v, self.w, self.origin, self.size, self.h, out)

    def splat(self, x, impulse):
        """Add impulses [N s] at points ``x`` to the fluid: du_f = sum_i w_if J_i / m_f."""
        return splat_mac(x, impulse, self.u, self.v, self.w, self.origin, self.size, self.h,
                         1.0 / self.face_mass)

    def sample_pressure_gradient(self, x, out):
        """Pressure gradient [Pa/m] at points (from the face gradients of p, trilinear)."""
        gx = np.zeros_like(self.u)
        gy = np.zeros_like(self.v)
        gz = np.zeros_like(self.w)
        gx[1:-1] = np.diff(self.p, axis=0) / self.h[0]
        gy[:, 1:-1] = np.diff(self.p, axis=1) / self.h[1]
        gz[:, :, 1:-1] = np.diff(self.p, axis=2) / self.h[2]
        # boundary faces: copy the neighbouring interior gradient (hydrostatics up to the wall)
        for g, ax in ((gx, 0), (gy, 1), (gz, 2)):
            m = g.shape[ax]
            if m > 2:
                sl0 = [slice(None)] * 3
                sl1 = [slice(None)] * 3
                sl0[ax], sl1[ax] = 0, 1
                g[tuple(sl0)] = g[tuple(sl1)]
                sl0[ax], sl1[ax] = m - 1, m - 2
                g[tuple(sl0)] = g[tuple(sl1)]
        sample_mac(x, gx, gy, gz, self.origin, self.size, self.h, out)

    def cell_velocity(self):
        """Velocity at cell centres [m/s], shape (nx, ny, nz, 3) (face averages)."""
        return np.stack([0.5 * (self.u[1:] + self.u[:-1]), 0.5 * (self.v[:, 1:] + self.v[:, :-1]),
                         0.5 * (self.w[:, :, 1:] + self.w[:, :, :-1])], axis=-1)


def solid_face_fractions(grid: MacGrid, inside, samples: int = 3, chunk: int = 200_000):
    """phi_s of every face (flat, order of :meth:`MacGrid.flat`): the fraction of a
    ``samples`` x ``samples`` lattice over the face's square that ``inside(points) -> bool``
    puts inside the solid."""
    centers = grid.face_centers()
    sizes = (grid.u.size, grid.v.size, grid.w.size)
    axis_of = np.repeat(np.arange(3), sizes)
    t = (np.arange(samples) + 0.5) / samples - 0.5
    phi = np.zeros(len(centers))
    for ax in range(3):
        a1, a2 = [k for k in range(3) if k != ax]
        offs = np.zeros((samples * samples, 3))
        g1, g2 = np.meshgrid(t * grid.h[a1], t * grid.h[a2], indexing="ij")
        offs[:, a1] = g1.ravel()
        offs[:, a2] = g2.ravel()
        ids = np.flatnonzero(axis_of == ax)
        for s0 in range(0, len(ids), chunk):
            sel = ids[s0:s0 + chunk]
            pts = (centers[sel, None, :] + offs[None]).reshape(-1, 3)
            phi[sel] = inside(pts).reshape(len(sel), -1).mean(axis=1)
    return phi


def pressure_poisson(n, h=1.0, kinds=(WALL, WALL, WALL, WALL, WALL, OPEN), solver="amg"):
    """A grid with only its pressure matrix, for benchmarks and tests."""
    return MacGrid(np.zeros(3), tuple(n), np.full(3, h) if np.isscalar(h) else h, 1.0,
                   np.asarray(kinds), np.zeros(6), solver=solver)


__all__ = ["FACES", "KINDS", "MAX_CELLS", "MacGrid", "PARALLEL_MIN_ITEMS", "PRESSURE_SOLVERS",
           "ProjectionStats", "advect_component", "maccormack_correct", "pcg", "pressure_poisson",
           "sample_mac", "solid_face_fractions", "splat_mac"]
