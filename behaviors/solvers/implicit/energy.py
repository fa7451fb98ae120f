"""The implicit energy protocol, and what the energies of every effect share.

A constraint behavior takes part in the implicit solve by giving two methods (written in an
"Implicit energy" section at the end of the module of its effect, beside its Nucleus kernels):

``energy_stencils(ctx, data) -> list[np.ndarray]``
    Called once (the first substep). One int64 array ``(m, k)`` per set of energy terms: the
    ``k`` global vertex indices each of the ``m`` terms couples. The solver builds the fixed
    block-sparse (3x3 blocks) pattern of the Hessian from them and a scatter map for each set.

``energy(ctx, data, x, grad, hess, opts) -> float``
    The energy [J] of this effect at positions ``x`` (n, 3). ``opts.mode`` is 0 (energy only),
    1 (also add the gradient dE/dx [N] into ``grad`` (n, 3)) or 2 (also write the Hessian blocks:
    ``hess[s]`` has shape ``(m, k, k, 3, 3)`` for stencil set ``s``, zeroed by the solver before
    the call; block ``[t, a, b]`` is d2E / dx_{S[t,a]} dx_{S[t,b]}). Every block written is
    positive semidefinite per term (see the kernels for how: exact where the exact Hessian is,
    clamped or Gauss-Newton where it is not). ``opts`` is an :class:`EnergyOptions`.

Optional:

``energy_update_multipliers(ctx, data, x, opts)`` / ``energy_multipliers(data)``
    Augmented Lagrangian rows (hard stretch, welds): the solver calls the update once per
    substep on the final positions; the multipliers live on the data (checkpointed by the
    behavior's ``state_arrays``).

``energy_lowrank(data) -> list[(k, g)]``
    Rank-one Hessian terms ``k g g^T`` (``g`` an (n, 3) array, ``k`` >= 0) of global rows (an
    enclosed volume), as of the last mode-2 call: dense over many vertices, so not written as
    blocks; the solver applies them in the CG product (``linear.lowrank_matvec``).

``implicit_project(ctx, data, p)``
    A projection the solver applies after the Newton solve for the part of the effect that is
    not an energy (sliding attachments).

Energies use the physical parameters the component carries through the compliances the Nucleus
constraint already packs: a row of compliance ``alpha`` is the energy ``C^2 / (2 alpha)``; a
hard row (``alpha = 0``) becomes a stiff penalty ``k = hard_stiffness * m / h^2`` (``m`` the
largest vertex mass of the row), i.e. ``hard_stiffness`` times the inertia of its vertices over
one substep (distance rows add a multiplier: augmented Lagrangian, see
``stretch.spring_energy``); ``alpha = inf`` is off.

Kernels here: the Gauss-Newton block writer of a scalar constraint energy (``_scalar_term``),
the penalty stiffness of a row (``row_k``), the block pattern (``build_pattern``) and the
assembly scatter (``scatter_blocks``; the solver adds the blocks by ``gather_blocks``, bitwise
the same).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from ..nucleus.xpbd import _INF, _hot


@dataclass
class EnergyOptions:
    """What the solver hands to ``energy``."""

    mode: int  # 0 energy, 1 + gradient, 2 + Hessian blocks
    #: hard penalty per vertex [N/m]: hard_stiffness * mass / h^2 (0 for massless vertices)
    hard_k: np.ndarray
    h: float
    #: a (1,) float64 scratch for kernels; dummy arrays used when grad / hess are not wanted
    dummy_grad: np.ndarray
    dummy_hess: np.ndarray


def grad_or_dummy(grad, opts):
    return grad if grad is not None and opts.mode >= 1 else opts.dummy_grad


def hess_or_dummy(hess, s, opts):
    return hess[s] if hess is not None and opts.mode >= 2 else opts.dummy_hess


@_hot
def row_k(alpha, hard_k, i0, i1):
    """Stiffness of a row of compliance ``alpha``: 1/alpha, or the hard penalty of vertices
    i0, i1 (the larger) when alpha == 0, or 0 (off) when alpha is infinite."""
    if alpha > 0.0:
        if not alpha < _INF:
            return 0.0
        return 1.0 / alpha
    a = hard_k[i0]
    b = hard_k[i1]
    return a if a > b else b


@_hot
def _scalar_term(j, verts, nv, g, k, c, dedc, mode, grad, hess):
    """Add the gradient ``dedc * grad C`` and write the Gauss-Newton blocks ``k g_a g_b^T`` of a
    scalar constraint energy for stencil row ``j`` (vertices ``verts[j, :nv]``, gradient ``g``
    (nv, 3)). ``k`` is the curvature d2E/dC2 (>= 0), so every block set is PSD (rank one)."""
    if mode >= 1:
        for a in range(nv):
            i = verts[j, a]
            grad[i, 0] += dedc * g[a, 0]
            grad[i, 1] += dedc * g[a, 1]
            grad[i, 2] += dedc * g[a, 2]
    if mode >= 2:
        for a in range(nv):
            for b in range(nv):
                for r in range(3):
                    for s in range(3):
                        hess[j, a, b, r, s] = k * g[a, r] * g[b, s]


@njit(cache=True)
def scatter_blocks(data, bmap, hloc):
    """data[bmap[t, a, b]] += hloc[t, a, b] (3x3 blocks) for every term t."""
    m, k = bmap.shape[0], bmap.shape[1]
    for t in range(m):
        for a in range(k):
            for b in range(k):
                blk = bmap[t, a, b]
                for r in range(3):
                    for s in range(3):
                        data[blk, r, s] += hloc[t, a, b, r, s]


def gather_map(bmap: np.ndarray, nb: int):
    """For ``gather_blocks``: per block of the matrix (nb blocks) the flat indices t k k + a k +
    b of the local blocks ``bmap`` (m, k, k) sends there, ascending (a stable sort), as CSR
    ``(ptr (nb + 1,), src)``."""
    dst = bmap.reshape(-1)
    src = np.argsort(dst, kind="stable").astype(np.int64)
    ptr = np.zeros(nb + 1, np.int64)
    np.cumsum(np.bincount(dst, minlength=nb), out=ptr[1:])
    return ptr, src


@njit(cache=True)
def gather_blocks(data, ptr, src, hloc):
    """``scatter_blocks`` block by block of the matrix: data[blk] += hloc[t, a, b] over the
    local blocks sent to blk (``gather_map``), in ascending (t, a, b), the order
    ``scatter_blocks`` adds them in, so ``data`` is bitwise the same. Each matrix block is read
    and written once instead of once per local block (the stencil order of a mesh's terms is
    not the order of the matrix rows: the hinges of a 128 x 128 cloth scatter in 13-21 ms, gather
    in ~10.5 ms; its stretch rows 5.4-6.1 / 1.5 ms; graphs/bench/implicit_cost.py)."""
    h9 = hloc.reshape(-1)
    d9 = data.reshape(-1)
    for blk in range(ptr.shape[0] - 1):
        q0 = ptr[blk]
        q1 = ptr[blk + 1]
        if q0 == q1:
            continue
        o = 9 * blk
        v0, v1, v2 = d9[o], d9[o + 1], d9[o + 2]
        v3, v4, v5 = d9[o + 3], d9[o + 4], d9[o + 5]
        v6, v7, v8 = d9[o + 6], d9[o + 7], d9[o + 8]
        for q in range(q0, q1):
            u = 9 * src[q]
            v0 += h9[u]
            v1 += h9[u + 1]
            v2 += h9[u + 2]
            v3 += h9[u + 3]
            v4 += h9[u + 4]
            v5 += h9[u + 5]
            v6 += h9[u + 6]
            v7 += h9[u + 7]
            v8 += h9[u + 8]
        d9[o], d9[o + 1], d9[o + 2] = v0, v1, v2
        d9[o + 3], d9[o + 4], d9[o + 5] = v3, v4, v5
        d9[o + 6], d9[o + 7], d9[o + 8] = v6, v7, v8


def build_pattern(n: int, stencils: list[np.ndarray]):
    """Block-sparse row pattern of an n-vertex Hessian holding the diagonal and every (a, b)
    pair of every stencil row. Returns ``(indptr, indices, diag, maps)``: CSR of the 3x3
    blocks, the block index of every diagonal block, and per stencil set the (m, k, k) block
    index of each local block."""
    rows = [np.arange(n, dtype=np.int64)]
    cols = [np.arange(n, dtype=np.int64)]
    for S in stencils:
        k = S.shape[1]
        rows.append(np.repeat(S, k, axis=1).ravel())
        cols.append(np.tile(S, (1, k)).ravel())
    key = np.concatenate(rows) * n + np.concatenate(cols)
    ukey = np.unique(key)
    r = ukey // n
    indices = (ukey % n).astype(np.int32)
    indptr = np.concatenate([[0], np.cumsum(np.bincount(r, minlength=n))]).astype(np.int32)
    diag = np.searchsorted(ukey, np.arange(n, dtype=np.int64) * (n + 1))
    maps = []
    for S in stencils:
        m, k = S.shape
        kk = np.repeat(S, k, axis=1) * n + np.tile(S, (1, k))
        maps.append(np.searchsorted(ukey, kk.ravel()).reshape(m, k, k).astype(np.int64))
    return indptr, indices, diag, maps


@njit(cache=True)
def limit_energy(x, idx, rest, alpha, hard_k, limit, kmul, mode, grad, data, bmap):
    """Stiff strain-limit terms of the hard distance rows (``alpha`` 0, rest length > 0) in the
    solve: ``kmul * k / 2 * (|x_a - x_b| - (1 + limit) L)_+^2`` with ``k`` the row's hard
    penalty (``row_k``), i.e. only rows stretched past ``limit`` get the extra stiffness. The
    gradient goes into ``grad`` (mode >= 1); with mode 2 the exact Hessian blocks
    ``kk n n^T + (f / l) (I - n n^T)`` (PSD: the force f > 0 where the term is on) are added
    straight into the BSR ``data`` through ``bmap`` (the (m, 2, 2) block map of the rows'
    stencil). Returns the energy [J]."""
    E = 0.0
    for j in range(idx.shape[0]):
        if alpha[j] != 0.0 or rest[j] <= 0.0:
            continue
        a = idx[j, 0]
        b = idx[j, 1]
        e0 = x[a, 0] - x[b, 0]
        e1 = x[a, 1] - x[b, 1]
        e2 = x[a, 2] - x[b, 2]
        ln = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        c = ln - (1.0 + limit) * rest[j]
        if c <= 0.0:
            continue
        kk = kmul * row_k(0.0, hard_k, a, b)
        f = kk * c
        E += 0.5 * kk * c * c
        n0 = e0 / ln
        n1 = e1 / ln
        n2 = e2 / ln
        if mode >= 1:
            grad[a, 0] += f * n0
            grad[a, 1] += f * n1
            grad[a, 2] += f * n2
            grad[b, 0] -= f * n0
            grad[b, 1] -= f * n1
            grad[b, 2] -= f * n2
        if mode >= 2:
            t = f / ln
            nn = (n0, n1, n2)
            for r in range(3):
                for q in range(3):
                    hv = (kk - t) * nn[r] * nn[q] + (t if r == q else 0.0)
                    data[bmap[j, 0, 0], r, q] += hv
                    data[bmap[j, 1, 1], r, q] += hv
                    data[bmap[j, 0, 1], r, q] -= hv
                    data[bmap[j, 1, 0], r, q] -= hv
    return E
