"""Linear solves of the implicit solver: preconditioned conjugate gradients on the block-sparse
Newton matrix (scipy.sparse BSR, 3x3 blocks), with a block-Jacobi preconditioner (the inverse of
every 3x3 diagonal block) or, for comparison, pyamg smoothed aggregation (one V-cycle).

The block-Jacobi PCG runs in one compiled loop (``pcg_block_jacobi_after``); with ``PARALLEL_PCG``
(opt-in) on more than one numba thread its vertex loops run in ``prange``
(``pcg_block_jacobi_par``): both give bitwise the same iterates. One iteration is one read of every
3x3 block; measured on the Newton matrix of the 128 x 128 drop's impact (19,203 vertices, 183,555
blocks, 13.2 MB; graphs/bench/implicit_cost_cg.py) the product alone takes ~0.5 ms, about 2.7 ns (~8
cycles) a block: bound by its 18 floating-point operations a block, not by the bytes (the matrix
stored as its upper triangle, 55 % of the bytes, saves ~10 %; the data in float32 is slower)."""

from __future__ import annotations

import math

import numpy as np
from numba import get_num_threads, njit, prange


@njit(cache=True)
def invert_blocks(diag_blocks, out):
    """out[i] = inverse of the 3x3 block diag_blocks[i] (symmetric positive definite expected;
    a singular block gets the identity)."""
    for i in range(diag_blocks.shape[0]):
        a = diag_blocks[i]
        c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
        c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
        c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
        det = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
        if det == 0.0 or not math.isfinite(det):
            for r in range(3):
                for s in range(3):
                    out[i, r, s] = 1.0 if r == s else 0.0
            continue
        idet = 1.0 / det
        out[i, 0, 0] = c00 * idet
        out[i, 1, 0] = c01 * idet
        out[i, 2, 0] = c02 * idet
        out[i, 0, 1] = (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) * idet
        out[i, 1, 1] = (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) * idet
        out[i, 2, 1] = (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) * idet
        out[i, 0, 2] = (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) * idet
        out[i, 1, 2] = (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) * idet
        out[i, 2, 2] = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) * idet


@njit(cache=True)
def apply_blocks(inv, r, z):
    """z[i] = inv[i] @ r[i] for (n, 3) vectors."""
    for i in range(inv.shape[0]):
        for a in range(3):
            z[i, a] = inv[i, a, 0] * r[i, 0] + inv[i, a, 1] * r[i, 1] + inv[i, a, 2] * r[i, 2]


@njit(cache=True, inline="always")
def _row_product(indptr, indices, d9, p, i):
    """Row i of the BSR product A p, the blocks read through the flat view ``d9`` of the data
    (9 values a block, row-major)."""
    y0 = 0.0
    y1 = 0.0
    y2 = 0.0
    for q in range(indptr[i], indptr[i + 1]):
        j = indices[q]
        x0 = p[j, 0]
        x1 = p[j, 1]
        x2 = p[j, 2]
        o = 9 * q
        y0 += d9[o] * x0 + d9[o + 1] * x1 + d9[o + 2] * x2
        y1 += d9[o + 3] * x0 + d9[o + 4] * x1 + d9[o + 5] * x2
        y2 += d9[o + 6] * x0 + d9[o + 7] * x1 + d9[o + 8] * x2
    return y0, y1, y2


@njit(cache=True)
def bsr_matvec(indptr, indices, data, x, y):
    """y = A x for a BSR matrix of 3x3 blocks, vectors (n, 3) (``_row_product`` per row)."""
    d9 = data.reshape(-1)
    for i in range(indptr.shape[0] - 1):
        y[i, 0], y[i, 1], y[i, 2] = _row_product(indptr, indices, d9, x, i)


@njit(cache=True)
def _dot(a, b):
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i, 0] * b[i, 0] + a[i, 1] * b[i, 1] + a[i, 2] * b[i, 2]
    return s


@njit(cache=True, inline="always")
def _precond_row(inv, r, z, i):
    """z[i] = inv[i] r[i]; returns vertex i's terms of r . r and r . z."""
    r0, r1, r2 = r[i, 0], r[i, 1], r[i, 2]
    z0 = inv[i, 0, 0] * r0 + inv[i, 0, 1] * r1 + inv[i, 0, 2] * r2
    z1 = inv[i, 1, 0] * r0 + inv[i, 1, 1] * r1 + inv[i, 1, 2] * r2
    z2 = inv[i, 2, 0] * r0 + inv[i, 2, 1] * r1 + inv[i, 2, 2] * r2
    z[i, 0], z[i, 1], z[i, 2] = z0, z1, z2
    return r0 * r0 + r1 * r1 + r2 * r2, r0 * z0 + r1 * z1 + r2 * z2


@njit(cache=True, inline="always")
def _step_row(x, r, z, p, Ap, inv, al, i):
    """Vertex i of a PCG step: x += al p, r -= al A p, z = P^-1 r; returns its terms of r . r
    and r . z (``_precond_row``)."""
    for a in range(3):
        x[i, a] += al * p[i, a]
        r[i, a] -= al * Ap[i, a]
    return _precond_row(inv, r, z, i)


@njit(cache=True)
def pcg_block_jacobi(indptr, indices, data, inv, b, tol, maxit, x, r, z, p, Ap):
    """PCG with the block-Jacobi preconditioner ``inv`` (inverse diagonal blocks), all in one
    compiled loop (the same iteration as :func:`pcg`). Returns (iterations, relative residual).

    The vector passes are fused into the matrix product and the preconditioner application
    (p . Ap summed as A p is formed, r . r as r is updated, r . z as z is formed), each sum in
    the order of ``_dot``: the iterates are bitwise those of the unfused loop
    (``bsr_matvec``, ``apply_blocks``, ``_dot``), in 3 passes over the vectors per iteration
    instead of 7 (the matrix is read once either way). The loop is that of
    :func:`pcg_block_jacobi_after` with its second stop test never taken."""
    return pcg_block_jacobi_after(indptr, indices, data, inv, b, tol, maxit + 1, 0.0, maxit, x, r,
                                  z, p, Ap)


@njit(cache=True)
def pcg_block_jacobi_after(indptr, indices, data, inv, b, tol, after, loose, maxit, x, r, z, p,
                           Ap):
    """The fused PCG loop of :func:`pcg_block_jacobi`, with a second stop test: from iteration
    ``after`` on it also stops at |r| <= loose |b| (the forcing term of ``cg_forcing_after``);
    a solve that meets ``tol`` within ``after`` iterations is bitwise that of
    :func:`pcg_block_jacobi` with ``tol``. Returns (iterations, relative residual).

    Per iteration three passes: the matrix product with p . Ap; the x and r updates with r . r,
    the preconditioner z = P^-1 r and r . z (z is formed before the stop test reads r . r: a
    solve that stops leaves z unused, as the loop before did not form it); p = z + beta p. The
    blocks are read through the flat view of ``data`` (9 values a block, row-major: the same
    products in the same order, about 10 % less time than the 3-d indexing)."""
    n = b.shape[0]
    d9 = data.reshape(-1)
    bb = 0.0
    for i in range(n):
        for a in range(3):
            x[i, a] = 0.0
            r[i, a] = b[i, a]
        bb += b[i, 0] * b[i, 0] + b[i, 1] * b[i, 1] + b[i, 2] * b[i, 2]
    bn = math.sqrt(bb)
    if bn == 0.0:
        return 0, 0.0
    rz = 0.0
    for i in range(n):
        rz += _precond_row(inv, r, p, i)[1]
    it = 0
    rn = bn
    while it < maxit:
        pAp = 0.0
        for i in range(n):
            y0, y1, y2 = _row_product(indptr, indices, d9, p, i)
            Ap[i, 0] = y0
            Ap[i, 1] = y1
            Ap[i, 2] = y2
            pAp += p[i, 0] * y0 + p[i, 1] * y1 + p[i, 2] * y2
        if pAp <= 0.0:
            break
        al = rz / pAp
        rr = 0.0
        rz_new = 0.0
        for i in range(n):
            trr, trz = _step_row(x, r, z, p, Ap, inv, al, i)
            rr += trr
            rz_new += trz
        it += 1
        rn = math.sqrt(rr)
        if rn <= tol * bn or (it >= after and rn <= loose * bn):
            break
        beta = rz_new / rz
        rz = rz_new
        for i in range(n):
            for a in range(3):
                p[i, a] = z[i, a] + beta * p[i, a]
    return it, rn / bn


@njit(cache=True, parallel=True)
def pcg_block_jacobi_par(indptr, indices, data, inv, b, tol, after, loose, maxit, x, r, z, p, Ap,
                         t):
    """:func:`pcg_block_jacobi_after` with its vertex loops in ``prange`` (numba threads),
    bitwise the same iterates at any thread count: each vertex's term of a dot product (the
    serial loop's expression) goes into the scratch ``t`` (n, 2) in parallel, and the terms are
    summed serially in vertex order, as the serial loop adds them; the matrix product splits
    by rows, each row's sum the serial one. Returns (iterations, relative residual)."""
    n = b.shape[0]
    d9 = data.reshape(-1)
    for i in prange(n):
        for a in range(3):
            x[i, a] = 0.0
            r[i, a] = b[i, a]
        t[i, 0] = b[i, 0] * b[i, 0] + b[i, 1] * b[i, 1] + b[i, 2] * b[i, 2]
    bb = 0.0
    for i in range(n):
        bb += t[i, 0]
    bn = math.sqrt(bb)
    if bn == 0.0:
        return 0, 0.0
    for i in prange(n):
        t[i, 0] = _precond_row(inv, r, p, i)[1]
    rz = 0.0
    for i in range(n):
        rz += t[i, 0]
    it = 0
    rn = bn
    while it < maxit:
        for i in prange(n):
            y0, y1, y2 = _row_product(indptr, indices, d9, p, i)
            Ap[i, 0] = y0
            Ap[i, 1] = y1
            Ap[i, 2] = y2
            t[i, 0] = p[i, 0] * y0 + p[i, 1] * y1 + p[i, 2] * y2
        pAp = 0.0
        for i in range(n):
            pAp += t[i, 0]
        if pAp <= 0.0:
            break
        al = rz / pAp
        for i in prange(n):
            t[i, 0], t[i, 1] = _step_row(x, r, z, p, Ap, inv, al, i)
        rr = 0.0
        rz_new = 0.0
        for i in range(n):
            rr += t[i, 0]
            rz_new += t[i, 1]
        it += 1
        rn = math.sqrt(rr)
        if rn <= tol * bn or (it >= after and rn <= loose * bn):
            break
        beta = rz_new / rz
        rz = rz_new
        for i in prange(n):
            for a in range(3):
                p[i, a] = z[i, a] + beta * p[i, a]
    return it, rn / bn


@njit(cache=True)
def pcg_block_jacobi_unfused(indptr, indices, data, inv, b, tol, maxit, x, r, z, p, Ap):
    """The PCG of :func:`pcg_block_jacobi` with separate passes (``bsr_matvec``,
    ``apply_blocks``, ``_dot``): the reference its fused loop reproduces bitwise."""
    n = b.shape[0]
    for i in range(n):
        for a in range(3):
            x[i, a] = 0.0
            r[i, a] = b[i, a]
    bn = math.sqrt(_dot(b, b))
    if bn == 0.0:
        return 0, 0.0
    apply_blocks(inv, r, z)
    for i in range(n):
        for a in range(3):
            p[i, a] = z[i, a]
    rz = _dot(r, z)
    it = 0
    rn = bn
    while it < maxit:
        bsr_matvec(indptr, indices, data, p, Ap)
        pAp = _dot(p, Ap)
        if pAp <= 0.0:
            break
        al = rz / pAp
        for i in range(n):
            for a in range(3):
                x[i, a] += al * p[i, a]
                r[i, a] -= al * Ap[i, a]
        it += 1
        rn = math.sqrt(_dot(r, r))
        if rn <= tol * bn:
            break
        apply_blocks(inv, r, z)
        rz_new = _dot(r, z)
        beta = rz_new / rz
        rz = rz_new
        for i in range(n):
            for a in range(3):
                p[i, a] = z[i, a] + beta * p[i, a]
    return it, rn / bn


def pcg(A, b, precond, tol, maxit, x, work, after=0, loose=0.0):
    """Solve A x = b (A symmetric positive definite, (3n, 3n)) by preconditioned CG from x = 0.

    ``b``, ``x``: (n, 3); ``precond(r, z)`` writes z = P^-1 r; stops when |r| <= tol |b|
    (Euclidean), from iteration ``after`` (> 0) on also when |r| <= loose |b|, or after
    ``maxit`` iterations. ``work``: dict of (n, 3) scratch arrays.
    Returns (iterations, relative residual).
    """
    r, z, p = work["r"], work["z"], work["p"]
    x[:] = 0.0
    r[:] = b
    bn = math.sqrt(float(np.vdot(b, b)))
    if bn == 0.0:
        return 0, 0.0
    precond(r, z)
    p[:] = z
    rz = float(np.vdot(r, z))
    it = 0
    rn = bn
    while it < maxit:
        Ap = (A @ p.reshape(-1)).reshape(-1, 3)
        pAp = float(np.vdot(p, Ap))
        if pAp <= 0.0:
            break  # not positive definite along p (should not happen with PSD blocks + mass)
        a = rz / pAp
        x += a * p
        r -= a * Ap
        it += 1
        rn = math.sqrt(float(np.vdot(r, r)))
        if rn <= tol * bn or (0 < after <= it and rn <= loose * bn):
            break
        precond(r, z)
        rz_new = float(np.vdot(r, z))
        p *= rz_new / rz
        p += z
        rz = rz_new
    return it, rn / bn


#: opt-in (positions bitwise the same either way): the block-Jacobi PCG runs its vertex loops on
#: numba's threads (``pcg_block_jacobi_par``) from ``PARALLEL_MIN_VERTICES`` unknowns on, when
#: more than one thread is set. Off: on this 2-core machine shared by other jobs (load ~5) two
#: threads took more wall time than one (graphs/bench/implicit_cost.py --ab, module docstring)
PARALLEL_PCG = False
PARALLEL_MIN_VERTICES = 4096


class BlockJacobi:
    """P = block diagonal of A (3x3 per vertex), inverted once per Newton iteration."""

    name = "block_jacobi"

    def __init__(self, n):
        self.inv = np.zeros((n, 3, 3))
        self.t = np.zeros((n, 2))  # the parallel loop's per-vertex dot-product terms

    def setup(self, A, diag_index):
        invert_blocks(A.data[diag_index], self.inv)

    def __call__(self, r, z):
        apply_blocks(self.inv, r, z)

    def solve(self, A, b, tol, maxit, x, work, after=0, loose=0.0):
        """The whole PCG in one compiled loop (see :func:`pcg_block_jacobi`; with ``after``
        > 0 :func:`pcg_block_jacobi_after`; with ``PARALLEL_PCG`` on more than one numba
        thread and from ``PARALLEL_MIN_VERTICES`` unknowns :func:`pcg_block_jacobi_par`, the
        same iterates)."""
        if PARALLEL_PCG and len(b) >= PARALLEL_MIN_VERTICES and get_num_threads() > 1:
            return pcg_block_jacobi_par(A.indptr, A.indices, A.data, self.inv, b, tol,
                                        after if after > 0 else maxit + 1, loose, maxit, x,
                                        work["r"], work["z"], work["p"], work["Ap"], self.t)
        if after > 0:
            return pcg_block_jacobi_after(A.indptr, A.indices, A.data, self.inv, b, tol, after,
                                          loose, maxit, x, work["r"], work["z"], work["p"],
                                          work["Ap"])
        return pcg_block_jacobi(A.indptr, A.indices, A.data, self.inv, b, tol, maxit, x,
                                work["r"], work["z"], work["p"], work["Ap"])


class Identity:
    """No preconditioner (plain CG), for measuring what the block-Jacobi one gains."""

    name = "none"

    def __init__(self, n):
        pass

    def setup(self, A, diag_index):
        pass

    def __call__(self, r, z):
        z[:] = r

    def solve(self, A, b, tol, maxit, x, work, after=0, loose=0.0):
        return pcg(A, b, self, tol, maxit, x, work, after, loose)


class SmoothedAggregation:
    """pyamg smoothed aggregation, one V-cycle per application (rebuilt per Newton iteration);
    for measurement against block-Jacobi."""

    name = "amg"

    def __init__(self, n):
        self.ml = None

    def setup(self, A, diag_index):
        import pyamg

        self.ml = pyamg.smoothed_aggregation_solver(A.tocsr(), max_coarse=300)
        self.M = self.ml.aspreconditioner(cycle="V")

    def __call__(self, r, z):
        z[:] = (self.M @ r.reshape(-1)).reshape(-1, 3)

    def solve(self, A, b, tol, maxit, x, work, after=0, loose=0.0):
        return pcg(A, b, self, tol, maxit, x, work, after, loose)
