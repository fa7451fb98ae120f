"""Global strain-limit step: fast projection (Goldenthal et al. 2007, "Efficient simulation of
inextensible cloth", section 4) of the edges over their strain limit, with the contacts.

Gauss-Seidel moves the excess of an edge only to its neighbours; in a saturated region (a cloth
draped over a sphere: every edge at its limit) the excess has to travel to the region's border,
one edge per sweep, and 100 sweeps still leave 5.4 % on the 64 x 64 drop against a 5 % limit.
The fast projection solves every active row at once. With the edge rows
``C(x) = |x_a - x_b| - limit`` over their limit and their gradient ``J``, a Newton step on the
constraint manifold is::

    (J W J^T + alpha diag(J W J^T)) dlam = C,        x -= W J^T dlam

(W: inverse masses, 0 for kinematic and pinned vertices), repeated until the worst edge excess
is within the tolerance or the pass count. ``alpha`` (Levenberg-Marquardt) is needed: a
triangle mesh has about three edges per vertex against two in-plane degrees of freedom, so in a
saturated region the rows are nearly redundant and the plain step diverges.

Contacts (``with_contacts``): 'filter' (default) makes W a 3 x 3 block per vertex, ``w (I -
n n^T)`` for a vertex of a contact with a collider (n: its most closed contact's normal), so that
the step slides cloth along the collider instead of into it; the system is then factorised once
and reused (chord Newton: right-hand side and J at the current x) while each pass at least halves
the worst excess and no edge outside the factorised set goes over. 'rows' adds the violated
vertex-face / edge-edge contacts (``n . (x_v - sum b_k x_k) - target``, ``n . (x_a(s) - x_b(t))
- target``, as ``project_vf`` / ``project_ee`` evaluate them) as rows of the same system,
inequality by dropping rows whose multiplier pulls, factorised every pass. Friction is not part
of the step. A step moves no vertex farther than half the shortest edge limit, and with contacts
it is halved (up to 4 times) while the worst edge gets worse.

With ``pivots`` > 0 every factorised pass solves the inequalities as a linear complementarity
problem (multipliers >= 0, no candidate row carried over its limit, complementary; block
principal pivoting, warm-started from the last pass's active set), and with 'rows' the
contacts are one row per vertex in contact with a collider, ``-(C + n . dx) <= 0`` along the
outward normal of its most closed contact: the cloth may lift off, not enter. This is what
makes the step converge on a cloth stretched over a sphere: the filter's tangent plane holds a
contacting vertex in both directions, and the equality step there stalls at ~1 % excess
(``global_pivots`` in strain_limit.py has the figures). The sparse system is factorised by
SuperLU (scipy.sparse.linalg.splu, COLAMD); J is assembled in numba kernels, the products by
scipy.sparse.

Why the passes converge linearly (measured on cloth_on_sphere at a 0.01 limit, the 'rows' +
pivots step, frame 9): each pass is a Gauss-Newton step, J re-linearised at the current x, but
the cloth needs moving by about an edge length (up to 19 mm against 15.6 mm edges) and the
linear step is only good for a small part of that: taken whole it rotates edges far enough that
they stretch at second order (worst edge 8.8 % -> 57 %, 31 % on the solved rows themselves,
with the complementarity problem solved exactly or not), so the guard halves it to 0.06-0.25
of itself. A smaller ``alpha`` makes the steps longer and worse; a larger one stalls (0.1:
3.7 %); where whole steps are taken, the excess left is the Levenberg-Marquardt residual
``alpha diag(A) dlam`` on the redundant rows. With ``smooth`` > 0 Gauss-Seidel sweeps of the
edge limits after each step take the second-order stretch out (it is local: a few sweeps fix
it), the guard takes whole steps (only the first one or two are shortened, by the cap on the
motion) and a smaller ``alpha`` (1e-4) holds. The sweeps move vertices freely, so each is
followed by the contact planes of the vertices in contact with a collider ('rows' with pivots:
the pass's rows; 'filter': the filter's vertices, once per run): a vertex behind its plane goes
back onto it. Without them the filter's sweeps pushed a 32 x 32 drape into its ball and the CCD
safe step's push-out stretched it to 2.93 % against a 1 % limit.

What a pass costs then (cloth_on_sphere, 0.01 limit, the opt-in A + S setting of
strain_limit.py's global_smooth, frames 7-18, cProfile): three SuperLU factorisations of the
pivots (~60 % of the step), the collider contact rows' closest points (~15 %, ``contact_rows``
over the rows with a kinematic vertex, now taken out of the contact lists once per step), the 40
sweeps (~3 ms a pass) and the products. ``fast`` (strain_limit.global_fast_lu) factorises with
small supernodes (8.2 -> 5.7 ms on frame 9's systems); ``chord`` (global_chord) re-solves the
last factorised active set with its factor while the passes converge (chord Newton: about 0.85
of the excess left per chord pass against 0.55 per factorised one, at a fifth of the cost).

Where the 128 x 128 drop's time goes at the defaults (graphs/bench/cloth_sphere_128.yaml, frames
7-12, NUMBA_NUM_THREADS=1, cProfile; 6.9 s a frame against the old defaults' 3.7 s): the step
2.47 s a frame, of it 39.5 SuperLU factorisations (13 LCP passes x 3 pivots) at 34 ms, 1.39 s
(56 %); 1140 smoothing sweeps (with the guard's halved steps), 0.46 s (19 %); the rest of
``_pivot`` (J W J^T, the diagonal, the submatrices, C - A dlam) 0.28 s (11 %); the collider
contact rows' closest points 0.19 s (8 %); solves 0.08 s. ``FAST_EXACT`` (submatrices by a
numba kernel, serial sweeps at one thread) is bitwise the same at about 0.93x the step's median
CPU; the factorisations are what is left: reusing an ordering changes the fill (``_splu``), and
global_pivots 1 holds 2.39 % there at the same cost (global_chord 6: the same 1.90 %, same cost).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numba import get_num_threads, njit

from .sparse_ldl import LDLFactor
from ..collision import contacts as _contacts
from .strain_limit import limit_edge, row_geometry, row_slid_apart


@njit(cache=True)
def edge_rows(p, w, edges, limit, sel, near, tol, out_idx, out_c, out_n):
    """Edges ``sel`` with ``|e| > (1 - near) limit`` and a movable vertex: their index, C [m]
    and unit direction (x_a - x_b) / |e| into the out arrays. Returns (count, worst relative
    excess |e| / limit - 1 over ``sel``, count over (1 + tol) limit)."""
    k = 0
    worst = -np.inf
    over = 0
    for ii in range(sel.shape[0]):
        j = sel[ii]
        a, b = edges[j, 0], edges[j, 1]
        dx = p[a, 0] - p[b, 0]
        dy = p[a, 1] - p[b, 1]
        dz = p[a, 2] - p[b, 2]
        ln = np.sqrt(dx * dx + dy * dy + dz * dz)
        r = ln / limit[j] - 1.0
        if r > worst:
            worst = r
        if r > tol:
            over += 1
        if r <= -near or ln < 1e-15 or w[a] + w[b] <= 0.0:
            continue
        out_idx[k] = j
        out_c[k] = ln - limit[j]
        out_n[k, 0] = dx / ln
        out_n[k, 1] = dy / ln
        out_n[k, 2] = dz / ln
        k += 1
    return k, worst, over


@njit(cache=True)
def contact_rows(p, w, rows, nrm, target, onesided, is_vf, keep, out_c, out_v, out_cf, out_n,
                 margin=0.0, collider_only=False, slide=0):
    """Contact rows (vertex-face when ``is_vf``, else edge-edge) with C < margin * target or
    flagged in ``keep`` (which they are then added to); with ``collider_only`` only rows with a
    kinematic vertex (w = 0): C [m] (< 0 when violated), the 4 vertices, their coefficients
    and the normal, as ``project_vf`` / ``project_ee`` evaluate them (the closest
    points and, on the start side, the current closest-point direction); with ``slide``
    (``contacts.SLIDE_APART``) not the rows slid apart along a collider (``row_slid_apart``),
    as the contact passes skip them. Returns the count."""
    k = 0
    for r in range(rows.shape[0]):
        i0, i1, i2, i3 = rows[r, 0], rows[r, 1], rows[r, 2], rows[r, 3]
        if collider_only and w[i0] > 0.0 and w[i1] > 0.0 and w[i2] > 0.0 and w[i3] > 0.0:
            continue
        c0, c1, c2, c3, n0, n1, n2, gap, d2 = row_geometry(p, rows, nrm, onesided, is_vf, r)
        if slide and row_slid_apart(w, rows, target, onesided, is_vf, r, d2, gap, slide):
            continue
        C = gap - target[r]
        if C >= margin * target[r] and not keep[r]:
            continue
        den = c0 * c0 * w[i0] + c1 * c1 * w[i1] + c2 * c2 * w[i2] + c3 * c3 * w[i3]
        if den <= 0.0:
            continue
        keep[r] = True
        out_c[k] = C
        out_v[k, 0], out_v[k, 1], out_v[k, 2], out_v[k, 3] = i0, i1, i2, i3
        out_cf[k, 0], out_cf[k, 1], out_cf[k, 2], out_cf[k, 3] = c0, c1, c2, c3
        out_n[k, 0], out_n[k, 1], out_n[k, 2] = n0, n1, n2
        k += 1
    return k


@njit(cache=True)
def contact_normals(w, c_v, c_cf, c_n, c_c, nc, best, out):
    """Per vertex the outward normal (from the collider to the vertex: the row's normal times
    the sign of the vertex's coefficient) of its most closed contact row (smallest C, held in
    ``best``), as ``contact_filter`` chooses it; ``best`` stays inf for vertices without one.
    Returns nothing."""
    for i in range(w.shape[0]):
        best[i] = np.inf
    for r in range(nc):
        for q in range(4):
            v = c_v[r, q]
            if abs(c_cf[r, q]) > 0.05 and w[v] > 0.0 and c_c[r] < best[v]:
                best[v] = c_c[r]
                s = 1.0 if c_cf[r, q] > 0.0 else -1.0
                for a in range(3):
                    out[v, a] = s * c_n[r, a]


@njit(cache=True)
def contact_filter(w, c_v, c_cf, c_n, c_c, nc, best, nrm, out):
    """Per-vertex inverse-mass blocks [1/kg] ``out`` (n, 3, 3) of the filtered global step:
    ``w I`` for free vertices, ``w (I - n n^T)`` for the vertices of a contact row (those with
    a coefficient over 0.05) along the normal of their most closed row (``contact_normals``,
    into ``best`` and the scratch ``nrm`` (n, 3); its sign cancels in n n^T), so that the step
    moves contacting vertices only in the contact's tangent plane. Returns nothing."""
    contact_normals(w, c_v, c_cf, c_n, c_c, nc, best, nrm)
    for i in range(w.shape[0]):
        for a in range(3):
            for b in range(3):
                if best[i] == np.inf:
                    out[i, a, b] = w[i] if a == b else 0.0
                else:
                    out[i, a, b] = w[i] * ((1.0 if a == b else 0.0) - nrm[i, a] * nrm[i, b])


@njit(cache=True)
def _coo(w, edges, e_idx, e_n, ne, c_v, c_cf, c_n, nc, row0, ri, ci, vi):
    """COO entries of J (rows: the ne edge rows, then the nc contact rows from ``row0``; columns:
    3 per vertex), leaving out vertices with w = 0. Returns the entry count."""
    k = 0
    for r in range(ne):
        j = e_idx[r]
        for v, sgn in ((edges[j, 0], 1.0), (edges[j, 1], -1.0)):
            if w[v] <= 0.0:
                continue
            for d in range(3):
                ri[k] = r
                ci[k] = 3 * v + d
                vi[k] = sgn * e_n[r, d]
                k += 1
    for r in range(nc):
        for q in range(4):
            v = c_v[r, q]
            cf = c_cf[r, q]
            if w[v] <= 0.0 or cf == 0.0:
                continue
            for d in range(3):
                ri[k] = row0 + r
                ci[k] = 3 * v + d
                vi[k] = cf * c_n[r, d]
                k += 1
    return k


@njit(cache=True)
def plane_project(p, vv, nn, c0, x0):
    """Vertices ``vv`` behind their contact plane (``c0 + nn . (p - x0) < 0``: C and position
    at the pass's start, outward normal) moved onto it along the normal. Returns nothing."""
    for r in range(vv.shape[0]):
        v = vv[r]
        c = c0[r]
        for a in range(3):
            c += nn[r, a] * (p[v, a] - x0[r, a])
        if c < 0.0:
            for a in range(3):
                p[v, a] -= c * nn[r, a]


@njit(cache=True)
def _principal_csc(indptr, indices, data, pos, idx, out_ptr, out_ind, out_val):
    """The principal submatrix R[idx][:, idx] of the CSC matrix (indptr, indices, data) (row
    indices sorted in each column) as CSC arrays into the out arrays (``pos``: each row's
    position in ``idx`` or -1; ``idx`` ascending, so the rows stay sorted): the arrays scipy's
    ``R[idx][:, idx].tocsc()`` gives, without its two fancy-indexing copies and conversion.
    Returns the entry count."""
    k = 0
    out_ptr[0] = 0
    for j in range(idx.shape[0]):
        c = idx[j]
        for q in range(indptr[c], indptr[c + 1]):
            r = pos[indices[q]]
            if r >= 0:
                out_ind[k] = r
                out_val[k] = data[q]
                k += 1
        out_ptr[j + 1] = k
    return k


@njit(cache=True)
def _sweeps_serial(p, w, edges, limit, color_ptr, n, planes, vv, nn, c0, x0):
    """``n`` Gauss-Seidel sweeps of the edge limits, each followed (with ``planes``) by the
    contact planes: ``project_strain_limit`` and ``plane_project`` in one call, serial. Within
    a colour the edges share no vertex, so this is bitwise the parallel kernel's result at any
    thread count; at one thread it skips the parallel launches (one per colour and sweep):
    40 sweeps of the 128 x 128 drop's 49k edges 27-32 -> 18-30 ms. Returns nothing."""
    for _ in range(n):
        for c in range(color_ptr.shape[0] - 1):
            for j in range(color_ptr[c], color_ptr[c + 1]):
                limit_edge(p, w, edges, limit, j)
        if planes:
            plane_project(p, vv, nn, c0, x0)


#: exact speedups of the step (positions bitwise the same): the pivots' principal submatrices
#: by ``_principal_csc`` and, at one numba thread, the smoothing sweeps by ``_sweeps_serial``;
#: False = scipy's indexing and the parallel kernel (for before/after timings in one process)
FAST_EXACT = True

_NO_CONTACTS = (np.zeros((0, 4), np.int64), np.zeros((0, 4)), np.zeros((0, 3)), 0)
_NO_PLANES = (np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)))


def _contact_planes(best, nrm, p):
    """The contact planes the Gauss-Seidel sweeps keep vertices in front of: the vertices with
    a contact (``best`` finite), their outward normals, C (``best``) and positions ``p``."""
    vv = np.flatnonzero(best < np.inf)
    return vv, np.ascontiguousarray(nrm[vv]), best[vv].copy(), p[vv].copy()


class GlobalStrainStep:
    """Work arrays of the global step for one StrainLimitConstraint (allocated at bind)."""

    def __init__(self, n_vertices, edges, limit, sel):
        m = len(sel)
        self.edges, self.limit, self.sel = edges, limit, np.ascontiguousarray(sel, np.int64)
        self.e_idx = np.zeros(m, np.int64)
        self.e_c = np.zeros(m)
        self.e_n = np.zeros((m, 3))
        self.n = n_vertices
        self.dmax = 0.5 * float(limit[sel].min()) if len(sel) else 0.0
        self.w3 = None
        self._blk = None
        self._nrm = None
        self.filter_min = 0.1
        # the pivots' systems are symmetric positive definite: a symmetric ordering with
        # diagonal pivots fills less than COLAMD (cloth_on_sphere at 0.01, 10 frames: the
        # step's CPU 1173 -> 737 ms per frame, the same worst strain)
        self.splu_opts = {"permc_spec": "MMD_AT_PLUS_A", "diag_pivot_thresh": 0.0,
                          "options": {"SymmetricMode": True}}
        self.stats = {"passes": 0, "factorisations": 0, "rows": 0, "contact_rows": 0}
        self.smooth = 0
        self._planes = None
        self._g_idx = None
        self._Rc = self._sub_pos = self._sub_ind = None
        self.ldl = False
        # the step's edges grouped by colour (``edges`` comes colour-sorted from the strain
        # limit's bind, ``sel`` ascending): the Gauss-Seidel smoothing sweeps them
        self.s_edges = np.ascontiguousarray(edges[self.sel])
        self.s_limit = np.ascontiguousarray(limit[self.sel])
        self.s_ptr = None

    def set_colors(self, color_ptr):
        """The colour groups of ``edges`` (``color_ptr``, as the strain limit's kernels take
        them), restricted to the step's edges: needed by the smoothing sweeps."""
        self.s_ptr = np.searchsorted(self.sel, color_ptr).astype(np.int64)

    def _contacts(self, c, kind):
        rows = getattr(c, kind)
        cap = len(rows)
        buf = getattr(self, "_cbuf_" + kind, None)
        if buf is None or len(buf[0]) < cap:
            cap = max(cap, 16) * 2
            buf = (np.zeros(cap), np.zeros((cap, 4), np.int64), np.zeros((cap, 4)),
                   np.zeros((cap, 3)), np.zeros(cap, np.bool_))
            setattr(self, "_cbuf_" + kind, buf)
        return buf

    def worst(self, p, w, tol):
        """Worst relative excess over the step's edges."""
        return edge_rows(p, w, self.edges, self.limit, self.sel, -np.inf, tol, self.e_idx,
                         self.e_c, self.e_n)[1]

    def _contact_set(self, p, w, contacts, kinds, margin, collider_only, sub=None):
        """The contact rows (see ``contact_rows``) of every kind, concatenated; with ``sub``
        (``_collider_subsets``, with collider_only) read from those subsets (the same rows, in
        the same order)."""
        cs = []
        for k in kinds:
            cb = self._contacts(contacts, k)
            if sub is None:
                nr = len(getattr(contacts, k))
                rows, nrm, tgt = (getattr(contacts, k), getattr(contacts, k + "_n"),
                                  getattr(contacts, k + "_target"))
                keep = cb[4][:nr]
                one = contacts.vf_onesided if k == "vf" else keep
            else:
                rows, nrm, tgt, one, keep = sub[k]
                keep[:] = False
            nk = contact_rows(p, w, rows, nrm, tgt, one, k == "vf", keep, cb[0], cb[1], cb[2],
                              cb[3], margin, collider_only, _contacts.slide_mode(False))
            if nk:
                cs.append((cb[0][:nk], cb[1][:nk], cb[2][:nk], cb[3][:nk]))
        if not cs:
            return np.zeros(0), np.zeros((0, 4), np.int64), np.zeros((0, 4)), np.zeros((0, 3))
        return tuple(np.concatenate([x[i] for x in cs]) for i in range(4))

    def _collider_subsets(self, w, contacts, kinds):
        """Per contact kind the rows with a kinematic vertex (w = 0), those ``contact_rows``
        reads with ``collider_only``: (rows, normals, targets, one-sided flags, keep scratch),
        taken once per run (the contacts do not change within the step)."""
        out = {}
        for k in kinds:
            rows = getattr(contacts, k)
            s = np.flatnonzero((w[rows] <= 0.0).any(axis=1))
            one = (contacts.vf_onesided[s] if k == "vf" else np.zeros(len(s), np.bool_))
            out[k] = (np.ascontiguousarray(rows[s]),
                      np.ascontiguousarray(getattr(contacts, k + "_n")[s]),
                      np.ascontiguousarray(getattr(contacts, k + "_target")[s]),
                      np.ascontiguousarray(one), np.zeros(len(s), np.bool_))
        return out

    def _weighted(self, J, Wb):
        """J W: the rows' Jacobian times the inverse masses (``Wb`` the block matrix where the
        contacts' filters make it one, else the diagonal ``w3``)."""
        return (J @ Wb) if Wb is not None else J.multiply(self.w3[None, :])

    def _freeze(self, rows):
        """Remember the edges of the solved ``rows`` (``e_idx[rows]``) as the next pass's
        frozen set, whose re-solve reuses this pass's factor; returns them."""
        frozen = self.e_idx[rows].copy()
        self._mark[:] = False
        self._mark[frozen] = True
        self.f_idx = np.zeros(len(frozen), np.int64)
        self.f_c = np.zeros(len(frozen))
        self.f_n = np.zeros((len(frozen), 3))
        return frozen

    def _jacobian(self, w, e_idx, e_n, ne, cv, ccf, cn, nc):
        cap = 6 * ne + 12 * nc
        ri = np.empty(cap, np.int64)
        ci = np.empty(cap, np.int64)
        vi = np.empty(cap)
        nnz = _coo(w, self.edges, e_idx, e_n, ne, cv, ccf, cn, nc, ne, ri, ci, vi)
        return sp.csr_matrix((vi[:nnz], (ri[:nnz], ci[:nnz])), shape=(ne + nc, 3 * self.n))

    def _factor(self, J, ne, alpha, Wb):
        """SuperLU of J W J^T + alpha diag(J W J^T) (W: the blocks ``Wb``, or the inverse
        masses), and the rows kept: with the contact filter, edge rows it leaves less than a
        tenth of their unfiltered motion for (their two vertices held along the edge) are
        dropped (they would need large multipliers for little motion)."""
        keep = None
        if Wb is not None:
            JW = (J @ Wb).tocsr()
            dg = np.asarray(JW.multiply(J).sum(axis=1)).ravel()
            d0 = np.asarray(J.multiply(J).multiply(self.w3[None, :]).sum(axis=1)).ravel()
            ok = dg > self.filter_min * d0
            if not ok.all():
                keep = np.flatnonzero(ok)
                J, JW = J[keep], JW[keep]
        else:
            JW = J.multiply(self.w3[None, :]).tocsr()
        A = (JW @ J.T).tocsc()
        A = A + sp.diags(alpha * A.diagonal() + 1e-300)
        return spla.splu(A.tocsc(), permc_spec="COLAMD"), keep

    def _splu(self, M):
        """SuperLU of the symmetric positive definite M with ``splu_opts``; with ``fast`` with
        small supernodes (``relax`` 1, ``panel_size`` 1): the systems' factors are sparse, and
        on cloth_on_sphere's frame-9 systems (21 factorisations, 4.6-8.0k rows) that takes
        8.2 -> 5.7 ms a factorisation at the same fill. Reusing a fill-reducing ordering did
        not pay: the first pass's over the later passes (rows it lacked appended) 8 -> 25 ms;
        one over every possible row (all edges and vertices) 6.3 -> 7.6 ms (1.5x the fill)."""
        if self.fast:
            return spla.splu(M.tocsc(), **self.splu_opts, relax=1, panel_size=1)
        return spla.splu(M.tocsc(), **self.splu_opts)

    def _pivot(self, J, C, lim, alpha, Wb, iters, tol, F0=None, update=0, need_lu=True):
        """The rows' inequalities as a linear complementarity problem: dlam >= 0, C - A dlam
        <= 0, complementary (A = J W J^T over the candidate rows, regularised by alpha
        diag(A) on the active ones), by block principal pivoting (Judice & Pires 1994): solve
        the active rows (at first those with C > 0 or in ``F0``), then swap every active row whose
        multiplier has the wrong sign out and every inactive row the step carries more than
        ``tol / 2`` of its ``lim`` over in, up to ``iters`` times; the active set with the
        fewest such rows is used. With ``update`` > 0 a pivot that changes at most that many
        rows from the last factorised set solves with that set's factor and a Schur
        complement over the changed rows (``_schur``) instead of factorising again (the
        same solve up to round-off). Returns (SuperLU of its rows -- None when ``need_lu``
        is False and the set was not factorised --, their indices into J, their J, their
        dlam)."""
        if Wb is not None:
            JW = (J @ Wb).tocsr()
            dg = np.asarray(JW.multiply(J).sum(axis=1)).ravel()
            d0 = np.asarray(J.multiply(J).multiply(self.w3[None, :]).sum(axis=1)).ravel()
            ok = np.flatnonzero(dg > self.filter_min * d0)
            if len(ok) < len(dg):
                J, JW, C, lim = J[ok], JW[ok], C[ok], lim[ok]
        else:
            ok = None
            JW = J.multiply(self.w3[None, :]).tocsr()
        A = (JW @ J.T).tocsr()
        dg = A.diagonal()
        R = (A + sp.diags(alpha * dg + 1e-300)).tocsr()
        if FAST_EXACT or self.ldl:
            self._principal_of(R)
        F = C > 0.0
        if F0 is not None:  # warm start: the last pass's active set
            F |= F0 if ok is None else F0[ok]
        gap = 0.5 * tol * lim
        best = base = None
        for it in range(iters + 1):
            idx = np.flatnonzero(F)
            dl = lu = None
            if base is not None:
                idx0, in0 = base[1], base[2]
                drop, add = idx0[~F[idx0]], idx[~in0[idx]]
                if len(drop) + len(add) <= update:
                    dl = self._schur(R, C, base, drop, add, idx)
                    self.stats["updates"] = self.stats.get("updates", 0) + 1
            if dl is None:
                lu = self._factorise(R, idx)
                dl = lu.solve(C[idx])
                if update:
                    pos = np.full(len(C), -1, np.int64)
                    pos[idx] = np.arange(len(idx))
                    base = (lu, idx, F.copy(), pos)
            dlam = np.zeros(len(C))
            dlam[idx] = dl
            Cn = C - A @ dlam
            out = F & (dlam < 0.0)
            inn = ~F & (Cn > gap)
            nbad = int(out.sum() + inn.sum())
            if best is None or nbad < best[0]:
                best = (nbad, lu, idx, dl)
            self.stats["pivots"] = self.stats.get("pivots", 0) + 1
            if nbad == 0 or it == iters:
                break
            F[out] = False
            F[inn] = True
        nbad, lu, idx, dl = best
        if lu is None and need_lu:
            lu = self._factorise(R, idx)
        self.stats["unpivoted"] = max(self.stats.get("unpivoted", 0), nbad)
        rows = idx if ok is None else ok[idx]
        return lu, rows, J[idx], dl

    def _factorise(self, R, idx):
        """The factor of R[idx][:, idx]: QDLDL's LDL^T with ``ldl`` (strain_limit.
        global_factor 'qdldl', ``sparse_ldl``), else SuperLU (``_splu``)."""
        if self.ldl:
            return LDLFactor(self._principal(idx))
        return self._splu(self._principal(idx) if FAST_EXACT else R[idx][:, idx])

    def _principal_of(self, R):
        """Take R (CSR, symmetric in structure) as the matrix ``_principal`` extracts from: its
        CSC form once a ``_pivot`` call, the work arrays grown to its size."""
        self._Rc = R.tocsc()
        n, nnz = R.shape[0], self._Rc.nnz
        if self._sub_pos is None or len(self._sub_pos) < n:
            self._sub_pos = np.full(2 * n, -1, np.int64)
            self._sub_ptr = np.zeros(2 * n + 1, np.int32)
        if self._sub_ind is None or len(self._sub_ind) < nnz:
            self._sub_ind = np.zeros(2 * nnz, np.int32)
            self._sub_val = np.zeros(2 * nnz)

    def _principal(self, idx):
        """R[idx][:, idx] as CSC (``_principal_csc``; the same arrays as scipy's indexing
        followed by tocsc, so the factor is bitwise the same: 7.3 + 2.4 ms -> ~1 ms a pivot
        on the 128 x 128 drop's 30k-row systems). The arrays are fresh copies: the factor
        outlives the next extraction."""
        Rc, pos = self._Rc, self._sub_pos
        m = len(idx)
        pos[idx] = np.arange(m)
        k = _principal_csc(Rc.indptr, Rc.indices, Rc.data, pos, idx, self._sub_ptr,
                           self._sub_ind, self._sub_val)
        pos[idx] = -1
        return sp.csc_matrix((self._sub_val[:k].copy(), self._sub_ind[:k].copy(),
                              self._sub_ptr[:m + 1].copy()), shape=(m, m))

    @staticmethod
    def _schur(R, C, base, drop, add, idx):
        """Solve R[idx, idx] x = C[idx] with the factor of R over the set ``idx0`` (``base``:
        SuperLU, idx0, its mask, position of each row in idx0), idx = idx0 - drop + add: the
        bordered system [[B, R0a, -E], [Ra0, Raa, 0], [E^T, 0, 0]] [x0, xa, mu] = [c0 (0 on
        the dropped rows), ca, 0] (B = R[idx0, idx0], E: the dropped rows' unit columns),
        eliminated through B: (S - W^T B^-1 V) [xa, mu] = [ca, 0] - W^T B^-1 c0."""
        lu, idx0, _, pos = base
        na, nd = len(add), len(drop)
        pd = pos[drop]
        c0 = C[idx0].copy()
        c0[pd] = 0.0
        y0 = lu.solve(c0)
        if na + nd == 0:
            return y0
        V = np.zeros((len(idx0), na + nd))
        Ra = np.zeros((0, 0))
        if na:
            Rc = R[:, add].tocsc()
            V[:, :na] = Rc[idx0].toarray()
            Ra = Rc[add].toarray()
        V[pd, na + np.arange(nd)] = -1.0
        Y = lu.solve(V)
        # W = V with the dropped columns' sign flipped
        M = np.zeros((na + nd, na + nd))
        M[:na, :na] = Ra
        M[:na] -= V[:, :na].T @ Y
        M[na:] -= Y[pd]
        r = np.zeros(na + nd)
        r[:na] = C[add] - V[:, :na].T @ y0
        r[na:] = -y0[pd]
        z = np.linalg.solve(M, r)
        x0 = y0 - Y @ z
        out = np.empty(len(idx))
        keep = pos[idx] >= 0
        out[keep] = x0[pos[idx[keep]]]
        out[~keep] = z[:na][np.searchsorted(add, idx[~keep])]
        return out

    def _smooth_sweeps(self, p, w):
        """``smooth`` Gauss-Seidel sweeps of the step's edge limits (``project_strain_limit``),
        each followed by the contact planes (``_planes``: vertices, outward normals, C and
        positions when taken -- each factorised pass with 'rows', the run's start with
        'filter' --; a vertex behind its plane is moved onto it along the normal)."""
        from .strain_limit import project_strain_limit

        pl = self._planes
        if FAST_EXACT and get_num_threads() == 1:
            if pl is None:
                _sweeps_serial(p, w, self.s_edges, self.s_limit, self.s_ptr, self.smooth,
                               False, *_NO_PLANES)
            else:
                _sweeps_serial(p, w, self.s_edges, self.s_limit, self.s_ptr, self.smooth,
                               True, *pl)
            return
        for _ in range(self.smooth):
            project_strain_limit(p, w, self.s_edges, self.s_limit, self.s_ptr)
            if pl is not None:
                plane_project(p, *pl)

    def _chord_pass(self, p, w, tol, worst, ch):
        """A chord pass of 'rows' + pivots (``chord``): the last factorised pass's active set
        (edges and contact rows, ``ch``) solved with that pass's factor, J and right-hand side
        at the current x (C clamped at 0: rows gone under their limit are held, not pulled
        back; a contact's C from its plane at that pass), then moved as a pass is. Returns
        False (nothing done) when an edge of the set has no row any more."""
        lu, fe, cv, ccf, cn, c0, x0 = ch
        if self._g_idx is None or len(self._g_idx) < len(fe):
            m = len(self.sel)
            self._g_idx, self._g_c, self._g_n = (np.zeros(m, np.int64), np.zeros(m),
                                                 np.zeros((m, 3)))
        nf, _, _ = edge_rows(p, w, self.edges, self.limit, fe, np.inf, tol, self._g_idx,
                             self._g_c, self._g_n)
        if nf != len(fe):
            return False
        cc = c0 + np.einsum("ij,ij->i", cn, p[cv[:, 0]] - x0)
        C = np.concatenate([np.maximum(self._g_c[:nf], 0.0), np.maximum(-cc, 0.0)])
        J = self._jacobian(w, self._g_idx, self._g_n, nf, cv, ccf, cn, len(cv))
        dlam = lu.solve(C)
        dx = J.multiply(self.w3[None, :]).T @ dlam
        self._move(p, w, tol, worst, dx.reshape(-1, 3), True)
        self.stats["passes"] += 1
        self.stats["chord"] = self.stats.get("chord", 0) + 1
        return True

    def _move(self, p, w, tol, worst, dx, guard):
        """p -= dx, the step capped at ``dmax`` per vertex and, with ``guard``, halved (up to 4
        times) while the worst edge gets worse; with ``smooth`` > 0 each tried step is followed
        by that many Gauss-Seidel sweeps of the edge limits (``_smooth_sweeps``) before the
        worst edge is measured."""
        big = np.sqrt(np.einsum("ij,ij->i", dx, dx).max())
        if big > self.dmax:
            dx *= self.dmax / big
        smooth = self.smooth > 0 and self.s_ptr is not None
        p0 = p.copy() if (guard or smooth) else None
        p -= dx
        if smooth:
            self._smooth_sweeps(p, w)
        if guard:
            for _h in range(4):
                if self.worst(p, w, tol) <= max(worst, tol):
                    break
                dx *= 0.5
                p[:] = p0 - dx
                if smooth:
                    self._smooth_sweeps(p, w)

    def run(self, p, w, contacts, passes, tol, near, alpha, with_contacts="filter",
            pivots=0, update=0, smooth=0, chord=0, chord_rate=0.5, fast=False):
        """Up to ``passes`` Newton steps on p (in place) until every edge is within
        (1 + tol) limit. Returns the worst relative excess left.

        'filter' (chord Newton): the contact filter is built once, from the contacts against
        colliders at the start; the system is factorised for the active edges and reused in the
        next passes (right-hand side C(x) of those rows, C clamped at 0 for rows that went
        under their limit, J(x) for the motion) until an edge outside that set goes over its
        limit or a pass fails to halve the worst excess. 'rows': the violated contacts are rows
        of the system (inequality: rows whose multiplier pulls are dropped and the system solved
        again), factorised every pass.
        'none': edges only. With ``pivots`` > 0 the factorised passes are LCPs (``_pivot``):
        'filter' over the edges (within ``near`` of their limit), 'rows' over the edges and one
        one-sided row per vertex in contact with a collider, factorised every pass.
        ``smooth`` > 0: each pass's step is followed by that many Gauss-Seidel sweeps of the
        edge limits (with 'rows' and pivots, interleaved with the pass's contact planes)
        before the guard measures it (``_move``)."""
        self.smooth = int(smooth)
        self.fast = bool(fast)
        self._planes = None
        if self.w3 is None or len(self.w3) != 3 * len(w):
            self.w3 = np.repeat(w, 3)
            self._mark = np.zeros(len(self.edges), np.bool_)
            self._act = np.zeros(len(self.edges) + len(w), np.bool_)
        self._act[:] = False
        filt = with_contacts == "filter"
        kinds = ()
        if contacts is not None and with_contacts in ("rows", "filter"):
            kinds = tuple(k for k in ("vf", "ee") if len(getattr(contacts, k)))
            for k in kinds:
                self._contacts(contacts, k)[4][:len(getattr(contacts, k))] = False
        Wb = None
        if filt:
            cc, cv, ccf, cn = self._contact_set(p, w, contacts, kinds, 1.0, True)
            if len(cc):
                if self._blk is None or len(self._blk) != len(w):
                    self._blk = np.zeros((len(w), 3, 3))
                    self._best = np.zeros(len(w))
                    self._bnrm = np.zeros((len(w), 3))
                contact_filter(w, cv, ccf, cn, cc, len(cc), self._best, self._bnrm, self._blk)
                nb = len(w)
                Wb = sp.bsr_matrix((self._blk, np.arange(nb), np.arange(nb + 1)),
                                   shape=(3 * nb, 3 * nb)).tocsr()
                self.stats["filtered"] = int((self._best < np.inf).sum())
                if self.smooth:
                    # the sweeps move vertices freely: without the filter's contact planes
                    # they pushed the drape's cloth into the ball (1.3 against 4.1 mm from its
                    # inradius), and what the CCD safe step then did stretched it to 2.9 %
                    self._planes = _contact_planes(self._best, self._bnrm, p)
        lu = frozen = None
        worst = last = np.inf
        sub = ch = None
        rows_piv = bool(kinds) and not filt and pivots
        if rows_piv:
            sub = self._collider_subsets(w, contacts, kinds)
        prev = np.inf  # the worst excess before the last pass
        n_chord = 0
        for _ in range(passes):
            n_over, worst, over = edge_rows(p, w, self.edges, self.limit, self.sel, -tol, tol,
                                            self.e_idx, self.e_c, self.e_n)
            if over == 0 or n_over == 0:
                break
            if (ch is not None and n_chord < chord and worst <= chord_rate * prev
                    and self._chord_pass(p, w, tol, worst, ch)):
                n_chord += 1
                prev = worst
                continue
            n_chord = 0
            prev = worst
            if lu is not None and worst > 0.5 * last:
                lu = None  # the chord steps converge slowly: factorise again
            last = worst
            if lu is not None and self._mark[self.e_idx[:n_over]].all():  # chord step
                nf, _, _ = edge_rows(p, w, self.edges, self.limit, frozen, np.inf, tol,
                                     self.f_idx, self.f_c, self.f_n)
                if nf == len(frozen):
                    J = self._jacobian(w, self.f_idx, self.f_n, nf, *_NO_CONTACTS)
                    dlam = lu.solve(np.maximum(self.f_c[:nf], 0.0))
                    dx = self._weighted(J, Wb).T @ dlam
                    self._move(p, w, tol, worst, dx.reshape(-1, 3), bool(kinds))
                    self.stats["passes"] += 1
                    continue
            ne, _, _ = edge_rows(p, w, self.edges, self.limit, self.sel, near, tol,
                                 self.e_idx, self.e_c, self.e_n)
            if (filt or not kinds) and pivots:
                J = self._jacobian(w, self.e_idx, self.e_n, ne, *_NO_CONTACTS)
                lu, rows, J, dlam = self._pivot(J, self.e_c[:ne], self.limit[self.e_idx[:ne]],
                                                alpha, Wb, pivots, tol, update=update)
                frozen = self._freeze(rows)
                dx = self._weighted(J, Wb).T @ dlam
            elif filt or not kinds:
                J = self._jacobian(w, self.e_idx, self.e_n, ne, *_NO_CONTACTS)
                rows = np.arange(ne)
                lu, keep = self._factor(J, ne, alpha, Wb)
                if keep is not None:
                    rows, J = rows[keep], J[keep]
                dlam = lu.solve(self.e_c[rows])
                frozen = self._freeze(rows)
                dx = self._weighted(J, Wb).T @ dlam
            elif pivots:  # rows, as one LCP with the edges, factorised every pass
                # one row per vertex in contact with a collider: its most closed contact's
                # outward normal n, -(C + n . u) <= 0 with a multiplier >= 0 (pushing)
                cc, cv, ccf, cn = self._contact_set(p, w, contacts, kinds, 1.0, True, sub)
                if self._nrm is None or len(self._nrm) != len(w):
                    self._nrm = np.zeros((len(w), 3))
                    self._vbest = np.zeros(len(w))
                nrm = self._nrm
                contact_normals(w, cv, ccf, cn, cc, len(cc), self._vbest, nrm)
                vv = np.flatnonzero(self._vbest < np.inf)
                nc = len(vv)
                if self.smooth:
                    self._planes = _contact_planes(self._vbest, nrm, p)
                cv = np.zeros((nc, 4), np.int64)
                cv[:, 0] = vv
                ccf = np.zeros((nc, 4))
                ccf[:, 0] = -1.0
                J = self._jacobian(w, self.e_idx, self.e_n, ne, cv, ccf,
                                   np.ascontiguousarray(nrm[vv]), nc)
                C = np.concatenate([self.e_c[:ne], -self._vbest[vv]])
                lim = np.concatenate([self.limit[self.e_idx[:ne]], np.full(nc, 2.0 * self.dmax)])
                ids = np.concatenate([self.e_idx[:ne], len(self.edges) + vv])
                lu, rows, J, dlam = self._pivot(J, C, lim, alpha, None, pivots, tol,
                                                self._act[ids], update, chord > 0)
                self._act[:] = False
                self._act[ids[rows]] = True
                dx = J.multiply(self.w3[None, :]).T @ dlam
                if chord > 0:
                    re, rc = rows[rows < ne], rows[rows >= ne] - ne
                    ch = (lu, self.e_idx[re].copy(), np.ascontiguousarray(cv[rc]),
                          np.ascontiguousarray(ccf[rc]), np.ascontiguousarray(nrm[vv[rc]]),
                          self._vbest[vv[rc]].copy(), p[vv[rc]].copy())
                lu = None
                for k in kinds:
                    self._contacts(contacts, k)[4][:] = False
                self.stats["contact_rows"] = max(self.stats["contact_rows"], nc)
            else:  # rows: the violated contacts join the system, factorised every pass
                cc, cv, ccf, cn = self._contact_set(p, w, contacts, kinds, 0.0, False)
                nc = len(cc)
                J = self._jacobian(w, self.e_idx, self.e_n, ne, cv, ccf, cn, nc)
                C = np.concatenate([self.e_c[:ne], cc])
                for it in range(2):
                    lu, _ = self._factor(J, ne, alpha, None)
                    dlam = lu.solve(C)
                    bad = np.zeros(len(C), np.bool_)
                    bad[ne:] = dlam[ne:] > 0.0  # a contact pulling
                    if it or not bad.any():
                        break
                    keep = np.flatnonzero(~bad)
                    J, C = J[keep], C[keep]
                dx = J.multiply(self.w3[None, :]).T @ dlam
                lu = None
                for k in kinds:  # rows join again only while violated
                    self._contacts(contacts, k)[4][:] = False
                self.stats["contact_rows"] = max(self.stats["contact_rows"], nc)
            self._move(p, w, tol, worst, dx.reshape(-1, 3), bool(kinds))
            self.stats["passes"] += 1
            self.stats["factorisations"] += 1
            self.stats["rows"] = max(self.stats["rows"], ne)
        else:
            worst = self.worst(p, w, tol)
        return worst
