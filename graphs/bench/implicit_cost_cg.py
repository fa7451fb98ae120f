"""The implicit solver's linear solve on saved Newton systems (issue #11: the cost per CG
iteration): what one CG iteration costs by part, and the variants of the solve measured side by
side on the same system.

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_cost_cg.py SYSTEM.npz [NEXT.npz]
    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_cost_cg.py --ab COMMIT SYS.npz ...

SYSTEM.npz is a Newton system ``graphs/bench/implicit_cost.py --save FRAME:ITER:PATH`` wrote
(the BSR matrix of 3x3 blocks, its diagonal blocks' indices, the right-hand side -g). NEXT.npz
(optional) the system of the next Newton iteration: a solve of it from SYSTEM's solution (the
previous Newton step as the initial guess) is compared with the solve from 0.

Printed: the matrix (vertices, blocks, MB); ms per call of the parts of one block-Jacobi CG
iteration run alone (the BSR product ``linear.bsr_matvec``, scipy's BSR product, the
preconditioner ``apply_blocks``, a dot product); then per solve variant at cg_tolerance 1e-3
and the 500 cap (the solver's defaults): iterations, relative residual reached, ms per solve
and per iteration, and whether the solution is bitwise that of the solver's loop
(``pcg_block_jacobi``). Variants: the solver's fused loop, the unfused reference, the fused loop
with its vertex loops in prange (``pcg_block_jacobi_par``, at the thread count of the run);
and, changing the iterates: the matrix in float32, the matrix stored as its upper triangle
(symmetric product; in the generic loop and fused as the solver's loop,
``pcg_block_jacobi_upper``), symmetric block Gauss-Seidel as the preconditioner, and the previous
Newton step as the initial guess. ``--ab COMMIT``: COMMIT's PCG loop against the tree's,
interleaved on each system.

Measured on the 128 x 128 drop's frame 8, Newton iteration 10 (``implicit_cost.py 128 10 --save
8:10:a8_10.npz --save 8:11:a8_11.npz --save 7:1:a7_1.npz``; 19,203 vertices, 183,555 blocks,
13.2 MB; 1 thread, load ~3; at bc9a2e2 unless said): the product alone 0.50 ms (scipy's BSR
product 0.96 ms), the preconditioner 0.05 ms, a dot product 0.016 ms, the setup (inverting the
diagonal blocks) 0.40 ms; a solve runs to the 500 cap at relative residual 5.1e-3 in 329 ms
(0.66 ms per iteration; unfused 0.67). Changing the iterates: the matrix in float32 0.90 ms per
iteration (slower), the upper triangle in the generic loop 0.60 (generic full 0.79), fused 0.58-
0.62 against 0.62-0.69; symmetric block Gauss-Seidel reaches 1e-3 in 386 iterations (block-Jacobi
5.1e-3 at 500) but at 1.94 ms per iteration (747 ms a solve against 329); the next Newton
system's solve from the previous Newton step instead of 0: still 500 iterations, residual 3.4e-3
instead of 4.8e-3. pyamg smoothed aggregation on these systems (graphs/bench/implicit_speedups.py):
setup 1.3 s, 3.6 s a solve. So on these systems no preconditioner tried pays, and the
block-Jacobi iteration is bound by the product's arithmetic (~2.7 ns a block).

``--ab bc9a2e2`` on the three systems (12 interleaved repeats each): 0.783 -> 0.709 ms per CG
iteration (medians), paired ratio 0.910: the flat view of the blocks and z formed in the x/r
pass.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from numba import get_num_threads, njit

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from lokigraph.behaviors.solvers.implicit import linear as L  # noqa: E402


def best_ms(f, reps=5, inner=1, wall=False):
    """Least CPU ms per call over ``reps`` runs of ``inner`` calls (with ``wall``: (CPU ms,
    wall ms), each the least)."""
    cpu, w = [], []
    for _ in range(reps):
        t, t0 = time.process_time(), time.perf_counter()
        for _ in range(inner):
            f()
        cpu.append((time.process_time() - t) / inner)
        w.append((time.perf_counter() - t0) / inner)
    return (1e3 * min(cpu), 1e3 * min(w)) if wall else 1e3 * min(cpu)


@njit(cache=True)
def _upper(indptr, indices, data):
    """The diagonal and upper blocks (j >= i) of a symmetric BSR matrix: (indptr, indices,
    data) of the upper triangle."""
    n = indptr.shape[0] - 1
    cnt = 0
    for i in range(n):
        for q in range(indptr[i], indptr[i + 1]):
            if indices[q] >= i:
                cnt += 1
    up = np.zeros(n + 1, np.int64)
    ui = np.zeros(cnt, np.int32)
    ud = np.zeros((cnt, 3, 3))
    k = 0
    for i in range(n):
        for q in range(indptr[i], indptr[i + 1]):
            if indices[q] >= i:
                ui[k] = indices[q]
                ud[k] = data[q]
                k += 1
        up[i + 1] = k
    return up, ui, ud


@njit(cache=True)
def _matvec_any(mode, indptr, indices, data, x, y):
    """y = A x; mode 0: full storage (any dtype), 1: upper triangle (symmetric product)."""
    n = indptr.shape[0] - 1
    if mode == 0:
        for i in range(n):
            y0 = 0.0
            y1 = 0.0
            y2 = 0.0
            for q in range(indptr[i], indptr[i + 1]):
                j = indices[q]
                x0 = x[j, 0]
                x1 = x[j, 1]
                x2 = x[j, 2]
                y0 += data[q, 0, 0] * x0 + data[q, 0, 1] * x1 + data[q, 0, 2] * x2
                y1 += data[q, 1, 0] * x0 + data[q, 1, 1] * x1 + data[q, 1, 2] * x2
                y2 += data[q, 2, 0] * x0 + data[q, 2, 1] * x1 + data[q, 2, 2] * x2
            y[i, 0] = y0
            y[i, 1] = y1
            y[i, 2] = y2
        return
    for i in range(n):
        y[i, 0] = 0.0
        y[i, 1] = 0.0
        y[i, 2] = 0.0
    for i in range(n):
        xi0 = x[i, 0]
        xi1 = x[i, 1]
        xi2 = x[i, 2]
        y0 = 0.0
        y1 = 0.0
        y2 = 0.0
        for q in range(indptr[i], indptr[i + 1]):
            j = indices[q]
            x0 = x[j, 0]
            x1 = x[j, 1]
            x2 = x[j, 2]
            y0 += data[q, 0, 0] * x0 + data[q, 0, 1] * x1 + data[q, 0, 2] * x2
            y1 += data[q, 1, 0] * x0 + data[q, 1, 1] * x1 + data[q, 1, 2] * x2
            y2 += data[q, 2, 0] * x0 + data[q, 2, 1] * x1 + data[q, 2, 2] * x2
            if j != i:
                y[j, 0] += data[q, 0, 0] * xi0 + data[q, 1, 0] * xi1 + data[q, 2, 0] * xi2
                y[j, 1] += data[q, 0, 1] * xi0 + data[q, 1, 1] * xi1 + data[q, 2, 1] * xi2
                y[j, 2] += data[q, 0, 2] * xi0 + data[q, 1, 2] * xi1 + data[q, 2, 2] * xi2
        y[i, 0] += y0
        y[i, 1] += y1
        y[i, 2] += y2


@njit(cache=True)
def _sgs(indptr, indices, data, dinv, diagq, r, z, w):
    """z = (D + L)^-1 D (D + U)^-1 r, one symmetric block Gauss-Seidel sweep from 0 (a
    symmetric positive definite preconditioner for a symmetric positive definite A)."""
    n = indptr.shape[0] - 1
    for i in range(n):  # forward: (D + L) w = r
        s0, s1, s2 = r[i, 0], r[i, 1], r[i, 2]
        for q in range(indptr[i], diagq[i]):
            j = indices[q]
            s0 -= data[q, 0, 0] * w[j, 0] + data[q, 0, 1] * w[j, 1] + data[q, 0, 2] * w[j, 2]
            s1 -= data[q, 1, 0] * w[j, 0] + data[q, 1, 1] * w[j, 1] + data[q, 1, 2] * w[j, 2]
            s2 -= data[q, 2, 0] * w[j, 0] + data[q, 2, 1] * w[j, 1] + data[q, 2, 2] * w[j, 2]
        for a in range(3):
            w[i, a] = dinv[i, a, 0] * s0 + dinv[i, a, 1] * s1 + dinv[i, a, 2] * s2
    for i in range(n - 1, -1, -1):  # backward: (D + U) z = D w
        q0 = diagq[i]
        d = data[q0]
        s0 = d[0, 0] * w[i, 0] + d[0, 1] * w[i, 1] + d[0, 2] * w[i, 2]
        s1 = d[1, 0] * w[i, 0] + d[1, 1] * w[i, 1] + d[1, 2] * w[i, 2]
        s2 = d[2, 0] * w[i, 0] + d[2, 1] * w[i, 1] + d[2, 2] * w[i, 2]
        for q in range(q0 + 1, indptr[i + 1]):
            j = indices[q]
            s0 -= data[q, 0, 0] * z[j, 0] + data[q, 0, 1] * z[j, 1] + data[q, 0, 2] * z[j, 2]
            s1 -= data[q, 1, 0] * z[j, 0] + data[q, 1, 1] * z[j, 1] + data[q, 1, 2] * z[j, 2]
            s2 -= data[q, 2, 0] * z[j, 0] + data[q, 2, 1] * z[j, 1] + data[q, 2, 2] * z[j, 2]
        for a in range(3):
            z[i, a] = dinv[i, a, 0] * s0 + dinv[i, a, 1] * s1 + dinv[i, a, 2] * s2


@njit(cache=True)
def pcg_variant(mmode, pmode, indptr, indices, data, dinv, diagq, b, tol, maxit, x0, x):
    """PCG from x0: matrix product ``_matvec_any(mmode)``, preconditioner pmode 0 block-Jacobi
    (``dinv``), 1 symmetric block Gauss-Seidel (on the full matrix ``indptr``/``indices``/
    ``data`` with ``diagq``; mmode 0 only). Returns (iterations, |r| / |b|)."""
    n = b.shape[0]
    r = np.empty((n, 3))
    z = np.empty((n, 3))
    p = np.empty((n, 3))
    Ap = np.empty((n, 3))
    w = np.empty((n, 3))
    _matvec_any(mmode, indptr, indices, data, x0, Ap)
    for i in range(n):
        for a in range(3):
            x[i, a] = x0[i, a]
            r[i, a] = b[i, a] - Ap[i, a]
    bn = math.sqrt(L._dot(b, b))
    if bn == 0.0:
        return 0, 0.0
    if pmode == 0:
        L.apply_blocks(dinv, r, z)
    else:
        _sgs(indptr, indices, data, dinv, diagq, r, z, w)
    p[:] = z
    rz = L._dot(r, z)
    it = 0
    rn = math.sqrt(L._dot(r, r))
    if rn <= tol * bn:
        return 0, rn / bn
    while it < maxit:
        _matvec_any(mmode, indptr, indices, data, p, Ap)
        pAp = L._dot(p, Ap)
        if pAp <= 0.0:
            break
        al = rz / pAp
        for i in range(n):
            for a in range(3):
                x[i, a] += al * p[i, a]
                r[i, a] -= al * Ap[i, a]
        it += 1
        rn = math.sqrt(L._dot(r, r))
        if rn <= tol * bn:
            break
        if pmode == 0:
            L.apply_blocks(dinv, r, z)
        else:
            _sgs(indptr, indices, data, dinv, diagq, r, z, w)
        rz_new = L._dot(r, z)
        beta = rz_new / rz
        rz = rz_new
        for i in range(n):
            for a in range(3):
                p[i, a] = z[i, a] + beta * p[i, a]
    return it, rn / bn


def upper_pattern(indptr, indices):
    """The upper triangle (diagonal included) of a BSR pattern whose rows hold sorted column
    indices: (row pointer, column indices, the block numbers in the full matrix's data), for
    :func:`pcg_block_jacobi_upper` ."""
    rows = np.repeat(np.arange(len(indptr) - 1), np.diff(indptr))
    keep = np.flatnonzero(indices >= rows)
    uptr = np.concatenate([[0], np.cumsum(np.bincount(rows[keep],
                                                      minlength=len(indptr) - 1))])
    return uptr.astype(np.int64), indices[keep].astype(np.int64), keep


@njit(cache=True)
def pcg_block_jacobi_upper(uptr, uidx, udata, inv, b, tol, after, loose, maxit, x, r, z, p, Ap):
    """The block-Jacobi PCG of ``linear.pcg_block_jacobi_after`` on a symmetric matrix stored as
    its upper triangle (``upper_pattern``; the diagonal block first in each row): the product
    reads each off-diagonal block once for both (i, j) and (j, i) (y_j += B^T p_i), 55 % of
    the full matrix's bytes. The sums run in another order than the full product's, so the
    iterates differ from ``linear.pcg_block_jacobi_after`` by rounding. Measured here and not
    taken into the solver: 0.58-0.62 against 0.62-0.69 ms per iteration on the 128 x 128 impact
    system (the product is bound by its arithmetic, not by the bytes it reads). Serial (the
    transposed updates write other rows). Returns (iterations, relative residual)."""
    n = b.shape[0]
    d9 = udata.reshape(-1)
    bb = 0.0
    for i in range(n):
        for a in range(3):
            x[i, a] = 0.0
            r[i, a] = b[i, a]
            Ap[i, a] = 0.0
        bb += b[i, 0] * b[i, 0] + b[i, 1] * b[i, 1] + b[i, 2] * b[i, 2]
    bn = math.sqrt(bb)
    if bn == 0.0:
        return 0, 0.0
    rz = 0.0
    for i in range(n):
        rz += L._precond_row(inv, r, p, i)[1]
    it = 0
    rn = bn
    while it < maxit:
        pAp = 0.0
        for i in range(n):  # Ap is zero here; row i is complete once row i is done
            pi0 = p[i, 0]
            pi1 = p[i, 1]
            pi2 = p[i, 2]
            y0 = 0.0
            y1 = 0.0
            y2 = 0.0
            for q in range(uptr[i], uptr[i + 1]):
                j = uidx[q]
                x0 = p[j, 0]
                x1 = p[j, 1]
                x2 = p[j, 2]
                o = 9 * q
                y0 += d9[o] * x0 + d9[o + 1] * x1 + d9[o + 2] * x2
                y1 += d9[o + 3] * x0 + d9[o + 4] * x1 + d9[o + 5] * x2
                y2 += d9[o + 6] * x0 + d9[o + 7] * x1 + d9[o + 8] * x2
                if j != i:
                    Ap[j, 0] += d9[o] * pi0 + d9[o + 3] * pi1 + d9[o + 6] * pi2
                    Ap[j, 1] += d9[o + 1] * pi0 + d9[o + 4] * pi1 + d9[o + 7] * pi2
                    Ap[j, 2] += d9[o + 2] * pi0 + d9[o + 5] * pi1 + d9[o + 8] * pi2
            y0 += Ap[i, 0]
            y1 += Ap[i, 1]
            y2 += Ap[i, 2]
            Ap[i, 0] = y0
            Ap[i, 1] = y1
            Ap[i, 2] = y2
            pAp += pi0 * y0 + pi1 * y1 + pi2 * y2
        if pAp <= 0.0:
            break
        al = rz / pAp
        rr = 0.0
        rz_new = 0.0
        for i in range(n):
            trr, trz = L._step_row(x, r, z, p, Ap, inv, al, i)
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
                Ap[i, a] = 0.0
    return it, rn / bn


def load(path):
    f = np.load(path)
    indptr, indices, data = f["indptr"], f["indices"], f["data"]
    return indptr, indices, np.ascontiguousarray(data), f["diag"], f["b"]


def main(path, nxt=None, tol=1e-3, maxit=500):
    indptr, indices, data, diag, b = load(path)
    n = len(indptr) - 1
    inv = np.zeros((n, 3, 3))
    L.invert_blocks(data[diag], inv)
    print(f"{Path(path).name}: {n} vertices, {len(indices)} blocks ({data.nbytes / 1e6:.1f} MB),"
          f" numba threads {get_num_threads()}")
    x = np.zeros((n, 3))
    y = np.zeros((n, 3))
    A = sp.bsr_matrix((data, indices, indptr), shape=(3 * n, 3 * n))
    pv = np.random.default_rng(0).standard_normal((n, 3))
    L.bsr_matvec(indptr, indices, data, pv, y)
    parts = {
        "bsr_matvec (numba)": lambda: L.bsr_matvec(indptr, indices, data, pv, y),
        "scipy BSR A @ p": lambda: A @ pv.reshape(-1),
        "apply_blocks (precond)": lambda: L.apply_blocks(inv, pv, y),
        "dot": lambda: L._dot(pv, y),
        "invert_blocks (setup)": lambda: L.invert_blocks(data[diag], inv),
    }
    print("part of a CG iteration, run alone: CPU ms per call")
    for k, f in parts.items():
        f()
        print(f"  {k:28s} {best_ms(f, 5, 20):8.3f}")
    w = {k: np.zeros((n, 3)) for k in ("r", "z", "p", "Ap")}
    t = np.zeros((n, 2))
    ref = np.zeros((n, 3))

    def fused(xo):
        return L.pcg_block_jacobi(indptr, indices, data, inv, b, tol, maxit, xo, w["r"], w["z"],
                                  w["p"], w["Ap"])

    def unfused(xo):
        return L.pcg_block_jacobi_unfused(indptr, indices, data, inv, b, tol, maxit, xo, w["r"],
                                          w["z"], w["p"], w["Ap"])

    def par(xo):
        return L.pcg_block_jacobi_par(indptr, indices, data, inv, b, tol, maxit + 1, 0.0, maxit,
                                      xo, w["r"], w["z"], w["p"], w["Ap"], t)
    up, ui, ud = _upper(indptr, indices, data)
    d32 = data.astype(np.float32)
    diagq = diag.astype(np.int64)
    zero = np.zeros((n, 3))

    def f32(xo):
        return pcg_variant(0, 0, indptr, indices, d32, inv, diagq, b, tol, maxit, zero, xo)

    def sym(xo):
        return pcg_variant(1, 0, up, ui, ud, inv, diagq, b, tol, maxit, zero, xo)

    def sgs(xo):
        return pcg_variant(0, 1, indptr, indices, data, inv, diagq, b, tol, maxit, zero, xo)

    fu_ptr, fu_idx, fu_src = upper_pattern(indptr, indices)
    fu_data = data[fu_src]

    def upper(xo):
        return pcg_block_jacobi_upper(fu_ptr, fu_idx, fu_data, inv, b, tol, maxit + 1, 0.0,
                                        maxit, xo, w["r"], w["z"], w["p"], w["Ap"])

    def var_bj(xo):
        return pcg_variant(0, 0, indptr, indices, data, inv, diagq, b, tol, maxit, zero, xo)
    fused(ref)
    print(f"upper triangle: {len(ui)} blocks ({ud.nbytes / 1e6:.1f} MB)")
    print(f"solve (tol {tol:g}, cap {maxit}): iterations, residual, CPU ms/solve, CPU "
          f"ms/iteration, wall ms/solve, wall ms/iteration, bitwise the solver's")
    rows = [("fused (solver)", fused), ("unfused", unfused), ("prange (par)", par),
            ("generic loop, block-Jacobi", var_bj), ("float32 matrix", f32),
            ("upper triangle (symmetric)", sym), ("fused upper triangle", upper),
            ("symmetric Gauss-Seidel", sgs)]
    for name, f in rows:
        xo = np.zeros((n, 3))
        it, res = f(xo)
        ms, wms = best_ms(lambda: f(xo), 3, wall=True)
        print(f"  {name:30s} {it:5d} {res:9.2e} {ms:9.1f} {ms / max(it, 1):8.3f} "
              f"{wms:9.1f} {wms / max(it, 1):8.3f} {str(np.array_equal(xo, ref)):>6s}",
              flush=True)
    if nxt is not None:
        i2, x2, d2, g2, b2 = load(nxt)
        inv2 = np.zeros((n, 3, 3))
        L.invert_blocks(d2[g2], inv2)
        for name, x0 in (("next system from 0", zero), ("next from previous step", ref)):
            xo = np.zeros((n, 3))
            it, res = pcg_variant(0, 0, i2, x2, d2, inv2, g2.astype(np.int64), b2, tol, maxit,
                                  x0, xo)
            print(f"  {name:30s} {it:5d} {res:9.2e}")


def ab(commit, paths, reps=12):
    """COMMIT's block-Jacobi PCG loop against the tree's, interleaved (ABBA) ``reps`` times on
    each saved system (500 iterations at the defaults' tolerance): CPU ms per CG iteration
    (medians) and the paired ratio."""
    import implicit_cost as C

    lb = C.before_linear(commit)
    res = {"before": [], "after": []}
    for path in paths:
        indptr, indices, data, diag, b = load(path)
        n = len(indptr) - 1
        inv = np.zeros((n, 3, 3))
        L.invert_blocks(data[diag], inv)
        w = [np.zeros((n, 3)) for _ in range(4)]
        x = np.zeros((n, 3))
        f = {"before": lambda: lb.pcg_block_jacobi(indptr, indices, data, inv, b, 1e-3, 500, x,
                                                   *w),
             "after": lambda: L.pcg_block_jacobi(indptr, indices, data, inv, b, 1e-3, 500, x,
                                                 *w)}
        for g in f.values():
            g()
        for rep in range(reps):
            for k in (("before", "after") if rep % 2 == 0 else ("after", "before")):
                t = time.process_time()
                it, _ = f[k]()
                res[k].append(1e3 * (time.process_time() - t) / it)
    for k, v in res.items():
        print(f"{k}: median {np.median(v):.3f} ms per CG iteration (min {min(v):.3f}, "
              f"{len(v)} solves)")
    r = np.array(res["after"]) / np.array(res["before"])
    print(f"paired ratio after / before: median {np.median(r):.3f}")


if __name__ == "__main__":
    if sys.argv[1] == "--ab":
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        ab(sys.argv[2], sys.argv[3:])
    else:
        main(*sys.argv[1:3])
