"""Constitutive strain limiting (Loki supplement section 2, eq. 9-10).

Every edge obeys the inequality ``|x_i - x_j| <= (1 + eps_e) L0``. In ``constitutive`` mode it is
a unilateral constraint type with the same order and importance as the contacts, projected in the
same Gauss-Seidel passes and in the final collision rounds, so contacts and strain limits agree
at convergence. ``post`` mode (kept for comparison) runs the classic strain-limiting pass after
everything else, which can push cloth back into colliders.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numba import njit, prange
from pydantic import Field

from lokigraph.behavior import ConstraintBehavior, ConstraintParams
from lokigraph.component import resolve_paintable
from lokigraph.components.core import Dynamic
from lokigraph.components.materials import DiscreteShell, Rod

from .. import topology as T
from ..collision import contacts as _contacts
from ..collision.contacts import _slid_apart
from ..collision.narrowphase import row_coefficients


#: an edge whose squared length is below limit^2 (1 - 1e-12) is within its limit after the
#: square root's rounding too (``limit_edge`` skips it without the root: the same result)
_UNDER = 1.0 - 1e-12


@njit(cache=True)
def limit_edge(p, w, edges, limit, j):
    """Shorten edge j to its limit [m] if it is longer (hard, unilateral), mass-weighted.
    Edges clearly within their limit (squared length under ``_UNDER`` limit^2) return before
    the square root: bitwise the result of testing the root, 5.8x faster on the 128 x 128
    drop's smoothing sweeps, where about 5 % of the edges are over their limit."""
    a, b = edges[j, 0], edges[j, 1]
    dx = p[a, 0] - p[b, 0]
    dy = p[a, 1] - p[b, 1]
    dz = p[a, 2] - p[b, 2]
    d2 = dx * dx + dy * dy + dz * dz
    lim = limit[j]
    if d2 < lim * lim * _UNDER:
        return
    ws = w[a] + w[b]
    if ws <= 0.0:
        return
    ln = np.sqrt(d2)
    C = ln - lim
    if C <= 0.0 or ln < 1e-15:
        return
    s = C / (ws * ln)
    p[a, 0] -= w[a] * s * dx
    p[a, 1] -= w[a] * s * dy
    p[a, 2] -= w[a] * s * dz
    p[b, 0] += w[b] * s * dx
    p[b, 1] += w[b] * s * dy
    p[b, 2] += w[b] * s * dz


@njit(cache=True, parallel=True)
def project_strain_limit(p, w, edges, limit, color_ptr):
    """Shorten every edge longer than its limit [m] (hard, unilateral; ``limit_edge``, the
    edges of a colour in parallel). Returns nothing."""
    for c in range(color_ptr.shape[0] - 1):
        for j in prange(color_ptr[c], color_ptr[c + 1]):
            limit_edge(p, w, edges, limit, j)


@njit(cache=True)
def strain_excess(p, edges, limit):
    """Largest |x_i - x_j| / limit - 1 over the edges (<= 0 when every limit holds)."""
    worst = -np.inf
    for j in range(edges.shape[0]):
        a, b = edges[j, 0], edges[j, 1]
        d = np.sqrt((p[a, 0] - p[b, 0]) ** 2 + (p[a, 1] - p[b, 1]) ** 2
                    + (p[a, 2] - p[b, 2]) ** 2)
        worst = max(worst, d / limit[j] - 1.0)
    return worst


#: cosine of the angle between two collider contacts' outward normals at a vertex over which the
#: vertex counts as pinched (between two collider surfaces): 0.5 = more than 120 degrees apart
PINCH_COS = -0.5


@njit(cache=True, inline="always")
def row_geometry(p, rows, nrm, onesided, is_vf, r):
    """Contact row r (vertex-face when ``is_vf``, else edge-edge) at ``p`` as ``project_vf`` /
    ``project_ee`` evaluate it: the 4 vertices' coefficients of the closest points' separation,
    the normal (the stored one; on its side, and unless one-sided, the current closest-point
    direction), the separation along it and the closest points' squared distance. Returns
    (c0, c1, c2, c3, n0, n1, n2, gap, d2)."""
    i0, i1, i2, i3 = rows[r, 0], rows[r, 1], rows[r, 2], rows[r, 3]
    n0, n1, n2 = nrm[r, 0], nrm[r, 1], nrm[r, 2]
    d2, c0, c1, c2, c3 = row_coefficients(p, rows, is_vf, r)
    dv0 = c0 * p[i0, 0] + c1 * p[i1, 0] + c2 * p[i2, 0] + c3 * p[i3, 0]
    dv1 = c0 * p[i0, 1] + c1 * p[i1, 1] + c2 * p[i2, 1] + c3 * p[i3, 1]
    dv2 = c0 * p[i0, 2] + c1 * p[i1, 2] + c2 * p[i2, 2] + c3 * p[i3, 2]
    if not (is_vf and onesided[r]):
        dist = np.sqrt(d2)
        if dist > 1e-12 and dv0 * n0 + dv1 * n1 + dv2 * n2 > 0.0:
            n0, n1, n2 = dv0 / dist, dv1 / dist, dv2 / dist
    return c0, c1, c2, c3, n0, n1, n2, dv0 * n0 + dv1 * n1 + dv2 * n2, d2


@njit(cache=True, inline="always")
def row_slid_apart(w, rows, target, onesided, is_vf, r, d2, gap, mode):
    """``contacts.SLIDE_APART`` for contact row r as ``row_geometry`` evaluated it (its
    separation ``gap`` along the normal, its closest points' squared distance ``d2``): a
    two-sided row against a collider on the far side of its start normal whose closest points
    lie at least its target apart across that normal, inactive as ``project_vf`` /
    ``project_ee`` take it with ``slide`` (``mode``: ``contacts.slide_mode(False)``)."""
    if gap > 0.0 or mode == 0 or (is_vf and onesided[r]):
        return False
    i0, i1, i2, i3 = rows[r, 0], rows[r, 1], rows[r, 2], rows[r, 3]
    if is_vf:
        return _slid_apart(d2, gap, target[r], w[i0], w[i1] + w[i2] + w[i3], mode)
    return _slid_apart(d2, gap, target[r], w[i0] + w[i1], w[i2] + w[i3], mode)


@njit(cache=True)
def count_pinched(p, w, cloth, rows, nrm, target, onesided, is_vf, first, seen, slide=0):
    """Vertices (w > 0, ``cloth``) of collider contact rows (rows with a vertex not of the
    cloth: kinematic, w = 0, or of another element, the compliant skin of an arm) within
    twice the row's target distance at ``p``, whose outward normals (from the collider to the
    vertex: the row's normal, oriented along the closest points' direction as ``project_vf`` /
    ``project_ee`` do, times the sign of the vertex's coefficient, those over 0.05 as in
    strain_limit_global.contact_normals) make more than the angle of ``PINCH_COS`` with the
    first such normal met at that vertex: cloth held between two collider surfaces facing each
    other (a crease). ``first`` (n, 3) and ``seen`` (n,) are scratch (``seen`` cleared by the
    caller). ``slide``: rows slid apart along a collider are not contacts
    (``row_slid_apart``, ``contacts.SLIDE_APART``). Returns the count of pinched vertices
    (each counted once)."""
    k = 0
    for r in range(rows.shape[0]):
        i0, i1, i2, i3 = rows[r, 0], rows[r, 1], rows[r, 2], rows[r, 3]
        if cloth[i0] and cloth[i1] and cloth[i2] and cloth[i3]:
            continue
        c0, c1, c2, c3, n0, n1, n2, gap, d2 = row_geometry(p, rows, nrm, onesided, is_vf, r)
        if gap >= 2.0 * target[r] or (slide and row_slid_apart(
                w, rows, target, onesided, is_vf, r, d2, gap, slide)):
            continue
        for q in range(4):
            v = rows[r, q]
            cf = (c0, c1, c2, c3)[q]
            if w[v] <= 0.0 or not cloth[v] or abs(cf) <= 0.05:
                continue
            sg = 1.0 if cf > 0.0 else -1.0
            if seen[v] == 0:
                first[v, 0], first[v, 1], first[v, 2] = sg * n0, sg * n1, sg * n2
                seen[v] = 1
            elif seen[v] == 1 and sg * (first[v, 0] * n0 + first[v, 1] * n1
                                        + first[v, 2] * n2) < PINCH_COS:
                seen[v] = 2
                k += 1
    return k

class StrainLimitParams(ConstraintParams):
    mode: Literal["constitutive", "post"] = Field(
        "constitutive", description="'constitutive': solved together with the contacts; "
        "'post': a strain-limiting pass after the solve (for comparison).")
    post_iterations: int = Field(10, ge=1, le=10000, description="Passes of the post mode.")
    implicit: Literal["energy", "projection"] = Field(
        "energy", description="With solver: implicit (constitutive mode): 'energy' makes each "
        "limited edge a one-sided augmented-Lagrangian row of the Newton solve itself (force "
        "max(0, lam + k C), k the hard penalty hard_stiffness m / h^2, lam carried between "
        "substeps), so the limit pushes back on the elastic and contact terms of the same "
        "solve, with the projection pass after it kept as a safety projection; 'projection' "
        "applies the limit in that pass alone (before). Measured on tests/"
        "test_implicit_strain_limit.py's scene (a soft 20 x 20 cloth, E t = 0.3 N/m, "
        "max_strain 0.1, pinned at two sides and pushed up by a ball; 36 frames, "
        "NUMBA_NUM_THREADS=1): at 1 substep 'energy' 10.28 % worst edge strain (frames 9-36 "
        "10.09 %) at 4.9 s CPU, 'projection' 36.48 % (22.18 %) at 2.7 s; at 4 substeps "
        "10.11 % at 23.6 s against 15.58 % at 43.2 s; 0 intersecting pairs with the ball in "
        "every frame either way (the post mode: up to 146). The stress case 'Young's modulus "
        "1e9 Pa' at full size passes with both; the 64 x 64 drop with a painted 1 % limit at 1 "
        "substep (12 frames) 2.52 % against 2.56 % (its hard stretch rows hold it; 3.22 "
        "against 2.99 s CPU a contact frame). Ignored by the Nucleus solver.")
    joint_iterations: int = Field(40, ge=1, le=10000, description="Most joint contact + "
                                  "strain-limit passes in the final collision rounds (stops "
                                  "when both hold) when some element paints max_strain.")
    inextensible_joint_iterations: int = Field(
        10, ge=1, le=10000, description="Most joint passes when only the inextensible limit "
        "(inextensible_max_strain) is present: resting contacts keep every pass active, so "
        "each costs a full contact and strain-limit sweep. Measured against 40 "
        "(graphs/bench/cloth_strain.py, 24 frames): cloth_on_sphere 7.5 % instead of 6.6 % "
        "at -18 % CPU per frame, sleeve_elbow 20.7 % instead of 10.1 % at -16 %. 3 in setting B "
        "of global_chord (with the global step, which holds what the joint passes leave). 10 "
        "with the defaults of stop 29 (inextensible_max_strain): with 3 the sleeve around "
        "sleeve_elbow's crease moved at 0.826 m/s at 14 solver iterations as the elbow "
        "straightens (tests/test_elbow.py's bound 0.73 m/s), with 10 0.707 m/s (both with "
        "stretch.joint_long_range true; 0.671 m/s with 10 and 'pinch', the defaults).")
    inextensible_pinch_iterations: int | None = Field(
        40, ge=1, le=10000, description="Most joint passes (instead of "
        "inextensible_joint_iterations) in a substep whose contacts pinch inextensible cloth "
        "between two collider surfaces facing each other (a vertex with collider contacts "
        "whose outward normals are more than 120 degrees apart, count_pinched: a sleeve in a "
        "bending elbow's crease); null = inextensible_joint_iterations in every substep (the "
        "step before, bitwise). Without a pinch the joint passes pay for little (the global "
        "step holds the rest) and every one costs a full contact sweep. A default since stop "
        "29 (inextensible_max_strain): sleeve_elbow's crease needs 40 (setting B's 3: 18.6 % "
        "in the closing crease, graphs/bench/sleeve_elbow_girth.py), and 40 in every substep "
        "cost 1.99x the defaults' CPU on cloth_on_sphere (B + 40, stop 28), where nothing is "
        "pinched. The compliant skin of an arm counts as a collider (a row with a vertex "
        "outside the cloth's edges): its vertices are dynamic.")
    tolerance: float = Field(1e-3, ge=0, description="Accepted relative excess over the limit.")
    inextensible_max_strain: float | None = Field(
        0.01, ge=0, le=10.0, description="Strain limit eps_e [-] given to every inextensible "
        "DiscreteShell (youngs_modulus null) that sets no max_strain, solved with the contacts "
        "like a painted one; null = none (the default before issue #13). Default 0.01 since "
        "stop 29, with the global strain step once a frame (setting B of global_chord: "
        "global_passes 20, global_near 0.005, global_contacts 'rows', global_pivots 2, "
        "global_tolerance 0.005, global_every 'frame', global_smooth 40, global_alpha 1e-4, "
        "global_fast_lu, global_chord 3 at global_chord_rate 0.8), 10 joint passes, 40 in "
        "substeps whose contacts pinch the cloth (inextensible_pinch_iterations) and in those "
        "the long-range rows in the joint passes (stretch.joint_long_range 'pinch'): worst "
        "edge strain in "
        "every frame under issue #13's 2 % (graphs/bench/cloth_strain.py 'old_defaults' -> "
        "'defaults', NUMBA_NUM_THREADS=1, worst frame; CPU per frame over the second half, "
        "interleaved ABBA, 24 frames): cloth_on_sphere 6.63 -> 1.50 % at 341 -> 506 ms "
        "(1.49x), skirt_walk 5.00 -> 1.10 % at 44 -> 45 ms, sleeve_elbow 13.16 -> 1.50 % at "
        "219 -> 312 ms (1.42x; all 60 frames: 13.16 -> 1.50 %, median CPU 197 -> 260 ms, "
        "1.32x). The slow elbow tests hold (tests/test_elbow.py, sleeve speed within 0.15 m "
        "of the joint, bound 0.73 m/s, 1 thread: 0.638 m/s, 0.671 at 14 solver "
        "iterations, where inextensible_joint_iterations 3 gave 0.826; 0 sleeve-arm pairs). "
        "Default 0.05 (stops 24-28; "
        "graphs/bench/cloth_strain.py 'old_defaults') with 10 "
        "joint passes and stretch long_range_levels 5, sweeps 3, inextensible_compression 10 "
        "(worst-frame edge strain over 24 frames, graphs/bench/cloth_strain.py 'before' -> "
        "'defaults'): cloth_on_sphere 183.6 -> 6.6 %, sleeve_elbow 94.8 -> 23.9 %, skirt_walk "
        "8.0 -> 5.0 %, flag_wind 17.1 -> 5.0 %, the 128 x 128 drop 914 -> 15.9 %, at about the "
        "CPU per frame of the drop before; the full-size "
        "stress projectile keeps 0 penetrations with them (it crossed from frame 6 on before "
        "the side memory of the contacts took only a nearest triangle the vertex projects "
        "onto). With hard compression of the edges (stretch.inextensible_compression null) the "
        "sleeve caught in the crease of the slow elbow test moves faster than the forearm. "
        "The quick stress case of a cloth starting interpenetrated ends with 308 crossing "
        "pairs after 307 at its first frame (309 -> 309 before): one more cloth-ball pair on "
        "the circle where the sheet cuts the ball, whose count follows the triangle sizes "
        "along it; its tangle measures (self-intersecting pairs, cloth vertices inside the "
        "ball) do not grow. A Nucleus default: the implicit solver, which projects strain "
        "limits after its solve (not in it), gets it only when set explicitly (at 0.05 the "
        "implicit sleeve_pinch example moved at 0.347 m/s against its 0.3 m/s calm bound, "
        "tests/test_implicit_pinch.py). A tighter limit is no cure where the limit is not "
        "met (measured in one run, 24 frames; 0.05 / 0.03 / 0.02 / 0.015 / 0.01): the limit-"
        "bound skirt_walk follows it (5.00 / 3.08 / 2.00 / 1.54 / 1.15 %), but the drops get "
        "worse (cloth_on_sphere 6.6 / 8.6 / 9.7 / 10.2 / 10.8 %; the 128 x 128 drop, 23 frames, "
        "15.9 / 17.8 / 19.2 / -- / 20.4 %), and so do flag_wind (5.0 / 6.5 / 5.1 / 6.0 / 6.3 %: "
        "without contacts the limit gets no joint passes, only the iterations) and sleeve_elbow "
        "(23.9 / 24.3 / 29.7 / 26.1 / 26.5 %), at the same CPU per frame. On the drops the "
        "residue is the limit's own Gauss-Seidel: on the 64 x 64 drop's worst substep (frame 10, "
        "6.6 % after the final rounds) 100 sweeps of the limit alone, contacts left out, still "
        "leave 5.4 % (a saturated region whose excess must travel to the border), 100 joint "
        "passes with the contacts 5.8 % (5.7 % without friction); the CCD step changes nothing "
        "(graphs/bench/cloth_strain.py --stages).")
    global_passes: int = Field(
        20, ge=0, le=100, description="Most Newton passes of the global strain-limit step "
        "(Goldenthal et al. 2007 fast projection, strain_limit_global.py) after the final "
        "collision rounds and before the CCD safe step (constitutive mode, DiscreteShell edges "
        "only; hair is never touched): the edges over their limit solved as one sparse system "
        "(J W J^T + alpha diag) dlam = C, x -= W J^T dlam, with the vertices in contact with "
        "a collider moving only in the contact's tangent plane (global_contacts), until every "
        "edge holds within the tolerance. 0 = off (the Gauss-Seidel limit alone, bitwise). "
        "20 in setting B of global_chord, a Nucleus default since stop 29 (0 before; "
        "inextensible_max_strain has the figures; other solvers get the step only when "
        "global_passes is set explicitly); the measurements below are "
        "of the plain step (global_contacts 'filter', no pivots, no sweeps) in every substep. "
        "Measured at 20 (graphs/bench/cloth_strain.py, 12 frames, worst frame; CPU per frame "
        "over the second half, in contact, 1 thread, one interleaved run): cloth_on_sphere at "
        "0.05 6.64 -> 5.13 % at 779 -> 778 ms; at 0.02 9.69 -> 2.91 % at 731 -> 1507 ms; at "
        "0.01 10.80 -> 2.26 % at 803 -> 1808 ms; the 128 x 128 drop at 0.05 15.9 -> 9.1 % "
        "(last frame 13.8 -> 5.6 %) at 5.0 -> 7.0 s; sleeve_elbow (24 frames) 23.9 -> 9.6 % at "
        "311 -> 378 ms; skirt_walk, flag_wind and cloth_pinned, which hold their limit, the "
        "same figures. No intersecting pairs on the drops, no cloth vertex inside the sphere "
        "(sleeve_elbow: 227 intersecting pairs in its worst frame against 244 without).")
    global_near: float = Field(
        0.005, ge=0, le=1.0, description="Edges within this fraction under their limit join the "
        "global step's active set too (held at their length) [-]. 1e-3 against 0 on "
        "cloth_on_sphere at 0.01: 3.1 against 2.3 % (more redundant rows, the plain step). With "
        "global_pivots (the pivots' candidate rows) 0.005 against 0.02: 5-7 % less CPU per "
        "frame on cloth_on_sphere at the same worst strain (setting B, global_chord). "
        "Setting B's value, a default since stop 29 (0 before; "
        "inextensible_max_strain).")
    global_contacts: Literal["filter", "rows", "none"] = Field(
        "rows", description="Contacts in the global step. 'filter': a vertex of a contact "
        "with a collider (a row with a kinematic vertex) within twice its target distance "
        "moves only in the tangent plane of its most closed contact (W -> w (I - n n^T)); "
        "the system is factorised once and reused while it converges (chord Newton). 'rows': "
        "the violated contacts (vertex-face, edge-edge, self included) are rows of the system "
        "(inequality: pulling rows dropped), factorised every pass: on a 40 x 40 drape at "
        "0.01 (9 frames) 1.06 % against the filter's 1.07 % at twice the step's CPU (both "
        "factorised every pass); with global_pivots > 0 instead one one-sided row per vertex "
        "within twice its target distance of a collider, along its most closed contact's "
        "outward normal (self contacts left to the CCD safe step), solved with the edges as "
        "one complementarity problem. 'none': edges only, the contacts left to the CCD safe step, "
        "whose contact rounds then stretch the cloth again (32 x 32 drape: 2.6 % against "
        "1.1 %). 'rows' with global_pivots 2 in setting B (global_chord): the filter stalls "
        "over a ball (global_pivots). With global_smooth the filter's sweeps are followed by its "
        "vertices' contact planes (as 'rows' has them): without them the sweeps pushed the "
        "32 x 32 drape into the ball (1.3 against 4.1 mm from its inradius) and the safe "
        "step's push-out stretched it to 2.93 % (tests/test_strain_limit_global.py: 1.10 % "
        "with them at global_tolerance 1e-3, 1.50 % at 0.005). "
        "Setting B's value, a default since stop 29 ('filter' before; "
        "inextensible_max_strain).")
    global_pivots: int = Field(
        2, ge=0, le=100, description="> 0: each factorised pass of the global step solves the "
        "edge limits (and with global_contacts 'rows' the contacts) as the inequalities they "
        "are, a linear complementarity problem (multipliers >= 0, no row left over its limit, "
        "complementary) over the candidate rows (edges over (1 - global_near) limit; with "
        "'rows' one row per vertex in contact with a collider, along its most closed "
        "contact's outward normal: the cloth may leave the collider, not enter it), by block "
        "principal pivoting (Judice & Pires 1994) with up to this many re-factorised "
        "solves; 0 = the equality solve of the edges over their limit (the step before). "
        "Why the equality step stalls (measured on the 64 x 64 drop's frame-10 substep at a "
        "0.01 limit, 20 passes; tests/test_strain_limit_global.py): the filter holds every "
        "contacting vertex in its tangent plane, in both directions, and a cloth stretched "
        "over the sphere cannot shorten that way: a penalty primal solve of the linearised "
        "problem with the filter keeps 1.22 / 1.16 % excess at a penalty of 1e4 / 1e6 (the "
        "step's start state); where the filter stalls, 0.000 % with no contact constraint "
        "(but 3.2 mm into the sphere) and 0.11 % with the contacts one-sided. At that substep (excess 5.37 % at the step's start) the filter leaves 1.41 %, "
        "the filter with pivoting (global_near 0.02, 5) 1.15 %, 'rows' with pivoting "
        "(global_near 0.02, 10) 0.07 % (16 passes); 'rows' without pivoting 0.66 %. Worst "
        "frame over 24 frames (graphs/bench/cloth_strain.py, one interleaved run, CPU per "
        "frame, 2 cores shared): cloth_on_sphere at the defaults 6.64 % (629 ms), global "
        "step 'filter' at 0.01 2.62 % (1444 ms), 'rows' + pivots (global_passes 20, "
        "global_near 0.02, global_pivots 10) at 0.01 1.10 % (3813 ms, 6.1x the defaults) and "
        "at 0.015 1.60 % (2638 ms, 4.2x); skirt_walk 5.00 % (88 ms) / 1.08 % / 1.08 % / "
        "1.54 % (89-91 ms: the Gauss-Seidel limit holds there, the step has nothing to "
        "do). The 128 x 128 drop (graphs/bench/cloth_sphere_128.yaml, 12 frames, warm-started "
        "pivoting) at 0.01: 15.90 % (defaults, frame 9, last 13.76 %, 6.6 s CPU per frame in "
        "contact) -> 8.20 % (frame 8, last 2.43 %, 72.6 s, 11x): there 20 passes do not "
        "converge in the first contact frames. sleeve_elbow (24 frames) at 0.01: 23.91 -> "
        "15.41 % at 354 -> 648 ms (the arm forces ring 9 over 2 %, tests/test_cloth_strain.py). "
        "Fewer pivots, one run, cloth_on_sphere at 0.015: 10 -> 3 the same 1.60 % at 2425 -> "
        "1999 ms. Not a default then: the CPU (2 in setting B of global_chord). "
        "Setting B's value, a default since stop 29 (0 before; "
        "inextensible_max_strain).")
    global_update: int = Field(
        16, ge=0, le=10000, description="With global_pivots: a pivot that swaps at most this "
        "many rows in or out of the last factorised active set solves with that set's factor "
        "and a dense Schur complement over the swapped rows instead of factorising again (the "
        "same solve up to round-off); 0 = factorise every pivot. Measured (cloth_on_sphere, 0.01, "
        "global_passes 20, global_near 0.02, 'rows', global_pivots 10, 10 frames, one process "
        "per pair, CPU of the step per frame): 0 -> 16: 1209 -> 925 ms (213 of 647 pivots "
        "updated), the same 1.09 % worst and 0 penetrations; 8: 986 ms; 40: 3133 ms (the dense "
        "solves over the swapped rows cost more than a factorisation). 24 frames, one interleaved "
        "run (graphs/bench/cloth_strain.py, CPU per frame over the second half): defaults "
        "6.64 % (560 ms); 0: 1.10 % (2762 ms, 4.9x); 16: 1.10 % (2423 ms, 4.3x), 0 "
        "penetrations both. With the pivots' symmetric ordering (SuperLU MMD_AT_PLUS_A, "
        "strain_limit_global.py) too, one interleaved run, 24 frames: defaults 6.64 % "
        "(658 ms); global_update 0 with COLAMD (the step before) 1.10 % (3417 ms, 5.2x); "
        "global_update 16 with the symmetric ordering 1.10 % (2457 ms, 3.7x), 0 penetrations.")
    global_tolerance: float | None = Field(
        0.005, ge=0, le=10.0, description="Accepted relative excess over the limit in the "
        "global step (its stopping test and the pivots' gap); null = tolerance (1e-3). Where "
        "an element paints max_strain the step uses tolerance instead unless this is set "
        "explicitly: a painted limit is held to the tolerance it states (the full-size stress "
        "case 'Young's modulus 1e9 Pa', max_strain 0.05: 5.50 % at the end with 0.005, 5.07 % "
        "with 1e-3, its bound 5.2 %; 12.1 -> 12.8 s CPU for 48 frames, NUMBA_NUM_THREADS=1). 0.005 "
        "in setting B of global_chord (the 1 % limit held to 1.5 %, under issue #13's 2 %). The "
        "step converges linearly (about 0.8 of the excess left per pass on the 64 x 64 "
        "drop's impact substeps: the edges rotate over a pass, and a smaller global_alpha "
        "diverges), so a looser stop saves passes. Measured with inextensible_max_strain "
        "0.01, global_passes 20, global_near 0.02, 'rows' (graphs/bench/cloth_strain.py, "
        "24 frames, one interleaved run, NUMBA_NUM_THREADS=1, CPU per frame over the second "
        "half): cloth_on_sphere at the defaults 6.63 % (484 ms); global_pivots 10 at 1e-3 "
        "1.10 % (2286 ms, 4.7x); global_pivots 2 at 0.005 1.50 % (1392 ms, 2.9x); "
        "skirt_walk 5.00 / 1.08 / 1.15 % (65 ms each: the Gauss-Seidel limit holds there); "
        "the 128 x 128 drop (12 frames) 15.93 % (4787 ms) / -- / 9.37 % (last frame 2.37 %, "
        "21490 ms, 4.5x; global_pivots 10 at 1e-3 was 8.20 % at 11x in another run). No "
        "penetrations. Tried and left out (they did not pay): chord passes re-solving the "
        "last factorised active set with its factor (1507 against 1392 ms), a warm start "
        "from the last substep's active set (within the noise), the step at 0.01 over a "
        "Gauss-Seidel limit kept at 0.05 (1453 against 1445 ms), Nucleus iterations 8 "
        "instead of 15 with the step (14 frames: 2581 against 2165 ms, the step has more "
        "to do). "
        "Setting B's value, a default since stop 29 (null, the tolerance 1e-3 before; "
        "inextensible_max_strain).")
    global_every: Literal["substep", "frame"] = Field(
        "frame", description="When the global step runs: every substep, or only in the "
        "last substep of each frame (the frames' positions hold the limit, the substeps "
        "between them only the Gauss-Seidel limit). One interleaved run (as for "
        "global_tolerance; inextensible_max_strain 0.01, global_passes 20, global_near 0.02, "
        "'rows', global_pivots 2, global_tolerance 0.005): cloth_on_sphere 'substep' 1.50 % "
        "(1387 ms, 2.9x the defaults' 483 ms), 'frame' 1.84 % (1061 ms, 2.2x), 'frame' with "
        "inextensible_joint_iterations 3 1.50 % (1084 ms, 2.2x); skirt_walk 1.15 / 1.15 / "
        "1.41 % (52-54 ms, the defaults 5.00 % at 52 ms); the 128 x 128 drop (12 frames, "
        "'frame' with 3 joint iterations) 11.71 % (last frame 5.81 %) at 13046 ms (2.7x the "
        "defaults' 4787 ms). No penetrations. Cheaper still did not hold (another run, "
        "'frame' with 3 joint iterations: 1.50 % at 1060 ms, defaults 467 ms): "
        "global_passes 10 3.91 % (1081 ms), global_pivots 1 4.07 % (1108 ms). "
        "Setting B's value, a default since stop 29 ('substep' before; "
        "inextensible_max_strain).")
    global_smooth: int = Field(
        40, ge=0, le=1000, description="Gauss-Seidel sweeps of the edge limits after each "
        "pass of the global step (with global_contacts 'rows' and global_pivots each sweep "
        "followed by the pass's contact planes: a vertex behind its plane goes back onto it), "
        "before its guard measures the worst edge; 0 = off (the step before, bitwise). Why "
        "the step converges linearly without them (cloth_on_sphere at inextensible_max_strain "
        "0.01, frame 9's step, strain_limit_global.py's doc): each pass is a Gauss-Newton "
        "step re-linearised at the current positions, but the cloth must move by about an "
        "edge length (up to 19 mm against 15.6 mm edges); the whole linear step takes the "
        "worst edge from 8.8 % to 57 % (edges it rotates stretch at second order), so the "
        "guard halves it to 0.06-0.25 of itself in most passes. Over frames 7-12's steps "
        "(88 passes) a line search on the worst edge (91) or on the summed squared excess "
        "(92), a second-order correction through the same factor (90) and global_alpha "
        "falling from 0.1 to 1e-3 over the passes (94-97) did not help; over frames 9, 10, 13 "
        "and 14 (62 passes) the complementarity problem solved to the end (30 pivots) took 49 "
        "passes at 1.5x the CPU. The sweeps take that stretch out, the guard takes whole steps, "
        "and global_alpha 1e-4 holds (without the sweeps it diverges). Frames 9, 10, 13 and "
        "14's steps replayed: 62 passes (186 solves) -> 23 (69) with 40 sweeps and "
        "global_alpha 1e-4 (36 with 40 sweeps at 1e-3, 31 with 100 at 1e-4). One interleaved "
        "run (graphs/bench/cloth_strain.py, 24 frames, NUMBA_NUM_THREADS=1, CPU per frame over "
        "the second half; the setting A = inextensible_max_strain 0.01, global_passes 20, "
        "global_near 0.02, 'rows', global_pivots 2, global_tolerance 0.005, global_every "
        "frame, inextensible_joint_iterations 3): cloth_on_sphere defaults 6.63 % (469 ms), "
        "A 1.50 % (1027 ms, 2.19x), A + global_smooth 40 + global_alpha 1e-4 1.50 % (715 ms, "
        "1.52x), 0 penetrations; skirt_walk 5.00 / 1.41 / 1.41 % (54-56 ms: the step has "
        "nothing to do there); sleeve_elbow 23.91 % (293 ms) / 33.11 % (966 ms) / 37.86 % "
        "(326 ms): the arm forces its rings over the limit and neither holds it; the 128 x 128 "
        "drop (graphs/bench/cloth_sphere_128.yaml, 12 frames) 15.93 % (5474 ms) / 11.71 % "
        "(last frame 5.81 %, 14301 ms: 20 passes do not converge there) / 1.66 % (last "
        "frame 1.45 %, 12243 ms, 2.24x), 0 penetrations. Passes per frame on cloth_on_sphere "
        "(--passes, frames 7-14): 112 -> 46 in all, 10-19 -> 4-7 a frame, about 0.55 of the "
        "excess left per pass instead of 0.8. A without "
        "the step costs 472 ms on cloth_on_sphere (11.40 %, another run), so the sweeps halve "
        "the step's own cost (613 -> 298 ms in that run). Not a default: 1.5x the defaults' "
        "CPU, the target was 1.3x (with global_fast_lu and global_chord: setting B). With "
        "'filter' the sweeps are followed by the filter's contact planes (global_contacts). "
        "Setting B's value, a default since stop 29 (0 before; "
        "inextensible_max_strain). More sweeps on the moving sphere "
        "(graphs/bench/moving_strain.py 128 24, stop 34, one setting a run, load ~3): "
        "there the step stops at its 20 passes in most contact frames, its Newton steps "
        "(40-690 mm) cut to 3.95 mm and the worst edge going up and down from pass to pass "
        "(17-40 % in frame 7). Frames 6-22: 40 sweeps 137.6 s CPU, worst 50.7 %, 1,654 edges "
        "over 5 % a frame (mean); 100: 146.0 s, 61.1 %, 634; 200: 164.5 s, 32.5 %, 224. "
        "global_alpha 1e-3 or 1e-2, global_pivots 8, global_chord 0, a per-pass cap twice or "
        "four times as large, contact rows from three times as far, and keeping the best "
        "pass changed frame 7 (29.3 %) to 17-37 % at 20 passes. Not a default: the worst "
        "frame is no better at 100 and 200 costs 1.2x.")
    global_chord: int = Field(
        3, ge=0, le=100, description="With global_contacts 'rows' and global_pivots: up to "
        "this many passes after a factorised one re-solve its active set (edges and contact "
        "rows) with its factor, J and the right-hand side at the current positions (chord "
        "Newton; rows gone under their limit held, not pulled back; a contact row's C from "
        "the factorised pass's contact plane), while each pass leaves at most "
        "global_chord_rate of the worst excess before it; 0 = every pass factorised (the step "
        "before, bitwise). A chord pass leaves about 0.85 of the excess against 0.55 for a "
        "factorised one, at a fifth of its cost. Measured on cloth_on_sphere with A + S "
        "(global_smooth's setting) and global_fast_lu, frames 8-14 (graphs/bench/"
        "cloth_strain.py --passes, one interleaved run): the step 224 -> 173 ms a frame at 3 "
        "and rate 0.8 (67 passes against 44; worst 1.48 against 1.49 %); rate 0.5 seldom "
        "takes one. With global_near 0.005 too (B = A + S + global_fast_lu + global_chord 3 + "
        "global_chord_rate 0.8 + global_near 0.005), 24 frames, NUMBA_NUM_THREADS=1, CPU per "
        "frame over the second half: cloth_on_sphere defaults 429 ms (6.63 %), A + S 643 ms "
        "(1.50x, 1.50 %), B 552 ms (1.29x, 1.50 %); another run with the defaults and B "
        "twice each: 400 / 406 ms, A + S 619 ms (1.54x), B 542 / 567 ms (1.38x); skirt_walk "
        "1.41 % at the defaults' CPU; sleeve_elbow 33.5 % (defaults 23.9 %, A + S 37.9 %) at "
        "325 ms (defaults 295 ms): cloth_strain.py --where. Not a default. With B as the "
        "defaults (stop 28) the default suite passes (test_bench's pruned and unpruned graphs "
        "differed because graphs/bench/minimal_cloth.yaml had no strain limit and the 1 % "
        "limit acts on the pinned drape's corner edges, 1.1 % without it: the graph has one "
        "now; the filter drape went to 2.9 % for want of contact planes in its sweeps, "
        "global_contacts; four tests pinned the old defaults) but the slow set does not: "
        "tests/test_elbow.py's sleeve_elbow with mechanisms and with compression near "
        "contacts fail: the speed around the crease 0.813 and 0.883 m/s against the 0.73 m/s "
        "bound (0.587 / 0.682 at the defaults), and without the mechanisms the sleeve stays "
        "through the arm from frame 16 to the end (28-277 pairs; the test wants 0 in the last "
        "12 frames). One interleaved ABBA run (cloth_strain.py --only defaults B --abba, "
        "NUMBA_NUM_THREADS=1, CPU per frame over the second half): cloth_on_sphere 6.63 -> "
        "1.50 % at 1.34x, skirt_walk 5.00 -> 1.41 % at 1.01x, sleeve_elbow 23.91 -> 33.47 % at "
        "1.09x, cloth_sphere_64 (12 frames) 6.63 -> 1.50 % at 1.25x. "
        "Setting B's value, a default since stop 29 (0 before; "
        "inextensible_max_strain).")
    global_chord_rate: float = Field(
        0.8, ge=0, le=1.0, description="A chord pass (global_chord) is taken only when the "
        "pass before it left at most this fraction of the worst excess [-]; otherwise the "
        "pass is factorised. 0.8 in setting B (global_chord; 0.5 seldom takes one). "
        "Setting B's value, a default since stop 29 (0.5 before; "
        "inextensible_max_strain).")
    global_fast_lu: bool = Field(
        True, description="With global_contacts 'rows' and global_pivots: the step's "
        "SuperLU factorisations with small supernodes (relax 1, panel_size 1; on "
        "cloth_on_sphere's frame-9 systems 8.2 -> 5.7 ms a factorisation at the same fill, "
        "strain_limit_global.py, GlobalStrainStep._splu; the step over frames 8-14 330 -> "
        "224 ms a frame with A + S, graphs/bench/cloth_strain.py --passes, one interleaved "
        "run); false = the factorisations before, bitwise. "
        "Setting B's value, a default since stop 29 (false before; "
        "inextensible_max_strain).")
    global_factor: Literal["superlu", "qdldl"] = Field(
        "qdldl", description="With global_pivots: how the global step factorises its "
        "systems (symmetric positive definite). 'superlu': SuperLU with a minimum-degree "
        "ordering of each system (global_fast_lu); 'qdldl': LDL^T with an AMD ordering of "
        "each system (the qdldl package, sparse_ldl.py): 0.48x SuperLU's CPU per "
        "factorisation at the same fill on the 128 x 128 drop's systems (graphs/bench/"
        "global_factor.py), the frame 0.88x. The same systems solved to round-off. "
        "'qdldl' is the default since stop 30 ('superlu' before).")
    global_alpha: float = Field(
        1e-4, ge=0, le=1.0, description="Levenberg-Marquardt regularisation of the global "
        "step's system, relative to its diagonal [-]. An inextensible triangle mesh has about "
        "three edges per vertex against two in-plane degrees of freedom: J W J^T is nearly "
        "singular where a region is saturated, and with 1e-8 the Newton steps diverged "
        "(a 40 x 40 drape at 0.01: worst 30-50 % after a step); at 1e-3 the drape ends at "
        "1.07 % (1e-4 1.09 %, 1e-2 1.23 %, 1e-1 1.88 %, frame 9). 1e-4 needs global_smooth "
        "(without the sweeps a smaller alpha diverges). "
        "Setting B's value, a default since stop 29 (1e-3 before; "
        "inextensible_max_strain).")


@dataclass
class _Limits:
    edges: np.ndarray
    limit: np.ndarray
    color_ptr: np.ndarray
    lam: np.ndarray | None = None  # the implicit energy rows' multipliers [N] (``implicit``)
    energy_on: bool = False  # the limit is a row set of the implicit solve (``implicit``)
    e_alpha: np.ndarray | None = None  # the energy rows' compliances (0: hard) ...
    e_alpha2: np.ndarray | None = None  # ... and compressed ones (inf: tension only)
    glob: object = None
    pinch: tuple | None = None  # count_pinched's scratch (first normals, seen flags, cloth mask)


class StrainLimitConstraint(ConstraintBehavior):
    """Edges of elements whose material sets ``max_strain`` stay below (1 + eps_e) L0."""

    ParamsModel = StrainLimitParams
    requires = (Dynamic,)
    requires_any = (DiscreteShell, Rod)
    default_importance = 0.5
    default_order = 51

    def bind(self, ctx, elements):
        es, lims, shell = [], [], []
        auto = self.params.inextensible_max_strain
        nucleus = getattr(ctx.scene.spec, "solver", "nucleus") == "nucleus"
        if not nucleus and "inextensible_max_strain" not in self.params.model_fields_set:
            auto = None  # a Nucleus default: other solvers get it only when set explicitly
        # so are the global step and the pinch's joint passes (Nucleus defaults since stop 29)
        self._global_passes = (self.params.global_passes if nucleus or "global_passes"
                               in self.params.model_fields_set else 0)
        self._pinch_n = (self.params.inextensible_pinch_iterations if nucleus
                         or "inextensible_pinch_iterations" in self.params.model_fields_set
                         else None)
        self._painted = False
        for e in elements:
            c = e.get(DiscreteShell) or e.get(Rod)
            if c.max_strain is None and (auto is None or not isinstance(c, DiscreteShell)
                                         or c.youngs_modulus is not None
                                         or not len(e.geometry.triangles)):
                continue
            g = e.geometry
            edges = T.triangle_edges(g.triangles) if len(g.triangles) else g.edges
            if not len(edges):
                continue
            self._painted |= c.max_strain is not None
            eps = (np.full(e.vertex_count, float(auto)) if c.max_strain is None else
                   resolve_paintable(c.max_strain, e, f"{type(c).__name__}.max_strain"))
            if np.any(eps < 0):
                ctx.error(e, f"{type(c).__name__}.max_strain", "must be >= 0")
                continue
            X = ctx.model.particle_rest[e.vertex_slice]
            L0 = np.linalg.norm(X[edges[:, 1]] - X[edges[:, 0]], axis=1)
            L0 = L0 * getattr(c, "rest_length_scale", 1.0)
            eps_e = 0.5 * (eps[edges[:, 0]] + eps[edges[:, 1]])
            es.append(edges + e.vertex_offset)
            shell.append(np.full(len(edges), isinstance(c, DiscreteShell)))
            lims.append((1.0 + eps_e) * L0)
        if not es:
            return None
        edges = np.concatenate(es).astype(np.int64)
        limit = np.concatenate(lims)
        perm, ptr = T.color_constraints(edges, vertex_count=ctx.model.particle_count)
        d = _Limits(np.ascontiguousarray(edges[perm]), np.ascontiguousarray(limit[perm]), ptr)
        d.energy_on = (getattr(ctx.scene.spec, "solver", "nucleus") == "implicit"
                       and self.params.implicit == "energy" and self.params.mode == "constitutive")
        if d.energy_on:  # tension-only hard rows at the limit's length (the energy section)
            d.lam = np.zeros(len(d.edges))
            d.e_alpha = np.zeros(len(d.edges))
            d.e_alpha2 = np.full(len(d.edges), np.inf)
        sel = np.flatnonzero(np.concatenate(shell)[perm])
        if self._global_passes > 0 and self.params.mode == "constitutive" and len(sel):
            from .strain_limit_global import GlobalStrainStep

            d.glob = GlobalStrainStep(ctx.model.particle_count, d.edges, d.limit, sel)
            d.glob.set_colors(d.color_ptr)
            d.glob.ldl = self.params.global_factor == "qdldl"
        if self._pinch_n is not None and not self._painted:
            n = ctx.model.particle_count
            cloth = np.zeros(n, np.bool_)
            cloth[d.edges[sel]] = True
            d.pinch = (np.zeros((n, 3)), np.zeros(n, np.int8), cloth)
        return d

    def begin_substep(self, ctx, d):
        """With ``inextensible_pinch_iterations``: this substep's joint passes, that many when
        the substep's contacts pinch the cloth (``count_pinched``), else
        inextensible_joint_iterations."""
        self._joint_n = None
        self.pinched = False  # read by stretch.joint_long_range 'pinch'
        if d is None or d.pinch is None:
            return
        c = ctx.state.fields.get("contacts")
        k = 0
        if c is not None and (len(c.vf) or len(c.ee)):
            first, seen, cloth = d.pinch
            seen[:] = 0
            w = ctx.model.particle_inv_mass
            x = ctx.state.particle_q
            sl = _contacts.slide_mode(False)
            k = count_pinched(x, w, cloth, c.vf, c.vf_n, c.vf_target, c.vf_onesided, True,
                              first, seen, sl)
            k += count_pinched(x, w, cloth, c.ee, c.ee_n, c.ee_target, c.vf_onesided[:0],
                               False, first, seen, sl)
        ctx.stats["max_pinched"] = max(ctx.stats.get("max_pinched", 0), k)
        if k:
            self._joint_n = self._pinch_n
            self.pinched = True

    def project(self, ctx, d, p):
        if self.params.mode == "constitutive":
            project_strain_limit(p, ctx.model.particle_inv_mass, d.edges, d.limit, d.color_ptr)

    def project_joint(self, ctx, d, p):
        """Called by the final collision rounds (constitutive mode only)."""
        if self.params.mode == "constitutive":
            project_strain_limit(p, ctx.model.particle_inv_mass, d.edges, d.limit, d.color_ptr)

    def joint_iterations(self) -> int:
        if self.params.mode != "constitutive":
            return 0
        if getattr(self, "_painted", True):
            return self.params.joint_iterations
        return getattr(self, "_joint_n", None) or self.params.inextensible_joint_iterations

    def satisfied(self, ctx, d, p) -> bool:
        return self.params.mode != "constitutive" or strain_excess(
            p, d.edges, d.limit) <= self.params.tolerance

    def finalize(self, ctx, d, p):
        """The global step (``global_passes``), after the final collision rounds (order 51 >
        the contacts' 50) and before their CCD safe step (``after_finalize``)."""
        if d.glob is None:
            return
        if (self.params.global_every == "frame"
                and (ctx.substep + 1) % max(int(ctx.model.substeps), 1)):
            return
        n0 = d.glob.stats["passes"]
        tol = self.params.global_tolerance
        if tol is None or (self._painted
                           and "global_tolerance" not in self.params.model_fields_set):
            tol = self.params.tolerance  # a painted limit is held to its stated tolerance
        d.glob.run(p, ctx.model.particle_inv_mass, ctx.state.fields.get("contacts"),
                   self._global_passes, tol, self.params.global_near,
                   self.params.global_alpha, self.params.global_contacts,
                   self.params.global_pivots, self.params.global_update,
                   self.params.global_smooth, self.params.global_chord,
                   self.params.global_chord_rate, self.params.global_fast_lu)
        ctx.stats["max_global_strain_passes"] = max(ctx.stats.get("max_global_strain_passes", 0),
                                                    d.glob.stats["passes"] - n0)

    def after_finalize(self, ctx, d, p):
        if d is not None and d.energy_on:
            limit_stats(self, ctx, d, p)
        if self.params.mode == "post":
            for _ in range(self.params.post_iterations):
                project_strain_limit(p, ctx.model.particle_inv_mass, d.edges, d.limit,
                                     d.color_ptr)

    def residual(self, ctx, d, p):
        return float(max(strain_excess(p, d.edges, d.limit), 0.0))

    def describe(self, d):
        return f"{len(d.edges)} edges ({self.params.mode})" if d is not None else ""


# ==============================================================================================
# Implicit energy (behaviors/solvers/implicit/energy.py has the protocol)
# ==============================================================================================
# With ``StrainLimitParams.implicit`` 'energy' (the default) each limited edge is a one-sided
# augmented Lagrangian row of the Newton solve itself (Loki supplement eq. 8-10 as a penalty row, as the
# contacts there are): ``C = |x_a - x_b| - (1 + eps_e) L0 <= 0``, the force ``f = max(0, lam +
# k C)`` with ``k`` the hard penalty of its vertices (``hard_stiffness`` m / h^2) and ``lam`` the
# multiplier carried between substeps, so the limit pushes back on the elastic and contact terms
# of the same solve instead of moving vertices after it. This is a hard tension-only distance
# row of ``stretch.spring_energy`` (rest length: the limit, compression off), whose gradient,
# PSD Hessian blocks and multiplier update are used as they are. The projection pass after the
# solve still applies the limit (a safety projection, as for the contacts).
from ..solvers.implicit.energy import grad_or_dummy, hess_or_dummy  # noqa: E402
from .stretch import spring_energy, spring_update_lam  # noqa: E402


def _energy_rows(d) -> bool:
    return d is not None and d.energy_on


def limit_multipliers(self, d):
    """The energy rows' multipliers [N] (tension pushed back by the limit; allocated at bind),
    kept on the data between substeps; none without energy rows."""
    return d.lam if _energy_rows(d) else np.zeros(0)


def limit_energy_stencils(self, ctx, d):
    """The limited edges when they are rows of the implicit solve (``implicit`` 'energy'),
    else none (the solver then projects the limit after the solve)."""
    return [d.edges] if _energy_rows(d) else []


def limit_energy(self, ctx, d, x, grad, hess, opts):
    if not _energy_rows(d):
        return 0.0
    return spring_energy(x, d.edges, d.limit, d.e_alpha, d.e_alpha2, d.lam, opts.hard_k,
                         opts.mode, grad_or_dummy(grad, opts), hess_or_dummy(hess, 0, opts))


def limit_stats(self, ctx, d, x):
    """run.json statistics of the energy rows at the end of a substep: ``strain_limit_rows`` /
    ``max_strain_limit_rows`` (rows whose multiplier pushed back in the substep's solve:
    > 0; the solver updates them after this) and
    ``max_strain_limit_excess`` (the largest relative excess over the limit after the solve and
    its projection pass) [-]."""
    e = x[d.edges[:, 0]] - x[d.edges[:, 1]]
    excess = float((np.sqrt(np.einsum("ij,ij->i", e, e)) / d.limit).max() - 1.0)
    active = int(np.count_nonzero(d.lam > 0.0))
    s = ctx.stats
    s["strain_limit_rows"] = s.get("strain_limit_rows", 0) + active
    s["max_strain_limit_rows"] = max(s.get("max_strain_limit_rows", 0), active)
    s["max_strain_limit_excess"] = max(s.get("max_strain_limit_excess", -1.0), excess)


def limit_update_multipliers(self, ctx, d, x, opts):
    if _energy_rows(d):
        spring_update_lam(x, d.edges, d.limit, d.e_alpha, d.e_alpha2, d.lam, opts.hard_k)


def limit_state_arrays(self, d):
    """Checkpointed run state: the energy rows' multipliers (none without them)."""
    return {"implicit_lam": d.lam} if _energy_rows(d) else {}


def limit_load_state_arrays(self, d, arrays):
    if _energy_rows(d) and "implicit_lam" in arrays:
        d.lam[:] = arrays["implicit_lam"]


StrainLimitConstraint.energy_stencils = limit_energy_stencils
StrainLimitConstraint.energy = limit_energy
StrainLimitConstraint.energy_update_multipliers = limit_update_multipliers
StrainLimitConstraint.energy_multipliers = limit_multipliers
StrainLimitConstraint.state_arrays = limit_state_arrays
StrainLimitConstraint.load_state_arrays = limit_load_state_arrays
