"""Stretch and compression (Nucleus type 1): the length of cloth edges, hair segments and tet
edges, with separate stretch and compression compliance and optional stretch damping.

:class:`StretchConstraint` packs the edges of all bound elements at bind; the XPBD kernels below
project them (conventions in :mod:`lokigraph.behaviors.solvers.nucleus.xpbd`). Stitches
(:mod:`lokigraph.behaviors.attachments.stitch`) reuse the same edge projection. Inextensible
cloth can add hierarchical long-range rows and extra edge sweeps (``long_range_levels``,
``sweeps``; on by default, see the section comment before the behavior and the parameters)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numba import njit, prange
from pydantic import Field

from lokigraph.behavior import ConstraintBehavior, ConstraintParams
from lokigraph.components.core import Dynamic
from lokigraph.components.materials import DiscreteShell, Rod, Volume
from lokigraph.geometry import triangle_areas

from .. import topology as T
from ..solvers.nucleus.xpbd import _INF, _LEN_EPS, _hot, _nudge, residual, sequential_sweep
from .common import Packed, _concat, _rest
from .rod import solved_directly
from .volume import rest_tet_volumes


# ==============================================================================================
# XPBD kernels
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


def residual_stretch(p, edges, rest):
    """(max |C| [m], RMS [m]) of the stretch constraints."""
    return residual(stretch_values(p, edges, rest))


def rest_lengths(x, edges):
    """Rest lengths [m] of edges at positions x, shape (m,)."""
    x = np.asarray(x, dtype=np.float64)
    return np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1)


# ------------------------------------------------------------------ hierarchical long-range rows
#
# Gauss-Seidel over the edges of a sheet moves a correction about one edge per colour sweep, so
# an inextensible cloth that must stop (landing on a body, caught by a contact, a gust) stretches
# by whatever the iterations cannot carry across it: measured on the 64 x 64 drop onto a sphere,
# the edge strain after the iterations is what the frame keeps (the final collision rounds and
# the CCD step change it by less than 0.1 %), contacts first or last, with or without friction
# or self-collision, and 400 alternating stretch/contact sweeps on a stretched state leave it at
# 150 %. The long-range rows below carry the correction across the sheet in one sweep: along
# every straight line of mesh edges, vertices 2, 4, ... 2^levels edges apart keep at most the
# rest length of the line between them, ``|p_i - p_j| <= sum of the rest edge lengths``. The
# bound is the length of a curve on the rest surface, so every isometric deformation meets it
# (the rows never fight an unstretched cloth); they are unilateral and hard, projected with the
# same mass weighting as the edges, before the edge sweeps of every stretch pass.


@njit(cache=True)
def _straight_next(X, src, dst, ptr, cos_min):
    """For every directed edge (src -> dst), the out-edge of dst that continues it most
    straightly in the rest positions X (cosine above ``cos_min``), or -1."""
    m = src.shape[0]
    nxt = np.full(m, -1, np.int64)
    for e in range(m):
        a = src[e]
        b = dst[e]
        dx = X[b, 0] - X[a, 0]
        dy = X[b, 1] - X[a, 1]
        dz = X[b, 2] - X[a, 2]
        la = math.sqrt(dx * dx + dy * dy + dz * dz)
        if la <= 0.0:
            continue
        best = cos_min
        for f in range(ptr[b], ptr[b + 1]):
            c = dst[f]
            ex = X[c, 0] - X[b, 0]
            ey = X[c, 1] - X[b, 1]
            ez = X[c, 2] - X[b, 2]
            lb = math.sqrt(ex * ex + ey * ey + ez * ez)
            if lb <= 0.0:
                continue
            cs = (dx * ex + dy * ey + dz * ez) / (la * lb)
            if cs > best:
                best = cs
                nxt[e] = f
    return nxt


@njit(cache=True)
def _line_pairs(X, src, dst, rev, nxt, levels, out_i, out_j, out_l, line):
    """Walk the straight lines of directed edges (``nxt``: continuation, ``rev``: the reverse
    edge) and write the long-range rows of every line: vertices k and k + s (s = 2, 4, ...,
    2^levels edges apart, k a multiple of s / 2) with the rest length of the line between them.
    Each undirected edge belongs to one line. Returns the number of rows."""
    m = src.shape[0]
    has_prev = np.zeros(m, np.bool_)
    for e in range(m):
        if nxt[e] >= 0:
            has_prev[nxt[e]] = True
    seen = np.zeros(m, np.bool_)
    cum = np.zeros(line.shape[0] + 1)
    k = 0
    for sweep in range(2):  # open lines from their first edge, then closed loops anywhere
        for e0 in range(m):
            if seen[e0] or (sweep == 0 and has_prev[e0]):
                continue
            nv = 0
            line[nv] = src[e0]
            cum[0] = 0.0
            e = e0
            while e >= 0 and not seen[e]:
                seen[e] = True
                seen[rev[e]] = True
                a = src[e]
                b = dst[e]
                nv += 1
                line[nv] = b
                cum[nv] = cum[nv - 1] + math.sqrt((X[b, 0] - X[a, 0]) ** 2
                                                  + (X[b, 1] - X[a, 1]) ** 2
                                                  + (X[b, 2] - X[a, 2]) ** 2)
                e = nxt[e]
            for lv in range(1, levels + 1):
                s = 1 << lv
                if s > nv:
                    break
                step = s // 2
                for i in range(0, nv - s + 1, step):
                    out_i[k] = line[i]
                    out_j[k] = line[i + s]
                    out_l[k] = cum[i + s] - cum[i]
                    k += 1
    return k


def long_range_rows(X, edges, levels, cos_min=0.95):
    """Hierarchical long-range rows of a mesh (see the section comment): ``(pairs (r, 2) int64,
    bound [m] (r,))`` for the rest positions X [m] (n, 3) and edges (m, 2), lines continuing
    where the next edge turns by less than ``acos(cos_min)``."""
    X = np.ascontiguousarray(X, dtype=np.float64)
    edges = np.asarray(edges, dtype=np.int64)
    m = len(edges)
    if levels <= 0 or m == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0)
    src = np.concatenate([edges[:, 0], edges[:, 1]])
    dst = np.concatenate([edges[:, 1], edges[:, 0]])
    order = np.argsort(src, kind="stable")
    inv = np.empty_like(order)
    inv[order] = np.arange(2 * m)
    src, dst = src[order], dst[order]
    rev = inv[(order + m) % (2 * m)]  # position of the reverse of each sorted directed edge
    ptr = np.concatenate([[0], np.cumsum(np.bincount(src, minlength=len(X)))]).astype(np.int64)
    nxt = _straight_next(X, src, dst, ptr, cos_min)
    cap = 2 * m * levels + 16
    oi, oj, ol = np.zeros(cap, np.int64), np.zeros(cap, np.int64), np.zeros(cap)
    k = _line_pairs(X, src, dst, rev, nxt, int(levels), oi, oj, ol, np.zeros(m + 1, np.int64))
    return np.stack([oi[:k], oj[:k]], axis=1), ol[:k]


# ------------------------------------------------------------------ Nucleus constraint behavior


def _project_edges(ctx, d, p, alpha2=None):
    """Distance rows of a Packed set (stretch edges, stitches): damped where it has beta,
    sequential or coloured parallel by its size. ``alpha2``: compression compliances to use
    instead of ``d.alpha2`` (the stretch set's Nucleus compliances)."""
    w = ctx.model.particle_inv_mass
    a2 = d.alpha2 if alpha2 is None else alpha2
    seq = sequential_sweep(d.sequential)
    if d.beta is not None:
        fn = project_stretch_damped_seq if seq else project_stretch_damped
        fn(p, ctx.state.particle_q, w, d.idx, d.rest, d.alpha, a2, d.beta, d.lam,
           ctx.dt, d.color_ptr)
    else:
        fn = project_stretch_seq if seq else project_stretch
        fn(p, w, d.idx, d.rest, d.alpha, a2, d.lam, ctx.dt, d.color_ptr)


class StretchParams(ConstraintParams):
    long_range_levels: int = Field(5, ge=0, le=16, description="Hierarchical long-range rows "
                                   "of inextensible DiscreteShell cloth (see the module's "
                                   "section comment): along every straight line of edges, "
                                   "vertices 2, 4, ..., 2^levels edges apart stay within the "
                                   "rest length of the line between them; 0 = off (the default "
                                   "before issue #13). Default 5 with 3 sweeps, "
                                   "strain_limit.inextensible_max_strain 0.05 and "
                                   "inextensible_compression 10 (graphs/bench/cloth_strain.py "
                                   "'before' -> 'defaults', worst-frame edge strain over 24 "
                                   "frames): cloth_on_sphere 183.6 -> 6.6 %, skirt_walk 8.0 -> "
                                   "5.0 %, sleeve_elbow 94.8 -> 23.9 %, the 128 x 128 drop 914 "
                                   "-> 15.9 %, at about the CPU per frame of the drop before. "
                                   "The rows alone (no limit, hard compression): cloth_on_sphere "
                                   "184 -> 26 %, cloth_pinned 10.2 -> 2.0 %, flag_wind 17.1 -> "
                                   "6.1 %, skirt_walk 8.0 -> 6.6 %, sleeve_elbow 95 -> 99 %. "
                                   "With rows and limit but hard compression, the sleeve caught "
                                   "in the crease of the slow elbow test moves faster than the "
                                   "forearm (0.95 to 1.39 m/s at 14-17 solver iterations against "
                                   "the 0.73 m/s bound; see inextensible_compression, which "
                                   "holds it at 0.55 to 0.68). The stress case of a cloth "
                                   "starting interpenetrated keeps 37 self-intersecting pairs "
                                   "and no more cloth vertices inside the ball than after its "
                                   "first frame (lokigraph.bench.stress.tangle_counts).")
    sweeps: int = Field(3, ge=1, le=100, description="Edge sweeps per stretch pass when the "
                        "set holds inextensible cloth (other sets always 1; 1 before issue "
                        "#13). Edges are cheap next to contacts; more sweeps carry corrections "
                        "farther per iteration (cloth_on_sphere with 5 long-range levels, 1 -> "
                        "3 sweeps: 47 -> 26 %). Cost of 5 levels + 3 sweeps, CPU ms/frame "
                        "before -> after in one run: 534 -> 482 on the 64 x 64 drop (fewer "
                        "active contacts), 15 -> 30 on cloth_pinned (32 x 32, no contacts).")
    inextensible_compression: float | None = Field(
        10.0, gt=0, description="Membrane compression stiffness E t [N/m] of the edges of "
        "inextensible DiscreteShell cloth (youngs_modulus null) that have a vertex in a "
        "contact row of the substep (the detection's candidates), times the shell's "
        "compression_ratio (0 keeps compression off), in the Nucleus projection; other edges "
        "and the implicit solver's energy (unless implicit_compression) stay hard in "
        "compression; null = hard everywhere (the default before issue #13). Cloth squeezed "
        "in contact buckles instead of pushing back: with hard "
        "compression rows, a sleeve pinched in a closing elbow crease is held between the "
        "contacts, the long-range rows and the strain limit (edges of one vertex at -20 % and "
        "+20 % in the same iteration, the vertex moved 3-4 mm back and forth in every "
        "iteration), and its frame-end speed is the residue of that fight. Measured with "
        "long_range_levels 5, sweeps 3 and strain_limit.inextensible_max_strain 0.05 "
        "(graphs/bench/cloth_strain.py 'in_contact_hard' -> 'defaults'), sleeve speed within "
        "0.15 m of the elbow "
        "joint over 60 frames (tests/test_elbow.py; bound 0.73 m/s) at 14/15/16/17 solver "
        "iterations: hard 0.95/0.86/1.15/1.39 m/s, 10 N/m 0.68/0.59/0.64/0.55 m/s, 100 N/m "
        "1.15/1.01/0.85/0.78 m/s; compression off 0.80/0.79/0.80/0.83 (a fold of the collapsed "
        "sleeve falls freely once the crease opens). Compliant on every edge instead of only "
        "near contacts, the 10 N/m flag in wind reaches 18.3 % strain (5.0 % hard).")
    implicit_compression: Literal["hard", "near_contacts"] = Field(
        "hard", description="The implicit solver's energy of the hard edges of inextensible "
        "DiscreteShell cloth in compression: 'hard' the augmented-Lagrangian penalty both ways "
        "(the default); 'near_contacts' the Nucleus projection's compression stiffness "
        "(inextensible_compression) on the edges with a vertex in a contact row of the "
        "substep, so that cloth squeezed in contact buckles in the Newton solve as it does in "
        "the Nucleus projection (opt-in; issue #11). Cause measured on sleeve_elbow with "
        "solver: implicit (graphs/bench/implicit_compliant_elbow.py --dirichlet --energy 12 13): "
        "with 'hard' "
        "the crease compresses the sleeve's edges at the joint by up to 33 % (frame 13) and "
        "the incremental potential at the Newton cap holds 9.9 J, 8.5 J of it in these rows "
        "(the sleeve's kinetic energy is a few mJ); with 'near_contacts' 0.1-1.2 J. "
        "Near-joint speed (bound 0.73 m/s; frames 5-61, 0 intersecting pairs in every frame; "
        "CPU of the 60 frames): 'hard' 1.071 m/s, 12 frames over the bound, 47.4 s; "
        "'near_contacts' 1.069 m/s, 8 frames, 50.6 s: the rest is Newton stopping at its cap "
        "far from the minimum. With compliant_kinematics: energy, compliant_depth 0.01 and "
        "contact_newton_iterations 20 / 60 / 100: 1.050 m/s, 11 frames / 0.871 m/s, 2 frames "
        "/ 0.707 m/s, 0 frames (largest sleeve speed 0.979 m/s, 222 s: the elbow's bounds "
        "met, tests/test_implicit_elbow.py); hard compression there 1.300 m/s at 20 and "
        "1.626 m/s at 100 (graphs/bench/implicit_compliant_elbow.py's table).")
    joint_long_range: bool | Literal["pinch"] = Field(
        "pinch", description="Project the long-range rows also in every joint pass of the "
        "final collision rounds and of the CCD rounds (before the strain limits and the "
        "contacts), where they carry the strain limit's corrections across the sheet: true in "
        "every substep, 'pinch' only in the substeps whose joint passes are "
        "strain_limit.inextensible_pinch_iterations (their contacts pinch the cloth between two "
        "collider surfaces), false never (the default before stop 29). 'pinch' is a Nucleus "
        "default since stop 29 (other solvers get it only when set explicitly), with "
        "strain_limit's defaults of that stop (inextensible_max_strain): sleeve_elbow's crease "
        "with 40 joint passes 3.85 % without the rows, 1.18 % with them (frames 22-28, "
        "graphs/bench/sleeve_elbow_girth.py). Not true: in every substep the rows stiffened the "
        "24 x 24 cloth pinned at its corners that stops a 20 m/s shape-matched ball at one "
        "substep (tests/test_collisions.py) so much that the ball's centroid passed the cloth's "
        "centre vertex (18 mm at frame 3; 'pinch' and false never). Measured with true "
        "(graphs/bench/cloth_strain.py, worst frame of 24, CPU ms/frame beside 5 levels, 3 "
        "sweeps and the 5 % inextensible limit with 10 passes, in one run): with "
        "strain_limit.inextensible_joint_iterations 40 and inextensible_max_strain 0.02 "
        "cloth_on_sphere 7.5 -> 3.8 % (492 -> 759 ms), sleeve_elbow 20.7 -> 3.2 % (242 -> 318), "
        "skirt_walk 5.0 -> 2.0 % (54 -> 56); at 10 joint passes it helps the sleeve (20.7 -> "
        "12.6 %) and not the drop (7.5 -> 9.8 %).")


@dataclass
class _StretchData(Packed):
    """The packed edges plus the long-range rows (None when there are none), the sweeps and
    the compression compliances of the Nucleus projection (None: ``alpha2``)."""

    long_range: Packed | None = None
    sweeps: int = 1
    alpha2_nucleus: np.ndarray | None = None
    #: the compression compliances of this substep (alpha2_nucleus on edges near contacts)
    alpha2_substep: np.ndarray | None = None
    near: np.ndarray | None = None  # scratch: vertices in a contact row of the substep


class StretchConstraint(ConstraintBehavior):
    """Type 1 (edge length) on cloth edges, hair segments and tet edges, with separate stretch
    and compression compliance (and optional stretch damping); inextensible cloth adds the
    hierarchical long-range rows (``long_range_levels``) and sweeps its edges ``sweeps`` times
    per pass."""

    ParamsModel = StretchParams
    requires = (Dynamic,)
    requires_any = (DiscreteShell, Rod, Volume)
    default_importance = 1.0
    default_order = 30

    def bind(self, ctx, elements):
        # joint_long_range: a Nucleus default (since stop 29); other solvers get it only when
        # set explicitly
        self._joint_lr = self.params.joint_long_range if (
            getattr(ctx.scene.spec, "solver", "nucleus") == "nucleus"
            or "joint_long_range" in self.params.model_fields_set) else False
        parts = []
        lr_parts = []
        shell = False  # any inextensible cloth: the extra sweeps apply
        for e in elements:
            g = e.geometry
            off = e.vertex_offset
            if e.has(DiscreteShell) and len(g.triangles):
                c = e.get(DiscreteShell)
                X = _rest(ctx, e, c)
                topo = T.triangle_topology(g.triangles)
                edges = topo.edges
                shell |= c.youngs_modulus is None
                if c.youngs_modulus is None and self.params.long_range_levels > 0:
                    pr, bound = long_range_rows(X, edges, self.params.long_range_levels)
                    if len(pr):
                        lr_parts.append((pr + off, bound * c.rest_length_scale))
                L = np.linalg.norm(X[edges[:, 1]] - X[edges[:, 0]], axis=1)
                area = triangle_areas(X, g.triangles)
                Ae = np.bincount(topo.tri_edges.ravel(), np.repeat(area / 3.0, 3),
                                 minlength=len(edges))
                if c.youngs_modulus is None:
                    a = np.zeros(len(edges))
                else:
                    a = L * L / (c.youngs_modulus * c.thickness * np.maximum(Ae, 1e-300))
                ac = _compress(a, c.compression_ratio)
                acn = ac
                kc = self.params.inextensible_compression
                if c.youngs_modulus is None and kc is not None and c.compression_ratio > 0:
                    # an edge of zero-area triangles gets infinite compliance (no stiffness)
                    with np.errstate(over="ignore"):
                        acn = L * L / (kc * c.compression_ratio * np.maximum(Ae, 1e-300))
                beta = np.full(len(edges), c.stretch_damping)
                parts.append((edges + off, L * c.rest_length_scale, a, ac, beta, acn))
            elif e.has(Rod) and len(g.edges) and not solved_directly(e):
                c = e.get(Rod)
                X = _rest(ctx, e, c)
                edges = g.edges
                L = np.linalg.norm(X[edges[:, 1]] - X[edges[:, 0]], axis=1)
                a = (np.zeros(len(edges)) if c.youngs_modulus is None
                     else L / (c.youngs_modulus * np.pi * c.radius ** 2))
                ac = _compress(a, c.compression_ratio)
                parts.append((edges + off, L * c.rest_length_scale, a, ac, np.zeros(len(edges)),
                              ac))
            elif e.has(Volume) and len(g.tetrahedra):
                c = e.get(Volume)
                X = _rest(ctx, e, c)
                tt = T.orient_tets(X, g.tetrahedra)
                edges = T.tet_edges(tt)
                L = np.linalg.norm(X[edges[:, 1]] - X[edges[:, 0]], axis=1)
                vol = rest_tet_volumes(X, tt)
                # volume share of an edge: each tet spreads V/6 over its 6 edges
                key = {tuple(r): i for i, r in enumerate(edges)}  # build-time only
                loc = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])
                te = np.sort(tt[:, loc], axis=2).reshape(-1, 2)
                ids = np.array([key[tuple(r)] for r in te])
                Ve = np.bincount(ids, np.repeat(np.abs(vol) / 6.0, 6), minlength=len(edges))
                a = L * L / (c.youngs_modulus * np.maximum(Ve, 1e-300))
                parts.append((edges + off, L, a, a, np.zeros(len(edges)), a))
        cat = _concat(parts)
        if cat is None:
            return None
        idx, L, a, ac, beta, acn = cat
        d = _StretchData.build(idx, L, a, ac, beta=beta if beta.any() else None)
        d.sweeps = int(self.params.sweeps) if shell else 1
        if not np.array_equal(acn, ac):
            d.alpha2_nucleus = np.ascontiguousarray(acn[d.perm])  # in d's (coloured) order
            d.alpha2_substep = d.alpha2.copy()
            d.near = np.zeros(ctx.model.particle_count, bool)
        if lr_parts:
            pr = np.concatenate([q[0] for q in lr_parts])
            bound = np.concatenate([q[1] for q in lr_parts])
            # hard (alpha 0), stretch only (compression compliance inf: never pushes apart)
            # one thread, in colour order: measured faster than the coloured parallel sweep
            # at 32^2 to 128^2 on the shared 2-core machine (40 colours of a few hundred rows)
            d.long_range = Packed.build(pr, bound, np.zeros(len(bound)),
                                        np.full(len(bound), np.inf), sequential=True)
        return d

    @staticmethod
    def _project_long_range(ctx, lr, p):
        fn = project_stretch_seq if sequential_sweep(lr.sequential) else project_stretch
        fn(p, ctx.model.particle_inv_mass, lr.idx, lr.rest, lr.alpha, lr.alpha2, lr.lam,
           ctx.dt, lr.color_ptr)

    def begin_substep(self, ctx, d):
        """XPBD multipliers to zero; with ``inextensible_compression``, the compression
        compliances of the substep: compliant on edges with a vertex in a contact row."""
        super().begin_substep(ctx, d)
        if d is None or d.alpha2_nucleus is None:
            return
        c = ctx.state.fields.get("contacts")
        near = d.near
        near[:] = False
        if c is not None:
            near[c.vf.ravel()] = True
            near[c.ee.ravel()] = True
        e = near[d.idx[:, 0]] | near[d.idx[:, 1]]
        np.copyto(d.alpha2_substep, d.alpha2)
        np.copyto(d.alpha2_substep, d.alpha2_nucleus, where=e)

    def project(self, ctx, d, p):
        if d.long_range is not None:
            self._project_long_range(ctx, d.long_range, p)
        for _ in range(d.sweeps):
            _project_edges(ctx, d, p, d.alpha2_substep)

    def project_joint(self, ctx, d, p):
        """Called by the final collision rounds and the CCD rounds before the strain limits
        and the contacts of every joint pass (``joint_long_range``): the long-range rows only
        (unilateral, consistent with any strain limit >= 0); the edges stay out (hard and
        bilateral, they would fight the contacts)."""
        lr = getattr(self, "_joint_lr", False)
        if lr == "pinch":  # only while a strain limit runs its pinch passes
            lr = any(getattr(b, "pinched", False) for b, _ in ctx.constraints)
        if d is not None and d.long_range is not None and lr:
            self._project_long_range(ctx, d.long_range, p)

    def joint_iterations(self) -> int:
        return 0  # the strain limits and the collision parameters set the joint passes

    def satisfied(self, ctx, d, p) -> bool:
        return True  # the strain limits judge the edges

    def residual(self, ctx, d, p):
        return float(residual_stretch(p, d.idx, d.rest)[0])

    def describe(self, d):
        if d is None:
            return ""
        lr = d.long_range
        return (f"{len(d)} edges, {len(d.color_ptr) - 1} colours"
                + (f", {d.sweeps} sweeps" if d.sweeps > 1 else "")
                + (f", {len(lr)} long-range rows" if lr is not None else ""))


def _compress(a, ratio):
    """Compression compliance: stretch compliance / ratio; ratio 0 switches compression off."""
    return a / ratio if ratio > 0 else np.full_like(a, np.inf)


# ==============================================================================================
# Implicit energy (behaviors/solvers/implicit/energy.py has the protocol)
# ==============================================================================================
from ..solvers.implicit.energy import grad_or_dummy, hess_or_dummy, row_k  # noqa: E402


@njit(cache=True)
def spring_energy(x, idx, rest, alpha, alpha2, lam, hard_k, mode, grad, hess):
    """Spring energy of edge rows ``(a, b)`` with ``C = |x_a - x_b| - L``.

    A soft row: ``E = k C^2 / 2`` with ``k = 1 / alpha`` when stretched and ``1 / alpha2`` when
    compressed (inf: off). A hard row (``alpha = 0``: inextensible, welds) is an augmented
    Lagrangian term with the penalty ``k = hard_k`` (the larger of its two vertices) and the
    multiplier ``lam`` [N] carried over from the previous substeps (``spring_update_lam``):
    ``E = ((lam + k C)^2 - lam^2) / (2 k)``, bilateral when ``alpha2 = 0``, tension only
    (``lam + k C`` clamped at 0) when compression is off (``alpha2 = inf``), and soft in
    compression when ``0 < alpha2 < inf`` (``StretchParams.implicit_compression``): where
    ``lam + k C < 0``, i.e. below ``C0 = -lam / k``, the spring ``k2 (C - C0)^2 / 2`` with
    ``k2 = 1 / alpha2`` (C1 at C0; its multiplier is clamped at 0 like a tension-only row's).
    At rest the multiplier converges to the tension and C to 0, so a moderate,
    well-conditioned penalty still gives an inextensible edge.

    With the force ``f = lam + k C`` (tension > 0): gradient ``f n`` exact; Hessian
    ``k n n^T + max(0, f / l) (I - n n^T)``: exact under tension, the negative transverse part of
    a compressed row clamped to 0, so the 2x2 block set ``[[H, -H], [-H, H]]`` is PSD. A
    zero-rest row (stitch) is ``k |x_a - x_b|^2 / 2`` exactly. Returns E [J]; adds the gradient
    (mode >= 1), writes blocks (mode 2)."""
    E = 0.0
    for j in range(idx.shape[0]):
        a = idx[j, 0]
        b = idx[j, 1]
        dx = x[a, 0] - x[b, 0]
        dy = x[a, 1] - x[b, 1]
        dz = x[a, 2] - x[b, 2]
        ln = math.sqrt(dx * dx + dy * dy + dz * dz)
        L = rest[j]
        c = ln - L
        lj = 0.0
        if alpha[j] == 0.0:  # hard: augmented Lagrangian
            k = row_k(0.0, hard_k, a, b)
            if k == 0.0:
                continue
            lj = lam[j]
            f = lj + k * c
            if f < 0.0 and not alpha2[j] < _INF:  # compression off: tension only
                E -= 0.5 * lj * lj / k
                continue
            if f < 0.0 and alpha2[j] > 0.0:  # soft in compression (implicit_compression)
                k2 = 1.0 / alpha2[j]  # the spring 1 / alpha2 beyond c0 = -lam / k (C1 there)
                c0 = -lj / k
                E += 0.5 * k2 * (c - c0) * (c - c0) - 0.5 * lj * lj / k
                f = k2 * (c - c0)
                k = k2
            else:
                E += 0.5 * (f * f - lj * lj) / k
        else:
            k = row_k(alpha[j] if c >= 0.0 else alpha2[j], hard_k, a, b)
            if k == 0.0:
                continue
            f = k * c
            E += 0.5 * k * c * c
        if ln < _LEN_EPS:
            if L > 0.0:
                continue  # no direction: energy counted, no gradient
            t = k
            nx = ny = nz = 0.0
            s = k
        else:
            nx = dx / ln
            ny = dy / ln
            nz = dz / ln
            t = f / ln
            if t < 0.0:
                t = 0.0
            s = f / ln
        if mode >= 1:
            grad[a, 0] += s * dx
            grad[a, 1] += s * dy
            grad[a, 2] += s * dz
            grad[b, 0] -= s * dx
            grad[b, 1] -= s * dy
            grad[b, 2] -= s * dz
        if mode >= 2:
            n0 = (nx, ny, nz)
            for r in range(3):
                for q in range(3):
                    hv = (k - t) * n0[r] * n0[q] + (t if r == q else 0.0)
                    hess[j, 0, 0, r, q] = hv
                    hess[j, 1, 1, r, q] = hv
                    hess[j, 0, 1, r, q] = -hv
                    hess[j, 1, 0, r, q] = -hv
    return E


@njit(cache=True)
def spring_update_lam(x, idx, rest, alpha, alpha2, lam, hard_k):
    """After a substep: ``lam += k C`` on every hard row (clamped at 0 for tension-only rows),
    the augmented Lagrangian update of ``spring_energy``."""
    for j in range(idx.shape[0]):
        if alpha[j] != 0.0:
            continue
        a = idx[j, 0]
        b = idx[j, 1]
        k = row_k(0.0, hard_k, a, b)
        d = 0.0
        for r in range(3):
            t = x[a, r] - x[b, r]
            d += t * t
        lam[j] += k * (math.sqrt(d) - rest[j])
        if lam[j] < 0.0 and alpha2[j] > 0.0:  # tension only, or soft in compression
            lam[j] = 0.0


def edge_multipliers(self, d):
    """The hard rows' multipliers [N] of a Packed set of distance rows (zero for soft rows),
    kept on the data between substeps (the implicit solver checkpoints them)."""
    lam = getattr(d, "_implicit_lam", None)
    if lam is None:
        lam = d._implicit_lam = np.zeros(len(d.idx))
    return lam


def edge_state_arrays(self, d):
    """Checkpointed run state: the implicit solver's multipliers of the hard rows (zeros when
    the scene runs the Nucleus solver)."""
    return {"implicit_lam": edge_multipliers(self, d)} if d is not None else {}


def edge_load_state_arrays(self, d, arrays):
    if d is not None and "implicit_lam" in arrays:
        edge_multipliers(self, d)[:] = arrays["implicit_lam"]


def edge_energy_stencils(self, ctx, d):
    """Energy stencils of a Packed set of distance rows (stretch edges, stitches)."""
    return [d.idx]


def _energy_alpha2(self, d):
    """The compression compliances of the implicit energy: ``d.alpha2`` (hard rows bilateral,
    or tension only), or with ``implicit_compression: near_contacts`` this substep's Nucleus
    compliances (``alpha2_substep``: soft on edges with a vertex in a contact row)."""
    if (getattr(self.params, "implicit_compression", "hard") == "near_contacts"
            and getattr(d, "alpha2_substep", None) is not None):
        return d.alpha2_substep
    return d.alpha2


def edge_energy(self, ctx, d, x, grad, hess, opts):
    """Spring energy of a Packed set of distance rows (see ``spring_energy``). Stretch damping
    (``beta``) is not part of the energy (backward Euler damps by itself)."""
    return spring_energy(x, d.idx, d.rest, d.alpha, _energy_alpha2(self, d),
                         edge_multipliers(self, d), opts.hard_k, opts.mode,
                         grad_or_dummy(grad, opts), hess_or_dummy(hess, 0, opts))


def edge_update_multipliers(self, ctx, d, x, opts):
    spring_update_lam(x, d.idx, d.rest, d.alpha, _energy_alpha2(self, d),
                      edge_multipliers(self, d), opts.hard_k)


# the implicit energy protocol on the Nucleus constraint type of this effect
StretchConstraint.energy_stencils = edge_energy_stencils
StretchConstraint.energy = edge_energy
StretchConstraint.energy_update_multipliers = edge_update_multipliers
StretchConstraint.energy_multipliers = edge_multipliers
StretchConstraint.state_arrays = edge_state_arrays
StretchConstraint.load_state_arrays = edge_load_state_arrays
