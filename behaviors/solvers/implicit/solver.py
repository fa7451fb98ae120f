"""The implicit solver (Loki supplement eq. 1): backward Euler as an optimisation, Newton's
method with a backtracking line search, block-sparse Hessians and preconditioned CG.

Per substep of size h, with x^n, v^n the state, f the forces the force stage accumulated
(gravity, wind, pressure, rest springs ...), M the lumped masses and Psi the sum of the
energies of every bound constraint behavior that implements the implicit energy protocol
(:mod:`.energy`), the new positions minimise the incremental potential

    E(x) = 1/(2 h^2) |x - x~|^2_M + Psi(x) + 1/(2 h) |x - x^n - h u|^2_D,
    x~   = x^n + h v^n + h^2 M^-1 f,

which is the velocity form v = argmin 1/2 |v - v^n|^2_M - h f.v + Psi(x^n + h v) (+ the
implicit drag h/2 |v - u|^2_D, with D and u the per-vertex drag tensor and air velocity of
``drag_D`` / ``drag_u``, Avatar eq. 1-4) written in x = x^n + h v. Its stationarity is
backward Euler: M (v - v^n) = h (f - grad Psi(x) + D (u - v)). ``Dynamic.damping`` damps v^n
first, as in the Nucleus solver.

Newton: the gradient and the Hessian of E are assembled into a block-sparse matrix (3x3 blocks)
whose pattern is fixed once from the energy stencils (values refilled per iteration by numba
scatter kernels, no pattern building per iteration); every energy writes PSD blocks, so the
Newton matrix M/h^2 + D/h + sum of PSD blocks is positive definite and CG applies. Hard rows
(inextensible stretch, welds) are augmented Lagrangian terms: a penalty ``hard_stiffness`` times
the inertia m/h^2 of their vertices plus a multiplier that carries the constraint force over
from one substep to the next (updated after every substep; each behavior checkpoints its own
through ``state_arrays``), so that a moderate,
well-conditioned penalty converges to the hard constraint at rest. A hard distance row stretched
past ``hard_limit`` (2 %) also gets a one-sided term ``hard_limit_stiffness`` (100) times
stiffer (``energy.limit_energy``): a strain limit inside the solve, where a sudden load (a cloth
hitting a sphere at one substep) meets the penalty alone (see the Field for the measurements).
The step solves H dx = -grad E by PCG (block-Jacobi preconditioner by default; ``amg_reuse``
an aggregation multigrid kept across Newton iterations, opt-in) to ``cg_tolerance``; a
backtracking line search (Armijo, halving) on E takes the step; iterations stop when the Newton
step dx (before the line search) changes no velocity by more than ``newton_tolerance`` [m/s]
or after ``newton_iterations`` (``newton_stop``: testing the line-searched step instead let a
step cut by 2^-9 pass as converged after one iteration; measured in the Field).

Dirichlet vertices: kinematic vertices sit at their animated pose, pinned vertices (inverse
mass 0) at x^n + h v^n (as in Nucleus); both are removed from the unknowns (their rows and
columns of the Newton matrix become the identity, their gradient entries zero).

Contacts in the Newton solve (``implicit/contact.py``): with ``shape_contact: energy`` (the
default) the analytic colliders of ``ShapeCollisionConstraint`` (plane, sphere, capsule) are a
one-sided penalty ``contact_stiffness * m / h^2`` on the signed distance minus thickness plus
IPC-style smoothed Coulomb friction with the normal force and normal lagged from the previous
Newton iterate (the first iteration of a substep takes the last substep's), the penalty's
normal force carried over between substeps as an augmented Lagrangian multiplier
(``contact_multipliers``) and the free vertices' initial guess x + h v (``contact_start``: a
body resting on a collider starts where it rests, not h^2 g inside it); a final safety
projection pushes any vertex still inside out along the normal. With ``mesh_contact: energy``
(the default) the vertex-face and edge-edge rows ``CollisionDetect`` built for the substep
enter the solve the same way (penalty on n0 . sum c_a x_a - target, closest-point
coefficients and normal forces lagged, block-diagonal Hessian), and ``CollisionConstraint``'s
projection pass below stays as their safety projection (re-detection and CCD included). Newton
does not stop while a lagged normal force changes by more than ``contact_tolerance`` of the
largest, up to ``contact_newton_iterations``. Only the live rows are visited per Newton
iteration (``contact.lag_rows_live`` / ``extend_live``): rows whose gap cannot be negative at the
iterate, nor anywhere on the line-search segment, whatever their closest-point coefficients (a
concave lower bound of the gap, ``_gap_bound``), hold no energy, so leaving them out is exact
(positions bitwise unchanged); on graphs/bench/cloth_sphere_64.yaml at one substep the pipeline
hands ~1.2 M rows per substep at impact (a detection margin of the substep's motion), of which
~7,000 are live; after a line search only the rows ``extend_live`` listed for its segment
are visited (``contact.lag_rows_sel``; measured in graphs/bench/implicit_speedups.py). This is
a penalty method, not the
complementarity solve of the Loki supplement eq. 5-7: contacts leave a small penetration (at
rest ~ g h^2 / contact_stiffness) that the safety projection removes.

Safeguards of the contact rows, measured with ``lokigraph stress --solver implicit``
(``--quick``: 16x16 cloth unless said; the figures of this paragraph up to the last two
sentences are from before ``hold_kinematic``): ``violated_rows: hold`` (rows the start of the
substep already violates only stop approaching in the solve; CollisionConstraint's projection
pass pushes them back as in Nucleus) and ``start_at_rest`` (Newton starts from x^n where E is lower
there), both on by default; ``contact_reach`` (near rows' curvature in the Newton matrix), off
by default. Pinch case (cloth vertex speed bound 0.5 m/s): none of them 0.65 m/s (fails),
hold + rest 0.38 m/s, hold + rest + reach 0.0005 m 0.22 m/s; reach 0.0005 m with hold but no
rest, or with neither, fails (speed, frames 30-36). Projectile at 48x48: hold + rest 0
crossing pairs (passes), hold + rest + reach 0.0005 m 22 pairs (fails), push + no rest + reach
0.0005 m 0; at 16x16 hold + rest + reach 0.002 m gives 57 pairs. "Cloth starting
interpenetrated" (energy bound 1e-6 J) failed in every one of those settings: worst energy
excess 0.28 J with none, 0.053 J with hold + rest, 0.0066 J with hold + rest + reach
0.0005 m (0.0021 J with hold + rest and the defaults since). ``violated_rows:
hold_kinematic`` (the default now) holds only the rows against kinematic vertices, where the
pinch needs it, and lets the solve push the crossed self pairs against the cloth's
elasticity instead of leaving that push to the projection pass, whose stretch the next solve
released as motion (measured in the Field): the case passes at --quick and full size, and the
pinch, sleeve_pinch, sleeve_elbow, trouser knee and 64x64 drop keep their figures. The 16x16
cloth-on-sphere-mesh test (1 substep): max strain 1.7 % with none, 0.9 % with hold + rest,
36 % with hold + reach 0.002 m and no rest.

Compliant kinematic vertices (``Kinematic.stiffness`` > 0, Loki's receding surfaces): with
``compliant_kinematics: dirichlet`` they sit at their animated pose in the Newton
solve like the other kinematic vertices and only the projection pass below moves them; with
``energy`` (the default since stop 36) they are unknowns of the solve whose inertia term, of
mass K h^2 (the Nucleus solver's inverse mass) around the animated pose, is the goal spring
K/2 |x - x_anim|^2, pushed by the contact rows' penalty and not by their friction
(``compliant_tangential``: the same spring in every direction, or hard across the surface
normal). ``energy`` holds the flat pinches
(pinch, sleeve_pinch) within the Nucleus speed bounds, but not the knee or the elbow, whose
compliant surfaces recede far (Field descriptions) unless ``compliant_depth`` caps each
vertex's recession (0.01 m by default; with it the knee holds, 0 intersecting pairs, and all
but the elbow's near-joint speed meet the Nucleus bounds, which ``dirichlet`` fails on every
scene but the elbow's overall bound; ``compliant_shape_stiffness``, opt-in, couples
neighbouring compliant unknowns by a Laplacian energy on their recession: the knee calmer, the
sleeves faster, Field description). The compliant unknowns carry no momentum
and, without ``compliant_shape_stiffness``, no energy stencil (the supplement's "new vertices"
of eq. 4 are the kinematic body's own vertices here, the same unknowns): their rows of the
Newton matrix hold only their diagonal 3x3 block (the goal spring plus the contact rows'
block-diagonal terms), so ``compliant_solve: block`` solves them apart from CG by that
block's inverse, exactly, and CG runs on the cloth's unknowns alone (opt-in; ``cg``, the
default, keeps them in the block-Jacobi CG, whose preconditioner holds the same blocks); measured
(graphs/bench/implicit_compliant.py) without a preconditioner block of their own
(``cg_identity``) the pinch needs 9.9x the CG iterations, with it in CG (``cg``) or apart
(``block``) the same.

Constraints that are not energies: mesh collisions (``CollisionConstraint``, also after their
rows were in the solve), analytic colliders with ``shape_contact: projection``, strain limits
(``StrainLimitConstraint``), enclosed-volume pressure (``PressureConstraint``) and sliding
attachments are inequality or global constraints. They are applied, as the Nucleus solver's
final rounds do, by a projection pass on the end-of-step positions after the Newton solve
(``projection_iterations`` Gauss-Seidel passes of their ``project``, then ``finalize`` and
``after_finalize``: the collision final rounds re-detect over the solved motion), and v is then
(x' - x^n) / h. Strain limits are also rows of the Newton solve (``strain_limit.implicit:
energy``, the default: one-sided augmented-Lagrangian rows, ``strain_limit.py``'s implicit
energy), so they push back on the elastic and contact terms of the same step; the projection
pass then only cleans up (with ``implicit: projection`` it is the limit's only pass).
So is the enclosed volume of a closed mesh (``pressure.implicit: energy``, the default: an
augmented-Lagrangian row C = V(x) - V_target, ``pressure.py``'s implicit energy). Its Hessian
k g g^T (g = dV/dx) is dense over the mesh's vertices: it is not assembled; an energy hands such
rank-one terms to the solver (``energy_lowrank``) and the linear solve adds k g (g . v) to its
matrix product (``linear.lowrank_matvec`` through ``pcg_fused``, whatever the preconditioner;
the preconditioners see none of it: with the terms' per-vertex diagonal blocks k g_i g_i^T in
the matrix, ``LOWRANK_DIAG``, block-Jacobi took 1.2x / 1.8x the CG iterations and 1.1x / 1.9x
the CPU on the pressure ball at 1 / 4 substeps, graphs/bench/implicit_pressure.py --diag).
Measured there (E = 2e5, 40 frames, energy / projection): at 1 substep the volume holds within
0.018 % / 27.8 % (in the Newton solution 0.12 % / 100 %: without the row the solve flattens
the ball on the ground, the pass re-inflates it into the ground, the ground's safety
projection takes the volume back) with speeds after landing of 0.51 / 24.1 m/s.
Tethers (``TetherConstraint``, a Gauss-Seidel convergence aid for inextensible
materials) are not used: the Newton solve carries the stretch stiffness across the mesh. Any
other constraint type bound in an implicit scene that has no energy is an error at
the first substep, naming it (never a silent skip).

Statistics per substep in ``ctx.stats`` (summed over the frame in run.json, ``max_`` keys take
the maximum): ``newton_iterations``, ``cg_iterations``, ``line_search_halvings``,
``max_newton_iterations``, ``max_cg_iterations`` (one linear solve), ``max_newton_step``
(the last line-searched step's largest velocity change [m/s]), ``max_cg_residual`` (relative),
``cut_steps`` (Newton iterations whose line-searched step passed ``newton_tolerance`` but whose
Newton step did not);
with contacts in the solve ``active_contacts`` / ``max_active_contacts`` (vertex-shape pairs in
contact at the last Newton iterate), ``max_projection_move`` (largest move of a vertex by the projection pass [m]),
``max_contact_projection`` (largest move of the shape
safety projection [m]), ``contact_rows`` / ``max_contact_rows`` (active pipeline rows),
``held_rows`` (rows held at their start gap, ``violated_rows``), ``rest_starts`` (substeps
whose Newton solve started from x^n, ``start_at_rest``), ``kept_multipliers`` (substeps after
which ``hard_multipliers`` kept the hard rows' multipliers) and, with contact rows, their
complementarity residuals at the Newton solution (``contact.row_residuals``):
``max_complementarity`` (max |min(C, lam / k)| [m], for these penalty rows the largest
penetration) and ``max_cone_violation`` [N].

Hard rows and unconverged contact solves (``hard_multipliers``): the augmented Lagrangian
update lam += k C of the hard rows (inextensible stretch, welds) assumes the Newton solve reached
the minimum of its subproblem. Where contacts jam an inextensible cloth against moving Dirichlet
bodies (graphs/examples/trouser_knee.yaml, sleeve_elbow.yaml, the pinches with
``compliant_kinematics: dirichlet``), Newton stops at its cap and the update integrated the
unconverged violation, and the projection pass's moves, substep after substep: measured on the
knee, the largest stretch multiplier grew from 10 N at frame 2 to 1,660 N at frame 17 (a 94 g
trouser), the contact rows' normal forces to ~230 N (penetrations of 1-1.8 cm in the Newton
solution, which the projection pass then removed by moving vertices 2-3 cm in one substep: the
4-5 m/s speeds). 'converged' (the default) keeps the multipliers after such substeps, and
after converged ones whose contact rows end penetrated by more than ``jam_penetration`` (the
same jam: with contact_newton_iterations 100 some knee substeps converge, and updating after
them wound the multipliers up again, 3.6 m/s by frame 10; kept, 1.8 m/s). This bounds the
windup; it does not make Newton converge at the knee, which still stops at its cap in every
substep (the incremental potential flat to 1e-3 while steps stay ~0.05 m/s: the inextensible
trouser jammed between Dirichlet surfaces).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.sparse as sp
from pydantic import Field

from lokigraph.behavior import Behavior, Params
from lokigraph.components.colliders import ShapeCollider
from lokigraph.components.core import Dynamic
from lokigraph.errors import InputError

from ...collision.contacts import _vertex_normals_kernel
from ..damping import apply_damping, bind_damping
from .contact import (_ALL_MOVED, ENDPOINTS, NO_ENDPOINTS, contact_energy_al, extend_live,
                      lag_contacts_al, lag_rows, lag_rows_live, lag_rows_sel, mark_closing,
                      row_energy, row_energy_coupled, row_residuals, safety_project,
                      start_targets_on, update_contact_multipliers)
from .energy import EnergyOptions, build_pattern, gather_blocks, gather_map, limit_energy
from .compliant import compliant_edges, shape_energy
from .linear import (AggregationReuse, BlockJacobi, Direct, Identity, SmoothedAggregation,
                     invert_blocks, lowrank_matvec)

#: the rank-one Hessian terms' per-vertex diagonal blocks go into the Newton matrix (so every
#: preconditioner holds them); False: the CG product applies the whole term, the
#: preconditioners see none of it (measured in graphs/bench/implicit_pressure.py)
LOWRANK_DIAG = False
#: constraint types applied by the projection pass after the Newton solve (see module docstring)
PROJECTED_TYPES = ("CollisionConstraint", "ShapeCollisionConstraint", "StrainLimitConstraint",
                   "PressureConstraint")
#: energy types whose hard distance rows (alpha 0: inextensible stretch, hard stitches) take the
#: strain-limit terms of ``hard_limit`` (``limit_energy``)
LIMITED_TYPES = ("StretchConstraint", "StitchConstraint")
#: constraint types the implicit solver does not need, with the reason (module docstring)
NOT_NEEDED = {"TetherConstraint": "tethers are a Gauss-Seidel convergence aid; the Newton solve "
                                  "carries the (hard-penalty) stretch stiffness globally"}


def _tangential_ratio(solver):
    """Tangential / normal stiffness of the compliant vertices' goal spring [-]."""
    return solver.params.hard_stiffness if solver.params.compliant_tangential == "hard" else 0.0


def _change_over_stiffness(dlam, k):
    """Largest |change of a normal force| / stiffness [m] over the contacts with k > 0 (the gap
    change the change of force stands for); 0 where there are none."""
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.where(k > 0.0, dlam / np.where(k > 0.0, k, 1.0), 0.0)
    return float(g.max()) if g.size else 0.0


class ImplicitParams(Params):
    newton_iterations: int = Field(8, ge=1, le=1000, description="Most Newton iterations per "
                                   "substep.")
    newton_tolerance: float = Field(1e-3, gt=0, description="Newton stops when a step changes "
                                    "no vertex velocity by more than this [m/s] (default from "
                                    "graphs/bench/drape_ref.yaml at 4 substeps: 1e-3 gives the "
                                    "error of 1e-5 (0.0870 m) with half the Newton iterations; "
                                    "1e-2 0.0871 m).")
    newton_stop: Literal["newton_step", "line_search_step"] = Field(
        "newton_step", description="Which step the newton_tolerance test reads: 'newton_step' "
        "the Newton step dx (the CG solution), 'line_search_step' the step the line search took "
        "(alpha dx, the test before), which a step cut by the line search passes without "
        "converging (iterations where the two disagree are counted per frame as "
        "``cut_steps``). Measured on graphs/bench/cloth_sphere_64.yaml at 1 substep: at 16x16 "
        "(30 frames) every contact substep that converged with line_search_step (7 of 25) was "
        "one iteration whose step the line search had cut by 2^-9 (a resting cloth: the first "
        "step presses into rows that hold no curvature in the Newton matrix, and the tiny "
        "step changes no lagged force); with newton_step none converges within 20 iterations "
        "(the Newton steps stay 0.02-0.3 m/s), 12 of 25 within 100. 64x64 (24 frames, "
        "graphs/bench/implicit_drop.py): worst strain 2.55 % with both, Newton iterations 290 "
        "-> 385, CPU 1.84 -> 2.59 s per frame; trouser_knee (72 frames) and sleeve_elbow "
        "(60) the same per-frame speeds and Newton counts until the last 4 / 12 frames (the "
        "limb at rest), same largest speeds; graphs/examples/pinch.yaml (60 frames) 0.330 -> "
        "0.355 m/s, at rest 3 Newton iterations per substep instead of 1-2.")
    cg_iterations: int = Field(500, ge=1, le=100000, description="Most CG iterations per Newton "
                               "iteration.")
    cg_tolerance: float = Field(1e-3, gt=0, lt=1, description="CG stops at this residual "
                                "relative to the Newton gradient [-] (default from "
                                "graphs/bench/drape_ref.yaml: 1e-2 .. 1e-5 give the same error, "
                                "1e-3 keeps a margin at 70 % of the CG iterations of 1e-4; "
                                "with contacts, graphs/bench/implicit_knee.py and "
                                "implicit_drop.py, 1e-3 / 1e-2: the whole trouser knee 2.14 / "
                                "2.33 m/s (bound 2.2), the 64x64 drop 2.55 / 2.75 % strain at "
                                "2.59 / 1.89 s CPU per frame).")
    cg_forcing: Literal["fixed", "eisenstat_walker"] = Field(
        "fixed", description="CG tolerance per Newton iteration: 'fixed' cg_tolerance in every "
        "iteration; 'eisenstat_walker' the inexact-Newton forcing term (Eisenstat and Walker "
        "1996, choice 2: eta = 0.9 (|g_k| / |g_k-1|)^2, safeguarded by 0.9 eta_k-1^2 where "
        "that exceeds 0.1) between cg_tolerance and cg_forcing_max, cg_forcing_max at the "
        "first iteration of a substep (opt-in). Measured with graphs/bench/implicit_speedups.py "
        "--table (cloth-on-sphere at 1 substep, frames 2-10, interleaved; CPU ms/frame, CG "
        "iterations per frame, worst edge strain; 0 intersecting pairs in every frame of "
        "each): 64x64 fixed 1,798 / 3,597 / 4.45 %, eisenstat_walker with cg_forcing_max 0.1 "
        "962 / 513 / 5.65 %, 0.5 737 / 235 / 3.08 %; 128x128 fixed 9,613 / 4,720 / 3.57 %, "
        "0.1 4,507 / 631 / 7.01 % (over the 5 % bound), 0.5 2,333 / 286 / 3.07 %. Newton stops "
        "at its cap in every contact substep with each, so the iteration counts are the same "
        "and the strain moves both ways (chaotic): not the default until the knee, elbow and "
        "pinch bounds are remeasured with it.")
    cg_forcing_max: float = Field(0.5, gt=0, lt=1, description="cg_forcing: "
                                  "eisenstat_walker: the loosest relative CG tolerance [-] "
                                  "(0.5 from the figures of cg_forcing, where 0.1 took the "
                                  "128x128 drop over 5 % strain).")
    cg_forcing_after: int = Field(
        0, ge=0, description="cg_forcing: eisenstat_walker: a linear solve runs to "
        "cg_tolerance for its first cg_forcing_after CG iterations and stops at the forcing "
        "term's looser tolerance only after them (0: from the first iteration, the Eisenstat-"
        "Walker solve as measured in cg_forcing) [-]: cheap solves stay tight, where a loose "
        "one costs Newton iterations. Measured with graphs/bench/implicit_speedups.py --table "
        "(cloth_sphere_64, frames 2-10, interleaved, cg_forcing_max 0.5, cg_forcing_scope "
        "contacts; CPU ratio to the fixed tolerance / CG iterations per frame / worst strain): "
        "0 (scope all) 0.38 / 235 / 3.08 %, 25 0.43 / 281 / 4.00 %, 50 0.62 / 555 / 3.68 %, "
        "100 0.84 / 1,079 / 2.79 % (fixed 3,597 / 4.45 %), 0 intersecting pairs in each; "
        "cloth_sphere_128 (the run of the table in graphs/bench/implicit_speedups.py) 0 (scope "
        "all) 0.23 / 286 / 3.07 %, 25 0.21 / 285 / 5.49 % (over the issue's 5 % bound: Newton "
        "stops at its cap in every contact substep, and the strain there moves both ways with "
        "the tolerance), fixed 4,720 / 3.57 %; on graphs/examples/pinch.yaml "
        "(compliant_kinematics: energy; its solves take <= 22 CG iterations in frame 2) 25 "
        "keeps the fixed tolerance's Newton iterations through frame 26 (at most 5.25 a "
        "substep in frames 2-20, the test bound 6), where 0 took 10.5 (measured before this "
        "change). Opt-in: as the default (with scope contacts) 3 tests fail, comparisons "
        "measured at the fixed tolerance, and the 128 x 128 drop's strain passes 5 % "
        "(graphs/bench/implicit_speedups.py).")
    cg_forcing_scope: Literal["all", "contacts"] = Field(
        "all", description="cg_forcing: eisenstat_walker: in which substeps the forcing term "
        "applies: 'all', or 'contacts' only those with contacts in the Newton solve (analytic "
        "colliders or contact rows; the others solve to cg_tolerance). Measured on "
        "graphs/bench/catenary.yaml at 1 substep (72 frames, the inextensible chain, no "
        "contacts): Newton converges in 7 iterations a substep at cg_tolerance (0.0003 mm from "
        "the catenary at rest, bound 1 mm) and stops at its cap of 8 with the looser solves "
        "tried ('all' with cg_forcing_after 0 108.5 mm, 25 19.1 mm; a CG stop on the relative "
        "energy-norm error of the step at 0.1 / 0.03 22.0 / 5.2 mm, at 0.01 7 iterations and "
        "26,867 CG iterations against 28,120: graphs/bench/implicit_speedups.py); 'contacts' "
        "leaves it bitwise the fixed tolerance.")
    preconditioner: Literal["block_jacobi", "amg", "amg_reuse", "none", "direct"] = Field(
        "block_jacobi", description="CG preconditioner: inverse 3x3 diagonal blocks, pyamg "
        "smoothed aggregation (one V-cycle, rebuilt per Newton iteration), 'amg_reuse' "
        "(aggregation multigrid whose aggregation is built once and reused, its coarse "
        "matrices refreshed from every Newton matrix: linear.AggregationReuse, amg_cycle, "
        "amg_smooth, amg_rebuild_growth), or none (plain CG, for comparison; measured in "
        "graphs/bench/implicit_precond.py). amg_reuse measured with graphs/bench/implicit_amg.py "
        "(cloth-on-sphere at 1 substep, interleaved in one process, 1 thread; block_jacobi / "
        "amg_reuse additive / v): 128x128 impact frames 6-9, CPU s of the linear solves 25.9 / "
        "12.6 / 15.7, of the frames 60.4 / 42.2 / 44.3, CG iterations 33,776 / 8,729 / 4,068, "
        "Newton at its cap (80) in each, worst edge strain 3.32 / 4.38 / 6.06 %; 64x64 frames "
        "6-12 CG s 10.2 / 7.0 / 8.2, strain 4.45 / 3.54 / 2.85 %; 0 intersecting pairs in every "
        "frame of each. graphs/bench/implicit_precond.py (6 frames, ms/frame CPU, block_jacobi / "
        "amg_reuse): drape_64 2,056 / 1,238, cloth_sphere_32 966 / 306, pinch 87 / 95, elastica "
        "and catenary 2 / 7 (one CG iteration: the coarsest level solves them). Opt-in: the "
        "strain moves both ways with the linear solve (Newton stops at its cap at impact; an "
        "earlier run of the additive cycle reached 6.08 % at 128x128, the V-cycle 5.13-6.06 %). "
        "'direct' factorises the Newton matrix (QDLDL, AMD ordering kept within a substep; "
        "linear.Direct) and solves it exactly, for measuring what an exact Newton step gains: "
        "graphs/bench/implicit_precond.py --preconditioners block_jacobi amg_reuse direct (6 "
        "frames, ms/frame CPU, stop 36): elastica 5 / 13 / 12, catenary 4 / 13 / 7, drape_64 "
        "3,444 / 3,737 / 7,972, cloth_sphere_32 541 / 894 / 443, pinch 91 / 221 / 201, the same "
        "Newton counts. On sleeve_elbow (graphs/bench/implicit_knee.py, 60 frames) Newton "
        "still stops at its cap in every substep with it: near-joint speed 1.092 against "
        "1.300 m/s with block_jacobi, 95.7 against 47.8 s CPU: the inexact linear solve is not "
        "what keeps Newton from converging there.")
    amg_cycle: Literal["additive", "v"] = Field(
        "additive", description="preconditioner: amg_reuse: 'additive' the finest level's "
        "block-Jacobi plus the coarse levels' V-cycle on the restricted residual (one matrix "
        "read a CG iteration), 'v' a symmetric V-cycle with block Gauss-Seidel on every level "
        "(fewer, dearer CG iterations); measured in graphs/bench/implicit_amg.py.")
    amg_smooth: Literal["tentative", "smoothed"] = Field(
        "tentative", description="preconditioner: amg_reuse: the prolongators, pyamg's "
        "tentative (plain aggregation, one block a fine row) or smoothed aggregation.")
    amg_rebuild_growth: float = Field(
        2.0, ge=0.0, description="preconditioner: amg_reuse: the aggregation is rebuilt when a "
        "linear solve takes more than this times the CG iterations of the first solve after "
        "the last build [-]; 0: rebuilt at the first Newton iteration of every substep.")
    hard_stiffness: float = Field(1e4, gt=0, description="Penalty of hard rows (inextensible "
                                  "stretch, welds, hard attachments) as a multiple of the "
                                  "inertia m / h^2 of their heaviest vertex [-]; stretch rows "
                                  "add a multiplier carried between substeps (augmented "
                                  "Lagrangian). Measured at 24 fps, 1 substep: the catenary "
                                  "bench at rest is within 4e-7 m at 1e4 (Newton stalls at 1e5: "
                                  "2.6 cm); graphs/bench/drape_64.yaml (64x64, inextensible) "
                                  "stretches by up to 11 % at 1e4 and 6 % at 3e4 while it falls "
                                  "(the multipliers lag a sudden load).")
    line_search: bool = Field(True, description="Backtracking line search on the incremental "
                              "potential (false: full Newton steps).")
    projection_iterations: int = Field(10, ge=0, le=10000, description="Gauss-Seidel passes of "
                                       "the projected constraint types (collisions, strain "
                                       "limits, pressure) after the Newton solve.")
    shape_contact: Literal["energy", "projection"] = Field(
        "energy", description="Analytic colliders (ShapeCollider): 'energy' puts a one-sided "
        "penalty and lagged smoothed Coulomb friction into the Newton solve (implicit/contact.py) "
        "plus a final safety projection; 'projection' applies ShapeCollisionConstraint in the "
        "projection pass after the Newton solve.")
    mesh_contact: Literal["energy", "projection"] = Field(
        "energy", description="Contacts of the collision pipeline (CollisionDetect's vertex-face "
        "and edge-edge rows): 'energy' also puts them into the Newton solve as penalty rows with "
        "lagged smoothed friction (implicit/contact.py) before CollisionConstraint's projection "
        "pass (which stays as the safety projection, CCD included); 'projection': that pass "
        "only.")
    contact_newton_iterations: int = Field(
        20, ge=1, le=1000, description="Most Newton iterations of a substep with contacts in the "
        "solve (analytic colliders or contact rows; newton_iterations otherwise). Measured on "
        "a 16x16 inextensible cloth dropped on a sphere mesh at 1 substep: max edge strain 11 % "
        "at 8, 1.7 % at 20.")
    contact_hessian: Literal["diagonal", "coupled"] = Field(
        "diagonal", description="Newton-matrix blocks of the contact rows of the collision "
        "pipeline (mesh_contact: energy): 'diagonal' the 3x3 diagonal block c_a^2 (k n n^T + "
        "friction block) of each free vertex of a row only; 'coupled' also the off-diagonal "
        "blocks c_a c_b (...) between a row's vertices wherever the Hessian pattern holds them "
        "(cloth against a kinematic body: the row's cloth vertices share a triangle or edge), "
        "a diagonal majorizer for the pairs it lacks (contact.row_energy_coupled). Measured "
        "with graphs/bench/implicit_newton_table.py (interleaved, 1 thread, frames 2-10; CPU "
        "ms/frame, CG/frame, worst strain, diagonal / coupled): 64x64 drop 1,555 / 1,487, "
        "3,597 / 3,327, 4.45 / 3.05 %; sleeve_elbow (60 frames) 937 / 925 ms, near-joint "
        "speed 0.897 / 0.948 m/s; 0 intersecting pairs; Newton stays at its cap in every "
        "contact substep with both (opt-in).")
    contact_sticky: bool = Field(
        False, description="Contact rows of the collision pipeline that were active (normal "
        "force > 0) at any Newton iterate of the substep keep their penalty curvature k n n^T "
        "in the Newton matrix where inactive (energy and gradient unchanged), as contact_reach "
        "gives it to every row near its target: a row that the steps open and close in turn "
        "(graphs/bench/implicit_newton.py) is seen by the model on both sides; so do the rows "
        "that a full Newton step closes (``contact.mark_closing``) before the line search "
        "cuts it short of them. Measured with graphs/bench/implicit_newton_table.py "
        "(interleaved, 1 thread; with contact_hessian: coupled; CPU ms/frame, CG/frame, "
        "line-search halvings/frame, worst strain, off / on): 64x64 drop (frames 2-10) 1,555 / "
        "1,464, 3,597 / 3,137, 23 / 11, 4.45 / 2.10 %; 128x128 drop 8,798 / 9,264, 4,720 / "
        "4,227, 19 / 10, 3.57 / 3.03 %; sleeve_elbow (60 frames) 937 / 887 ms, 125 / 96 "
        "halvings, near-joint 0.897 / 0.871 m/s (bound 0.73), 20 Newton iterations per "
        "substep at rest with both; 0 intersecting pairs everywhere. With friction_hessian: "
        "irls too: 64x64 1,388 ms, 128x128 9,631 ms, sleeve_elbow 801 ms, 16 halvings, "
        "0.783 m/s, 16.5 Newton per substep at rest. Opt-in: Newton stays at its cap at "
        "impact with all of them (graphs/bench/implicit_newton.py has the causes measured).")
    contact_stiffness: float = Field(1e4, gt=0, description="Contact penalty per vertex as a "
                                     "multiple of its inertia m / h^2 [-] (shape_contact: "
                                     "energy).")
    friction_velocity: float = Field(1e-5, gt=0, description="Tangential speed below which "
                                     "friction is a smoothed stick (IPC's eps_v) [m/s]; a "
                                     "sticking vertex creeps at about friction_velocity * "
                                     "tan(slope) / (2 mu).")
    friction_hessian: Literal["irls", "exact"] = Field(
        "exact", description="Friction Hessian block: 'irls' mu lam f1(y)/y (I - n n^T), a "
        "quadratic majorizer (every full step lowers the friction energy); 'exact' IPC's PSD "
        "Hessian (zero curvature along a sliding direction). Measured on ropes over a drum "
        "(graphs/bench/capstan.py, 1 substep): with end weights both give the capstan "
        "threshold, 'exact' in 6-14 Newton iterations per substep, 'irls' in 13-20; a uniform "
        "heavy rope 15 % above its limit slides with 'irls' (strain 0.6 %) but 'exact' steps "
        "the wrap off the drum along straight tangents (strain 8 %, 20 % at 4 substeps).")
    friction_slip_curvature: float = Field(
        0.2, ge=0.0, le=1.0, description="Analytic colliders (shape_contact: energy) with "
        "friction_hessian 'exact': the friction block's curvature along the slip direction is "
        "kept at least this fraction of its curvature across it, mu lam f1(y) / y (IPC's exact "
        "block has 0 there while sliding, 1 is the 'irls' block; the energy and its gradient "
        "are the same). Where nothing else resists the slip the exact block leaves the Newton "
        "matrix singular along it: graphs/examples/pressure_ball.yaml with solver: implicit "
        "(a soft shell, E t = 20 N/m, on a ground of friction 0.3) then ran every contact "
        "substep to the Newton cap with 12 line-search halvings an iteration and threw vertices "
        "at up to 489 m/s with its volume projected after the solve (friction 0: 3.6 m/s in 24 "
        "frames). graphs/bench/implicit_friction_floor.py (48 frames, interleaved; largest "
        "speed after landing, Newton iterations / line-search halvings / CPU ms a frame) with "
        "Pressure (its volume a row of the solve): 0 2,593 m/s, 59.1 / 654 / 551; 0.1 2.69 m/s, "
        "31.3 / 24 / 73; 0.2 2.69 m/s, 39.8 / 40 / 121; 0.5 2.69 m/s, 33.4 / 2 / 79; irls 2.69 "
        "m/s, 40.3 / 6 / 105; without Pressure 0: 805 m/s, 0.2: 3.67 m/s (with the volume "
        "projected after the solve, as before pressure.implicit: 0 489 m/s, 0.2 2.73 m/s). The "
        "block is unchanged where the slip is under about 0.9 "
        "friction_velocity h (0.2), so a sticking contact keeps Newton's exact model (the "
        "capstan tests pass at 0.2; 'irls' lets their sticking rope creep 0.09 mm against "
        "the 0.05 mm bound). The contact rows of the collision pipeline keep the exact block: "
        "there 0.2 left 2 of the 30 frames of tests/test_implicit_contact.py's drop converged "
        "within 100 Newton iterations against 12.")
    edge_endpoint_rows: Literal["keep", "skip", "skip_collider"] = Field(
        "keep", description="Edge-edge contact rows (mesh_contact: energy) whose lagged "
        "closest point is an end of an edge are the same contact as the vertex-face rows of "
        "that end, so at a corner one contact counts several times in the solve's penalty: "
        "'keep' (the default) keeps them; 'skip' leaves every such row out of the Newton "
        "energy (stiffness 0 while its closest point stays at the end; the projection pass "
        "still holds every row); 'skip_collider' only those whose end is a collider's vertex "
        "(both vertices of that edge Dirichlet) against the inside of the other edge (opt-in; "
        "rows with a vertex of a curve are always kept: a strand's edges have no faces whose "
        "vertex-face rows could hold the end). Measured on "
        "graphs/examples/skirt_follow.yaml (the skirt hangs over the body's bottom rim, every "
        "vertex at its contact distance; graphs/bench/implicit_rim.py): at frame 30 the "
        "largest normal forces, 11-17 N each on a 0.05 kg skirt (up to 1,830 N summed over the "
        "rows), sit at the rim, each contact of a skirt vertex there in 1 vertex-face and 4-5 "
        "edge-edge rows with the same gap; Newton ends at its cap (20) in every substep, calm "
        "frames too. Largest skirt speed over 48 frames (Nucleus 0.458 m/s): keep 0.941, skip "
        "0.342, skip_collider 0.529 m/s. But, one run each (NUMBA_NUM_THREADS=1, "
        "graphs/bench/implicit_knee.py; near-joint / crease speeds move with any change "
        "there): sleeve_elbow near the joint keep 1.071, skip 1.347, skip_collider 1.065 m/s "
        "(bound 0.73; largest from frame 8 1.048 / 1.347 / 1.282, bound 1.47); trouser_knee "
        "(72 frames) frames 37-48 1.624 / 1.751 / 2.213 m/s (bound 1.65), from frame 8 2.352 / "
        "3.048 / 2.213 (bound 2.2); sleeve_pinch (compliant_kinematics: energy) from frame 8 "
        "0.140 / 0.079 / 0.098 m/s; 0 intersecting pairs in every frame of every run: not the "
        "default.")
    coupling_iterations: int = Field(
        4, ge=1, le=100, description="Most solid solves per substep when a coupling runs inside "
        "the solver (two-way fluid: Avatar supplement Figure 2, steps A-C repeated until the "
        "fluid velocity at the vertices changes by less than coupling_tolerance) [-].")
    coupling_tolerance: float = Field(
        1e-3, gt=0, description="The coupling loop stops when the fluid velocity it feeds to "
        "drag changes by less than this between two solid solves [m/s].")
    contact_multipliers: bool = Field(
        True, description="Analytic colliders (shape_contact: energy): carry each contact's "
        "normal force over from one substep to the next as an augmented Lagrangian multiplier "
        "(as hard stretch rows do), so that a resting contact's penetration goes to 0 whatever "
        "load presses it; false: the plain penalty (penetration ~ load / contact_stiffness).")
    contact_start: Literal["inertial", "velocity"] = Field(
        "velocity", description="Initial Newton guess of the free vertices with analytic "
        "colliders in the solve: 'inertial' x + h v + h^2 f / m (exact for free particles), "
        "'velocity' x + h v (a resting contact starts where it rests instead of h^2 g inside "
        "the collider, where the lagged normal forces of the first iterations are far off).")
    violated_rows: Literal["hold", "hold_kinematic", "push"] = Field(
        "hold_kinematic", description="Contact rows of the collision pipeline that the start of the "
        "substep already violates (crossed pairs, pairs pressed inside their thickness): "
        "'hold' gives them the target min(target, start gap) in the Newton solve (they stop "
        "approaching; CollisionConstraint's projection pass pushes them back as in Nucleus), "
        "'push' the pipeline's target (their penalty holds energy at the start, which the "
        "solve turns into motion), 'hold_kinematic' holds only the rows with a kinematic "
        "vertex (cloth against animated bodies, compliant ones included) and pushes the others "
        "(self and dynamic-dynamic pairs). Counted per frame as ``held_rows``. Measured on the "
        "stress case 'cloth starting interpenetrated' (crossed.obj, the same for --quick and "
        "full size): with 'hold' the crossed self pairs' recovery push is left to the "
        "projection pass, which moves vertices by up to 1.2 cm (its iterations) and 2.1 cm "
        "(CCD impact zones) in the first two substeps with no elasticity to resist; the hard "
        "stretch rows start substep 2 holding 18.6 J of penalty and 732 J of hard_limit "
        "energy (the 0.2 kg cloth has 0.002 J of kinetic energy), which the Newton solve "
        "turns into motion: +0.0097 J of kinetic energy against 0.0042 J of gravity work in "
        "that substep, 0.0021 J over the stress bound at frame 2 (fails). Kinetic energy minus "
        "the gravity work at frame 2 (its worst frame; the tangle measures stay 37 / 139 in "
        "each): hold +0.0021 J, push -0.0012 J, hold_kinematic -0.0014 J. Sleeve_pinch "
        "(graphs/bench/implicit_knee.py, 60 frames, largest cloth speed from frame 5): hold "
        "0.458 m/s, push 0.517 m/s.")
    start_at_rest: bool = Field(
        True, description="With contact rows of the collision pipeline in the solve, Newton "
        "starts from x^n (free vertices at rest, Dirichlet vertices at their targets) when the "
        "incremental potential is lower there than at the usual initial guess: every accepted "
        "line-search step lowers E, so even a Newton solve stopped at its iteration cap ends "
        "with E (inertia + elastic + contact terms) no higher than at x^n; from the inertial "
        "guess, rows it violates can make E far higher than that "
        "(measured on the stress case 'cloth starting interpenetrated', 16x16: see the "
        "module docstring). Counted per frame as ``rest_starts``.")
    contact_reach: float = Field(
        0.0, ge=0.0, description="Contact rows of the collision pipeline (mesh_contact: "
        "energy) that are inactive at a Newton iterate but within this distance of their "
        "target [m] put their penalty curvature into the Newton matrix (energy and gradient "
        "unchanged), so that a step does not overshoot into contacts it is about to close. "
        "Off by default: on the stress pinch without violated_rows: hold / start_at_rest, 0 "
        "gives ~100 line-search halvings per frame and 0.65 m/s bounces, 0.002 none and "
        "0.14 m/s, but with them on 0.0005 makes the 48x48 stress projectile end with 22 "
        "crossing pairs (module docstring).")
    compliant_kinematics: Literal["dirichlet", "energy"] = Field(
        "energy", description="Compliant kinematic vertices (Kinematic.stiffness > 0): "
        "'dirichlet' holds them at the animated pose in the Newton solve (only the projection "
        "pass after it moves them); 'energy' makes them unknowns of the solve with the goal "
        "spring K/2 |x - x_anim|^2 (an inertia term of mass K h^2 around the animated pose, as "
        "the Nucleus solver's inverse mass), pushed by the contact rows' penalty but not by "
        "their friction. Measured with graphs/bench/implicit_knee.py (largest cloth speed, "
        "dirichlet / energy; 0 intersecting pairs in every frame of both): pinch 1.74 / 0.26 "
        "m/s, sleeve_pinch 0.67 / 0.22 m/s (Nucleus test bound 0.3), but sleeve_elbow 4.7 / "
        "9.1 m/s (bound 1.47; energy to frame 25) and trouser_knee 4.95 / 7.4 m/s over frames "
        "8-25 / 8-19 (bound 2.2), where the compliant surface drifts 1.15 m by frame 23 "
        "(contact forces up to ~100 N against goal springs of ~7 N/m per vertex). Those "
        "figures are with hard_multipliers: always; with converged (the default): pinch 0.32 / "
        "0.267 m/s, sleeve_pinch 0.43 / 0.21 m/s, sleeve_elbow 1.08 / 4.93 m/s (25 frames), "
        "trouser_knee 2.19 / 1.72 m/s but with energy 10 trouser-leg intersecting pairs at "
        "frame 24: hence dirichlet by default then. Remeasured since "
        "(graphs/bench/implicit_knee.py, whole runs, dirichlet / energy): pinch 0.355 / 0.001 "
        "m/s from frame 5 (bound 0.3), "
        "sleeve_pinch 0.458 / 0.140 m/s (bound 0.3), 0 intersecting pairs in each; but "
        "trouser_knee 1.912 m/s in frames 37-48 (bound 1.65) / 2.45 m/s by frame 18 and "
        "intersecting pairs from frame 24 (54, then thousands), sleeve_elbow 0.897 m/s near the "
        "joint (bound 0.73) / pairs from frame 22. Cause measured on the knee: the compliant "
        "vertices, each held by its own goal spring only (K ~7 N/m per vertex here), recede "
        "independently and the compliant surface crumples: 2 inverted triangles at frame 5, 22 at "
        "16, 97 at 23, recession up to 6.4 cm by frame 22 and 14 cm at 23. With the painted "
        "stiffness 10x (2e5) no explosion, but the knee still intersects from frame 28 (40 "
        "pairs) and the elbow keeps 0.888 m/s near the joint (0 pairs, 1.284 m/s overall, "
        "bound 1.47). 'energy' with compliant_depth 0.01 is the default since stop 36: "
        "with it pinch, sleeve_pinch and the whole knee hold their Nucleus bounds, which "
        "dirichlet fails (Field compliant_depth has the figures).")
    compliant_solve: Literal["block", "cg", "cg_identity"] = Field(
        "cg", description="With compliant_kinematics: energy, how the linear solve of a "
        "Newton iteration treats the compliant unknowns (Loki supplement section 1: momentum-free "
        "unknowns whose Newton-matrix rows hold only their diagonal 3x3 block, the goal spring "
        "K I plus the contact rows' blocks, which are block-diagonal): 'block' solves them "
        "apart by the inverse of that block (exact: nothing couples them to the cloth in the "
        "matrix; a compliant vertex whose row holds an off-diagonal block, an energy stencil "
        "through it, stays in CG) and runs CG on the cloth only (its tolerance relative to the "
        "cloth's gradient); 'cg' keeps them in CG with the preconditioner's own treatment "
        "(block-Jacobi: the same blocks); 'cg_identity' keeps them in CG with the identity as "
        "their preconditioner block (block_jacobi only; for measuring what the block gains). "
        "Measured with graphs/bench/implicit_compliant.py (60 frames, interleaved; CG "
        "iterations, CG per Newton iteration, CPU ms per frame, block / cg / cg_identity): "
        "pinch 22,504 / 22,483 / 222,724, 19.2 / 19.7 / 195.9 (the 500 cap reached, worst "
        "relative residual 0.31), 197 / 191 / 271 ms; sleeve_pinch (the cloth's CG at its cap "
        "in most iterations) 1,522,806 / 1,440,383 / 1,620,014, 336 / 322 / 359, 1266 / "
        "1233 / 1311 ms; 0 intersecting pairs with each, lid recession at closure 8.00 mm "
        "with each (tests/test_implicit_compliant.py). 'cg' by default (the solve before, "
        "bitwise): with 'block' the pinch's first frames take more Newton iterations per "
        "substep (frames 3 / 4: 7.75 / 6.25 against 5.2 / 3.8; "
        "tests/test_implicit_pinch.py bounds them at 6).")
    compliant_tangential: Literal["free", "hard"] = Field(
        "free", description="With compliant_kinematics: energy: 'free' the goal spring of a "
        "compliant vertex is the same in every direction; 'hard' it is hard_stiffness times "
        "stiffer across the animated surface normal (the surface recedes along its normal "
        "only). Measured with graphs/bench/implicit_knee.py, free / hard: pinch 0.26 / 0.22 "
        "m/s, sleeve_pinch 0.22 / 0.42 m/s (bound 0.3); trouser_knee at frame 7: the shin's "
        "most displaced compliant vertex moved 3.4 cm (0.4 cm of it inward) / 2.7 cm, all "
        "inward, and by frame 23 the compliant surface had moved up to 1.15 m / receded 15 "
        "cm: neither holds the knee.")
    compliant_depth: float = Field(
        0.01, ge=0.0, description="With compliant_kinematics: energy, the largest recession "
        "of a compliant vertex from its animated pose [m] (0: none; 0.01 by default since stop "
        "36, a soft cap at character scale): beyond it the goal spring "
        "stiffens by compliant_depth_stiffness (the energy k/2 (|x - x_anim| - depth)^2, exact "
        "Hessian; diagonal blocks only). The goal springs alone (~7 N/m per vertex at the knee) "
        "let single vertices recede independently by centimetres and the compliant surface "
        "crumples (Field compliant_kinematics). Measured with graphs/bench/implicit_knee.py "
        "(energy, depth 0.01, whole runs; 0 intersecting pairs in every frame of all four): "
        "trouser_knee 1.573 m/s in frames 37-48 (bound 1.65), 1.720 m/s overall (bound 2.2); "
        "pinch 0.001 m/s, sleeve_pinch 0.201 m/s from frame 5 (bound 0.3); sleeve_elbow 1.141 "
        "m/s (bound 1.47) but 0.928 m/s within 0.15 m of the joint (bound 0.73; remeasured at "
        "stop 36: 1.300 m/s there and overall, frame 43; dirichlet 1.071; 1.097 at depth "
        "0.005, 1.084 at 0.02, 0.837 with compliant_depth_stiffness 100, but then the knee "
        "intersects from frame 26; 1.052 with compliant_tangential: hard). Without it the knee "
        "intersects from frame 24. The cap is soft: the knee's recession still reaches 41 mm "
        "by frame 25 (graphs/bench/implicit_compliant_diag.py), with at most 7 inverted "
        "triangles to frame 26 against 97 at frame 23 without it. Tried "
        "first and not kept: starting each substep's compliant unknowns from their animation "
        "(kinematic_q_prev, as Nucleus predicts them): knee pairs from frame 18, and with "
        "depth 0.02 from frame 12; clamping the projection pass's result to the depth: knee "
        "pairs from frame 12. Soft: the pinch's closure still takes 8.0 mm at depth 6 mm "
        "(tests/test_implicit_compliant.py).")
    compliant_depth_stiffness: float = Field(
        1e3, gt=0.0, description="compliant_depth: the stiffness beyond the depth as a multiple "
        "of the compliant vertex's goal spring K [-].")
    compliant_shape_stiffness: float = Field(
        0.0, ge=0.0, description="With compliant_kinematics: energy, the stiffness s [-] "
        "between neighbouring compliant unknowns (0: none): over the collider mesh's edges "
        "whose two vertices are compliant, the energy s K_e / 2 |u_a - u_b|^2 with u = x - "
        "x_anim and K_e the mean goal spring of the two (a Laplacian smoothing of the "
        "recession, exact Hessian with off-diagonal blocks; behaviors/solvers/implicit/"
        "compliant.py), so that a dent spreads over about sqrt(s) edges instead of one vertex "
        "crumpling the surface. Measured with graphs/bench/implicit_compliant_shape.py (energy, "
        "compliant_depth 0.01, whole runs, s = 0 / 10 / 100; 0 intersecting pairs in every "
        "frame of all): trouser_knee frames 37-48 1.573 / 1.550 / 1.448 m/s (bound 1.65); "
        "pinch 0.001 / 0.000 / 0.000; but sleeve_pinch 0.201 / 0.379 / 0.446 (bound 0.3; "
        "0.254 / 0.286 at s = 1 / 3) and sleeve_elbow near the joint 0.928 / 1.006 / 1.473 "
        "(bound 0.73; 1.025 / 1.703 / 1.368 at s = 1 / 3 / 1000): the "
        "coupling spreads the load so that the per-vertex depth cap no longer engages and the "
        "whole patch recedes (sleeve_elbow mean recession 10 mm by frame 8 at s = 100 against "
        "1.9 mm at 0). Opt-in: no value meets all four bounds.")
    hard_multipliers: Literal["converged", "always"] = Field(
        "converged", description="Augmented Lagrangian update of the hard rows' multipliers "
        "(lam += k C, inextensible stretch, welds) after a substep: 'always' after every "
        "substep; 'converged' not after a substep whose Newton solve had contacts in it "
        "(analytic colliders or contact rows) and stopped at contact_newton_iterations without "
        "converging (counted per frame as ``kept_multipliers``; scenes without contacts, and "
        "substeps that converge, are unchanged). The update assumes the solve reached the "
        "minimum of its subproblem; where contacts jam an inextensible cloth against moving "
        "Dirichlet bodies and Newton does not converge, it integrates the unconverged violation "
        "(and the projection pass's moves) substep after substep. Measured with "
        "graphs/bench/implicit_knee.py, always / converged: trouser_knee's largest stretch "
        "multiplier 10 N at frame 2, 1,660 N / 0 N by frame 17, its cloth speed over frames "
        "8-25 4.95 / 2.19 m/s (Nucleus test bound 2.2), sleeve_elbow 4.67 / 1.08 m/s (bound "
        "1.47); updating every substep at the Newton solution instead of after the projection "
        "pass: knee 5.5 m/s, elbow 4.7 m/s.")
    hard_limit: float = Field(
        0.02, ge=0.0, description="Strain |e| / L - 1 above which a hard distance row "
        "(inextensible stretch, hard stitches) gets the extra energy hard_limit_stiffness * k / "
        "2 * (|e| - (1 + hard_limit) L)^2 in the Newton solve (k its hard penalty; a one-sided "
        "strain limit inside the solve, exact Hessian; 0: off) [-]. Cause measured with "
        "graphs/bench/implicit_drop.py (cloth on a sphere mesh, 1 substep): at impact the hard "
        "rows hold by their penalty alone (Newton stops at its cap in every impact substep, "
        "so hard_multipliers: converged keeps the multipliers, and they lag a sudden load "
        "anyway), and the penalty's strain grows with the square of the resolution. Worst edge "
        "strain 64x64 (24 frames) / 128x128 (11 frames): 6.8 % / 7.0 % off, 2.6 % / 4.8 % at "
        "0.02, 128x128 at 0.01 5.0 % (3.6 % in the Newton solution, the projection pass "
        "stretches the rest); hard_stiffness 1e5 instead: 64x64 2.1 % (10 frames) at twice "
        "the CG iterations; hard_multipliers: always 4.7 %, more augmented Lagrangian updates "
        "within the substep (2 / 4 Newton solves) 3.5 % / 9.3 %. Trouser knee (25 frames) "
        "2.19 -> 1.60 m/s, sleeve elbow 0.84 m/s from frame 8.")
    compliant_carry: float = Field(
        0.0, ge=0.0, le=1.0, description="With compliant_kinematics: dirichlet: the fraction "
        "r of its last recession a compliant vertex keeps in the next Newton solve (its "
        "Dirichlet target is the animated pose plus r times where the projection pass left it "
        "relative to the last substep's animated pose; 0: the animated pose, as Nucleus "
        "predicts it) [-]. Cause measured on graphs/examples/pinch.yaml (4 substeps): the "
        "projection pass lets the compliant lid recede by up to 1.2 cm per substep around "
        "frame 25, the next Newton solve puts it back on its animation into the cloth, which "
        "it squeezes again (Newton at its cap, cloth speeds 0.4-0.53 m/s in the Newton "
        "solutions of frames 25-26). Largest cloth speed from frame 5 (implicit_knee.py, 60 "
        "frames): pinch 0.355 m/s at 0, 0.144 m/s at 0.5 (the lid recedes 9.5 mm at frame 25 "
        "and is back on its animation over the last 10 frames, 0 intersecting pairs), 0.011 "
        "m/s at 1 (40 frames); but sleeve_pinch 0.458 / 0.554 m/s and sleeve_elbow 1.11 / "
        "1.25 m/s at 0 / 0.5: off by default.")
    hard_limit_stiffness: float = Field(
        100.0, gt=0, description="hard_limit: the extra stiffness of a row stretched past the "
        "limit, as a multiple of its hard penalty [-] (64x64 drop: 2.6 % at 100, 5.5 % at 10).")
    jam_penetration: float = Field(
        1e-4, gt=0, description="With hard_multipliers: converged, the hard rows' multipliers "
        "are also kept after a substep whose contact rows end the Newton solve penetrated by "
        "more than this [m] (``max_complementarity``): at a converged solve a feasible contact "
        "presses in by load / contact stiffness (measured at most 3.9e-5 m on the 16 x 16 "
        "cloth resting on a sphere mesh, tests/test_implicit_contact.py), a jammed one (the "
        "contact penalty balancing hard rows pulled by Dirichlet bodies) by frame maxima of "
        "0.2-9 mm (trouser_knee with contact_newton_iterations 100, where some substeps "
        "converge): "
        "raising the multipliers there only pushes the contacts deeper.")
    contact_tolerance: float = Field(1e-4, gt=0, lt=1, description="Newton does not stop while "
                                     "the lagged normal forces of the contacts change by more "
                                     "than this fraction of the largest one [-]; for the "
                                     "contact rows of the collision pipeline, unless every "
                                     "change over its row's stiffness (the gap change it "
                                     "stands for) is below newton_tolerance * h: measured on "
                                     "graphs/examples/pinch.yaml at rest (normal forces ~3e-4 N), "
                                     "the lagged forces cycle by 4e-5 N (12 %) while the steps "
                                     "are 7e-8 m/s, so the fraction alone kept every substep at "
                                     "the Newton cap.")


@dataclass
class _ImplicitData:
    damp_rate: np.ndarray
    keyed_damping: list
    fixed: np.ndarray  # bool per vertex: Dirichlet
    #: mass of the inertia term per vertex [kg]: the particle mass, and K h^2 (1 / inverse mass)
    #: for compliant kinematic vertices in the solve (their goal spring K/2 |x - x_anim|^2)
    inertia: np.ndarray
    compliant: np.ndarray  # bool per vertex: compliant kinematic vertex in the solve
    #: compliant vertices in the solve: global indices, the triangles (global) of their
    #: elements, and their animated surface normals (refreshed every substep)
    comp_idx: np.ndarray | None = None
    comp_tris: np.ndarray | None = None
    comp_nrm: np.ndarray | None = None
    ready: bool = False
    energies: list = field(default_factory=list)  # (behavior, data, maps, hloc list)
    gather: list = field(default_factory=list)  # per energy, per stencil set: gather_map
    projected: list = field(default_factory=list)
    A: object = None
    diag: np.ndarray | None = None
    fixed_blocks: np.ndarray | None = None
    fixed_diag: np.ndarray | None = None
    brow: np.ndarray | None = None  # block row of every stored block
    cur_fixed: np.ndarray | None = None  # Dirichlet set of the current Newton solve
    precond: object = None
    work: dict = field(default_factory=dict)
    shapes: tuple | None = None  # (kinds, centers, dirs, radii, lengths, mus) of contact energy
    contact: dict = field(default_factory=dict)  # kc, lam, nrm, lam_prev, dummies
    mesh: bool = False  # contact rows of CollisionDetect in the Newton solve
    rows: dict = field(default_factory=dict)  # grow-only buffers and this substep's views
    couplings: list = field(default_factory=list)  # SolverCoupling objects (model.data)
    carry: np.ndarray | None = None  # compliant vertices held as Dirichlet (compliant_carry)
    #: compliant unknowns solved apart from CG by their diagonal block (compliant_solve: block):
    #: indices, their diagonal block numbers, the inverse blocks and the right-hand side
    elim: np.ndarray | None = None
    elim_diag: np.ndarray | None = None
    elim_inv: np.ndarray | None = None
    elim_rhs: np.ndarray | None = None
    all_on: np.ndarray | None = None  # True per vertex (violated_rows: hold)
    #: ``edge_endpoint_rows`` per vertex for the lag kernels (int8): its mode at the vertices
    #: of elements with triangles, 0 at the others (curves: their edges have no faces); the
    #: empty ``NO_ENDPOINTS`` with 'keep'
    endpoints: np.ndarray = field(default_factory=lambda: NO_ENDPOINTS)
    #: compliant_shape_stiffness: the compliant edges (m, 2), their mean goal-spring mass
    #: (K h^2) and their (m, 2, 2) block map
    shape_edges: np.ndarray | None = None
    shape_kbar: np.ndarray | None = None
    shape_map: np.ndarray | None = None
    #: per Newton iteration diagnostics (a list a bench script sets; None: off), ``_trace``
    trace: list | None = None
    #: rank-one Hessian terms k g g^T of global rows (the volume rows of PressureConstraint,
    #: ``energy_lowrank``): the energies that give them, and per term its g masked at the
    #: Dirichlet vertices (m, n, 3) and k (m,), refreshed with the Newton matrix; ``lowrank``
    #: (U, k) for the linear solve while there are terms, else None
    lr_energies: list = field(default_factory=list)
    lr_U: np.ndarray | None = None
    lr_k: np.ndarray | None = None
    lowrank: tuple | None = None


class ImplicitSolver(Behavior):
    """Backward Euler by Newton + PCG on the incremental potential (see module docstring)."""

    stage = "solve"
    solver = "implicit"
    requires = (Dynamic,)
    reads_optional = ("particle_f", "constraints", "kinematic_q", "drag")
    writes = ("particle_q", "particle_qd")
    ParamsModel = ImplicitParams

    def bind(self, ctx, elements):
        m = ctx.model
        damp, keyed = bind_damping(m, elements)
        compliant = m.particle_compliant & (m.particle_inv_mass > 0)
        if self.params.compliant_kinematics == "dirichlet":
            compliant = np.zeros_like(compliant)
        fixed = (m.particle_kinematic & ~compliant) | (m.particle_inv_mass <= 0)
        inertia = m.particle_mass.astype(np.float64)
        if compliant.any():
            inertia = inertia.copy()
            inertia[compliant] = 1.0 / m.particle_inv_mass[compliant]
        d = _ImplicitData(damp, keyed, fixed, inertia, compliant)
        dc = m.particle_compliant & m.particle_kinematic & ~compliant
        d.carry = np.flatnonzero(dc) if dc.any() else None
        d.all_on = np.ones(m.particle_count, dtype=np.bool_)
        mode = ENDPOINTS[self.params.edge_endpoint_rows]
        if mode:
            d.endpoints = np.zeros(m.particle_count, dtype=np.int8)
            for e in ctx.scene.elements:
                if e.geometry is not None and e.vertex_count and len(e.geometry.triangles):
                    d.endpoints[e.vertex_slice] = mode
        if compliant.any():
            d.comp_idx = np.flatnonzero(compliant)
            tris = [np.asarray(e.geometry.triangles, dtype=np.int64) + e.vertex_offset
                    for e in ctx.scene.elements
                    if e.geometry is not None and e.vertex_count
                    and compliant[e.vertex_slice].any() and len(e.geometry.triangles)]
            d.comp_tris = np.concatenate(tris) if tris else np.zeros((0, 3), np.int64)
            d.comp_nrm = np.zeros((len(d.comp_idx), 3))
        ns = (sum(1 for e in ctx.scene.elements if e.has(ShapeCollider))
              if self.params.shape_contact == "energy" else 0)
        d.contact = self._contact_state(m.particle_count, ns)
        return d

    @staticmethod
    def _contact_state(n, ns):
        """The run state of the analytic-collider contacts (checkpointed): multipliers, lagged
        normal forces and normals per (vertex, shape); scratch buffers."""
        return {"kc": np.zeros(n), "lam": np.zeros((n, ns)), "mult": np.zeros((n, ns)),
                "lam_prev": np.zeros((n, ns)), "nrm": np.zeros((n, ns, 3)),
                "g1": np.zeros((1, 3)), "A1": np.zeros((1, 3, 3)), "active": 0}

    def state_arrays(self, data):
        """Checkpointed run state: the contact multipliers [N], lagged normal forces [N] and
        normals of the analytic colliders in the solve (the hard rows' multipliers are their
        behaviors' state)."""
        C = data.contact if data is not None else {}
        if not C or C["mult"].shape[1] == 0:
            return {}
        return {"contact_mult": C["mult"], "contact_lam": C["lam"], "contact_nrm": C["nrm"]}

    def load_state_arrays(self, data, arrays):
        for k in ("mult", "lam", "nrm"):
            if f"contact_{k}" in arrays:
                data.contact[k][...] = arrays[f"contact_{k}"]

    # -- first substep: sort the constraint types, build the Hessian pattern -----------------
    def _prepare(self, ctx, d):
        n = ctx.model.particle_count
        energies, projected, stencils = [], [], []
        shapes = []
        for b, bd in ctx.constraints:
            name = type(b).__name__
            if name == "ShapeCollisionConstraint" and self.params.shape_contact == "energy":
                if bd is not None and len(bd.kinds):
                    shapes.append(bd)
                continue
            if hasattr(b, "energy") and hasattr(b, "energy_stencils"):
                st = [np.ascontiguousarray(s, dtype=np.int64) for s in b.energy_stencils(ctx, bd)]
                if not st and name in PROJECTED_TYPES:  # not in the solve in this scene
                    projected.append((b, bd))  # (strain limits' ``implicit: projection``)
                    continue
                energies.append([b, bd, st])
                stencils.extend(st)
                if hasattr(b, "implicit_project") or name in PROJECTED_TYPES:
                    projected.append((b, bd))  # safety projection after the solve
            elif name in PROJECTED_TYPES:
                projected.append((b, bd))
            elif name in NOT_NEEDED:
                continue
            else:
                raise InputError(f"the implicit solver cannot run constraint {b.name!r} "
                                 f"({name}): it has no implicit energy and no projection; "
                                 f"remove it from the scene or use solver: nucleus")
        if d.comp_idx is not None and self.params.compliant_shape_stiffness > 0.0:
            d.shape_edges = compliant_edges(d.comp_tris, d.compliant)
            d.shape_kbar = 0.5 * d.inertia[d.shape_edges].sum(axis=1)
            stencils.append(d.shape_edges)
        indptr, indices, diag, maps = build_pattern(n, stencils)
        if d.shape_edges is not None:
            d.shape_map = maps.pop()
        nb = len(indices)
        data = np.zeros((nb, 3, 3))
        d.A = sp.bsr_matrix((data, indices, indptr), shape=(3 * n, 3 * n), blocksize=(3, 3))
        if not np.shares_memory(d.A.data, data):  # pragma: no cover - scipy keeps it today
            raise RuntimeError("scipy copied the BSR data array")
        k = 0
        d.gather = []
        for e in energies:
            ns = len(e[2])
            e.append(maps[k:k + ns])
            # per stencil set the blocks' gather map (energy.gather_blocks: the scatter,
            # matrix block by block)
            d.gather.append([gather_map(mp, nb) for mp in maps[k:k + ns]])
            e.append([np.zeros((s.shape[0], s.shape[1], s.shape[1], 3, 3)) for s in e[2]])
            k += ns
        d.energies = energies
        d.lr_energies = [(e[0], e[1]) for e in energies if hasattr(e[0], "energy_lowrank")]
        m_lr = sum(len(b.energy_lowrank(bd)) for b, bd in d.lr_energies)
        if m_lr:
            d.lr_U = np.zeros((m_lr, n, 3))
            d.lr_k = np.zeros(m_lr)
        d.projected = projected
        d.diag = diag
        d.brow = np.repeat(np.arange(n), np.diff(indptr))
        if d.comp_idx is not None and self.params.compliant_solve == "block":
            # compliant unknowns whose Newton-matrix row holds only the diagonal block
            ci = d.comp_idx
            alone = np.diff(indptr)[ci] == 1
            if alone.any():
                d.elim = ci[alone]
                d.elim_diag = diag[d.elim]
                d.elim_inv = np.zeros((len(d.elim), 3, 3))
                d.elim_rhs = np.zeros((len(d.elim), 3))
        if (d.comp_idx is not None and self.params.compliant_solve == "cg_identity"
                and self.params.preconditioner != "block_jacobi"):
            raise InputError("compliant_solve: cg_identity needs preconditioner: block_jacobi")
        P = self.params
        d.precond = (Identity(n) if P.preconditioner == "none" else
                     Direct(n) if P.preconditioner == "direct" else
                     SmoothedAggregation(n) if P.preconditioner == "amg" else
                     AggregationReuse(n, P.amg_smooth, P.amg_rebuild_growth,
                                      cycle=P.amg_cycle) if P.preconditioner == "amg_reuse"
                     else BlockJacobi(n))
        d.work = {k: np.zeros((n, 3)) for k in ("r", "z", "p", "g", "dx", "xt", "xs", "x0",
                                               "du", "Ap", "pp")}
        d.couplings = [getattr(v, "solver_coupling", None) for v in ctx.model.data.values()]
        d.couplings = [c for c in d.couplings if c is not None]
        d.mesh = (self.params.mesh_contact == "energy"
                  and any(type(b).__name__ == "CollisionConstraint" for b, _ in projected))
        if shapes:
            d.shapes = tuple(np.ascontiguousarray(np.concatenate([getattr(b, f) for b in shapes]))
                             for f in ("kinds", "centers", "dirs", "radii", "lengths", "mus"))
            ns = len(d.shapes[0])
            if d.contact.get("mult") is None or d.contact["mult"].shape != (n, ns):
                d.contact = self._contact_state(n, ns)  # (bind counts the colliders)
        d.ready = True

    # -- energy, gradient and Hessian of the incremental potential ---------------------------
    def _potential(self, ctx, d, x, mode, opts, xt, grad):
        """E(x); with mode >= 1 the gradient into ``grad``; with mode 2 the Newton matrix."""
        h = ctx.dt
        mass = d.inertia  # particle masses; K h^2 at compliant vertices in the solve
        free = ~d.cur_fixed
        dxt = x - xt
        E = 0.5 / (h * h) * float(np.einsum("i,ij,ij->", mass * free, dxt, dxt))
        if mode >= 1:
            np.multiply(dxt, (mass * free / (h * h))[:, None], out=grad)
        if d.comp_idx is not None and _tangential_ratio(self) > 0.0:
            # compliant vertices recede along their animated surface normal only: the goal
            # spring across the normal is hard_stiffness times stiffer
            ci, cn = d.comp_idx, d.comp_nrm
            dc = dxt[ci]
            dt_ = dc - np.einsum("ij,ij->i", dc, cn)[:, None] * cn
            kt = (_tangential_ratio(self) - 1.0) * mass[ci] / (h * h)
            E += 0.5 * float(np.einsum("i,ij,ij->", kt, dt_, dt_))
            if mode >= 1:
                grad[ci] += kt[:, None] * dt_
        depth = self.params.compliant_depth if d.comp_idx is not None else 0.0
        if depth > 0.0:  # compliant_depth: k/2 (|x - x_anim| - depth)^2 beyond the depth
            ci = d.comp_idx
            dc = dxt[ci]
            r = np.sqrt(np.einsum("ij,ij->i", dc, dc))
            over = np.maximum(r - depth, 0.0)
            kd = self.params.compliant_depth_stiffness * mass[ci] / (h * h)
            E += 0.5 * float(np.dot(kd, over * over))
            deep = over > 0.0
            if mode >= 1 and deep.any():
                u = dc[deep] / r[deep, None]
                grad[ci[deep]] += (kd[deep] * over[deep])[:, None] * u
        D = ctx.state.fields.get("drag_D")
        if D is not None:
            du = x - d.work["x0"] - h * ctx.state.fields["drag_u"]
            Ddu = np.einsum("nij,nj->ni", D, du)
            Ddu[d.cur_fixed] = 0.0
            E += 0.5 / h * float(np.vdot(du, Ddu))
            if mode >= 1:
                grad += Ddu / h
        opts.mode = mode
        if mode >= 2:
            A = d.A.data
            A[:] = 0.0
            for (b, bd, st, maps, hloc), gmaps in zip(d.energies, d.gather):
                for hl in hloc:
                    hl[:] = 0.0
                E += b.energy(ctx, bd, x, grad, hloc, opts)
                for (ptr, src), hl in zip(gmaps, hloc):
                    gather_blocks(A, ptr, src, hl)
            E += self._limit_energy(d, x, mode, opts, grad, A)
            if d.lr_U is not None:
                self._lowrank_blocks(d, A)
            if d.shape_edges is not None:  # compliant_shape_stiffness
                E += shape_energy(x, xt, d.shape_edges, d.shape_kbar,
                                  self.params.compliant_shape_stiffness / (h * h), 2, grad, A,
                                  d.shape_map)
            diag = A[d.diag]
            eye = np.eye(3)
            diag += (mass / (h * h))[:, None, None] * eye
            if d.comp_idx is not None and _tangential_ratio(self) > 0.0:
                ci, cn = d.comp_idx, d.comp_nrm
                kt = (_tangential_ratio(self) - 1.0) * mass[ci] / (h * h)
                diag[ci] += kt[:, None, None] * (eye - cn[:, :, None] * cn[:, None, :])
            if depth > 0.0 and deep.any():  # k (u u^T + (1 - depth / r) (I - u u^T))
                uu = u[:, :, None] * u[:, None, :]
                f = (over[deep] / r[deep])[:, None, None]
                diag[ci[deep]] += kd[deep, None, None] * (uu + f * (eye - uu))
            if D is not None:
                diag += D / h
            A[d.diag] = diag
            A[d.fixed_blocks] = 0.0
            A[d.fixed_diag] = eye
        else:
            for b, bd, st, maps, hloc in d.energies:
                E += b.energy(ctx, bd, x, grad if mode >= 1 else None, None, opts)
            E += self._limit_energy(d, x, mode, opts, grad if mode >= 1 else opts.dummy_grad,
                                    d.A.data)
            if d.shape_edges is not None:
                E += shape_energy(x, xt, d.shape_edges, d.shape_kbar,
                                  self.params.compliant_shape_stiffness / (h * h), mode,
                                  grad if mode >= 1 else opts.dummy_grad, d.A.data, d.shape_map)
        if d.rows.get("sets"):
            g1 = grad if mode >= 1 else d.rows["g1"]
            A1 = d.A.data if mode >= 2 else d.rows["A1"]
            irls = self.params.friction_hessian == "irls"
            coupled = self.params.contact_hessian == "coupled"
            eps = self.params.friction_velocity * h
            for (rows, nrm, tgt, mu, coef, kr, lam, _lp, _vf, _mk, sel, ns), hot in zip(
                    d.rows["sets"], d.rows["hot"]):
                E += row_energy_coupled(x, d.work["x0"], d.cur_fixed, rows, nrm, tgt, coef,
                                        kr, lam, mu, eps, mode, g1, A1, d.diag, irls,
                                        self.params.contact_reach, xt, d.compliant,
                                        sel[:ns[0]], d.A.indptr, d.A.indices, coupled, hot)
        if d.shapes is not None:
            C = d.contact
            E += contact_energy_al(x, d.work["x0"], d.cur_fixed, *d.shapes, C["kc"], C["mult"],
                                   C["lam"], C["nrm"], self.params.friction_velocity * h, mode,
                                   grad if mode >= 1 else C["g1"],
                                   d.A.data if mode >= 2 else C["A1"], d.diag,
                                   1.0 if self.params.friction_hessian == "irls"
                                   else self.params.friction_slip_curvature)  # skips Dirichlet
        if mode >= 1:
            grad[d.cur_fixed] = 0.0
        return E

    def _lowrank_blocks(self, d, A):
        """The rank-one terms k g g^T of this Newton matrix (``energy_lowrank``, read after the
        energies' mode-2 evaluation): g masked at the Dirichlet vertices into ``lr_U``, the
        per-vertex diagonal blocks k g_i g_i^T added to A's diagonal blocks (the linear solve
        adds the rest, k g (g . v) less those blocks, in its matrix product:
        ``linear.lowrank_matvec``)."""
        j = 0
        free = ~d.cur_fixed
        for b, bd in d.lr_energies:
            for k, g in b.energy_lowrank(bd):
                U = d.lr_U[j]
                np.multiply(g, free[:, None], out=U)
                d.lr_k[j] = k
                if k != 0.0 and LOWRANK_DIAG:
                    A[d.diag] += k * (U[:, :, None] * U[:, None, :])
                j += 1
        d.lowrank = ((d.lr_U, d.lr_k, 1.0 if LOWRANK_DIAG else 0.0) if (d.lr_k != 0.0).any()
                     else None)

    def _matvec(self, d, v):
        """The Newton matrix times v (n, 3), rank-one terms included."""
        Av = (d.A @ v.reshape(-1)).reshape(-1, 3)
        if d.lowrank is not None:
            lowrank_matvec(v, Av, *d.lowrank)
        return Av

    def step(self, ctx, data):
        d = data
        if not d.ready:
            self._prepare(ctx, d)
        m, st, ctl = ctx.model, ctx.state, ctx.control
        h = ctx.dt
        P = self.params
        x, v = st.particle_q, st.particle_qd
        apply_damping(ctx, v, d.damp_rate, d.keyed_damping)
        for b, bd in ctx.constraints:
            b.begin_substep(ctx, bd)
        w = d.work
        x0 = w["x0"]
        x0[:] = x
        # x~ = x + h v + h^2 f / m (free vertices); Dirichlet vertices at their target
        xt = w["xt"]
        np.multiply(st.particle_f, (h * h * m.particle_inv_mass)[:, None], out=xt)
        xt += h * v
        xt += x
        kin = m.particle_kinematic
        if kin.any():
            xt[kin] = ctl.kinematic_q[kin]
            if P.compliant_carry > 0.0 and d.carry is not None:  # keep part of the recession
                ci = d.carry
                xt[ci] += P.compliant_carry * (x[ci] - ctl.kinematic_q_prev[ci])
        if d.comp_idx is not None and _tangential_ratio(self) > 0.0:  # only 'hard' reads them
            self._compliant_normals(d, ctl.kinematic_q)
        xs = w["xs"]
        xs[:] = xt  # initial guess: the inertial prediction (exact for free particles)
        if d.shapes is not None and P.contact_start == "velocity":  # free vertices: x + h v
            np.multiply(v, h, out=xs)
            xs += x
            np.copyto(xs, xt, where=(d.fixed | d.compliant)[:, None])
        opts = EnergyOptions(2, P.hard_stiffness * m.particle_mass / (h * h), h,
                             np.zeros((1, 3)), np.zeros((1, 1, 1, 3, 3)))
        counts = {"newton": 0, "cg": 0, "halvings": 0, "cg_max": 0, "cg_res": 0.0,
                  "step_v": 0.0, "coupling": 0, "rest_starts": 0,
                  "held_rows": 0, "capped": 0, "cut_steps": 0}
        self._set_fixed(d, d.fixed)
        if d.shapes is not None:
            np.multiply(m.particle_mass, P.contact_stiffness / (h * h), out=d.contact["kc"])
        self._bind_rows(ctx, d)
        if d.couplings:  # Figure 2 of the Avatar supplement: solid solve <-> fluid, repeated
            for cp in d.couplings:
                cp.begin(ctx)
            for _ in range(P.coupling_iterations):
                self._newton(ctx, d, xs, xt, opts, counts)
                counts["coupling"] += 1
                change = max(cp.iterate(ctx, x0, xs, xt) for cp in d.couplings)
                if change < P.coupling_tolerance:
                    break
            ctx.stats["max_coupling_change"] = max(ctx.stats.get("max_coupling_change", 0.0),
                                                   change)
        elif (d.energies or st.fields.get("drag_D") is not None or d.shapes is not None
                or d.rows.get("sets")):
            self._newton(ctx, d, xs, xt, opts, counts)
        p = xs
        jammed = False
        if d.rows.get("sets"):  # complementarity of the rows at the Newton solution
            jammed = self._row_residuals(ctx, d, p, xt) > P.jam_penetration
        for b, bd in ctx.constraints:  # statistics of the Newton solution (volume rows)
            if hasattr(b, "implicit_solved"):
                b.implicit_solved(ctx, bd, p)
        if d.projected:
            pp = w["pp"]
            pp[:] = p
            self._project(ctx, d, p)
            pp -= p
            moved = float(np.sqrt(np.einsum("ij,ij->i", pp, pp).max())) if len(pp) else 0.0
            ctx.stats["max_projection_move"] = max(ctx.stats.get("max_projection_move", 0.0),
                                                   moved)
        if d.shapes is not None:  # safety projection: no vertex ends inside a shape
            if P.contact_multipliers:  # augmented Lagrangian update at the solved positions
                update_contact_multipliers(p, d.cur_fixed, *d.shapes[:5], d.contact["kc"],
                                           d.contact["mult"])
            moved = safety_project(p, d.cur_fixed, *d.shapes[:5])
            s = ctx.stats
            s["active_contacts"] = s.get("active_contacts", 0) + d.contact["active"]
            s["max_active_contacts"] = max(s.get("max_active_contacts", 0), d.contact["active"])
            s["max_contact_projection"] = max(s.get("max_contact_projection", 0.0), moved)
        if d.rows.get("sets"):
            s = ctx.stats
            s["contact_rows"] = s.get("contact_rows", 0) + d.rows["active"]
            s["max_contact_rows"] = max(s.get("max_contact_rows", 0), d.rows["active"])
        for b, bd in ctx.constraints:  # statistics of the substep's end (volume rows)
            if hasattr(b, "implicit_end_substep"):
                b.implicit_end_substep(ctx, bd, p)
        done = {id(b) for b, _ in d.projected}  # their after_finalize ran in the pass
        for b, bd, *_ in d.energies:  # per-substep hooks on the final positions (the rods'
            if hasattr(b, "after_finalize") and id(b) not in done:  # material-frame twist)
                b.after_finalize(ctx, bd, p)
        if P.hard_multipliers == "always" or not (counts["capped"] or jammed):
            for b, bd, *_ in d.energies:  # augmented Lagrangian multipliers of hard rows
                if hasattr(b, "energy_update_multipliers"):
                    b.energy_update_multipliers(ctx, bd, p, opts)
        else:
            ctx.stats["kept_multipliers"] = ctx.stats.get("kept_multipliers", 0) + 1
        np.subtract(p, x, out=v)
        v *= 1.0 / h
        x[:] = p
        s = ctx.stats
        c = counts
        s["newton_iterations"] = s.get("newton_iterations", 0) + c["newton"]
        s["cg_iterations"] = s.get("cg_iterations", 0) + c["cg"]
        s["line_search_halvings"] = s.get("line_search_halvings", 0) + c["halvings"]
        s["max_newton_iterations"] = max(s.get("max_newton_iterations", 0), c["newton"])
        s["max_cg_iterations"] = max(s.get("max_cg_iterations", 0), c["cg_max"])
        s["max_newton_step"] = max(s.get("max_newton_step", 0.0), c["step_v"])
        s["max_cg_residual"] = max(s.get("max_cg_residual", 0.0), c["cg_res"])
        if c["cut_steps"]:
            s["cut_steps"] = s.get("cut_steps", 0) + c["cut_steps"]
        if c["held_rows"]:
            s["held_rows"] = s.get("held_rows", 0) + c["held_rows"]
        if c["rest_starts"]:
            s["rest_starts"] = s.get("rest_starts", 0) + c["rest_starts"]
        if c["coupling"]:
            s["coupling_iterations"] = s.get("coupling_iterations", 0) + c["coupling"]
            s["max_coupling_iterations"] = max(s.get("max_coupling_iterations", 0),
                                               c["coupling"])

    def _bind_rows(self, ctx, d):
        """This substep's contact rows (CollisionDetect's packed sets) as views of grow-only
        buffers: coefficients, stiffness, lagged normal forces."""
        d.rows["sets"] = []
        d.rows["hot"] = []  # per set: the rows' contact_sticky flags (uint8)
        d.rows.setdefault("hotbuf", {})
        if not d.mesh:
            return
        c = ctx.state.fields.get("contacts")
        if c is None:
            return
        if "g1" not in d.rows:
            d.rows.update(g1=np.zeros((1, 3)), A1=np.zeros((1, 3, 3)), active=0,
                          buf={"vf": None, "ee": None})
        for kind, rows, nrm, tgt, mu in (("vf", c.vf, c.vf_n, c.vf_target, c.vf_mu),
                                         ("ee", c.ee, c.ee_n, c.ee_target, c.ee_mu)):
            m = len(rows)
            if m == 0:
                continue
            buf = d.rows["buf"][kind]
            if buf is None or buf[0].shape[0] < m:
                cap = max(64, 2 * m)
                buf = (np.zeros((cap, 4)), np.zeros(cap), np.zeros(cap), np.zeros(cap),
                       np.zeros(cap), np.zeros(cap, np.uint8), np.zeros(cap, np.int64),
                       np.zeros(1, np.int64))
                d.rows["buf"][kind] = buf
            if self.params.violated_rows != "push":  # the solve's targets (start_targets)
                tgt_solve = buf[4][:m]
                tgt_solve[:] = tgt
            else:
                tgt_solve = tgt
            d.rows["sets"].append((rows, nrm, tgt_solve, mu, buf[0][:m], buf[1][:m],
                                   buf[2][:m], buf[3][:m], kind == "vf", buf[5][:m],
                                   buf[6][:m], buf[7]))
            hot = d.rows["hotbuf"].get(kind)
            if hot is None or hot.shape[0] < m:
                hot = d.rows["hotbuf"][kind] = np.zeros(buf[0].shape[0], np.uint8)
            hot = hot[:m]
            if self.params.contact_sticky:  # rows new every substep: none active yet
                hot[:] = 0
            d.rows["hot"].append(hot)

    def _lag_rows(self, ctx, d, x, live=False, on_segment=False):
        """Lag coefficients and normal forces of the contact rows at x; returns
        (active rows, largest |change| of a normal force [N], largest normal force [N],
        largest |change| of a normal force over its row's stiffness [m]). With ``live`` only
        the rows live at x (``lag_rows_live``; the others are inactive at x, whatever their
        coefficients) are lagged and listed for ``row_energy``; otherwise every row. With
        ``on_segment`` (and ``live``, contact_reach 0) x lies on the segment that
        ``_extend_live`` has just visited, and only the rows it listed are visited
        (``lag_rows_sel``, the same results)."""
        h = ctx.dt
        m = ctx.model
        h2k = self.params.contact_stiffness / (h * h)
        ep = d.endpoints
        act, dl, top, dgap = 0, 0.0, 0.0, 0.0
        for rows, nrm, tgt, mu, coef, kr, lam, lam_prev, is_vf, mark, sel, ns in d.rows["sets"]:
            if live and on_segment and self.params.contact_reach == 0.0:
                a, ns[0], dl1, top1, dgap1 = lag_rows_sel(
                    x, d.cur_fixed, m.particle_mass, h2k, rows, nrm, tgt, is_vf, coef, kr, lam,
                    0.0, mark, sel, ns[0], ep)
                act += a
                dl, top, dgap = max(dl, dl1), max(top, top1), max(dgap, dgap1)
                continue
            if live:  # the changes of the live rows (the others have lam 0 before and after)
                a, ns[0], dl1, top1, dgap1 = lag_rows_live(
                    x, d.cur_fixed, m.particle_mass, h2k, rows, nrm, tgt, is_vf, coef, kr, lam,
                    self.params.contact_reach, mark, sel, ep)
                act += a
                dl, top, dgap = max(dl, dl1), max(top, top1), max(dgap, dgap1)
                continue
            lam_prev[:] = lam
            act += lag_rows(x, d.cur_fixed, m.particle_mass, h2k, rows, nrm, tgt, is_vf,
                            coef, kr, lam, ep)
            mark[:] = 1
            sel[:] = np.arange(len(sel))
            ns[0] = len(sel)
            if len(lam):
                dlam = np.abs(lam - lam_prev)
                dl = max(dl, float(dlam.max()))
                top = max(top, float(lam.max()))
                dgap = max(dgap, _change_over_stiffness(dlam, kr))
        d.rows["active"] = act
        if self.params.contact_sticky:  # the rows active at x keep their curvature
            for st, hot in zip(d.rows["sets"], d.rows["hot"]):
                sel = st[10][:st[11][0]]
                hot[sel[st[6][sel] > 0.0]] = 1
        return act, dl, top, dgap

    def _extend_live(self, ctx, d, xb, x, moved=None):
        """Before a line search from x toward xb: the rows live somewhere on the segment join
        the live rows, lagged at x (``extend_live``). ``moved`` (bool per vertex): xb differs
        from x only there, and every row not live has its gap bound >= ``LIVE_SLACK`` at x
        (only rows with a moved vertex are tested: the same result)."""
        h2k = self.params.contact_stiffness / (ctx.dt * ctx.dt)
        mv = _ALL_MOVED if moved is None else moved
        for rows, nrm, tgt, mu, coef, kr, lam, _lp, is_vf, mark, sel, ns in d.rows["sets"]:
            ns[0] = extend_live(xb, x, d.cur_fixed, ctx.model.particle_mass, h2k, rows, nrm,
                                tgt, is_vf, coef, kr, lam, mark, sel, mv,
                                d.endpoints)

    def _row_residuals(self, ctx, d, x, xt):
        """The contact rows' complementarity residuals at the Newton solution x into the
        frame's stats (maxima; ``row_residuals``): ``max_complementarity`` [m] and
        ``max_cone_violation`` [N]. Returns
        this substep's normal residual [m]."""
        eps = self.params.friction_velocity * ctx.dt
        s = ctx.stats
        worst = 0.0
        for rows, nrm, tgt, mu, coef, kr, lam, _lp, _vf, _mk, sel, ns in d.rows["sets"]:
            nr, cr = row_residuals(x, d.work["x0"], d.cur_fixed, rows, nrm, tgt, coef,
                                   kr, lam, mu, eps, xt, d.compliant, sel[:ns[0]])
            for key, v in (("max_complementarity", nr), ("max_cone_violation", cr)):
                s[key] = max(s.get(key, 0.0), v)
            worst = max(worst, nr)
        return worst

    @staticmethod
    def _compliant_normals(d, q):
        """Area-weighted vertex normals of the animated pose ``q`` at the compliant vertices
        (the collision pipeline's normal kernel)."""
        vn = np.zeros((len(q), 3))
        _vertex_normals_kernel(q, d.comp_tris, vn)
        d.comp_nrm[:] = vn[d.comp_idx]

    def _set_fixed(self, d, fixed):
        """The Dirichlet set of the next Newton solve (blocks to clear, diagonals to set)."""
        d.cur_fixed = fixed
        d.fixed_blocks = np.flatnonzero(fixed[d.brow] | fixed[d.A.indices])
        d.fixed_diag = d.diag[fixed]

    def _limit_energy(self, d, x, mode, opts, grad, A):
        """The strain-limit terms of the hard distance rows (``hard_limit``, ``limit_energy``)
        at x; 0 when off."""
        P = self.params
        if P.hard_limit <= 0.0:
            return 0.0
        E = 0.0
        for b, bd, st, maps, hloc in d.energies:
            if type(b).__name__ not in LIMITED_TYPES:
                continue
            idx, rest, alpha = bd.idx, bd.rest, bd.alpha
            if len(idx) == 0 or idx.shape[1] != 2 or len(st) != 1 or st[0].shape != idx.shape:
                continue
            E += limit_energy(x, idx, rest, alpha, opts.hard_k, P.hard_limit,
                              P.hard_limit_stiffness, mode, grad, A, maps[0])
        return E

    def _newton(self, ctx, d, xs, xt, opts, c):
        """Newton with a backtracking line search on E from ``xs`` (in place); Dirichlet
        vertices (``d.cur_fixed``) stay where ``xs`` has them."""
        P = self.params
        h = ctx.dt
        w = d.work
        g, dx = w["g"], w["dx"]
        fixed = d.cur_fixed
        C = d.contact
        if hasattr(d.precond, "begin_substep"):  # amg_reuse: its rebuild policy
            d.precond.begin_substep()
        if d.shapes is not None:  # first iteration: the normal forces of the last substep
            C["active"] = int(np.count_nonzero(C["lam"]))
        if d.rows.get("sets"):  # rows are new every substep: lag from the start positions
            for st in d.rows["sets"]:
                st[6][:] = 0.0
                st[9][:] = 0
            # the live rows only (exact, ``lag_rows_live``; all rows with contact_reach, which
            # the extensions below do not cover)
            live = P.contact_reach == 0.0
            self._lag_rows(ctx, d, w["x0"], live=live)
            if P.violated_rows != "push":
                low = 0
                on = (ctx.model.particle_kinematic if P.violated_rows == "hold_kinematic"
                      else d.all_on)
                for rows, nrm, tg, _mu, coef, _k, _l, _p, _v, _m, sel, ns in d.rows["sets"]:
                    low += start_targets_on(w["x0"], rows, nrm, tg, coef, tg, sel[:ns[0]], on)
                c["held_rows"] += low
                # the rows not live at x^n keep their targets (start_targets_on visits the
                # live ones), so lagging the listed rows again is what a pass over every row
                # gives (``lag_rows_sel`` at the same point: exact)
                self._lag_rows(ctx, d, w["x0"], live=live, on_segment=live)
            if live:  # rows that the start guess and x^n may close, lagged at x^n
                self._extend_live(ctx, d, xs, w["x0"])
                if P.start_at_rest:
                    xr = w["pp"]
                    np.copyto(xr, w["x0"])
                    np.copyto(xr, xs, where=fixed[:, None])
                    # xr is x^n but at the Dirichlet vertices: only rows with a vertex that
                    # moved there can join (``extend_live`` with ``moved``; none when none moved)
                    moved = fixed & (xr != w["x0"]).any(axis=1)
                    if moved.any():
                        self._extend_live(ctx, d, xr, w["x0"], moved)
        contacts = d.shapes is not None or bool(d.rows.get("sets"))
        n_it = P.contact_newton_iterations if contacts else P.newton_iterations
        if P.start_at_rest and d.rows.get("sets"):  # the lower of E(guess) and E(x^n)
            xr = w["pp"]
            np.copyto(xr, w["x0"])
            np.copyto(xr, xs, where=fixed[:, None])
            if (self._potential(ctx, d, xr, 0, opts, xt, None)
                    < self._potential(ctx, d, xs, 0, opts, xt, None)):
                xs[:] = xr
                c["rest_starts"] += 1
        # a contact row's lagged normal force counts as converged when its change, over the
        # row's stiffness, is a gap change that moves slower than newton_tolerance over the
        # substep (the analytic colliders keep the relative test alone: with the gap test the
        # sticking rope of tests/test_implicit_capstan.py creeps 0.81 mm instead of 0.012 mm)
        gap_tol = P.newton_tolerance * h
        ew = P.cg_forcing == "eisenstat_walker" and (P.cg_forcing_scope == "all" or contacts)
        after = P.cg_forcing_after if ew else 0
        g_prev, eta = 0.0, P.cg_forcing_max  # cg_forcing: eisenstat_walker
        for it_n in range(1, n_it + 1):
            c["newton"] += 1
            E0 = self._potential(ctx, d, xs, 2, opts, xt, g)
            cg_tol = P.cg_tolerance
            if ew:
                gn = float(np.sqrt(np.vdot(g, g)))
                if g_prev > 0.0:
                    e_new = 0.9 * (gn / g_prev) ** 2
                    if 0.9 * eta * eta > 0.1:
                        e_new = max(e_new, 0.9 * eta * eta)
                    eta = min(e_new, P.cg_forcing_max)
                g_prev = gn
                cg_tol = max(eta, P.cg_tolerance)
            loose = cg_tol
            if after:  # cg_forcing_after: cg_tolerance for the first `after` CG iterations
                cg_tol = P.cg_tolerance
            d.precond.setup(d.A, d.diag)
            neg = w["du"]
            np.negative(g, out=neg)
            if d.comp_idx is not None and P.compliant_solve == "cg_identity":
                d.precond.inv[d.comp_idx] = np.eye(3)  # no preconditioner block of their own
            if d.elim is not None:  # compliant unknowns apart: -g_c by their diagonal block
                np.copyto(d.elim_rhs, neg[d.elim])
                neg[d.elim] = 0.0
            if d.trace is not None:
                tr0 = self._trace_start(ctx, d, xs, xt, g)
            if d.lowrank is None:
                it, res = d.precond.solve(d.A, neg, cg_tol, P.cg_iterations, dx, w, after,
                                          loose)
            else:  # rank-one terms in the product (every preconditioner: pcg_fused's hook)
                it, res = d.precond.solve(d.A, neg, cg_tol, P.cg_iterations, dx, w, after,
                                          loose, lowrank=d.lowrank)
            if d.elim is not None:
                invert_blocks(d.A.data[d.elim_diag], d.elim_inv)
                dx[d.elim] = np.einsum("nij,nj->ni", d.elim_inv, d.elim_rhs)
            c["cg"] += it
            c["cg_max"] = max(c["cg_max"], it)
            c["cg_res"] = max(c["cg_res"], res)
            dx[fixed] = 0.0
            slope = float(np.vdot(g, dx))
            alpha, E1 = 1.0, np.nan
            on_segment = False  # xs ends on a segment _extend_live visited
            if P.line_search and slope < 0.0:
                xtry = xs + dx
                if d.rows.get("sets"):  # rows that the segment xs -> xs + dx may close
                    self._extend_live(ctx, d, xtry, xs)
                    on_segment = True
                    if P.contact_sticky:  # rows the full step closes: curvature from now on
                        for st, hot in zip(d.rows["sets"], d.rows["hot"]):
                            mark_closing(xtry, st[0], st[1], st[2], st[4], st[5],
                                         st[10][:st[11][0]], hot)
                slack = 1e-12 * abs(E0)  # rounding of E near convergence
                for _ in range(30):
                    E1 = self._potential(ctx, d, xtry, 0, opts, xt, None)
                    if np.isfinite(E1) and E1 <= E0 + 1e-4 * alpha * slope + slack:
                        break
                    alpha *= 0.5
                    c["halvings"] += 1
                    np.multiply(dx, alpha, out=xtry)
                    xtry += xs
                xs[:] = xtry
            else:
                xs += dx
            full = float(np.abs(dx).max()) / h if dx.size else 0.0
            c["step_v"] = alpha * full
            # the stop test reads the Newton step dx itself, not the step the line search took:
            # a step cut by the line search is small because E rose along dx, not because the
            # iterate is near the solution (``newton_stop``)
            stop_v = full if P.newton_stop == "newton_step" else c["step_v"]
            if c["step_v"] < P.newton_tolerance <= full:
                c["cut_steps"] += 1
            lagged_ok = True
            dl = top = dgap = 0.0
            if d.shapes is not None:  # friction lagged from this iterate's normal forces
                C["lam_prev"][:] = C["lam"]
                C["active"] = lag_contacts_al(xs, fixed, *d.shapes[:5], C["kc"], C["mult"],
                                              C["lam"], C["nrm"])
                top = float(C["lam"].max()) if C["active"] else 0.0
                if top > 0.0:
                    lagged_ok = (float(np.abs(C["lam"] - C["lam_prev"]).max())
                                 <= P.contact_tolerance * top)
            if d.rows.get("sets"):
                act, dl, top, dgap = self._lag_rows(ctx, d, xs, live=True,
                                                    on_segment=on_segment)
                if top > 0.0 and dl > P.contact_tolerance * top and dgap > gap_tol:
                    lagged_ok = False
            if d.trace is not None:
                self._trace_end(ctx, d, xs, xt, opts, tr0, it_n, full, alpha, E0, E1,
                                lagged_ok, dl, top, dgap, (it, res))
            if stop_v < P.newton_tolerance and lagged_ok:
                break
        else:  # stopped at the cap: hard_multipliers 'converged' keeps the multipliers
            c["capped"] += int(contacts)

    def _trace_start(self, ctx, d, x, xt, g):
        """``d.trace``: the state before a Newton iteration's step: the contact rows' active
        set and the 2-norms of the gradient, of the rows' friction part and of their normal
        part."""
        sets = d.rows.get("sets", [])
        gf = np.zeros_like(x)
        gn = np.zeros_like(x)
        eps = self.params.friction_velocity * ctx.dt
        for rows, nrm, tgt, mu, coef, kr, lam, _lp, _vf, _mk, sel, ns in sets:
            for m, gg in ((mu, gf), (0.0 * mu, gn)):
                row_energy(x, d.work["x0"], d.cur_fixed, rows, nrm, tgt, coef, kr, lam, m, eps,
                           1, gg, d.rows["A1"], d.diag, False, 0.0, xt, d.compliant,
                           sel[:ns[0]])
        gf -= gn
        gf[d.cur_fixed] = 0.0
        gn[d.cur_fixed] = 0.0
        return {"act": [st[6] > 0.0 for st in sets], "g": float(np.linalg.norm(g)),
                "g_fric": float(np.linalg.norm(gf)), "g_normal": float(np.linalg.norm(gn))}

    def _trace_end(self, ctx, d, x, xt, opts, tr0, it_n, full, alpha, E0, E1, lagged_ok, dl,
                   top, dgap, cg):
        """``d.trace``: one record per Newton iteration (see graphs/bench/implicit_newton.py)."""
        enter = leave = live = 0
        for a0, st in zip(tr0["act"], d.rows.get("sets", [])):
            a1 = st[6] > 0.0
            enter += int(np.count_nonzero(a1 & ~a0))
            leave += int(np.count_nonzero(a0 & ~a1))
            live += int(st[11][0])
        # the full Newton step's energy change by parts (rows lagged as in the step's model):
        # the contact rows' penalty and friction, the rest (inertia + elastic), and the
        # quadratic model's prediction g.dx + dx.A dx / 2
        dxs = d.work["dx"]
        xb = x - alpha * dxs
        parts = {}
        for key, xe in (("b", xb), ("f", xb + dxs)):
            pen = fr = 0.0
            eps = self.params.friction_velocity * ctx.dt
            for rows, nrm, tgt, mu, coef, kr, lam, _lp, _vf, _mk, sel, ns in d.rows.get("sets",
                                                                                        []):
                e_all = row_energy(xe, d.work["x0"], d.cur_fixed, rows, nrm, tgt, coef, kr, lam,
                                   mu, eps, 0, d.rows["g1"], d.rows["A1"], d.diag, False, 0.0,
                                   xt, d.compliant, sel[:ns[0]])
                e_pen = row_energy(xe, d.work["x0"], d.cur_fixed, rows, nrm, tgt, coef, kr, lam,
                                   0.0 * mu, eps, 0, d.rows["g1"], d.rows["A1"], d.diag, False,
                                   0.0, xt, d.compliant, sel[:ns[0]])
                pen += e_pen
                fr += e_all - e_pen
            parts[key] = (self._potential(ctx, d, xe, 0, opts, xt, None), pen, fr)
        Adx = self._matvec(d, dxs)
        pred = float(np.vdot(d.work["g"], dxs)) + 0.5 * float(np.vdot(dxs, Adx))
        dE = [parts["f"][i] - parts["b"][i] for i in range(3)]
        E2 = self._potential(ctx, d, x, 0, opts, xt, None)  # with the rows lagged at x
        sp = np.sqrt(np.einsum("ij,ij->i", d.work["dx"], d.work["dx"])) / ctx.dt
        tol = self.params.newton_tolerance
        inrow = np.zeros(len(x), dtype=bool)  # vertices of the live rows
        for st in d.rows.get("sets", []):
            inrow[st[0][st[10][:st[11][0]]].ravel()] = True
        over = sp > tol
        d.trace.append(dict(it=it_n, dx=full, alpha=alpha, E0=E0, E1=E1, E2=E2, dl=dl, top=top,
                            dgap=dgap, live=live, active=int(d.rows.get("active", 0)),
                            enter=enter, leave=leave, g=tr0["g"], g_fric=tr0["g_fric"],
                            g_normal=tr0["g_normal"], lagged_ok=lagged_ok, cg=cg[0],
                            cg_res=cg[1], n_over=int(over.sum()), dE_full=dE[0],
                            dE_pen=dE[1], dE_fric=dE[2], dE_rest=dE[0] - dE[1] - dE[2],
                            dE_pred=pred,
                            n_over_rows=int((over & inrow).sum()),
                            p99=float(np.percentile(sp[~d.cur_fixed], 99)) if len(sp) else 0.0,
                            dt=ctx.dt))

    def _project(self, ctx, d, p):
        """The projection pass of the non-energy constraint types (module docstring)."""
        for _ in range(self.params.projection_iterations):
            for b, bd in d.projected:
                if hasattr(b, "implicit_project"):
                    b.implicit_project(ctx, bd, p)
                else:
                    b.project(ctx, bd, p)
        for b, bd in d.projected:
            if not hasattr(b, "implicit_project"):
                b.finalize(ctx, bd, p)
        for b, bd in d.projected:
            if hasattr(b, "after_finalize"):
                b.after_finalize(ctx, bd, p)

    def describe(self, data):
        return (f"Newton <= {self.params.newton_iterations} (tol {self.params.newton_tolerance:g}"
                f" m/s), PCG {self.params.preconditioner} (tol {self.params.cg_tolerance:g}), "
                f"{int((~data.fixed).sum())} free / {int(data.fixed.sum())} fixed vertices")
