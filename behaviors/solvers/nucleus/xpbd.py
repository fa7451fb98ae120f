"""Shared XPBD primitives of the Nucleus solver's constraint kernels, and their conventions.

The projection kernels live beside the behavior that packs their rows, one module per physical
effect: stretch (:mod:`lokigraph.behaviors.materials.stretch`), corner angle / shear
(:mod:`~lokigraph.behaviors.materials.shear`), dihedral and curve bend
(:mod:`~lokigraph.behaviors.materials.bend`), tet volume
(:mod:`~lokigraph.behaviors.materials.volume`), mesh volume / pressure
(:mod:`~lokigraph.behaviors.materials.pressure`), shape matching
(:mod:`~lokigraph.behaviors.materials.rigid`), goals and point-to-triangle attachments
(:mod:`lokigraph.behaviors.attachments.goal`, :mod:`~lokigraph.behaviors.attachments.surface`).
This module holds what they share: the multiplier update (``_xpbd_step``), the position update
(``_nudge``), the no-NRT compile decorator (``_hot``), the degeneracy thresholds, the residual
of a set of constraint values and the size below which a set runs sequentially.

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

import numba
import numpy as np
from numba import njit

__all__ = ["PARALLEL_MIN_CONSTRAINTS", "residual", "sequential_sweep"]

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


#: Constraint sets smaller than this run the sequential Gauss-Seidel kernel: below it a coloured
#: parallel sweep spends more on thread barriers (one per colour) than it saves, and it stalls
#: badly when other processes share the cores. Measured with lokigraph/bench/kernels.py on 2
#: idle cores: 800 stretch rows 0.6x (parallel slower), 1536 shear rows 1.1x, 3136 stretch rows
#: 1.2x, 6144 shear rows 1.7x, 24576 shear rows 1.9x.
PARALLEL_MIN_CONSTRAINTS = 2048


def sequential_sweep(sequential: bool) -> bool:
    """Whether a coloured set runs its sequential kernel now: a set packed sequential (smaller
    than ``PARALLEL_MIN_CONSTRAINTS``), or any set while numba runs its parallel kernels on one
    thread (``NUMBA_NUM_THREADS=1``, ``numba.set_num_threads(1)``). On one thread the coloured
    sweep's ``prange`` runs the rows of each colour in storage order, which is the sequential
    kernel's order, so both give bitwise the same positions; the coloured sweep only adds its
    per-colour launch. Measured on the 64 x 64 / 128 x 128 drop's sets (1 thread, one process,
    400 calls each alternating, medians): stretch 12,416 rows 177 -> 139 us, 49,408 rows 996 ->
    674 us; dihedral bend 12,160 rows 819 -> 698 us, 48,896 rows 3262 -> 2830 us."""
    return sequential or numba.get_num_threads() == 1
