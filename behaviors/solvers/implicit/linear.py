"""Linear solves of the implicit solver: preconditioned conjugate gradients on the block-sparse
Newton matrix (scipy.sparse BSR, 3x3 blocks), with a block-Jacobi preconditioner (the inverse of
every 3x3 diagonal block), an aggregation multigrid whose aggregation is built once and kept
across Newton iterations (``AggregationReuse``, ``preconditioner: amg_reuse``, opt-in) or, for
comparison, pyamg smoothed aggregation rebuilt per Newton iteration (one V-cycle) and an exact
sparse LDL^T solve (``Direct``, ``preconditioner: direct``).

``AggregationReuse``: a hierarchy from pyamg rebuilt per Newton matrix costs more than it saves
(setup 1.3 s at 128 x 128), and one built once and used unchanged is worse than block-Jacobi
(graphs/bench/implicit_speedups.py: the contact and strain-limit rows switch between Newton
iterations). Keeping only the aggregation (the prolongators P) and refreshing the coarse matrices
P^T A P and the smoothers' diagonal blocks from every Newton matrix works: on the 128 x 128
drop's impact systems (frames 7-8, 40 Newton systems) with an aggregation from the first one,
rebuilt when a solve's iterations double, block-Jacobi takes 19,257 CG iterations (many at the
500 cap, short of cg_tolerance 1e-3) in 15.3 s, the additive cycle 5,370 iterations (every solve
to 1e-3) in 7.5 s, the V-cycle with block Gauss-Seidel 2,427 in 9.5 s, smoothed-aggregation
prolongators 4,439 in 9.2 s (graphs/bench/implicit_amg.py systems); one pass of the matrix costs
the same in each, so the additive cycle (one matrix read a CG iteration plus the coarse levels,
~1.1 ms against block-Jacobi's 0.75 ms) wins over the V-cycle (three reads, ~3.5 ms). The
coarsest level (pyamg's max_coarse 300 nodes: 165 at 128 x 128) is inverted once per refresh
(LAPACK potri) and applied as one dense product; a smaller coarsest level (max_coarse 50-150: a
fourth level of 20 nodes) took 17 % more iterations and 5 % more time.

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
import scipy.sparse as sp
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

    def solve(self, A, b, tol, maxit, x, work, after=0, loose=0.0, lowrank=None):
        """The whole PCG in one compiled loop (see :func:`pcg_block_jacobi`; with ``after``
        > 0 :func:`pcg_block_jacobi_after`; with ``PARALLEL_PCG`` on more than one numba
        thread and from ``PARALLEL_MIN_VERTICES`` unknowns :func:`pcg_block_jacobi_par`, the
        same iterates). With ``lowrank`` (rank-one terms of the matrix, :func:`pcg_fused`)
        :func:`pcg_fused` with the block-Jacobi application."""
        if lowrank is not None:
            return pcg_fused(A, b, self, tol, maxit, x, work, after, loose, lowrank=lowrank)
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

    def solve(self, A, b, tol, maxit, x, work, after=0, loose=0.0, lowrank=None):
        if lowrank is not None:
            return pcg_fused(A, b, self, tol, maxit, x, work, after, loose, lowrank=lowrank)
        return pcg(A, b, self, tol, maxit, x, work, after, loose)


class Direct:
    """The Newton matrix factorised (P A P^T = L D L^T by QDLDL with an AMD ordering) once per
    Newton iteration and solved exactly (the ordering and symbolic factorisation kept while
    the matrix's pattern is the same, which it is within a substep: ``qdldl.Solver.update``); with
    rank-one terms (``lowrank``) that factor preconditions :func:`pcg_fused` on the whole matrix.
    ``preconditioner: direct`` (opt-in): for measuring what an exact Newton step gains over
    block-Jacobi CG stopped at ``cg_tolerance`` or its cap."""

    name = "direct"

    def __init__(self, n):
        self.f = None
        self.pattern = None

    def setup(self, A, diag_index):
        import qdldl

        M = sp.triu(A.tocsr(), format="csc")  # explicit zeros kept: the pattern is A's
        if (self.f is not None and np.array_equal(M.indptr, self.pattern[0])
                and np.array_equal(M.indices, self.pattern[1])):
            self.f.update(M, upper=True)  # numeric refactorisation on the kept ordering
        else:
            self.f = qdldl.Solver(M, upper=True)
            self.pattern = (M.indptr.copy(), M.indices.copy())

    def __call__(self, r, z):
        z[:] = self.f.solve(r.reshape(-1)).reshape(-1, 3)

    def solve(self, A, b, tol, maxit, x, work, after=0, loose=0.0, lowrank=None):
        if lowrank is not None:
            return pcg_fused(A, b, self, tol, maxit, x, work, after, loose, lowrank=lowrank)
        bn = math.sqrt(_dot(b, b))
        if bn == 0.0:
            x[:] = 0.0
            return 0, 0.0
        self(b, x)
        r = work["r"]
        r[:] = b - (A @ x.reshape(-1)).reshape(-1, 3)
        return 1, math.sqrt(_dot(r, r)) / bn


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

    def solve(self, A, b, tol, maxit, x, work, after=0, loose=0.0, lowrank=None):
        if lowrank is not None:
            return pcg_fused(A, b, self, tol, maxit, x, work, after, loose, lowrank=lowrank)
        return pcg(A, b, self, tol, maxit, x, work, after, loose)


# -- aggregation multigrid with its aggregation reused (preconditioner: amg_reuse) -----------

@njit(cache=True)
def bsr_gs_sweep(indptr, indices, data, dinv, b, x, backward, from_zero):
    """One block Gauss-Seidel sweep on A x = b (BSR, 3x3 blocks, sorted block indices;
    ``dinv`` the inverse diagonal blocks), forward in row order or ``backward``; x in place.
    ``from_zero`` (forward only): x is 0 on entry, so only the blocks left of the diagonal
    are read (the same result)."""
    n = indptr.shape[0] - 1
    d9 = data.reshape(-1)
    for k in range(n):
        i = n - 1 - k if backward else k
        s0 = b[i, 0]
        s1 = b[i, 1]
        s2 = b[i, 2]
        for q in range(indptr[i], indptr[i + 1]):
            j = indices[q]
            if j >= i and from_zero:
                break
            if j == i:
                continue
            x0 = x[j, 0]
            x1 = x[j, 1]
            x2 = x[j, 2]
            o = 9 * q
            s0 -= d9[o] * x0 + d9[o + 1] * x1 + d9[o + 2] * x2
            s1 -= d9[o + 3] * x0 + d9[o + 4] * x1 + d9[o + 5] * x2
            s2 -= d9[o + 6] * x0 + d9[o + 7] * x1 + d9[o + 8] * x2
        x[i, 0] = dinv[i, 0, 0] * s0 + dinv[i, 0, 1] * s1 + dinv[i, 0, 2] * s2
        x[i, 1] = dinv[i, 1, 0] * s0 + dinv[i, 1, 1] * s1 + dinv[i, 1, 2] * s2
        x[i, 2] = dinv[i, 2, 0] * s0 + dinv[i, 2, 1] * s1 + dinv[i, 2, 2] * s2


@njit(cache=True, inline="always")
def _restrict_row(pptr, pind, p9, i, r0, r1, r2, rc):
    """rc += P_i^T (r0, r1, r2): fine row i's part of the restriction P^T r (P: BSR, 3x3
    blocks, fine rows; ``p9`` its data's flat view)."""
    for q in range(pptr[i], pptr[i + 1]):
        j = pind[q]
        o = 9 * q
        rc[j, 0] += p9[o] * r0 + p9[o + 3] * r1 + p9[o + 6] * r2
        rc[j, 1] += p9[o + 1] * r0 + p9[o + 4] * r1 + p9[o + 7] * r2
        rc[j, 2] += p9[o + 2] * r0 + p9[o + 5] * r1 + p9[o + 8] * r2


@njit(cache=True)
def bsr_residual_restrict(indptr, indices, data, b, x, pptr, pind, pdata, rc):
    """rc = P^T (b - A x): the residual of the fine level restricted by the prolongator P
    (BSR, 3x3 blocks, fine rows), in one pass over the fine rows."""
    d9 = data.reshape(-1)
    p9 = pdata.reshape(-1)
    rc[:] = 0.0
    for i in range(indptr.shape[0] - 1):
        y0, y1, y2 = _row_product(indptr, indices, d9, x, i)
        r0 = b[i, 0] - y0
        r1 = b[i, 1] - y1
        r2 = b[i, 2] - y2
        _restrict_row(pptr, pind, p9, i, r0, r1, r2, rc)


@njit(cache=True)
def bsr_tmatvec(pptr, pind, pdata, r, rc):
    """rc = P^T r (P: BSR, 3x3 blocks, fine rows)."""
    p9 = pdata.reshape(-1)
    rc[:] = 0.0
    for i in range(pptr.shape[0] - 1):
        r0 = r[i, 0]
        r1 = r[i, 1]
        r2 = r[i, 2]
        _restrict_row(pptr, pind, p9, i, r0, r1, r2, rc)


@njit(cache=True)
def bsr_prolong_add(pptr, pind, pdata, xc, x):
    """x += P xc (P: BSR, 3x3 blocks, fine rows)."""
    p9 = pdata.reshape(-1)
    for i in range(pptr.shape[0] - 1):
        y0, y1, y2 = _row_product(pptr, pind, p9, xc, i)
        x[i, 0] += y0
        x[i, 1] += y1
        x[i, 2] += y2


@njit(cache=True)
def diag_positions(indptr, indices, out):
    """out[i] = the position of block (i, i) in the BSR pattern (-1 where absent)."""
    for i in range(indptr.shape[0] - 1):
        out[i] = -1
        for q in range(indptr[i], indptr[i + 1]):
            if indices[q] == i:
                out[i] = q


def _bsr3(M):
    """M as a BSR matrix of 3x3 blocks with sorted indices, contiguous float64 data."""
    M = sp.bsr_matrix(M, blocksize=(3, 3))
    M.sort_indices()
    M.data = np.ascontiguousarray(M.data, dtype=np.float64)
    return M


class AggregationReuse:
    """Aggregation multigrid (pyamg's aggregation of the matrix with the three translations as
    near-null space B) as the CG preconditioner, one symmetric V-cycle per application: forward
    block Gauss-Seidel before the coarse correction and backward after it on every level, a
    dense Cholesky solve on the coarsest (``cycle: v``); or ``additive``: block-Jacobi on the
    finest level plus that V-cycle of the coarse levels on the restricted residual. The
    aggregation and prolongators (``smooth``: pyamg's smoothed aggregation or its tentative
    prolongator alone) are built from one Newton matrix and kept; every Newton iteration
    refreshes the coarse matrices from the new one (Galerkin products P^T A P) and the
    Gauss-Seidel diagonal blocks, so the V-cycle is that of the current matrix on an older
    aggregation (a fixed symmetric positive definite preconditioner per solve: PCG stays
    correct). The aggregation is rebuilt when a solve's CG iterations exceed ``growth`` times
    those of the first solve after the last build (0: at the first Newton iteration of every
    substep)."""

    name = "amg_reuse"

    def __init__(self, n, smooth="tentative", growth=2.0, max_coarse=300, cycle="v"):
        self.n = n
        self.cycle = cycle
        self.smooth = smooth
        self.growth = growth
        self.max_coarse = max_coarse
        self.P = None  # prolongators (BSR 3x3), level 0 first
        self.levels = None
        self.rebuild = True
        self.base_it = 0
        self.builds = 0
        self.stale = True
        self.B = np.kron(np.ones((n, 1)), np.eye(3))  # (pyamg gets a copy: it changes B)

    def begin_substep(self):
        if self.growth <= 0.0:
            self.rebuild = True

    def _build(self, A):
        import pyamg

        kw = {} if self.smooth == "smoothed" else {"smooth": None}
        # a new matrix object: pyamg caches on it (its inverse diagonal blocks, block_D_inv),
        # and the solver refills this one's data in place
        A = sp.bsr_matrix((A.data.copy(), A.indices.copy(), A.indptr.copy()), shape=A.shape)
        ml = pyamg.smoothed_aggregation_solver(A, B=self.B.copy(), max_coarse=self.max_coarse,
                                               keep=False, presmoother=None,
                                               postsmoother=None, **kw)
        self.P = [_bsr3(lv.P) for lv in ml.levels[:-1]]
        self.levels = None
        self.rebuild = False
        self.base_it = 0
        self.builds += 1

    def setup(self, A, diag_index):
        """Marks the hierarchy stale; :meth:`refresh` rebuilds or refreshes it at the next
        solve with a nonzero right-hand side (none is spent on solves that take no
        iteration)."""
        self.stale = True

    def refresh(self, A):
        import scipy.linalg as sla

        self.stale = False
        if self.rebuild or self.P is None:
            self._build(A)
        mats = [A]
        for P in self.P:
            mats.append(_bsr3(P.T @ (mats[-1] @ P)))
        if self.levels is None:
            self.levels = []
            for M in mats:
                nb = M.shape[0] // 3
                dpos = np.zeros(nb, dtype=np.int64)
                diag_positions(M.indptr, M.indices, dpos)
                self.levels.append({"n": nb, "dpos": dpos, "dinv": np.zeros((nb, 3, 3)),
                                    "b": np.zeros((nb, 3)), "x": np.zeros((nb, 3)),
                                    "rb": np.zeros((nb, 3)), "rx": np.zeros((nb, 3))})
        for lv, M in zip(self.levels, mats):
            lv["A"] = M
            dp = lv["dpos"]
            blocks = np.where((dp >= 0)[:, None, None], M.data[np.maximum(dp, 0)], 0.0)
            invert_blocks(blocks, lv["dinv"])
        Ac = mats[-1].toarray()
        Ac = 0.5 * (Ac + Ac.T)
        zero = np.flatnonzero(np.abs(Ac).sum(axis=1) == 0.0)
        Ac[zero, zero] = 1.0
        # the coarsest level's inverse, explicitly (a few hundred unknowns: one dense product
        # per cycle is cheaper than the triangular solves' call overhead)
        c, info = sla.lapack.dpotrf(Ac, lower=False)
        if info == 0:
            c, info = sla.lapack.dpotri(c, lower=False)  # the inverse from its factor
        if info != 0:
            raise np.linalg.LinAlgError(f"coarsest matrix not positive definite ({info})")
        self.coarse = np.triu(c) + np.triu(c, 1).T

    def vcycle(self, r, z, k0=0):
        """z = the V-cycle from level ``k0`` applied to r ((n, 3) arrays of that level)."""
        L = self.levels
        L[k0]["b"] = r
        L[k0]["x"] = z
        for k in range(k0, len(L) - 1):
            lv, P = L[k], self.P[k]
            A = lv["A"]
            lv["x"][:] = 0.0
            bsr_gs_sweep(A.indptr, A.indices, A.data, lv["dinv"], lv["b"], lv["x"], False, True)
            bsr_residual_restrict(A.indptr, A.indices, A.data, lv["b"], lv["x"], P.indptr,
                                  P.indices, P.data, L[k + 1]["b"])
        last = L[-1]
        np.dot(self.coarse, last["b"].reshape(-1), out=last["x"].reshape(-1))
        for k in range(len(L) - 2, k0 - 1, -1):
            lv, P = L[k], self.P[k]
            A = lv["A"]
            bsr_prolong_add(P.indptr, P.indices, P.data, L[k + 1]["x"], lv["x"])
            bsr_gs_sweep(A.indptr, A.indices, A.data, lv["dinv"], lv["b"], lv["x"], True,
                         False)

    def additive(self, r, z):
        """z = D^-1 r + P V1(P^T r): the finest level's block-Jacobi plus the coarse levels'
        V-cycle on the restricted residual (two-level additive)."""
        L = self.levels
        if len(L) == 1:
            return self.vcycle(r, z)
        P = self.P[0]
        apply_blocks(L[0]["dinv"], r, z)
        c = L[1]
        bsr_tmatvec(P.indptr, P.indices, P.data, r, c["rb"])
        self.vcycle(c["rb"], c["rx"], 1)
        bsr_prolong_add(P.indptr, P.indices, P.data, c["rx"], z)

    def pcg_additive(self, A, b, tol, maxit, x, work, after=0, loose=0.0):
        """:func:`pcg_fused` with the additive cycle's finest-level passes fused into the CG
        vector passes (the x, r update with z = D^-1 r and the restriction P^T r; the
        prolongation with r . z): the same iteration in four passes over the finest level's
        vectors instead of seven."""
        P, dinv, c, z = self.P[0], self.levels[0]["dinv"], self.levels[1], work["z"]

        def update(x, r, p, Ap, al):
            return _cg_update_jacobi_restrict(x, r, p, Ap, al, dinv, z, P.indptr, P.indices,
                                              P.data, c["rb"])

        def apply(r, z):
            self.vcycle(c["rb"], c["rx"], 1)
            return _prolong_add_dot(P.indptr, P.indices, P.data, c["rx"], z, r)

        return pcg_fused(A, b, self.additive, tol, maxit, x, work, after, loose, (update, apply))

    def __call__(self, r, z):
        if self.cycle == "additive":
            self.additive(r, z)
        else:
            self.vcycle(r, z)

    def solve(self, A, b, tol, maxit, x, work, after=0, loose=0.0, lowrank=None):
        """PCG with this preconditioner; with ``lowrank`` (rank-one terms of the matrix,
        applied in the product by :func:`pcg_fused`; the hierarchy holds their diagonal
        blocks only, which the caller put into A) the unfused cycle."""
        if not b.any():
            x[:] = 0.0
            return 0, 0.0
        if self.stale or self.levels is None:
            self.refresh(A)
        if lowrank is not None:
            it, res = pcg_fused(A, b, self, tol, maxit, x, work, after, loose, lowrank=lowrank)
        elif self.cycle == "additive" and len(self.levels) > 1:
            it, res = self.pcg_additive(A, b, tol, maxit, x, work, after, loose)
        else:
            it, res = pcg_fused(A, b, self, tol, maxit, x, work, after, loose)
        if self.base_it == 0:
            self.base_it = it  # (0 while the solves take none: b = 0 in free fall)
        elif self.growth > 0.0 and it > self.growth * self.base_it:
            self.rebuild = True
        return it, res


@njit(cache=True)
def _cg_matvec_dot(indptr, indices, data, p, Ap):
    """Ap = A p; returns p . Ap (the fused loop's first pass)."""
    d9 = data.reshape(-1)
    pAp = 0.0
    for i in range(p.shape[0]):
        y0, y1, y2 = _row_product(indptr, indices, d9, p, i)
        Ap[i, 0] = y0
        Ap[i, 1] = y1
        Ap[i, 2] = y2
        pAp += p[i, 0] * y0 + p[i, 1] * y1 + p[i, 2] * y2
    return pAp


@njit(cache=True)
def _cg_update(x, r, p, Ap, al):
    """x += al p, r -= al Ap; returns r . r."""
    rr = 0.0
    for i in range(x.shape[0]):
        for a in range(3):
            x[i, a] += al * p[i, a]
            r[i, a] -= al * Ap[i, a]
        rr += r[i, 0] * r[i, 0] + r[i, 1] * r[i, 1] + r[i, 2] * r[i, 2]
    return rr


@njit(cache=True)
def _cg_update_jacobi_restrict(x, r, p, Ap, al, dinv, z, pptr, pind, pdata, rc):
    """x += al p, r -= al Ap, z = D^-1 r (``dinv``), rc = P^T r; returns r . r."""
    p9 = pdata.reshape(-1)
    rc[:] = 0.0
    rr = 0.0
    for i in range(x.shape[0]):
        for a in range(3):
            x[i, a] += al * p[i, a]
            r[i, a] -= al * Ap[i, a]
        r0 = r[i, 0]
        r1 = r[i, 1]
        r2 = r[i, 2]
        rr += r0 * r0 + r1 * r1 + r2 * r2
        z[i, 0] = dinv[i, 0, 0] * r0 + dinv[i, 0, 1] * r1 + dinv[i, 0, 2] * r2
        z[i, 1] = dinv[i, 1, 0] * r0 + dinv[i, 1, 1] * r1 + dinv[i, 1, 2] * r2
        z[i, 2] = dinv[i, 2, 0] * r0 + dinv[i, 2, 1] * r1 + dinv[i, 2, 2] * r2
        _restrict_row(pptr, pind, p9, i, r0, r1, r2, rc)
    return rr


@njit(cache=True)
def _prolong_add_dot(pptr, pind, pdata, xc, z, r):
    """z += P xc; returns r . z."""
    p9 = pdata.reshape(-1)
    rz = 0.0
    for i in range(pptr.shape[0] - 1):
        y0, y1, y2 = _row_product(pptr, pind, p9, xc, i)
        z[i, 0] += y0
        z[i, 1] += y1
        z[i, 2] += y2
        rz += r[i, 0] * z[i, 0] + r[i, 1] * z[i, 1] + r[i, 2] * z[i, 2]
    return rz


@njit(cache=True)
def _cg_direction(p, z, beta):
    for i in range(p.shape[0]):
        for a in range(3):
            p[i, a] = z[i, a] + beta * p[i, a]


def pcg_fused(A, b, precond, tol, maxit, x, work, after=0, loose=0.0, fused=None,
              lowrank=None):
    """:func:`pcg` with the vector passes in compiled kernels (the matrix product with p . Ap,
    the updates with r . r), for preconditioners applied from Python (``precond(r, z)``).
    ``fused``: ``(update, apply)`` for the passes after the first application, a
    preconditioner's own fusion of them: ``update(x, r, p, Ap, al)`` does x += al p, r -= al
    Ap and returns r . r, ``apply(r, z)`` writes z = M^-1 r and returns r . z. ``lowrank``:
    ``(U (m, n, 3), k (m,))``, the matrix is A + sum_j k_j (u_j u_j^T - blockdiag(u_j u_j^T))
    (A holding the terms' diagonal blocks; :func:`lowrank_matvec`)."""
    r, z, p, Ap = work["r"], work["z"], work["p"], work["Ap"]
    if fused is None:
        def apply(r, z):
            precond(r, z)
            return _dot(r, z)

        fused = (_cg_update, apply)
    update, apply = fused
    x[:] = 0.0
    r[:] = b
    bn = math.sqrt(_dot(b, b))
    if bn == 0.0:
        return 0, 0.0
    precond(r, z)
    p[:] = z
    rz = _dot(r, z)
    it = 0
    rn = bn
    while it < maxit:
        pAp = _cg_matvec_dot(A.indptr, A.indices, A.data, p, Ap)
        if lowrank is not None:
            pAp += lowrank_matvec(p, Ap, lowrank[0], lowrank[1], lowrank[2])
        if pAp <= 0.0:
            break
        al = rz / pAp
        rn = math.sqrt(update(x, r, p, Ap, al))
        it += 1
        if rn <= tol * bn or (0 < after <= it and rn <= loose * bn):
            break
        rz_new = apply(r, z)
        _cg_direction(p, z, rz_new / rz)
        rz = rz_new
    return it, rn / bn


@njit(cache=True)
def lowrank_matvec(p, Ap, U, k, sub):
    """Ap += sum_j k_j (u_j (u_j . p) - blockdiag(u_j u_j^T) p): the rank-one terms k u u^T of
    global rows (the implicit solver's volume rows) less their per-vertex diagonal blocks,
    which the sparse matrix holds (so the preconditioners see them; ``sub`` 1.0, or 0.0 where
    it does not hold them: the whole term). Returns the added p . Ap. U: (m, n, 3), k: (m,)."""
    add = 0.0
    for j in range(U.shape[0]):
        kj = k[j]
        if kj == 0.0:
            continue
        s = 0.0
        for i in range(p.shape[0]):
            s += U[j, i, 0] * p[i, 0] + U[j, i, 1] * p[i, 1] + U[j, i, 2] * p[i, 2]
        d2 = 0.0
        for i in range(p.shape[0]):
            ui = U[j, i, 0] * p[i, 0] + U[j, i, 1] * p[i, 1] + U[j, i, 2] * p[i, 2]
            ui *= sub
            d2 += ui * ui
            f = kj * (s - ui)
            Ap[i, 0] += f * U[j, i, 0]
            Ap[i, 1] += f * U[j, i, 1]
            Ap[i, 2] += f * U[j, i, 2]
        add += kj * (s * s - d2)
    return add
