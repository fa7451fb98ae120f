"""Collision detection per collision group and the contact response in the Nucleus loop.

Per substep, ``CollisionDetect`` (collision stage) builds swept, inflated boxes of every member's
points, edges and triangles over the substep's predicted motion, finds vertex-face and
edge-edge candidates with the BVH, filters them by the exclusion rules and records the state of
each candidate at the start of the substep (distance, contact normal, which side). The solver
then projects ``CollisionConstraint`` in its interleaved loop like any other constraint type:
each candidate is a unilateral constraint ``n0 . (x_a - x_b) >= target`` along the contact normal
taken at the start of the substep, with position-based Coulomb friction. Because the side is
taken from the start of the substep and the candidates cover the whole swept motion, a fast
object cannot tunnel (the space-time idea of Nucleus section 7) as long as the start is free.
The final safe step checks that: after the final rounds the solved motion of the substep goes
through the narrow phase's conservative CCD (``ccd_safe_step``); pairs that would still collide
get contacts with the normal at the time of impact, then impact zones (see the CCD section).

Self pairs (``SPACETIME``, see the flag): the detections over a *known* motion, those of the
final rounds and of the CCD safe step (x -> the solved iterate), test the self-collision
candidates of an element with space-time boxes (``broadphase.spacetime_boxes``: a pair is kept
when, on every axis, the gap between the primitives' boxes at the start can be closed by their
relative displacement; a common motion cancels, so a falling sheet is not paired with its
neighbours) and never pair two kinematic elements. The detection over the *predicted* motion
(``CollisionDetect``, whose rows the iterations project) keeps the swept boxes
(``SPACETIME_PREDICTED``): the iterate leaves the predicted motion (a vertex stopped by a
contact while its neighbours move on), and the swept boxes hold every vertex anywhere on its
own path. Pairs of two elements keep every swept-box candidate: a solver iterate can leave the
linear motion by a lot when objects push each other (the fast ball through a pinned cloth of
``tests/test_collisions.py`` got through with space-time boxes for every pair). Measured: a
further gate in the filters (dropping self candidates whose start distance exceeds the
inflations plus their vertices' largest relative displacement) saved nothing on top
(cloth_sphere_64, per-frame CPU ratio 0.825 with it, 0.821 without) and is not kept. Nor is
a second final round that keeps the first one's candidates while no vertex moved more than
the inflation less half the largest target since (it held in 12 of the 15 second rounds of
cloth_sphere_64 frames 8-15; 0.97x CPU): the rows and their order differ from a fresh
detection's, and the slow elbow test then threw the sleeve out of the crease at 1.11 m/s
(frame 35).

Exact culling (``CONTACT_CULL``): every detected row keeps a lower bound of its gap along its
start normal at the detected end positions (``_cull_rows``); the projection skips a row whose
bound, moved by its vertices' motion since, still exceeds its target, and while no vertex is
farther than a few thicknesses from those positions it visits only the rows that can activate
at all. Skipped rows are provably inactive, so results are bitwise those of projecting every row.

Multilevel exclusion: per object (dynamic-dynamic, dynamic-kinematic, self), per element pair
(``exclude_pairs``), per vertex (the ``collide`` map) and per named vertex set
(``nocollide_sets``). One-sided colliders push only toward the outer side of their triangles and
let a vertex that starts inside through to the outside. Thickness maps scale the thickness per
vertex on the outer and inner side. Proximity-tolerant mode (Loki): a pair already closer than
its thickness at the start of the substep only stops approaching (target = start gap).

Limitations: the safe step runs in ``after_finalize``, so a strain limit in ``post`` mode (which
runs after it) can undo it; impact zones move as translations, so a zone caught by a rotating
collider may stay colliding (counted in the ``ccd_unresolved`` statistic). An edge-edge pair
with a one-sided collider counts only when it starts on the collider's outer side (by its
vertex normals); friction is position based (static and kinetic as one coefficient).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from pydantic import Field

from lokigraph.behavior import Behavior, ConstraintBehavior, ConstraintParams
from lokigraph.component import resolve_paintable
from lokigraph.components.collision import Collider, CollisionGroup, CollisionResponse

from . import broadphase as bp
from .narrowphase import (_alloc_ws, _ccd_query, _pt_tri_sq, _seg_seg_sq, _set_coeffs_ee,
                          _set_coeffs_vf, ee_ccd_batch_kernel, row_coefficients,
                          vf_ccd_batch_kernel)

_TOL = 1e-12
#: detection passes a vertex remembers which side of a kinematic sheet it came from after it
#: was last near it (pushed-through cloth may be out of the contact band for a while)
SIDE_MEMORY = 48
_NEVER = -(1 << 40)  # detection pass stamp of "never"
#: exact candidate culling in the projection (see ``_cull_rows``); False projects every
#: detected row (same results, slower: kept for benchmarks and tests)
CONTACT_CULL = True
#: a culled row is one that cannot activate unless some vertex moves more than
#: CULL_REACH x (largest box inflation of any group) away from the detected end positions
CULL_REACH = 2.0
_CULL_TOL = 1e-9  # [m] slack over rounding in the cull bound
#: two-sided contact rows (an edge-edge row, or a vertex-face row not one-sided) that ended on
#: the far side of their start normal n0 count as crossed only while their closest points lie
#: within the row's target of each other across n0 (``_slid_apart``); where they lie that far
#: apart across n0 the primitives have slid past each other (a moving collider carries its
#: edges 40 mm a substep under the cloth of cloth_sphere_moving_128) and the row is inactive, as
#: a row on its start side at that distance would be. 0: such rows push back along n0 (before,
#: bitwise); 1: rows against a collider (one primitive all kinematic or pinned, w = 0); 2: every
#: two-sided row (cloth-cloth too). Measured on cloth_sphere_moving_128 (frame 7, after the
#: final rounds, ``graphs/bench/cloth_strain.py --substages``): 252 of the 263 ball-cloth
#: edge-edge rows acting there were 'crossed' with their cloth point 6.8 mm (median) over the
#: sphere, 10 mm (median) across n0 from the ball edge, and pushed the cloth up to 7.5 mm along
#: n0 (50 degrees from the sphere's normal), taking the worst edge from 24 % to 90 %. With 1
#: (and the global strain step's contact rows skipping those rows too,
#: ``strain_limit_global.contact_rows``, measured as a wrapper before it was built in) one
#: interleaved run (``NUMBA_NUM_THREADS=1 python graphs/bench/peer_collision.py --moving --loki
#: 2x15 --frames 12 --newton none --all-flag SLIDE_APART=1 SLIDE_APART=0``):
#: worst frame-end strain of frames 7-11 21.5 / 20.4 / 18.6 / 34.7 / 86.6 % -> 3.1 / 1.4 / 2.2 /
#: 33.6 / 22.7 % at 0.92x the CPU of frames 2-12 (67.1 s against 72.7 / 72.8 s); the static
#: cloth_sphere_128 1.9 % (1.3-1.9 % a frame, never above the defaults') at 1.06x (45.8 against
#: 43.4 / 43.3 s, frame 6 left out: it compiles the wrapper); 0 intersecting pairs and 0
#: vertices inside in every frame of each. Frames 10-11 (and 14, 26.5 %): the CCD safe step (cloth-cloth hits at
#: the time of impact, then its pass over every row re-projects the cloth-cloth contacts the
#: global step moved the cloth into; ``cloth_strain.py --row-kinds``). Opt-in: results change
#: wherever a collider's rows slide (the static drop's too).
#: Not the default: with 1 the slow sleeve_elbow tests' near-joint speed went 0.638 / 0.671
#: -> 0.738 / 0.781 m/s against their bound 0.733 (stop 30, tests/test_elbow.py; stop 31:
#: 0.585 / 0.776 m/s against 0.596 / 0.638 with 0, test_sleeve_elbow_with_mechanisms /
#: _compression_near_contacts' 14-iteration run). Why (``graphs/bench/elbow_slide.py``, stop 31):
#: with 1 the contact passes skip 2-102 distinct rows a frame in frames 22-36, edge-edge rows
#: (80 %) against the unpainted forearm (a few against the upper arm), 4.0-8.2 mm across n0
#: (target 4 mm), 0-4.8 mm behind it, the forearm moving 0.8-1.6 mm a substep there (up to
#: 4.8 mm in frame 26, the reversal); the
#: sleeve's positions part from those of 0 from frame 23 (1.1 mm) to 10-16 mm by frames 32-37,
#: and the frame-end speed peak (frame 35, 0.776 against 0.638 m/s) is a vertex of no skipped
#: row (of the 10 vertices moved most against 0 in each frame, 0-1 are): a perturbation that
#: the crease's unsettled Gauss-Seidel fight turns into a different frame-end residue (the
#: iteration count alone moves it by as much, test_elbow), not cloth let go by the crease.
#: Only the contact passes matter there: with 1 but 0 in the passes the positions are bitwise
#: those of 0; with 1 but 0 in the pinch count, the CCD and the global step, those of 1.
#: 3: rows slid apart along a collider stay active in the contact passes of the solver
#: iterations and the final rounds, as with 0; the global strain step's contact rows
#: (``strain_limit_global.contact_rows``), the pinch count (``strain_limit.count_pinched``) and
#: the CCD safe step (its contacts at the time of impact and its passes over every row) skip
#: them, as with 1 (``row_slid_apart``). Measured (stop 31, at the defaults of 520cfbc):
#: sleeve_elbow positions bitwise those of 0 over the 60 frames at 14 and 15 iterations;
#: cloth_sphere_moving_128 (2x15, ``graphs/bench/cloth_strain.py --substages ... --frames 12
#: --contacts-flag SLIDE_APART=N``) worst edge at the end of frames 7-12:
#: 0: 17.8 / 20.1 / 3.7 / 16.6 / 27.1 / 12.6 %; 1: 3.2 / 1.6 / 47.7 / 62.8 / 12.4 / 1.5 %;
#: 3: 2.7 / 1.6 / 14.1 / 17.0 / 11.6 / 1.4 % (``peer_collision.py --moving --loki 2x15 --frames
#: 12 --newton none --all-flag SLIDE_APART=3``: 0.96x the CPU of frames 2-12; the static drop
#: 1.9 % at 1.04x; 0 intersecting pairs, 0 vertices inside). After the global step 1.4-2.7 % a frame
#: with 3 (the global step, not the passes, gives it: after the final rounds 97 / 63 % in
#: frames 7 / 8 with 3, 31 / 16 % with 1); frames 9-11 are the CCD safe step's. Keeping the
#: slid rows in the safe step too (the global step and the pinch count only) took frames 9-11
#: to 52.9 / 39.3 / 49.3 %: its pass over every row pushed the cloth back along them (ball-cloth
#: edge-edge rows alone 233 %, ``cloth_strain.py --row-kinds --at 9``). Also rejected (elbow
#: bitwise 0 as well, the ball no better after the global step): the passes skipping a slid row
#: only where the collider's own motion over the substep across n0 is at least the target
#: (3.79 / 1.87 / 2.24 % in frames 7-9), or where the lateral distance is at least 2.5 targets
#: (2.95 / 1.82 / 1.66 %). Not the default: besides frame 9 (over 5 %; the safe step's
#: cloth-cloth rows, ``cloth_strain.py --row-kinds --at 9``: 8.0 -> 44.3 %), with 3 as the
#: default the default suite (878 passed) and ``lokigraph stress --quick`` (8/8) pass but the
#: slow set fails test_sleeve_elbow_without_mechanisms: the sleeve the arm pushed through (CCD,
#: proximity tolerance and recovery off there) stays through it, 16-30 sleeve-arm pairs in
#: every frame from 37 to 61 (0 from frame 37 with 0). ``elbow_slide.py 0 3 3:global 3:pinch 1
#: --without``: with 3 but 0 in the global step's rows the run is bitwise that of 0, with 0 in
#: the pinch count that of 3: the global step takes real crossings 4 mm or more across their
#: start normal for slid rows and no longer pulls the sleeve back (the same test cannot tell
#: them apart; the collider's own motion over the substep, as in the rejected candidate above,
#: could, but ``contact_rows`` has no start positions).
SLIDE_APART = 0


def slide_mode(passes: bool) -> int:
    """The ``SLIDE_APART`` mode (0, 1 or 2) a site applies: ``passes`` for the contact passes of
    the solver iterations and final rounds, else for the CCD safe step, the global strain
    step's contact rows and the pinch count. 3 is 0 in the passes (they keep slid rows) and 1
    at the other sites; the kernels see only 0-2."""
    if SLIDE_APART == 3:
        return 0 if passes else 1
    return SLIDE_APART


#: with ``SLIDE_APART``, the CCD safe step's contacts at the time of impact too
CCD_SLIDE = True
#: space-time boxes (``broadphase.spacetime_boxes``) for the self pairs of every element, and no
#: pairs of two kinematic elements, in the detections over a known motion: the final rounds'
#: and the CCD safe step's (x -> the solved iterate p). Exact there: the final rounds project
#: from p, and the CCD needs the pairs that come within its distance along x -> p, which the
#: space-time test keeps. False: swept boxes in every detection (the former candidates, for
#: benchmarks and tests). Measured with ``graphs/bench/collision_scaling.py --ab --sizes 64 128
#: --frames 16 --from-frame 6`` (1 thread, interleaved with False): median per-frame CPU ratio
#: 0.85-0.92 at 64 x 64 (three runs), 0.81-0.83 at 128 x 128 (two runs), no intersections
#: either way; positions bitwise those with False over the 23 frames of cloth_sphere_64 and
#: the 60 of the slow test_sleeve_elbow_with_mechanisms (the rows it drops never activate in
#: the final rounds or the CCD there; at 128 x 128 they differ)
SPACETIME = True
#: in the detections over a known motion, pairs of two *different* elements (cloth on a
#: moving collider, two cloths) get the space-time test too, not the self pairs alone: exact for
#: the same reason (both move linearly along x -> p there). False: those pairs by their swept
#: boxes (before).
SPACETIME_CROSS = True
#: space-time boxes also in the detection over the *predicted* motion x -> x1 (the rows the
#: iterations project). Off: that test is exact for the predicted motion only, and the iterate
#: leaves it by more than the inflation (a vertex stopped by a contact while its neighbour keeps
#: falling; on cloth_sphere_64 the iterate at the end of the iterations lies up to 26 mm outside
#: the boxes of the predicted motion), so pairs the swept boxes keep are missing from the
#: iterations. Measured with it on: in the slow test_sleeve_elbow_with_mechanisms the rows it
#: dropped became active in 13-32 of the 32 contact passes of each of frames 21-34 (none in the
#: final rounds), and the sleeve was thrown out of the crease at 0.89 m/s (frame 33) against its
#: 0.73 m/s bound (0.65 with it off); ``tests/test_collision_spacetime.py`` builds that case
#: (1,114 pairs within their target at the iterate missing). It would save more: ``--ab
#: --ab-mode all --ab-ref known`` gives 0.92x (64 x 64) and 0.62x (128 x 128) of the CPU
#: with ``SPACETIME`` alone. Made safe by an incremental re-detection (built and measured, not
#: kept: before every contact pass of the iterations, query only the primitives of the
#: vertices whose iterate left the common path and add the pairs they reach; the test above
#: then finds no pair missing and the elbow's crease speed stays under its bound) it costs far
#: more: 1.91x the CPU at 64 x 64 (frames 6-16) and 4.04x at 128 x 128 (frames 6-14), no
#: intersections. The cause, measured on the 64 x 64 drop (frames 8-11): the common path
#: tolerates a deviation of only s = infl_min - target_max / 2 = 1 mm (2 mm thickness, 2 mm
#: margin), and in contact frames the iterate leaves its predicted end by more
#: than that for 2,000-3,500 of the 4,225 vertices at the first contact pass and for all of them
#: by the end of a substep (2,450-3,400 by then with the space-time boxes inflated 5 mm more),
#: so a query runs in every contact pass (16 a frame) and adds up to 57k rows (1.4M in 16
#: frames); the rows grow from 92-116k to 143-221k within a substep. Left off.
#: Nor does a first detection in the frame of a moving collider pay (built and measured on
#: the moving scene, cloth_sphere_moving_128, not kept): swept boxes over x -> x1 - D, D the
#: mean displacement of the group's kinematic vertices (0 for a static collider: unchanged),
#: inflated 0-5 mm more, exact while every iterate stays within bbox(x + D, x1) widened by
#: infl_min + slack - target_max / 2, checked before every contact pass and detected again
#: in that frame (boxes widened to the iterate) where not. There the cloth's own motion, not
#: the collider's translation, makes the rows: ``python graphs/bench/peer_collision.py
#: --rows-at-iterate`` (last substep of frames 7 / 9 / 12 / 14) gives 100 / 627 / 382 / 328
#: rows per cloth vertex with the absolute swept boxes, 247 / 763 / 371 / 318 in the
#: collider's frame (581 / 1,275 / 827 / 723 with 5 mm slack) and 26 / 81 / 58 / 51 with
#: space-time boxes; the iterations end 6-15 mm (median) and up to 82 mm from the predicted
#: x1, so 13.5-15.5k of the 16.6k cloth vertices lie outside their absolute swept box (and
#: 7-13k outside the collider-frame box even with 5 mm slack) and the re-detection ran in
#: 11-16 of the 16 contact passes of frames 7-11 (28.7-96.1 s CPU per frame, 1 thread). The
#: same check shows that the absolute swept rows, though their box test fails for most
#: vertices, miss no cloth-cloth pair within its target at that iterate (0 in each of the four
#: substeps), the space-time rows 12 (frame 9) and 2 (frame 14) of 145-1,606 (none with
#: 5 mm more inflation, but then 238 / 344 / 290 / 260 rows per cloth vertex and more
#: detection CPU than the absolute boxes in all four: 995 / 2,013 / 1,858 / 1,634 ms against
#: 397 / 1,712 / 972 / 792, ``--slack 0.005``; none with 1.5 mm more either, at 108 / 147 /
#: 110 / 103 rows per cloth vertex and 608 / 1,317 / 606 / 543 ms against the absolute
#: boxes' 100 / 627 / 382 / 328 rows and 471 / 1,628 / 1,005 / 766 ms, ``--slack 0.0015``: a
#: lead, not measured in a run or on the elbow, and no guarantee: the stopped walls of
#: ``tests/test_collision_spacetime.py`` deviate by 20 mm); every row set
#: misses the same 19-150 pairs with the collider (not examined: presumably those the
#: one-sided filter drops on purpose). This flag on the moving scene, in one interleaved run
#: (``NUMBA_NUM_THREADS=1 python graphs/bench/peer_collision.py --moving --loki 2x15
#: --moving-flag SPACETIME_PREDICTED``, 23 frames, load 2.6-3.8): the moving scene's CPU per
#: frame 10,752 -> 5,459 ms against the static scene's 2,434 (4.42 -> 2.24x median, 3.33 ->
#: 1.62x mean), the rows of a frame's first detections 11-28M -> 1.7-2.9M (frames 9-23), no
#: intersecting pair and no vertex inside in any frame either way, largest strain 93.4 ->
#: 90.3 %: not within 1.5x even so, and unsafe (above)
SPACETIME_PREDICTED = False
#: [m] extra box inflation of ``SPACETIME_PREDICTED``'s space-time detection over the predicted
#: motion (used only while that flag is on; 0: as before). The space-time rows then also hold
#: the pairs whose relative deviation from the predicted motion stays within about twice this
#: (measured on the moving scene's iterates with ``peer_collision.py --rows-at-iterate --slack
#: 0.0015``: no cloth-cloth pair within its target missing in four substeps)
PREDICTED_SLACK = 0.0
#: space-time boxes in the detection over the predicted motion x -> x1 made exact by a check:
#: the rows of ``CollisionDetect`` (self pairs and, as ``SPACETIME_CROSS``, pairs of two
#: elements) come from space-time boxes inflated by ``RELATIVE_SLACK`` [m] more, and before
#: every contact pass of the iterations ``_relative_flags`` finds the vertices whose
#: deviation from the detected end (d = p - x1) differs, on some axis, from that of a vertex
#: near it at the iterate p by more than 2 (infl_min + slack) - target_max; only a pair of two
#: such vertices' primitives can be missing from the rows and within its target at p (the
#: bound is derived in ``_relative_flags``). Where there is none the rows hold every pair
#: that can be active at p; where there is one the contacts are detected again in space-time
#: over x -> p (same slack) and the check then measures from p, or rows are added for the
#: flagged vertices' primitives (``RELATIVE_INCREMENTAL``). Pairs with a kinematic element
#: keep their swept boxes there (a cloth vertex stopped on its path by a collider stays in
#: its swept box, while its deviation from the collider's vertices is the whole stop).
#: False: swept boxes there (``SPACETIME_PREDICTED`` alone is the unchecked variant). Off:
#: exact, but it does not pay on the drop. Measured with ``NUMBA_NUM_THREADS=1
#: collision_scaling.py --ab --ab-flag SPACETIME_RELATIVE --sizes 64 --frames 14`` (and
#: ``--sizes 128 --frames 12``), interleaved with False, frames 6 on: the check flags
#: vertices in 97 of the 144 contact passes at 64 x 64 and 83 of 112 at 128 x 128 (h = 1/48
#: s: a vertex stopped by the sphere deviates by up to ~50 mm from its predicted end while a
#: neighbour two edges away does not; brute force finds self pairs within their target
#: missing from the rows in 2-5 of the 14-16 flagged passes of each of frames 9-11 at 64 x
#: 64, so the flags are not idle), and the first detection's rows per cloth vertex are 47 /
#: 118 against the swept boxes' 35 / 133: median per-frame CPU 2.50x (64, full re-detection
#: only: ``--ab-set RELATIVE_INCREMENTAL=0``) and 3.13x (128); with the incremental rows up
#: to 5 % flagged 2.17x (64) and 3.03x (128; 94 re-detections in 112 passes, 72 of them
#: full), 5.12x at 64 with the incremental rows only (``RELATIVE_INCREMENTAL=1``: the
#: reference stays x1, so the flags grow through the substep). No
#: intersecting pair either way; largest strain 6.6 -> 6.7 % (64), 15.9 -> 15.8 % (128).
#: Without slack (``--ab-set RELATIVE_SLACK=0``, 64 x 64): 27.4 rows per vertex against 35.0, flags in
#: 132 of 144 passes (105 full re-detections), 2.00x. The moving scene (``NUMBA_NUM_THREADS=1
#: peer_collision.py --moving --loki 2x15 --moving-flag SPACETIME_RELATIVE --frames 12``, one
#: interleaved run): CPU per frame against the static scene 5.91x median (3.55x mean) with it,
#: 2.11x (2.02x) without; its rows of a frame's first detections 3.0-6.7M against 2.1-20.5M
#: (frames 6-12; but 2.9M against 0.23M in the free fall of frames 1-5: at 128 x 128 the edge,
#: 7.8 mm, is shorter than the 9 mm the slack-widened boxes reach, and the swept boxes' 6 mm
#: is not), flags in 14-16 of the 16 passes of frames 7-12 (7-15 full re-detections a frame),
#: no intersecting pair and no vertex inside in any frame either way, largest strain 82.3 ->
#: 67.9 %
SPACETIME_RELATIVE = False
#: [m] extra inflation of the boxes of ``SPACETIME_RELATIVE``'s detections: the relative
#: deviation the check tolerates grows by twice this
RELATIVE_SLACK = 0.0015
#: where ``SPACETIME_RELATIVE``'s check flags vertices, add rows for the flagged vertices'
#: primitives only (``_relative_extra``: their boxes at the iterate against every primitive's,
#: pairs the detection's own boxes already held left out), projected after the detected rows
#: in that pass and replaced at the next check) while they are at most this fraction of the
#: groups' vertices; more (or 0): detect everything again over x -> p, which the check then
#: measures from
RELATIVE_INCREMENTAL = 0.05
#: the contact passes over culled rows first test each row's bound ``lb`` against the
#: distances its vertices moved from the reference positions (``Contacts.moved``, |p - ref|
#: per vertex, taken at the start of a pass and kept current by the rows that move vertices),
#: and only where that does not rule the row out its motion along n0 (the gate of
#: ``_project_ee_sel``): lb - max |u_a| - max |u_b| bounds lb + min (u_a . n0) - max (u_b . n0)
#: from below, so a row it skips the gate skips too (``_GATE_TOL`` over the rounding of the
#: two). Positions bitwise those of False (the gate alone).
MOVED_GATE = True
_GATE_TOL = 1e-12  # [m]
#: the swept-box detections (over the predicted motion) and the space-time ones (final rounds,
#: CCD) query into their own pair buffers: a buffer sizes the single traversal pass's scratch
#: from its previous query, and alternating 222k swept and 78k space-time edge pairs (64 x 64
#: drop, frame 10) overflowed it, so 12-74k pairs were traversed twice in 4 queries a frame.
#: Same pairs in the same order either way (False: one buffer, for benchmarks). Measured with
#: ``collision_scaling.py --ab --sizes 64 --frames 16 --from-frame 6 --ab-flag SPLIT_BUFFERS``
#: (1 thread): median per-frame CPU ratio 0.979
SPLIT_BUFFERS = True
#: detections write the primitives' boxes, the space-time boxes and the filters' rows into
#: arrays kept per group (``_row_buffers``, ``_scratch``) instead of new ones every time (the
#: trees copy the boxes, the packed rows are copies). Same results. Measured with
#: ``collision_scaling.py --ab --sizes 64 --frames 16 --from-frame 6 --ab-flag REUSE_BUFFERS``
#: (1 thread): median per-frame CPU ratio 0.960 (0.972 with the rows alone)
REUSE_BUFFERS = True
#: vertex-face and edge-edge candidates of the groups of at least ``COLUMN_GRID_MIN_TRIS``
#: triangles (self, dynamic and kinematic pairs) from the sorted column grid
#: (``broadphase.column_query_pairs`` / ``column_query_self``: the same candidate set as the
#: BVH queries, no trees built; space-time rows per primitive,
#: ``broadphase.spacetime_prim_boxes``) instead of the trees, put in the Z-order of their
#: Morton ranks (``GRID_ORDER``) before the filters. The filtered rows are the trees' set
#: (``tests/test_broadphase_columns.py``) in another order, so the contacts are projected in
#: another Gauss-Seidel order and the positions differ from the trees'. The grid's own order
#: (column by column) converged worse: four tests calibrated on the trees' order failed with
#: it (sleeve_elbow 14.4 % against a 13 % bound, see ``CANONICAL_ORDER`` for every order
#: tried); the Z-order, spatially coherent blocks like a tree-tree traversal's, gives 11.87 %
#: there (trees 11.61 %). Small groups keep the trees, as no canonical order passes the
#: order-calibrated tests on their small scenes (all under 10,000 triangles). First measured
#: in column order with ``collision_scaling.py --ab --ab-mode known --ab-flag COLUMN_GRID``
#: (1 thread, interleaved with False, machine load 8-12): median per-frame CPU ratio 0.760 and
#: 0.742 at 64 x 64 (frames 6-16, two runs; 470 -> 372 ms) and 0.832 and 0.938 at 128 x 128
#: (frames 6-14, two runs), no intersecting pairs either way, largest edge strain 6.6 -> 6.6 %
#: and 15.9 -> 16.4 %; with the Z-order and the threshold (``--sizes 64 --frames 14
#: --from-frame 6``, 1 thread, load 4-7): 0.792 (588 -> 489 ms), no intersecting pairs,
#: strain 6.6 -> 6.6 %. False: the trees everywhere, positions bitwise those before the grid
COLUMN_GRID = True
#: the candidates of every detection sorted before the filters: "index" by (vertex, triangle)
#: and (edge, edge) numbers (``broadphase.sort_pairs``, a counting sort), "morton" by the
#: primitives' Morton ranks (``broadphase.morton_rank``: the trees' leaf order), "zorder" by
#: the Z-order of the pair's two Morton ranks (``broadphase.zsort_pairs``, a radix sort: pairs
#: of nearby primitives together, block by block, about as a tree-tree traversal meets them).
#: Either way the contacts are projected in an order that does not depend on the broad phase:
#: the trees and the column grid give bitwise equal positions (``collision_scaling.py --ab
#: --ab-mode known --ab-flag COLUMN_GRID --sizes 32 --frames 12`` with "index": bitwise
#: equal). Off (False: the query's own order: the trees' for small groups, ``GRID_ORDER`` for
#: the column grid's) because four tests are calibrated on the trees' own order. The
#: Gauss-Seidel order matters on the sleeve elbow:
#: ``tests/test_cloth_strain.py::test_sleeve_elbow_joint_long_range``'s first run (bound
#: 13 %) gives 11.61 % with the trees (11.66 / 11.75 / 11.73 % with 64 / 256 / 4,096 top
#: tasks: other task partitions of the same trees) and 11.87 % with "zorder", against 13.41 %
#: with "index" (trees or grid alike), 13.46 % by descending index, 12.99 % by (triangle,
#: vertex), 13.21 % shuffled, 14.39 % with "morton" and 14.4 % in the grid's column order:
#: spatially coherent blocks of pairs converge better there. No order tried passes all four:
#: test_compliant_recession_independent_of_substeps fails with every one (bound 1 mm; 2.03 /
#: 3.43 / 2.05 mm with index / morton / zorder; the trees' 0.84 mm), the slow
#: test_hard_limit_holds_a_32x32_drop too (the 2 % limit's strain under 2.5 %: 2.65 / 2.24 /
#: 2.81 %; the control without it over 3.5 %: 3.21 / 3.38 / 4.68 %), and
#: test_cut_step_is_not_convergence passes with index and morton, not with zorder (one false
#: stop, needs two)
CANONICAL_ORDER = False
#: groups of at least this many triangles use the column grid when ``COLUMN_GRID`` is on;
#: smaller ones keep the trees and their order. At 6,000 the slow
#: test_hard_limit_holds_a_32x32_drop (a 32 x 32 cloth, 2,048 triangles, on the 5,120 of the
#: sphere) ran on the grid and failed (2.81 % strain with the 2 % limit, bound 2.5 %); the
#: 64 x 64 drop has 13,312
COLUMN_GRID_MIN_TRIS = 10000
#: the order of the column grid's candidates (as ``CANONICAL_ORDER``; False: column by
#: column): "zorder", spatially coherent blocks, as the trees' (see ``CANONICAL_ORDER``)
GRID_ORDER = "zorder"
#: the detection margin (``CollisionGroup.margin``, the band beyond the thicknesses in which
#: pairs are detected) of a vertex at most this many times the shortest mesh edge at it (in
#: the positions at bind time): a margin fixed in metres covers more and more edges as a mesh
#: is refined (2 mm is a quarter of an edge at 128 x 128 on the 1 m cloth, half of one at
#: 256 x 256), and the rows, and every stage that follows them, grow faster than the
#: vertices. 0: the group's margin everywhere (before). With 0.3 the margin binds below
#: 6.7 mm edges only: the 32-128 drops (7.8 mm edges and longer) are bitwise unchanged, the
#: 256 x 256 one (3.9 mm) gets 1.17 mm. Measured in one interleaved run, 1 thread, CPU
#: ms/frame over frames 7-8 (the first contact frames), the cloth 1 mm thick at every size
#: (``NUMBA_NUM_THREADS=1 peer_collision.py --sizes 32 64 128 256 --newton none --loki 2x15
#: --frames 8 --stages --stage-frames 7 8 --cloth-thickness 0.001 --all-flag
#: MARGIN_EDGE=0.3``, load ~5): 256 x 256 15,703 -> 10,940 (first detection 5,288 -> 5,136,
#: final rounds 7,240 -> 3,607, iterations 1,650 -> 1,273, CCD 691 -> 195; first-detection
#: edge-edge self rows per vertex 102.8 -> 70.8), the median of frames 2-8 6,904 -> 1,665;
#: the fitted exponent from 32 to 256 1.16 -> 1.08; no intersecting pair, no vertex inside,
#: largest strain 32.9 % either way. The CCD's coverage bound (``infl_min``) and the boxes
#: follow the per-vertex margin; the cull keeps the group's (a larger bound is still exact).
#: On (0.3) since 2026-11-24: the default suite (865 passed), the slow set (22 passed) and
#: ``lokigraph stress --quick`` (8/8) pass with it
MARGIN_EDGE = 0.3
#: opt-in (off: the defaults): in the swept-box detections (``CollisionDetect``'s over the
#: predicted motion x -> x1, and the iterations' re-detections) the primitives of kinematic
#: elements get boxes at their end positions only instead of over x -> x1 (their positions
#: during the iterations: p = x1 for a kinematic vertex). The cloth's boxes stay swept, so a
#: pair within its target at an iterate inside the cloth's boxes is still held (the argument
#: of ``_rows_hold``); dropped are the pairs with a collider primitive that passed by the cloth
#: during the substep, whose rows, with SLIDE_APART 0, act only as 'crossed' rows along their
#: stale start normal. Results change wherever a collider moves (a static one: bitwise).
#: Measured in the run of ``CCD_ROUND_INCREMENTAL`` (same command, frames 7-12 against the
#: same static run): first-detection rows with the ball per cloth vertex and frame ee 44.1 ->
#: 22.0, vf 7.0 -> 3.2 (cloth-cloth 248 / 102 -> 255 / 105); the first detection 2,719 ->
#: 2,269 ms CPU a frame, the whole frame 9,350 -> 8,802 ms: per-frame ratio against the static
#: drop median 1.64 -> 1.57, mean 1.78 -> 1.69, ratio of the means 1.68 -> 1.59. 0
#: intersecting pairs and 0 vertices inside in every frame, but the CCD safe step hits 89 / 103
#: pairs in frames 10 / 11 (7 / 38 with the defaults) and the worst edge at the end of frames
#: 7-12 is 21.3 / 17.6 / 17.9 / 16.2 / 7.8 / 18.3 % against 29.3 / 14.6 / 10.6 / 10.8 / 7.3 /
#: 4.9 %: the contacts with the ball are weaker during the iterations (the rows of triangles
#: that slid under a cloth vertex during the substep are gone; their replacements, found near
#: the end positions, are filtered at the start positions, where the vertex does not project
#: onto them). Not the default: not within 1.5x either, stretches more, and the default suite
#: and slow tests were not run with it.
KINEMATIC_END_BOXES = False


@dataclass
class _Group:
    name: str
    verts: np.ndarray  # global vertex indices of all members
    tris: np.ndarray  # (T, 3) global
    edges: np.ndarray  # (E, 2) global
    tri_elem: np.ndarray
    edge_elem: np.ndarray
    vert_elem: np.ndarray  # per global vertex (-1 if not a member)
    allow: np.ndarray  # (n_el, n_el) bool: may these elements collide
    tolerant: np.ndarray  # (n_el, n_el) bool: proximity tolerant for this pair
    th_out: np.ndarray  # per global vertex thickness outer [m]
    th_in: np.ndarray
    friction: np.ndarray  # per global vertex
    visible: np.ndarray  # per global vertex bool
    setmask: np.ndarray  # per global vertex int64 bitmask of nocollide sets
    one_sided: np.ndarray  # per element bool
    kinematic_el: np.ndarray  # per element bool
    do_vf: bool
    do_ee: bool
    margin: float
    strength: float
    damping: float
    restitution: float
    friction_scale: float
    # which side of each two-sided kinematic element a dynamic vertex came from (+1/-1, 0 =
    # unknown) and the detection pass that last saw the pair: history to recover crossings
    recover: np.ndarray = None  # per element bool: remember sides of this kinematic element
    side_mem: np.ndarray = None  # (n_vertices, n_el) int8
    side_seen: np.ndarray = None  # (n_vertices, n_el) int64
    crossed: np.ndarray = None  # (n_vertices, n_el) int64: pass in which the vertex was crossed
    # scratch of one detection pass: distance [m] to the plane of the nearest triangle of each
    # remembering element the vertex projects onto, and its side (+1/-1); reset after the pass
    near_d: np.ndarray = None  # (n_vertices, n_el) float64, inf when unset
    near_s: np.ndarray = None  # (n_vertices, n_el) int8
    stamp: int = 1
    # per global vertex detection margin [m] (``MARGIN_EDGE``; None: ``margin`` everywhere)
    margin_v: np.ndarray = None
    # pair buffers of the swept-box and of the space-time detections (``SPLIT_BUFFERS``)
    buf_vf: bp.PairBuffer = field(default_factory=lambda: bp.PairBuffer(1024))
    buf_ee: bp.PairBuffer = field(default_factory=lambda: bp.PairBuffer(1024))
    buf_vf_st: bp.PairBuffer = field(default_factory=lambda: bp.PairBuffer(1024))
    buf_ee_st: bp.PairBuffer = field(default_factory=lambda: bp.PairBuffer(1024))
    # detection scratch (``_row_buffers``, ``_scratch``; ``REUSE_BUFFERS``)
    bufs: dict = field(default_factory=dict)


@dataclass
class _Contacts:
    groups: list
    x1: np.ndarray  # predicted positions scratch
    # packed contacts of all groups, rebuilt each substep
    vf: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))
    vf_n: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    vf_target: np.ndarray = field(default_factory=lambda: np.zeros(0))
    vf_mu: np.ndarray = field(default_factory=lambda: np.zeros(0))
    vf_onesided: np.ndarray = field(default_factory=lambda: np.zeros(0, np.bool_))
    ee: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))
    ee_n: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    ee_target: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ee_mu: np.ndarray = field(default_factory=lambda: np.zeros(0))
    strength: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ee_strength: np.ndarray = field(default_factory=lambda: np.zeros(0))
    damping: float = 0.0
    tolerant_count: int = 0
    lam: None = None
    ccd: object = None  # _CCDWork of the final safe step, allocated on first use
    # end positions of the motion of the last detection (the rows above cover x -> det_ref)
    det_ref: np.ndarray = None
    p_det: np.ndarray = None  # copy of p at a final round's detection (allocated on first use)
    infl_min: float = -1.0  # smallest box inflation of any vertex of any group [m]
    # exact culling (``_cull_rows``): end positions of the last detection, the rows that can
    # activate while no vertex moves more than cull_b [m] from them (-1: no culling)
    cull_ref: np.ndarray = None
    cull_b: float = -1.0
    vf_sel: np.ndarray = field(default_factory=lambda: np.zeros(256, np.int64))
    ee_sel: np.ndarray = field(default_factory=lambda: np.zeros(256, np.int64))
    vf_lb: np.ndarray = field(default_factory=lambda: np.zeros(256))
    ee_lb: np.ndarray = field(default_factory=lambda: np.zeros(256))
    n_vf_sel: int = 0
    n_ee_sel: int = 0
    # ``SPACETIME_RELATIVE``: end positions of the motion the space-time rows were detected for
    # (None: the rows are not relative ones), its slack [m], a copy of an iterate they were
    # detected again for, per group (bound, largest target) of the check, and its scratch
    rel_ref: np.ndarray = None
    rel_slack: float = 0.0
    p_rel: np.ndarray = None
    rel_bounds: list = field(default_factory=list)
    rel_work: dict = field(default_factory=dict)
    # rows added by the last check (``RELATIVE_INCREMENTAL``): per group (vf, ee) tuples as
    # ``_detect_group``'s, projected after the packed rows; vertex normals at x (one-sided)
    rel_extra: list = field(default_factory=list)
    rel_vn: dict = field(default_factory=dict)
    cull_passes: int = 0  # projection passes over the culled rows / over every row (counts)
    full_passes: int = 0
    # ``MOVED_GATE``: |p - cull_ref| per vertex [m], kept current through a pass
    moved: np.ndarray = None


def _members(ctx, e, g):
    out = []
    for name in g.members:
        try:
            out.append(ctx.scene.element(name))
        except KeyError:
            import difflib

            near = difflib.get_close_matches(name, [x.name for x in ctx.scene.elements], n=1)
            ctx.error(e, "CollisionGroup.members", f"no element named {name!r}"
                      + (f"; did you mean {near[0]!r}?" if near else ""))
    return out


class CollisionDetect(Behavior):
    """Broad phase (BVH over swept boxes) and candidate filtering for every collision group."""

    stage = "collision"
    requires = (CollisionGroup,)
    writes = ("contacts",)

    def bind(self, ctx, elements):
        m = ctx.model
        n = m.particle_count
        groups = []
        for e in elements:
            g = e.get(CollisionGroup)
            resp = e.get(CollisionResponse) or CollisionResponse()
            mem = _members(ctx, e, g)
            mem = [x for x in mem if x.geometry is not None]
            if not mem:
                continue
            idx = {x.name: i for i, x in enumerate(mem)}
            k = len(mem)
            vert_elem = np.full(n, -1, np.int64)
            th_out = np.zeros(n)
            th_in = np.zeros(n)
            fric = np.zeros(n)
            vis = np.zeros(n, np.bool_)
            setmask = np.zeros(n, np.int64)
            set_bits: dict[str, int] = {}
            tris, edges, tri_el, edge_el, verts = [], [], [], [], []
            one_sided = np.zeros(k, np.bool_)
            kin = np.zeros(k, np.bool_)
            cols = []
            for i, x in enumerate(mem):
                c = x.get(Collider) or Collider()
                cols.append(c)
                sl = x.vertex_slice
                vert_elem[sl] = i
                th_out[sl] = c.thickness * resolve_paintable(c.thickness_outer, x,
                                                             "Collider.thickness_outer")
                th_in[sl] = c.thickness * resolve_paintable(c.thickness_inner, x,
                                                            "Collider.thickness_inner")
                fric[sl] = c.friction
                vis[sl] = resolve_paintable(c.collide, x, "Collider.collide") > 0
                for sname, vs in c.nocollide_sets.items():
                    if sname not in set_bits:
                        if len(set_bits) >= 62:
                            ctx.error(e, "Collider.nocollide_sets", "at most 62 set names")
                            continue
                        set_bits[sname] = 1 << len(set_bits)
                    vs = np.asarray(vs, np.int64)
                    if len(vs) and (vs.min() < 0 or vs.max() >= x.vertex_count):
                        ctx.error(x, f"Collider.nocollide_sets.{sname}", "vertex out of range")
                        continue
                    setmask[vs + x.vertex_offset] |= set_bits[sname]
                one_sided[i] = c.one_sided
                kin[i] = bool(m.particle_kinematic[sl].all())
                geo = x.geometry
                verts.append(np.arange(sl.start, sl.stop))
                if len(geo.triangles):
                    tris.append(geo.triangles + x.vertex_offset)
                    tri_el.append(np.full(len(geo.triangles), i))
                    from lokigraph.behaviors.topology import triangle_edges

                    ed = triangle_edges(geo.triangles)
                else:
                    ed = geo.edges
                if len(ed):
                    edges.append(ed + x.vertex_offset)
                    edge_el.append(np.full(len(ed), i))
            allow = np.zeros((k, k), np.bool_)
            tol = np.zeros((k, k), np.bool_)
            for i in range(k):
                for j in range(k):
                    ci, cj = cols[i], cols[j]
                    if kin[i] and kin[j]:
                        continue
                    if i == j:
                        allow[i, j] = "self" in g.methods and ci.collide_self
                    elif kin[i] or kin[j]:
                        allow[i, j] = ci.collide_kinematic and cj.collide_kinematic
                        tol[i, j] = g.proximity_tolerant != "off"
                    else:
                        allow[i, j] = ci.collide_dynamic and cj.collide_dynamic
                    if g.proximity_tolerant == "on":
                        tol[i, j] = True
            for a, b in g.exclude_pairs:
                for nm in (a, b):
                    if nm not in idx:
                        ctx.error(e, "CollisionGroup.exclude_pairs", f"{nm!r} is not a member")
                if a in idx and b in idx:
                    allow[idx[a], idx[b]] = allow[idx[b], idx[a]] = False
            cat = lambda xs, s: np.concatenate(xs).astype(np.int64) if xs else np.zeros(  # noqa
                s, np.int64)
            groups.append(_Group(
                e.name, cat(verts, (0,)), cat(tris, (0, 3)), cat(edges, (0, 2)),
                cat(tri_el, (0,)), cat(edge_el, (0,)), vert_elem, allow, tol, th_out, th_in,
                fric, vis, setmask, one_sided, kin, "vertex_face" in g.methods,
                "edge_edge" in g.methods, g.margin, resp.strength, resp.damping,
                resp.restitution, resp.friction_scale, recover=kin & g.recover_crossings,
                side_mem=np.zeros((n, k), np.int8), side_seen=np.full((n, k), _NEVER),
                crossed=np.full((n, k), _NEVER), near_d=np.full((n, k), np.inf),
                near_s=np.zeros((n, k), np.int8)))
        if not groups:
            return None
        if MARGIN_EDGE > 0.0:
            for g in groups:
                g.margin_v = _edge_margin(m.particle_q0, g.edges, n, g.margin, MARGIN_EDGE)
        return _Contacts(groups, np.zeros((n, 3)), damping=max(g.damping for g in groups))

    def init_state(self, model, state, data):
        state.fields["contacts"] = data

    def step(self, ctx, d):
        st, m = ctx.state, ctx.model
        h = ctx.dt
        x = st.particle_q
        # predicted end-of-substep positions (before constraints): x + h (v + h f / m)
        x1 = d.x1
        np.multiply(st.particle_f, (h * m.particle_inv_mass)[:, None], out=x1)
        x1 += st.particle_qd
        x1 *= h
        x1 += x
        kin = m.particle_kinematic
        if kin.any():
            x1[kin] = ctx.control.kinematic_q[kin]
        if SPACETIME_RELATIVE:
            tolerant = _detect_all(d, x, x1, st.particle_qd, h, "relative", RELATIVE_SLACK)
            _relative_setup(d, st.particle_qd, h, RELATIVE_SLACK)
            d.rel_ref = x1
        else:
            d.rel_ref = None
            pred = SPACETIME and SPACETIME_PREDICTED
            tolerant = _detect_all(d, x, x1, st.particle_qd, h, pred,
                                   PREDICTED_SLACK if pred else 0.0)
        d.tolerant_count = tolerant
        ctx.stats["contacts_vf"] = ctx.stats.get("contacts_vf", 0) + len(d.vf)
        ctx.stats["contacts_ee"] = ctx.stats.get("contacts_ee", 0) + len(d.ee)
        ctx.stats["contacts_tolerant"] = ctx.stats.get("contacts_tolerant", 0) + tolerant

    def state_arrays(self, d):
        """Crossing memory of every group (which side of a kinematic sheet a vertex came from,
        when it was last seen and crossed, and the detection-pass counter these refer to)."""
        out = {}
        for i, g in enumerate(d.groups):
            out[f"{i}.side_mem"] = g.side_mem
            out[f"{i}.side_seen"] = g.side_seen
            out[f"{i}.crossed"] = g.crossed
            out[f"{i}.stamp"] = np.array(g.stamp, np.int64)
        return out

    def load_state_arrays(self, d, arrays):
        for i, g in enumerate(d.groups):
            g.side_mem[...] = arrays[f"{i}.side_mem"]
            g.side_seen[...] = arrays[f"{i}.side_seen"]
            g.crossed[...] = arrays[f"{i}.crossed"]
            g.stamp = int(arrays[f"{i}.stamp"])

    def describe(self, d):
        return "; ".join(f"{g.name}: {len(g.verts)} vertices, {len(g.tris)} triangles, "
                         f"{len(g.edges)} edges" for g in d.groups)


def _row_buffers(g, kind, n):
    """Arrays for the filters' output rows of ``n`` candidates (rows, normals, targets,
    friction, one-sided flags), every kept row written by the filter and packed into copies
    (``_pack``). With ``REUSE_BUFFERS`` views of buffers of the group, grown by half when too
    small; else new zeroed arrays."""
    sink = g.bufs.get("_sink")
    if sink is not None:  # ``PACK_DIRECT``: the next rows of the packed arrays themselves
        return sink.reserve(kind, n)
    if not REUSE_BUFFERS:
        return (np.zeros((n, 4), np.int64), np.zeros((n, 3)), np.zeros(n), np.zeros(n),
                np.zeros(n, np.bool_))
    b = g.bufs.get(kind)
    if b is None or len(b[2]) < n:
        m = bp.grown_size(n, len(b[2]) if b is not None else 0)
        b = g.bufs[kind] = (np.empty((m, 4), np.int64), np.empty((m, 3)), np.empty(m),
                            np.empty(m), np.empty(m, np.bool_))
    return tuple(a[:n] for a in b)


def _scratch(g, key, shape, dtype=np.float64):
    """An array of ``shape`` and ``dtype`` kept in the group under ``key`` (``REUSE_BUFFERS``),
    or None (the callee allocates) when not reusing."""
    if not REUSE_BUFFERS:
        return None
    a = g.bufs.get(key)
    if a is None or a.shape != shape or a.dtype != dtype:
        a = g.bufs[key] = np.empty(shape, dtype)
    return a


def _use_grid(g):
    """Whether the detections of group ``g`` use the column grid (``COLUMN_GRID``,
    ``COLUMN_GRID_MIN_TRIS``)."""
    return COLUMN_GRID and len(g.tris) >= COLUMN_GRID_MIN_TRIS


def _ordered(g, cand, order, out, n_a, a, b=None):
    """The candidate pairs ``cand`` in ``order`` ("index", "morton" or "zorder": see
    ``CANONICAL_ORDER``). ``a`` / ``b``: (scratch key, lo, hi) of the first / second
    primitives' boxes, ``n_a`` the first's count; ``b`` None for self pairs."""
    ra = rb = None
    if order != "index":
        ra = bp.morton_rank(a[1], a[2], _scratch(g, a[0], (len(a[1]),), np.int64))
        rb = ra if b is None else bp.morton_rank(b[1], b[2],
                                                 _scratch(g, b[0], (len(b[1]),), np.int64))
    if order == "zorder":
        return bp.zsort_pairs(cand, ra, rb, b is None, out)
    return bp.sort_pairs(cand, n_a, out, ra, rb)


def _st_group(g, elem, spacetime=True):
    """The space-time boxes' group labels of primitives of elements ``elem``: the elements
    themselves (pairs of two elements by their swept boxes), or one label for all
    (``SPACETIME_CROSS``: every pair tested in space-time). ``spacetime`` "relative"
    (``SPACETIME_RELATIVE``): one label for the primitives of every dynamic element, their
    own for a kinematic element's (pairs with a collider by their swept boxes)."""
    if spacetime == "relative":
        key = ("st_group_rel", "t" if elem is g.tri_elem else "e" if elem is g.edge_elem
               else "v")  # the vertices' elements: g.vert_elem[g.verts], fixed
        z = g.bufs.get(key)
        if z is None:
            z = g.bufs[key] = np.where(g.kinematic_el[elem], elem + 1, 0).astype(np.int64)
        return z
    if not SPACETIME_CROSS:
        return elem
    z = g.bufs.get(("st_group", len(elem)))
    if z is None:
        z = g.bufs[("st_group", len(elem))] = np.zeros(len(elem), np.int64)
    return z


def _box_start(g, x, x1):
    """``KINEMATIC_END_BOXES``: the start positions of the boxes of group ``g``: ``x`` with
    the kinematic members' vertices at ``x1`` (a buffer of the group)."""
    km = g.bufs.get("kin_verts")
    if km is None:
        km = g.bufs["kin_verts"] = g.verts[g.kinematic_el[g.vert_elem[g.verts]]]
    xb = _scratch(g, "x_box", x.shape)
    if xb is None:
        xb = np.empty_like(x)
    xb[:] = x
    xb[km] = x1[km]
    return xb


def _detect_group(g, x, x1, infl, v, h, spacetime=False, xb=None):
    """Candidates of group ``g`` for the motion x -> x1 (boxes inflated by ``infl`` [m] per
    vertex), filtered into rows. ``xb``: the boxes' start positions instead of ``x``
    (``KINEMATIC_END_BOXES``; swept boxes only)."""
    if xb is None:
        xb = x
    vf = (np.zeros((0, 4), np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros(0),
          np.zeros(0, np.bool_), g.strength)
    ee = (np.zeros((0, 4), np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros(0), g.strength)
    tol_count = 0
    split = spacetime and SPLIT_BUFFERS  # the space-time detections' own pair buffers
    if g.do_vf and len(g.tris):
        nv, nt = len(g.verts), len(g.tris)
        lo_v, hi_v = bp.primitive_boxes(xb, g.verts, x1, infl,
                                        _scratch(g, "lo_v", (nv, 3)),
                                        _scratch(g, "hi_v", (nv, 3)))
        lo_t, hi_t = bp.primitive_boxes(xb, g.tris, x1, infl,
                                        _scratch(g, "lo_t", (nt, 3)),
                                        _scratch(g, "hi_t", (nt, 3)))
        sv = st = None
        out = g.buf_vf_st if split else g.buf_vf
        grid = _use_grid(g)
        order = CANONICAL_ORDER or (GRID_ORDER if grid else False)
        if grid:
            if spacetime:
                ev = g.vert_elem[g.verts]
                sv = bp.spacetime_prim_boxes(x, g.verts, x1, infl, ~g.kinematic_el[ev],
                                             _st_group(g, ev, spacetime), _scratch(g, "sv_p", (nv, 14)))
                st = bp.spacetime_prim_boxes(x, g.tris, x1, infl, ~g.kinematic_el[g.tri_elem],
                                             _st_group(g, g.tri_elem, spacetime),
                                             _scratch(g, "st_p", (nt, 14)))
            cand = bp.column_query_pairs(lo_v, hi_v, lo_t, hi_t, g.verts, g.tris, out=out,
                                         st_a=sv, st_b=st)
        else:
            bv = bp.build_bvh(lo_v, hi_v)
            bt = bp.build_bvh(lo_t, hi_t)
            if spacetime:
                # kinematic objects never collide with each other: their subtrees are not
                # paired and only the self pairs of an element are tested in space-time
                ev = g.vert_elem[g.verts]
                sv = bp.spacetime_boxes(bv, x, g.verts, x1, infl, ~g.kinematic_el[ev],
                                        _st_group(g, ev, spacetime), _scratch(g, "sv", (2 * nv - 1, 14)))
                st = bp.spacetime_boxes(bt, x, g.tris, x1, infl, ~g.kinematic_el[g.tri_elem],
                                        _st_group(g, g.tri_elem, spacetime),
                                        _scratch(g, "st", (2 * nt - 1, 14)))
            cand = bp.query_pairs(bv, bt, g.verts, g.tris, out=out, st_a=sv, st_b=st)
        if order:
            cand = _ordered(g, cand, order, out, nv, ("rank_v", lo_v, hi_v),
                            ("rank_t", lo_t, hi_t))
        n = len(cand)
        if n:
            rows, nrm, tgt, mu, one = _row_buffers(g, "vf", n)
            g.stamp += 1
            k, tc = _filter_vf(cand, g.verts, g.tris, g.tri_elem, g.vert_elem, g.allow,
                               g.tolerant, g.th_out, g.th_in, g.friction, g.visible, g.setmask,
                               g.one_sided, x, v, h, g.restitution, g.margin, rows, nrm, tgt,
                               mu, one, g.recover, g.side_mem, g.side_seen, g.crossed,
                               g.stamp, g.near_d, g.near_s)
            tol_count += tc
            mu = mu[:k]
            mu *= g.friction_scale  # in place: the same products as a new array's
            vf = (rows[:k], nrm[:k], tgt[:k], mu, one[:k], g.strength)
    if g.do_ee and len(g.edges):
        vn = _vertex_normals(x, g) if g.one_sided.any() else np.zeros((0, 3))
        ne = len(g.edges)
        lo_e, hi_e = bp.primitive_boxes(xb, g.edges, x1, infl,
                                        _scratch(g, "lo_e", (ne, 3)),
                                        _scratch(g, "hi_e", (ne, 3)))
        out = g.buf_ee_st if split else g.buf_ee
        grid = _use_grid(g)
        order = CANONICAL_ORDER or (GRID_ORDER if grid else False)
        if grid:
            se = bp.spacetime_prim_boxes(x, g.edges, x1, infl, ~g.kinematic_el[g.edge_elem],
                                         _st_group(g, g.edge_elem, spacetime),
                                         _scratch(g, "se_p", (ne, 14))) \
                if spacetime else None
            cand = bp.column_query_self(lo_e, hi_e, g.edges, st=se, out=out)
        else:
            be = bp.build_bvh(lo_e, hi_e)
            se = bp.spacetime_boxes(be, x, g.edges, x1, infl, ~g.kinematic_el[g.edge_elem],
                                    _st_group(g, g.edge_elem, spacetime),
                                    _scratch(g, "se", (2 * ne - 1, 14))) \
                if spacetime else None
            cand = bp.query_self(be, g.edges, st=se, out=out)
        if order:
            cand = _ordered(g, cand, order, out, ne, ("rank_e", lo_e, hi_e))
        n = len(cand)
        if n:
            rows, nrm, tgt, mu, _ = _row_buffers(g, "ee", n)
            k, tc = _filter_ee(cand, g.edges, g.edge_elem, g.allow, g.tolerant, g.th_out,
                               g.friction, g.visible, g.setmask, g.one_sided, x, v, h,
                               g.restitution, g.margin, rows, nrm, tgt, mu, vn, g.crossed,
                               g.stamp)
            tol_count += tc
            mu = mu[:k]
            mu *= g.friction_scale
            ee = (rows[:k], nrm[:k], tgt[:k], mu, g.strength)
    return vf, ee, tol_count


def _vertex_normals(x, g):
    """Area-weighted vertex normals [-] of the group's triangles (rows of the global numbering;
    zero for vertices without triangles)."""
    n = np.zeros((len(x), 3))
    if len(g.tris):
        _vertex_normals_kernel(x, g.tris, n)
    return n


@njit(cache=True)
def _vertex_normals_kernel(x, tris, n):
    """Sum the triangles' area-weighted normals into ``n`` (corner 0 of every triangle, then
    corner 1, then corner 2: the order of the former ``np.add.at`` per corner, so the sums are
    bitwise those) and normalise the nonzero rows in place."""
    for k in range(3):
        for t in range(tris.shape[0]):
            a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
            e0, e1, e2 = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
            f0, f1, f2 = x[c, 0] - x[a, 0], x[c, 1] - x[a, 1], x[c, 2] - x[a, 2]
            v = tris[t, k]
            n[v, 0] += e1 * f2 - e2 * f1
            n[v, 1] += e2 * f0 - e0 * f2
            n[v, 2] += e0 * f1 - e1 * f0
    for i in range(n.shape[0]):
        ln = np.sqrt(n[i, 0] ** 2 + n[i, 1] ** 2 + n[i, 2] ** 2)
        if ln > 0:
            n[i, 0] /= ln
            n[i, 1] /= ln
            n[i, 2] /= ln


def _detect_all(d, x, x1, v, h, spacetime=False, slack=0.0) -> int:
    """Detect and pack the contacts of every group for the motion x -> x1; returns the number
    of proximity-tolerant contacts. ``spacetime``: test the self pairs of every element with
    space-time boxes (exact for the linear motion x -> x1 only: see ``SPACETIME``); ``slack``
    [m]: inflate every box by that much more (``SPACETIME_RELATIVE``)."""
    vf_all, ee_all = [], []
    tolerant = 0
    sink = _PackSink(d) if PACK_DIRECT and PACK_BUFFERS else None
    for g in d.groups:  # loop over groups, not primitives
        # boxes of both sets are inflated, so a pair is found within 2 * infl
        infl = _infl(g, slack)
        if sink is not None:
            g.bufs["_sink"] = sink
        try:
            if KINEMATIC_END_BOXES and not spacetime:
                vf, ee, t = _detect_group(g, x, x1, infl, v, h, spacetime,
                                          _box_start(g, x, x1))
            else:
                vf, ee, t = _detect_group(g, x, x1, infl, v, h, spacetime)
        finally:
            g.bufs.pop("_sink", None)
        if sink is not None:
            sink.commit("vf", vf)
            sink.commit("ee", ee)
        else:
            vf_all.append(vf)
            ee_all.append(ee)
        tolerant += t
    if sink is not None:
        sink.finish()
    else:
        _pack(d, vf_all, ee_all)
    _cull(d, x1)
    return tolerant


def _cull(d, x1):
    """Index the packed rows that can activate while no vertex moves more than ``cull_b`` from
    the detected end positions ``x1`` (copied): ``_project_contacts`` then visits only those,
    in their order, as long as that holds, and every row otherwise."""
    d.cull_b = -1.0
    if not CONTACT_CULL:
        return
    if d.cull_ref is None or d.cull_ref.shape != x1.shape:
        d.cull_ref = np.empty_like(x1)
    d.cull_ref[:] = x1
    b = 0.0
    for g in d.groups:
        if len(g.verts):
            b = max(b, float(np.maximum(g.th_out, g.th_in)[g.verts].max()) + 0.5 * g.margin)
    b *= CULL_REACH
    lim = 2.0 * b + _CULL_TOL
    for kind in ("vf", "ee"):
        rows = getattr(d, kind)
        sel, lb = getattr(d, kind + "_sel"), getattr(d, kind + "_lb")
        if len(rows) > len(sel):
            sel = np.zeros(max(2 * len(sel), bp.grown_size(len(rows), len(sel))), np.int64)
            lb = np.zeros(len(sel))
            setattr(d, kind + "_sel", sel)
            setattr(d, kind + "_lb", lb)
        k = _cull_rows(rows, getattr(d, kind + "_n"), getattr(d, kind + "_target"),
                       d.cull_ref, kind == "vf", lim, sel, lb)
        setattr(d, "n_" + kind + "_sel", k)
    d.cull_b = b


@njit(cache=True)
def _cull_rows(rows, nrm, target, ref, is_vf, lim, sel, lb):
    """Rows that may activate; writes their numbers, in order, to ``sel``; returns the count.
    ``lb[r]`` gets ``L - target`` of every row (the projection's per-row gate, see
    ``_project_ee_sel``).

    A contact's gap in the projection, ``g = d . n`` (``d`` the closest-point difference at
    the iterate, ``n`` the start normal ``n0`` or, when ``d . n0 > 0``, ``d / |d|``), is at
    least ``d . n0``. As ``d`` is a convex combination of the pair's vertex differences,
    ``d . n0 >= L - 2 u`` where ``L`` = min over the first primitive's vertices of ``y . n0``
    minus max over the second's at the reference positions ``y`` and ``u`` the largest motion
    of any vertex away from ``y``. A row with ``L - target >= lim = 2 b + tol`` therefore stays
    inactive while ``u <= b``: it is left out of ``sel``."""
    k = 0
    for r in range(rows.shape[0]):
        n0, n1, n2 = nrm[r, 0], nrm[r, 1], nrm[r, 2]
        if is_vf:
            v = rows[r, 0]
            lo = ref[v, 0] * n0 + ref[v, 1] * n1 + ref[v, 2] * n2
            hi = -np.inf
            for j in range(1, 4):
                q = rows[r, j]
                hi = max(hi, ref[q, 0] * n0 + ref[q, 1] * n1 + ref[q, 2] * n2)
        else:
            a0, a1, b0, b1 = rows[r, 0], rows[r, 1], rows[r, 2], rows[r, 3]
            lo = min(ref[a0, 0] * n0 + ref[a0, 1] * n1 + ref[a0, 2] * n2,
                     ref[a1, 0] * n0 + ref[a1, 1] * n1 + ref[a1, 2] * n2)
            hi = max(ref[b0, 0] * n0 + ref[b0, 1] * n1 + ref[b0, 2] * n2,
                     ref[b1, 0] * n0 + ref[b1, 1] * n1 + ref[b1, 2] * n2)
        lb[r] = lo - hi - target[r]
        if not (lb[r] >= lim):  # NaN keeps the row
            sel[k] = r
            k += 1
    return k


def _project_contacts(c, p, x, w, slide=None) -> int:
    """One Gauss-Seidel pass over all packed contacts; returns the number of active ones.
    ``slide``: the ``SLIDE_APART`` mode of this pass (None: that of the solver's contact
    passes, ``slide_mode(True)``)."""
    a = 0
    sl = slide_mode(True) if slide is None else slide
    b = c.cull_b
    if b < 0.0 or c.cull_ref is None:
        if len(c.vf):
            a += project_vf(p, x, w, c.vf, c.vf_n, c.vf_target, c.vf_mu, c.strength,
                            c.damping, c.vf_onesided, sl)
        if len(c.ee):
            a += project_ee(p, x, w, c.ee, c.ee_n, c.ee_target, c.ee_mu, c.ee_strength,
                            c.damping, sl)
        return a
    # exact culling: rows are gated by their bound (``lb``) and, while no vertex is farther than
    # b from the detected end positions, only the rows that can then activate are visited, in
    # their order, until a contact moves a vertex past b (then every row from there on)
    ref, b2 = c.cull_ref, b * b
    lbv, lbe = c.vf_lb[:len(c.vf)], c.ee_lb[:len(c.ee)]
    if MOVED_GATE:
        if c.moved is None or len(c.moved) != len(p):
            c.moved = np.zeros(len(p))
        u = c.moved
        far = _moved_norms(p, ref, u) > b
    else:
        u = _NO_U
        far = _max_move(ref, p) > b
    nv, ne = (-1, -1) if far else (c.n_vf_sel, c.n_ee_sel)
    if nv >= 0:
        c.cull_passes += 1
    else:
        c.full_passes += 1
    rv = re = -1
    if len(c.vf):
        av, rv = _project_vf_sel(p, x, w, c.vf, c.vf_n, c.vf_target, c.vf_mu, c.strength,
                                 c.damping, c.vf_onesided, c.vf_sel, nv, 0, ref, b2, lbv, sl,
                                 u)
        a += av
        if rv >= 0:
            a += _project_vf_sel(p, x, w, c.vf, c.vf_n, c.vf_target, c.vf_mu, c.strength,
                                 c.damping, c.vf_onesided, c.vf_sel, -1, rv, ref, b2, lbv, sl,
                                 u)[0]
            ne = -1
    if len(c.ee):
        ae, re = _project_ee_sel(p, x, w, c.ee, c.ee_n, c.ee_target, c.ee_mu, c.ee_strength,
                                 c.damping, c.ee_sel, ne, 0, ref, b2, lbe, sl, u)
        a += ae
        if re >= 0:
            a += _project_ee_sel(p, x, w, c.ee, c.ee_n, c.ee_target, c.ee_mu, c.ee_strength,
                                 c.damping, c.ee_sel, -1, re, ref, b2, lbe, sl, u)[0]
    return a


#: ``_pack`` writes the groups' rows into grow-only buffers of the contacts object (two sets
#: used in turn, so the rows of the previous detection stay valid until the next-but-one: a
#: caller may keep views of ``c.vf``, ``c.vf_n``, ... across one re-detection) instead of new
#: arrays from ``np.concatenate`` at every detection. The same values (copies either way), so
#: the positions are bitwise those of False (new arrays, for benchmarks).
PACK_BUFFERS = True

_PACK_VF = (((4,), np.int64), ((3,), np.float64), ((), np.float64), ((), np.float64),
            ((), np.bool_), ((), np.float64))  # rows, normals, targets, mu, one-sided, strength
_PACK_EE = (((4,), np.int64), ((3,), np.float64), ((), np.float64), ((), np.float64),
            ((), np.float64))  # rows, normals, targets, mu, strength


def _pack_turn(d, kind):
    """The contacts ``d``'s buffers and the key of the next buffer set of ``kind`` ("vf" /
    "ee"): the two sets alternate, so the arrays a detection packs stay valid while the next
    one is packed."""
    bufs = d.__dict__.setdefault("_pack_bufs", {})
    turn = bufs.get(kind + "_turn", 1) ^ 1
    bufs[kind + "_turn"] = turn
    return bufs, (kind, turn)


def _pack_grown(bufs, key, n, layout, keep=0):
    """The buffer set ``bufs[key]`` holding at least ``n`` rows, grown by half when too small
    (its first ``keep`` rows copied into the new set)."""
    b = bufs.get(key)
    if b is None or len(b[0]) < n:
        m = bp.grown_size(n, len(b[0]) if b is not None else 0)
        nb = tuple(np.empty((m,) + shape, dt) for shape, dt in layout)
        if b is not None and keep:
            for a, o in zip(nb, b):
                a[:keep] = o[:keep]
        b = bufs[key] = nb
    return b


def _set_packed(d, kind, out):
    """The contacts' packed arrays of ``kind`` from ``out`` (``_PACK_VF`` / ``_PACK_EE``)."""
    if kind == "vf":
        d.vf, d.vf_n, d.vf_target, d.vf_mu, d.vf_onesided, d.strength = out
    else:
        d.ee, d.ee_n, d.ee_target, d.ee_mu, d.ee_strength = out


def _pack_set(d, kind, n, layout):
    """Views of the first ``n`` rows of the next buffer set of ``kind`` ("vf" / "ee") of the
    contacts ``d`` (the two sets alternate; grown by half when too small)."""
    bufs, key = _pack_turn(d, kind)
    return tuple(a[:n] for a in _pack_grown(bufs, key, n, layout))


def _pack(d, vf_all, ee_all):
    """The rows of every group, packed into ``d.vf``, ``d.vf_n``, ... (``PACK_BUFFERS``)."""
    if not PACK_BUFFERS:
        _pack_new(d, vf_all, ee_all)
        return
    for kind, parts, layout in (("vf", vf_all, _PACK_VF), ("ee", ee_all, _PACK_EE)):
        n = sum(len(a[0]) for a in parts)
        out = _pack_set(d, kind, n, layout)
        i = 0
        for a in parts:  # loop over groups
            k = len(a[0])
            if k:
                for j in range(len(out) - 1):
                    out[j][i:i + k] = a[j]
                out[-1][i:i + k] = a[-1]  # the group's strength
            i += k
        _set_packed(d, kind, out)


#: the filters write their rows straight into ``_pack``'s next buffer set, group after group
#: (``_PackSink``), instead of into the group's buffers that ``_pack`` then copies: the same
#: values in the same places (the friction scaled in place, the strengths filled per group),
#: so the positions are bitwise those of False (10 frames of cloth_sphere_64 and of
#: cloth_sphere_moving_128). Measured with ``NUMBA_NUM_THREADS=1 peer_collision.py --moving
#: --loki 2x15 --stages --stage-frames 8 12 --frames 12 --all-flag PACK_DIRECT=False`` (one
#: interleaved run, load ~5): the first detection 2,109 -> 1,791 ms a frame (static 128 x 128)
#: and 4,114 -> 3,653 (moving): its pack part 520 / 879 ms -> 0, the filters 873 -> 1,134 /
#: 1,820 -> 2,311 (the first touch of the grown buffers' pages moves into them); median
#: frame CPU 1,489 -> 1,336 and 2,900 -> 2,474 ms. Tried and dropped beside it: an int32
#: copy of the rows for the culled passes (written by ``_cull_rows``; bitwise the same
#: positions): passes 840 -> 824 / 1,664 -> 1,708 ms a frame (static / moving), the cull
#: 93 -> 212 / 169 -> 393 ms; and exact per-vertex or per-block culls of the passes (a row
#: skipped while its vertices' motion since the detection, |p - ref|, or the spread of that
#: motion over a block of 16-64 consecutive rows, cannot close its bound): on frame 9 of the
#: moving scene they would still visit 17-75 % (per vertex) and 60-85 % (blocks) of the rows
#: of the 16 contact passes, where the per-row gate opens for 2-7 %
PACK_DIRECT = True


class _PackSink:
    """``PACK_DIRECT``: hands the filters of one detection views of the next ``_pack`` buffer
    set at the running offset (``reserve``), takes each group's result (``commit``: in place
    when it is that view, copied otherwise, e.g. from a wrapped ``_detect_group``), and sets
    the contacts' arrays (``finish``). The buffer sets alternate as ``_pack_set``'s do."""

    def __init__(self, d):
        self.d = d
        self.key = {}
        self.off = {"vf": 0, "ee": 0}
        for kind in ("vf", "ee"):
            self.bufs, self.key[kind] = _pack_turn(d, kind)

    def _set(self, kind, n):
        """The buffer set of ``kind`` holding at least the offset plus ``n`` rows (grown by
        half, the rows so far copied)."""
        i = self.off[kind]
        return _pack_grown(self.bufs, self.key[kind], i + n,
                           _PACK_VF if kind == "vf" else _PACK_EE, keep=i)

    def reserve(self, kind, n):
        """As ``_row_buffers``: (rows, normals, targets, friction, one-sided flags or None) of
        ``n`` rows at the offset."""
        b = self._set(kind, n)
        i = self.off[kind]
        return tuple(a[i:i + n] for a in b[:4]) + ((b[4][i:i + n],) if kind == "vf" else (None,))

    def commit(self, kind, part):
        """Take a group's rows (``_detect_group``'s tuple for ``kind``) at the offset."""
        k = len(part[0])
        if not k:
            return
        b = self._set(kind, k)
        i = self.off[kind]
        for j in range(len(b) - 1):
            if part[j].__array_interface__["data"][0] != b[j][i:].__array_interface__["data"][0]:
                b[j][i:i + k] = part[j]
        b[-1][i:i + k] = part[-1]  # the group's strength
        self.off[kind] = i + k

    def finish(self):
        for kind in ("vf", "ee"):
            _set_packed(self.d, kind, tuple(a[:self.off[kind]] for a in self._set(kind, 0)))


def _pack_new(d, vf_all, ee_all):
    d.vf = np.concatenate([a[0] for a in vf_all]) if vf_all else np.zeros((0, 4), np.int64)
    d.vf_n = np.concatenate([a[1] for a in vf_all]) if vf_all else np.zeros((0, 3))
    d.vf_target = np.concatenate([a[2] for a in vf_all]) if vf_all else np.zeros(0)
    d.vf_mu = np.concatenate([a[3] for a in vf_all]) if vf_all else np.zeros(0)
    d.vf_onesided = np.concatenate([a[4] for a in vf_all]) if vf_all else np.zeros(0, np.bool_)
    d.strength = np.concatenate([np.full(len(a[0]), a[5]) for a in vf_all]) if vf_all \
        else np.zeros(0)
    d.ee = np.concatenate([a[0] for a in ee_all]) if ee_all else np.zeros((0, 4), np.int64)
    d.ee_n = np.concatenate([a[1] for a in ee_all]) if ee_all else np.zeros((0, 3))
    d.ee_target = np.concatenate([a[2] for a in ee_all]) if ee_all else np.zeros(0)
    d.ee_mu = np.concatenate([a[3] for a in ee_all]) if ee_all else np.zeros(0)
    d.ee_strength = np.concatenate([np.full(len(a[0]), a[4]) for a in ee_all]) if ee_all \
        else np.zeros(0)


@njit(cache=True, inline="always")
def _tri_normal_s(x, a, b, c):
    """Unit normal of triangle abc and twice its area [m^2]: (n0, n1, n2, |n|); for a degenerate
    one the unnormalised normal and 0. Scalars, no allocation."""
    e0, e1, e2 = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
    f0, f1, f2 = x[c, 0] - x[a, 0], x[c, 1] - x[a, 1], x[c, 2] - x[a, 2]
    n0 = e1 * f2 - e2 * f1
    n1 = e2 * f0 - e0 * f2
    n2 = e0 * f1 - e1 * f0
    ln = np.sqrt(n0 ** 2 + n1 ** 2 + n2 ** 2)
    if ln < 1e-300:
        return n0, n1, n2, 0.0
    return n0 / ln, n1 / ln, n2 / ln, ln


@njit(cache=True)
def _min_bary(p, a, b, c):
    """Smallest barycentric coordinate of p projected onto the plane of triangle abc."""
    v0 = b - a
    v1 = c - a
    v2 = p - a
    d00 = v0[0] * v0[0] + v0[1] * v0[1] + v0[2] * v0[2]
    d01 = v0[0] * v1[0] + v0[1] * v1[1] + v0[2] * v1[2]
    d11 = v1[0] * v1[0] + v1[1] * v1[1] + v1[2] * v1[2]
    d20 = v2[0] * v0[0] + v2[1] * v0[1] + v2[2] * v0[2]
    d21 = v2[0] * v1[0] + v2[1] * v1[1] + v2[2] * v1[2]
    den = d00 * d11 - d01 * d01
    if den <= 0.0:
        return -1.0
    bb = (d11 * d20 - d01 * d21) / den
    cc = (d00 * d21 - d01 * d20) / den
    return min(1.0 - bb - cc, bb, cc)


@njit(cache=True, inline="always")
def _remembers_side(side_mem, side_seen, p, e, stamp):
    """Does vertex p still remember a side of element e (seen within SIDE_MEMORY passes)?"""
    return side_mem[p, e] != 0 and side_seen[p, e] >= stamp - SIDE_MEMORY


@njit(cache=True)
def _filter_vf(cand, verts, tris, tri_elem, vert_elem, allow, tolerant, th_out, th_in, fric,
               visible, setmask, one_sided, x, v, h, restitution, margin, rows, nrm, tgt, mu,
               one, recover, side_mem, side_seen, crossed_at, stamp, near_d, near_s):
    """Keep allowed vertex-triangle candidates; record start normal, target gap, friction.

    A dynamic vertex near a two-sided kinematic element remembers the side it came from (set
    when the pair is first found, kept while it stays a candidate, forgotten SIDE_MEMORY passes
    after it was last one). If animation pushed it through (an impossible pinch), the contact
    points back to the remembered side and pulls it back by at most half its thickness per
    substep, so the cloth returns once the gap reopens instead of staying on the wrong side.

    The side of an element is the side of its *nearest* triangle, taken where the vertex
    projects onto it (found in two first passes over the candidates: the nearest distance,
    then a triangle the vertex projects onto at that distance): on a closed or curved two-sided
    mesh the vertex is below the planes of the far triangles it also projects onto, and taking
    the side of whichever candidate comes first would flag a vertex outside a ball as crossed.
    Where the nearest point is on an edge or a corner that no triangle the vertex projects
    onto reaches (outside a convex mesh), the side stays undecided for that pass: the nearest
    of the triangles it does project onto is a far one it lies behind (measured: the stress
    projectile, a 20 m/s ball, remembered a cloth vertex 25 mm in front of it as inside, then
    pulled it in as "crossed"; 4 crossing pairs from frame 6 to the end -> 0)."""
    k = 0
    tcount = 0
    for r in range(cand.shape[0]):  # distance of every (vertex, element) to its nearest triangle
        p = verts[cand[r, 0]]
        t = cand[r, 1]
        et = tri_elem[t]
        ep = vert_elem[p]
        if not recover[et] or recover[ep] or not allow[ep, et]:
            continue
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        d2 = _pt_tri_sq(x[p, 0], x[p, 1], x[p, 2], x[a, 0], x[a, 1], x[a, 2],
                        x[b, 0], x[b, 1], x[b, 2], x[c, 0], x[c, 1], x[c, 2])[0]
        if d2 < near_d[p, et]:
            near_d[p, et] = d2
    for r in range(cand.shape[0]):  # the side of a nearest triangle the vertex projects onto
        p = verts[cand[r, 0]]
        t = cand[r, 1]
        et = tri_elem[t]
        ep = vert_elem[p]
        if not recover[et] or recover[ep] or not allow[ep, et] or near_s[p, et] != 0:
            continue
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        tn0, tn1, tn2, area2 = _tri_normal_s(x, a, b, c)
        if area2 == 0.0 or _min_bary(x[p], x[a], x[b], x[c]) < -1e-3:
            continue
        side = ((x[p, 0] - x[a, 0]) * tn0 + (x[p, 1] - x[a, 1]) * tn1
                + (x[p, 2] - x[a, 2]) * tn2)
        if side * side <= near_d[p, et] * (1.0 + 1e-6) + 1e-24:
            near_s[p, et] = 1 if side >= 0.0 else -1
    for r in range(cand.shape[0]):
        p = verts[cand[r, 0]]
        t = cand[r, 1]
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        ep = vert_elem[p]
        et = tri_elem[t]
        if not allow[ep, et]:
            continue
        if recover[ep] and (crossed_at[a, ep] >= stamp - 1 or crossed_at[b, ep] >= stamp - 1
                           or crossed_at[c, ep] >= stamp - 1):
            continue  # a sheet vertex against cloth pushed through it: would hold it there
        if not (visible[p] and visible[a] and visible[b] and visible[c]):
            continue
        if setmask[p] & setmask[a] & setmask[b] & setmask[c]:
            continue
        d2, b0, b1, b2 = _pt_tri_sq(x[p, 0], x[p, 1], x[p, 2], x[a, 0], x[a, 1], x[a, 2],
                                     x[b, 0], x[b, 1], x[b, 2], x[c, 0], x[c, 1], x[c, 2])
        d0 = np.sqrt(d2)
        tn0, tn1, tn2, area2 = _tri_normal_s(x, a, b, c)
        # scalar arithmetic (no per-candidate allocation), the same operations as vectors
        df0 = x[p, 0] - (b0 * x[a, 0] + b1 * x[b, 0] + b2 * x[c, 0])
        df1 = x[p, 1] - (b0 * x[a, 1] + b1 * x[b, 1] + b2 * x[c, 1])
        df2 = x[p, 2] - (b0 * x[a, 2] + b1 * x[b, 2] + b2 * x[c, 2])
        side = df0 * tn0 + df1 * tn1 + df2 * tn2
        if one_sided[et]:
            if area2 == 0.0:
                continue
            # the plane test is only meaningful where the vertex projects onto the triangle
            # (a vertex above a sphere is "behind" the planes of the equator triangles)
            if _min_bary(x[p], x[a], x[b], x[c]) < -0.05:
                continue
            if side < -(th_out[p] + th_in[a] + margin):
                continue  # deep inside a one-sided body: let it through
            n0, n1, n2 = tn0, tn1, tn2
            gap0 = side  # signed: negative = inside
            th = th_out[p] + (th_out[a] * b0 + th_out[b] * b1 + th_out[c] * b2)
            onesd = True
        else:
            cur = 1 if side >= 0.0 else -1
            crossed = False
            # the side is only meaningful where the vertex projects onto the triangle (beside
            # a box it is "below" the top face's plane and still outside)
            if recover[et] and not recover[ep] and area2 > 0.0 \
                    and _min_bary(x[p], x[a], x[b], x[c]) >= -1e-3:
                near = near_s[p, et]  # the element's side: that of its nearest triangle
                if not _remembers_side(side_mem, side_seen, p, et, stamp):
                    side_mem[p, et] = near  # first seen: trust the start
                side_seen[p, et] = stamp
                # crossed if the nearest triangle says so, through the triangles on that side
                crossed = side_mem[p, et] != near and cur == near
            elif recover[et] and (crossed_at[p, et] >= stamp - 1 or (
                    near_s[p, et] != 0 and _remembers_side(side_mem, side_seen, p, et, stamp)
                    and side_mem[p, et] != near_s[p, et])):
                # pushed through this sheet: only the triangles it is under pull back (also in
                # the pass that first finds it through, whatever the candidate order: a
                # triangle it does not project onto, met before the one that flags it, kept
                # a row from the start separation that pushed it farther in)
                continue
            if crossed:
                crossed_at[p, et] = stamp
                if side >= 0.0:
                    n0, n1, n2 = -tn0, -tn1, -tn2
                else:
                    n0, n1, n2 = tn0, tn1, tn2
                gap0 = -d0
                side = -side
            elif d0 > 1e-12:
                n0, n1, n2 = df0 / d0, df1 / d0, df2 / d0
                gap0 = d0
            elif area2 > 0.0:
                if side >= 0.0:
                    n0, n1, n2 = tn0, tn1, tn2
                else:
                    n0, n1, n2 = -tn0, -tn1, -tn2
                gap0 = d0
            else:
                continue
            if side >= 0.0:  # the (remembered) side decides outer or inner thickness
                th = th_out[p] + (th_out[a] * b0 + th_out[b] * b1 + th_out[c] * b2)
            else:
                th = th_out[p] + (th_in[a] * b0 + th_in[b] * b1 + th_in[c] * b2)
            onesd = False
        # relative normal approach speed at the start (for restitution)
        vn = ((v[p, 0] - (b0 * v[a, 0] + b1 * v[b, 0] + b2 * v[c, 0])) * n0
              + (v[p, 1] - (b0 * v[a, 1] + b1 * v[b, 1] + b2 * v[c, 1])) * n1
              + (v[p, 2] - (b0 * v[a, 2] + b1 * v[b, 2] + b2 * v[c, 2])) * n2)
        target = th
        if restitution > 0.0 and vn < 0.0:
            target = th - restitution * vn * h
        if gap0 < th and tolerant[ep, et]:
            target = max(gap0, 0.0) if not onesd else gap0
            tcount += 1
        if not onesd and gap0 < 0.0:  # crossed: back toward the remembered side, gently
            target = min(gap0 + 0.5 * th, th)
        rows[k, 0] = p
        rows[k, 1] = a
        rows[k, 2] = b
        rows[k, 3] = c
        nrm[k, 0] = n0
        nrm[k, 1] = n1
        nrm[k, 2] = n2
        tgt[k] = target
        mu[k] = 0.5 * (fric[p] + (fric[a] + fric[b] + fric[c]) / 3.0)
        one[k] = onesd
        k += 1
    for r in range(cand.shape[0]):  # reset the scratch for the next pass
        p = verts[cand[r, 0]]
        et = tri_elem[cand[r, 1]]
        near_d[p, et] = np.inf
        near_s[p, et] = 0
    return k, tcount


@njit(cache=True)
def _filter_ee(cand, edges, edge_elem, allow, tolerant, th, fric, visible, setmask, one_sided,
               x, v, h, restitution, margin, rows, nrm, tgt, mu, vnorm, crossed_at, stamp):
    k = 0
    tcount = 0
    for r in range(cand.shape[0]):
        i, j = cand[r, 0], cand[r, 1]
        a0, a1 = edges[i, 0], edges[i, 1]
        b0, b1 = edges[j, 0], edges[j, 1]
        ea, eb = edge_elem[i], edge_elem[j]
        if not allow[ea, eb] or (one_sided[ea] and one_sided[eb]):
            continue
        # an edge with an end pushed through a kinematic sheet is pulled back by the
        # vertex-face contacts; an edge-edge push here would hold it on the wrong side
        if (crossed_at[a0, eb] >= stamp - 1 or crossed_at[a1, eb] >= stamp - 1
                or crossed_at[b0, ea] >= stamp - 1 or crossed_at[b1, ea] >= stamp - 1):
            continue
        if not (visible[a0] and visible[a1] and visible[b0] and visible[b1]):
            continue
        if setmask[a0] & setmask[a1] & setmask[b0] & setmask[b1]:
            continue
        d2, s, t = _seg_seg_sq(x[a0, 0], x[a0, 1], x[a0, 2], x[a1, 0], x[a1, 1], x[a1, 2],
                               x[b0, 0], x[b0, 1], x[b0, 2], x[b1, 0], x[b1, 1], x[b1, 2])
        d0 = np.sqrt(d2)
        # scalar arithmetic (no per-candidate allocation), the same operations as vectors
        if d0 > 1e-12:
            n0 = ((1 - s) * x[a0, 0] + s * x[a1, 0] - ((1 - t) * x[b0, 0] + t * x[b1, 0])) / d0
            n1 = ((1 - s) * x[a0, 1] + s * x[a1, 1] - ((1 - t) * x[b0, 1] + t * x[b1, 1])) / d0
            n2 = ((1 - s) * x[a0, 2] + s * x[a1, 2] - ((1 - t) * x[b0, 2] + t * x[b1, 2])) / d0
        else:  # rare: touching or crossing edges, normal of both edges
            n = np.cross(x[a1] - x[a0], x[b1] - x[b0])
            ln = np.sqrt(n[0] ** 2 + n[1] ** 2 + n[2] ** 2)
            if ln < 1e-300:
                continue
            n = n / ln
            n0, n1, n2 = n[0], n[1], n[2]
        if one_sided[ea] or one_sided[eb]:
            # against a one-sided mesh: only a pair that starts on its outer side collides
            # (outer = along the mesh's vertex normals at its closest point)
            if d0 <= 1e-12:
                continue
            if one_sided[eb]:
                out = (n0 * ((1 - t) * vnorm[b0, 0] + t * vnorm[b1, 0])
                       + n1 * ((1 - t) * vnorm[b0, 1] + t * vnorm[b1, 1])
                       + n2 * ((1 - t) * vnorm[b0, 2] + t * vnorm[b1, 2]))
            else:
                out = -(n0 * ((1 - s) * vnorm[a0, 0] + s * vnorm[a1, 0])
                        + n1 * ((1 - s) * vnorm[a0, 1] + s * vnorm[a1, 1])
                        + n2 * ((1 - s) * vnorm[a0, 2] + s * vnorm[a1, 2]))
            if out <= 0.0:
                continue
        thk = (1 - s) * th[a0] + s * th[a1] + (1 - t) * th[b0] + t * th[b1]
        vn = (((1 - s) * v[a0, 0] + s * v[a1, 0] - (1 - t) * v[b0, 0] - t * v[b1, 0]) * n0
              + ((1 - s) * v[a0, 1] + s * v[a1, 1] - (1 - t) * v[b0, 1] - t * v[b1, 1]) * n1
              + ((1 - s) * v[a0, 2] + s * v[a1, 2] - (1 - t) * v[b0, 2] - t * v[b1, 2]) * n2)
        target = thk
        if restitution > 0.0 and vn < 0.0:
            target = thk - restitution * vn * h
        if d0 < thk and tolerant[ea, eb]:
            target = d0
            tcount += 1
        rows[k, 0] = a0
        rows[k, 1] = a1
        rows[k, 2] = b0
        rows[k, 3] = b1
        nrm[k, 0] = n0
        nrm[k, 1] = n1
        nrm[k, 2] = n2
        tgt[k] = target
        mu[k] = 0.25 * (fric[a0] + fric[a1] + fric[b0] + fric[b1])
        k += 1
    return k, tcount


@njit(cache=True, inline="always")
def _slid_apart(d2, dn, tgt, wa, wb, mode):
    """A two-sided row on the far side of n0 (``dn`` = separation . n0 <= 0) whose primitives'
    closest points (squared distance ``d2``) lie at least its target ``tgt`` apart across n0,
    with ``mode`` 1 only where one primitive is immovable (summed inverse masses ``wa`` or
    ``wb`` zero), with 2 any: slid past each other, not crossed (``SLIDE_APART``, as
    ``slide_mode`` gives it to the site)."""
    return ((mode >= 2 or wa <= 0.0 or wb <= 0.0) and mode >= 1
            and d2 - dn * dn >= tgt * tgt)


@njit(cache=True)
def project_vf(p, x, w, rows, nrm, target, mu, strength, damping, onesided, slide=0):
    """Gauss-Seidel over vertex-face contacts: n . (p_v - sum b_k p_k) >= target, plus
    position-based Coulomb friction on the relative tangential motion of the substep.
    ``slide``: ``SLIDE_APART``."""
    return _project_vf_sel(p, x, w, rows, nrm, target, mu, strength, damping, onesided,
                           _NO_SEL, -1, 0, _NO_REF, -1.0, _NO_LB, slide)[0]


_NO_SEL = np.zeros(0, np.int64)
_NO_REF = np.zeros((0, 3))
_NO_LB = np.zeros(0)
_NO_U = np.zeros(0)  # no per-vertex moved distances (``MOVED_GATE`` off)


@njit(cache=True, inline="always")
def _dn(p, ref, i, n0, n1, n2):
    """Motion [m] of vertex i from its reference position along (n0, n1, n2)."""
    return (p[i, 0] - ref[i, 0]) * n0 + (p[i, 1] - ref[i, 1]) * n1 + (p[i, 2] - ref[i, 2]) * n2


@njit(cache=True)
def _moved2(p, ref, i):
    """Squared distance [m^2] of vertex i from its reference position."""
    return (p[i, 0] - ref[i, 0]) ** 2 + (p[i, 1] - ref[i, 1]) ** 2 + (p[i, 2] - ref[i, 2]) ** 2


@njit(cache=True)
def _project_vf_sel(p, x, w, rows, nrm, target, mu, strength, damping, onesided, sel, nsel,
                    start, ref, b2, lb, slide=0, u=_NO_U):
    """``project_vf`` over the rows ``sel[:nsel]`` in that order (rows ``start:`` if nsel < 0).
    Over a selection, a row that moves one of its vertices farther than ``sqrt(b2)`` from
    ``ref`` ends the pass early: returns (active, the row number to resume every row from);
    otherwise (active, -1). With ``lb`` (``L - target`` of every row, ``_cull_rows``), a row
    whose gap provably exceeds its target, ``lb + min over the first primitive's vertices of
    (p - ref) . n0 - max over the second's >= tol``, is skipped before its distance query
    (exact: it would be inactive)."""
    active = 0
    n_it = rows.shape[0] if nsel < 0 else nsel
    for it in range(start if nsel < 0 else 0, n_it):
        r = it if nsel < 0 else sel[it]
        v, a, b, c = rows[r, 0], rows[r, 1], rows[r, 2], rows[r, 3]
        if lb.shape[0]:
            if u.shape[0] and (lb[r] - u[v] - max(u[a], u[b], u[c])
                               >= _CULL_TOL + _GATE_TOL):
                continue
            m0, m1, m2 = nrm[r, 0], nrm[r, 1], nrm[r, 2]
            sv = _dn(p, ref, v, m0, m1, m2)
            sa = _dn(p, ref, a, m0, m1, m2)
            sb = _dn(p, ref, b, m0, m1, m2)
            sc = _dn(p, ref, c, m0, m1, m2)
            if lb[r] + sv - max(sa, sb, sc) >= _CULL_TOL:
                continue
        # (bc0, bc1, bc2: barycentric; ``b2`` is the cull bound, kept for the early exit)
        d2, bc0, bc1, bc2 = _pt_tri_sq(p[v, 0], p[v, 1], p[v, 2], p[a, 0], p[a, 1], p[a, 2],
                                        p[b, 0], p[b, 1], p[b, 2], p[c, 0], p[c, 1], p[c, 2])
        n0, n1, n2 = nrm[r, 0], nrm[r, 1], nrm[r, 2]
        qx = bc0 * p[a, 0] + bc1 * p[b, 0] + bc2 * p[c, 0]
        qy = bc0 * p[a, 1] + bc1 * p[b, 1] + bc2 * p[c, 1]
        qz = bc0 * p[a, 2] + bc1 * p[b, 2] + bc2 * p[c, 2]
        dx, dy, dz = p[v, 0] - qx, p[v, 1] - qy, p[v, 2] - qz
        if not onesided[r]:
            # still on the start side: separate along the current closest-point direction
            # (follows the geometry around edges and corners); crossed: push back along n0
            dist = np.sqrt(d2)
            dn = dx * n0 + dy * n1 + dz * n2
            if dist > 1e-12 and dn > 0.0:
                n0, n1, n2 = dx / dist, dy / dist, dz / dist
            elif slide and _slid_apart(d2, dn, target[r], w[v], w[a] + w[b] + w[c], slide):
                continue
        gap = dx * n0 + dy * n1 + dz * n2
        C = gap - target[r]
        if C >= 0.0:
            continue
        den = w[v] + bc0 * bc0 * w[a] + bc1 * bc1 * w[b] + bc2 * bc2 * w[c]
        if den <= 0.0:
            continue
        active += 1
        dl = -C / den * strength[r]
        p[v, 0] += w[v] * dl * n0
        p[v, 1] += w[v] * dl * n1
        p[v, 2] += w[v] * dl * n2
        for k, bk in ((a, bc0), (b, bc1), (c, bc2)):
            p[k, 0] -= w[k] * bk * dl * n0
            p[k, 1] -= w[k] * bk * dl * n1
            p[k, 2] -= w[k] * bk * dl * n2
        # friction: relative tangential displacement over the substep
        m = mu[r]
        if m > 0.0 or damping > 0.0:
            rx = (p[v, 0] - x[v, 0]) - (bc0 * (p[a, 0] - x[a, 0]) + bc1 * (p[b, 0] - x[b, 0])
                                        + bc2 * (p[c, 0] - x[c, 0]))
            ry = (p[v, 1] - x[v, 1]) - (bc0 * (p[a, 1] - x[a, 1]) + bc1 * (p[b, 1] - x[b, 1])
                                        + bc2 * (p[c, 1] - x[c, 1]))
            rz = (p[v, 2] - x[v, 2]) - (bc0 * (p[a, 2] - x[a, 2]) + bc1 * (p[b, 2] - x[b, 2])
                                        + bc2 * (p[c, 2] - x[c, 2]))
            rn = rx * n0 + ry * n1 + rz * n2
            tx, ty, tz = rx - rn * n0, ry - rn * n1, rz - rn * n2
            tl = np.sqrt(tx * tx + ty * ty + tz * tz)
            if tl > 1e-300:
                f = min(1.0, m * (-C) / tl + damping)
                s = f / den
                p[v, 0] -= w[v] * s * tx
                p[v, 1] -= w[v] * s * ty
                p[v, 2] -= w[v] * s * tz
                for k, bk in ((a, bc0), (b, bc1), (c, bc2)):
                    p[k, 0] += w[k] * bk * s * tx
                    p[k, 1] += w[k] * bk * s * ty
                    p[k, 2] += w[k] * bk * s * tz
        if u.shape[0]:
            for k in (v, a, b, c):
                u[k] = np.sqrt(_moved2(p, ref, k))
        if nsel >= 0 and (_moved2(p, ref, v) > b2 or _moved2(p, ref, a) > b2
                          or _moved2(p, ref, b) > b2 or _moved2(p, ref, c) > b2):
            return active, sel[it] + 1
    return active, -1


@njit(cache=True)
def project_ee(p, x, w, rows, nrm, target, mu, strength, damping, slide=0):
    """Gauss-Seidel over edge-edge contacts: n . (x_a(s) - x_b(t)) >= target, with friction.
    ``slide``: ``SLIDE_APART``."""
    return _project_ee_sel(p, x, w, rows, nrm, target, mu, strength, damping, _NO_SEL, -1, 0,
                           _NO_REF, -1.0, _NO_LB, slide)[0]


@njit(cache=True)
def _project_ee_sel(p, x, w, rows, nrm, target, mu, strength, damping, sel, nsel, start, ref,
                    b2, lb, slide=0, u=_NO_U):
    """``project_ee`` over the rows ``sel[:nsel]`` in that order (rows ``start:`` if nsel < 0);
    scalar arithmetic, no per-row allocation.
    Over a selection, a row that moves one of its vertices farther than ``sqrt(b2)`` from
    ``ref`` ends the pass early: returns (active, the row number to resume every row from);
    otherwise (active, -1). With ``lb`` (``L - target`` of every row, ``_cull_rows``), a row
    whose gap provably exceeds its target, ``lb + min over the first primitive's vertices of
    (p - ref) . n0 - max over the second's >= tol``, is skipped before its distance query
    (exact: it would be inactive)."""
    active = 0
    n_it = rows.shape[0] if nsel < 0 else nsel
    for it in range(start if nsel < 0 else 0, n_it):
        r = it if nsel < 0 else sel[it]
        a0, a1, b0, b1 = rows[r, 0], rows[r, 1], rows[r, 2], rows[r, 3]
        n0, n1, n2 = nrm[r, 0], nrm[r, 1], nrm[r, 2]
        if lb.shape[0]:
            if u.shape[0] and (lb[r] - max(u[a0], u[a1]) - max(u[b0], u[b1])
                               >= _CULL_TOL + _GATE_TOL):
                continue
            s0 = _dn(p, ref, a0, n0, n1, n2)
            s1 = _dn(p, ref, a1, n0, n1, n2)
            s2 = _dn(p, ref, b0, n0, n1, n2)
            s3 = _dn(p, ref, b1, n0, n1, n2)
            if lb[r] + min(s0, s1) - max(s2, s3) >= _CULL_TOL:
                continue
        d2, s, t = _seg_seg_sq(p[a0, 0], p[a0, 1], p[a0, 2], p[a1, 0], p[a1, 1], p[a1, 2],
                               p[b0, 0], p[b0, 1], p[b0, 2], p[b1, 0], p[b1, 1], p[b1, 2])
        ca, cb, cc, cd = 1.0 - s, s, -(1.0 - t), -t
        dv0 = ca * p[a0, 0] + cb * p[a1, 0] + cc * p[b0, 0] + cd * p[b1, 0]
        dv1 = ca * p[a0, 1] + cb * p[a1, 1] + cc * p[b0, 1] + cd * p[b1, 1]
        dv2 = ca * p[a0, 2] + cb * p[a1, 2] + cc * p[b0, 2] + cd * p[b1, 2]
        dist = np.sqrt(d2)
        dn = dv0 * n0 + dv1 * n1 + dv2 * n2
        if dist > 1e-12 and dn > 0.0:
            # same side as at the start: follow the current geometry
            n0, n1, n2 = dv0 / dist, dv1 / dist, dv2 / dist
        elif slide and _slid_apart(d2, dn, target[r], w[a0] + w[a1], w[b0] + w[b1], slide):
            continue
        g = dv0 * n0 + dv1 * n1 + dv2 * n2
        C = g - target[r]
        if C >= 0.0:
            continue
        den = ca * ca * w[a0] + cb * cb * w[a1] + cc * cc * w[b0] + cd * cd * w[b1]
        if den <= 0.0:
            continue
        active += 1
        dl = -C / den * strength[r]
        for vtx, cf in ((a0, ca), (a1, cb), (b0, cc), (b1, cd)):
            p[vtx, 0] += w[vtx] * cf * dl * n0
            p[vtx, 1] += w[vtx] * cf * dl * n1
            p[vtx, 2] += w[vtx] * cf * dl * n2
        m = mu[r]
        if m > 0.0 or damping > 0.0:
            r0 = 0.0
            r1 = 0.0
            r2 = 0.0
            for vtx, cf in ((a0, ca), (a1, cb), (b0, cc), (b1, cd)):
                r0 += cf * (p[vtx, 0] - x[vtx, 0])
                r1 += cf * (p[vtx, 1] - x[vtx, 1])
                r2 += cf * (p[vtx, 2] - x[vtx, 2])
            rn = r0 * n0 + r1 * n1 + r2 * n2
            t0, t1, t2 = r0 - rn * n0, r1 - rn * n1, r2 - rn * n2
            tl = np.sqrt(t0 ** 2 + t1 ** 2 + t2 ** 2)
            if tl > 1e-300:
                f = min(1.0, m * (-C) / tl + damping)
                sc = f / den
                for vtx, cf in ((a0, ca), (a1, cb), (b0, cc), (b1, cd)):
                    p[vtx, 0] -= w[vtx] * cf * sc * t0
                    p[vtx, 1] -= w[vtx] * cf * sc * t1
                    p[vtx, 2] -= w[vtx] * cf * sc * t2
        if u.shape[0]:
            for k in (a0, a1, b0, b1):
                u[k] = np.sqrt(_moved2(p, ref, k))
        if nsel >= 0 and (_moved2(p, ref, a0) > b2 or _moved2(p, ref, a1) > b2
                          or _moved2(p, ref, b0) > b2 or _moved2(p, ref, b1) > b2):
            return active, sel[it] + 1
    return active, -1


# ---------------------------------------------------------------------------------------------
# Continuous collision detection in the loop: the final safe step
# ---------------------------------------------------------------------------------------------
#
# After the final rounds, the motion x -> p of the substep is checked with the narrow phase's
# conservative CCD for every eligible pair (found by the broad phase over x -> p, filtered like
# the contacts, and starting on its side) that can close its start distance in this substep. A
# pair that would come within ``d`` (a fraction of its thickness, never more than half its start
# distance) gets a contact whose normal is taken at the time of impact, and the contacts are
# projected again (``ccd_rounds`` rounds, each checked again). Pairs still colliding then go
# to impact zones: the vertices of colliding pairs, merged transitively, move by one common
# translation (that of their kinematic vertices if they have any), so that no pair inside a zone
# moves relative to another; zones grow until the CCD finds no collision. Cost: one broad phase
# and the CCD of the few pairs that move more than their distance, per substep; more only in
# substeps that have hits.

_CCD_ZONE_ITERS = 32  # impact-zone merges per substep at most


@njit(cache=True)
def _translated_clear(x, p, v, a, b, c, dd):
    """A triangle that only translates (a static collider, a rigidly moving one) keeps its
    plane; the vertex's signed distance to it is then linear in t, and a vertex on the same
    side farther than dd at both ends never comes within dd of the triangle."""
    for j in range(3):
        da = p[a, j] - x[a, j]
        tol = 1e-12 * (abs(x[a, j]) + abs(p[a, j]) + 1e-300)
        if abs(p[b, j] - x[b, j] - da) > tol or abs(p[c, j] - x[c, j] - da) > tol:
            return False
    n = np.cross(x[b] - x[a], x[c] - x[a])
    ln = np.sqrt(n[0] ** 2 + n[1] ** 2 + n[2] ** 2)
    if ln <= 0.0:
        return False
    s0 = ((x[v, 0] - x[a, 0]) * n[0] + (x[v, 1] - x[a, 1]) * n[1]
          + (x[v, 2] - x[a, 2]) * n[2]) / ln
    s1 = ((p[v, 0] - p[a, 0]) * n[0] + (p[v, 1] - p[a, 1]) * n[1]
          + (p[v, 2] - p[a, 2]) * n[2]) / ln
    return (s0 > dd and s1 > dd) or (s0 < -dd and s1 < -dd)


@njit(cache=True)
def _ccd_select(rows, nrm, target, is_vf, x, p, frac, sel, dsel):
    """Rows that start on their side (the stored normal agrees with the start separation) and
    whose relative motion is large enough to close the start distance minus ``d``; writes
    their row numbers to ``sel`` and their ``d`` [m] to ``dsel``; returns the count."""
    k = 0
    for r in range(rows.shape[0]):
        i0, i1, i2, i3 = rows[r, 0], rows[r, 1], rows[r, 2], rows[r, 3]
        d2, c0, c1, c2, c3 = row_coefficients(x, rows, is_vf, r)
        side = 0.0
        for j in range(3):
            side += nrm[r, j] * (c0 * x[i0, j] + c1 * x[i1, j] + c2 * x[i2, j] + c3 * x[i3, j])
        if side <= 0.0:
            continue  # starts on the wrong side (crossed, inside a one-sided body) or touching
        d0 = np.sqrt(d2)
        dd = min(frac * max(target[r], 0.0), 0.5 * d0)
        # largest relative motion of a point of one primitive against a point of the other
        # (the separation moves by a convex combination of these vertex differences)
        move = 0.0
        na = 1 if is_vf else 2
        for qa in range(na):
            ia = rows[r, qa]
            for qb in range(na, 4):
                ib = rows[r, qb]
                m = 0.0
                for j in range(3):
                    m += ((p[ia, j] - x[ia, j]) - (p[ib, j] - x[ib, j])) ** 2
                move = max(move, m)
        move = np.sqrt(move)
        if move < d0 - dd:  # the distance cannot shrink by more than that: no impact
            continue
        # the distance is move-Lipschitz in t from both ends: it stays above
        # (d0 + d1 - move) / 2, with d1 the distance at the end
        e2 = row_coefficients(p, rows, is_vf, r)[0]
        if 0.5 * (d0 + np.sqrt(e2) - move) > dd:
            continue
        if is_vf and _translated_clear(x, p, i0, i1, i2, i3, dd):
            continue
        sel[k] = r
        dsel[k] = dd
        k += 1
    return k


@njit(cache=True)
def _toi_normals(rows, nrm, is_vf, x, p, sel, toi, out_n):
    """Contact normal at the time of impact of each hit (closest-point direction of the pair at
    ``toi``; the primitive's normal oriented like the stored normal when they touch)."""
    for k in range(sel.shape[0]):
        r = sel[k]
        t = toi[k]
        q = np.zeros((4, 3))
        for a in range(4):
            i = rows[r, a]
            for j in range(3):
                q[a, j] = x[i, j] + t * (p[i, j] - x[i, j])
        if is_vf:
            d2, b0, b1, b2 = _pt_tri_sq(q[0, 0], q[0, 1], q[0, 2], q[1, 0], q[1, 1], q[1, 2],
                                         q[2, 0], q[2, 1], q[2, 2], q[3, 0], q[3, 1], q[3, 2])
            c0, c1, c2, c3 = 1.0, -b0, -b1, -b2
            g = np.cross(q[2] - q[1], q[3] - q[1])
        else:
            d2, s, tt = _seg_seg_sq(q[0, 0], q[0, 1], q[0, 2], q[1, 0], q[1, 1], q[1, 2],
                                    q[2, 0], q[2, 1], q[2, 2], q[3, 0], q[3, 1], q[3, 2])
            c0, c1, c2, c3 = 1.0 - s, s, -(1.0 - tt), -tt
            g = np.cross(q[1] - q[0], q[3] - q[2])
        dv = c0 * q[0] + c1 * q[1] + c2 * q[2] + c3 * q[3]
        dl = np.sqrt(d2)
        ext = 0.0
        for a in range(1, 4):
            ext = max(ext, np.abs(q[a] - q[0]).max())
        if dl > 1e-9 * ext and dl > 0.0:
            n = dv / dl
        else:
            gl = np.sqrt(g[0] ** 2 + g[1] ** 2 + g[2] ** 2)
            n = nrm[r].copy() if gl <= 0.0 else g / gl
        if n[0] * nrm[r, 0] + n[1] * nrm[r, 1] + n[2] * nrm[r, 2] < 0.0 and not dl > 1e-9 * ext:
            n = -n
        out_n[k, 0] = n[0]
        out_n[k, 1] = n[1]
        out_n[k, 2] = n[2]


@njit(cache=True, inline="always")
def _find(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(cache=True)
def _zones_union(rows, sel, parent, inzone, touched, nt):
    """Merge the four vertices of every hit into one impact zone (union-find); ``touched``
    lists the vertices in a zone (``nt`` of them so far); returns the new count and whether
    any zone grew or merged."""
    changed = False
    for k in range(sel.shape[0]):
        r = sel[k]
        for a in range(4):
            i = rows[r, a]
            if not inzone[i]:
                inzone[i] = True
                touched[nt] = i
                nt += 1
                changed = True
        r0 = _find(parent, rows[r, 0])
        for a in range(1, 4):
            ra = _find(parent, rows[r, a])
            if ra != r0:
                parent[ra] = r0
                changed = True
    return nt, changed


@njit(cache=True)
def _zones_move(x, p_in, p, w, parent, touched, nt, acc):
    """Every impact zone moves as one translation: that of its kinematic vertices if it has any
    (it follows the collider), else its dynamic vertices' mass-weighted mean motion (momentum
    kept). Within a zone the relative motion is then zero, so no pair of it collides. A zone
    whose kinematic vertices do not move as one translation (a pinch between two colliders, a
    rotating collider) cannot be made safe by a translation: its vertices keep their motion.
    ``acc`` (n, 8) scratch: motion sums, weight, kinematic flag, first kinematic motion.
    Returns the zones' count."""
    for k in range(nt):
        r = _find(parent, touched[k])
        for j in range(8):
            acc[r, j] = 0.0
    for k in range(nt):
        i = touched[k]
        r = _find(parent, i)
        kin = w[i] <= 0.0
        if kin:
            if acc[r, 4] == 0.0:  # first kinematic vertex: drop the dynamic sums
                for j in range(4):
                    acc[r, j] = 0.0
                acc[r, 4] = 1.0
                for j in range(3):
                    acc[r, 5 + j] = p_in[i, j] - x[i, j]
            elif acc[r, 4] == 1.0:
                dev = 0.0
                size = 0.0
                for j in range(3):
                    dev = max(dev, abs(p_in[i, j] - x[i, j] - acc[r, 5 + j]))
                    size = max(size, abs(acc[r, 5 + j]))
                if dev > 1e-9 * (1.0 + size):
                    acc[r, 4] = 2.0  # kinematic vertices in conflict
        if kin or acc[r, 4] == 0.0:
            m = 1.0 if kin else 1.0 / w[i]
            for j in range(3):
                acc[r, j] += m * (p_in[i, j] - x[i, j])
            acc[r, 3] += m
    zones = 0
    for k in range(nt):
        i = touched[k]
        r = _find(parent, i)
        if r == i:
            zones += 1
        if w[i] > 0.0:
            if acc[r, 3] > 0.0 and acc[r, 4] < 2.0:
                for j in range(3):
                    p[i, j] = x[i, j] + acc[r, j] / acc[r, 3]
            else:
                for j in range(3):
                    p[i, j] = p_in[i, j]
    return zones


@dataclass
class _CCDWork:
    """Buffers of the CCD pass (per vertex ones sized at first use; per candidate ones grown,
    doubling, when a substep needs more)."""

    parent: np.ndarray  # impact-zone union-find
    inzone: np.ndarray
    touched: np.ndarray
    acc: np.ndarray  # (n, 8) zone sums
    p_in: np.ndarray  # positions at entry of the fail-safe
    cap: int = 0
    sel: np.ndarray = None
    dsel: np.ndarray = None
    toi: np.ndarray = None
    nrm: np.ndarray = None

    def ensure(self, n):
        if n > self.cap:
            self.cap = max(2 * self.cap, n, 256)
            self.sel = np.zeros(self.cap, np.int64)
            self.dsel = np.zeros(self.cap)
            self.toi = np.zeros(self.cap)
            self.nrm = np.zeros((self.cap, 3))


#: polish passes of the CCD safe step: after each round's ``n_it`` passes (joint strain passes,
#: the contacts at the time of impact, every contact row), this many joint passes with the
#: contacts at the time of impact alone; the CCD check after the round guards every pair as
#: before (0: none, before). The pass over every row re-projects the cloth-cloth contacts the
#: global strain step left the cloth in and ends the round with the cloth stretched: on
#: cloth_sphere_moving_128 (2x15) frame 9's safe step took the worst edge from 17.2 to 72.0 %
#: with one hit (``graphs/bench/cloth_strain.py --substages``); with 4: to 10.6 %, frame 10
#: 18.2 -> 10.8 %, frame 11 12.8 -> 7.3 %. One interleaved run (``NUMBA_NUM_THREADS=1 python
#: graphs/bench/peer_collision.py --moving --loki 2x15 --frames 16 --newton none --moving-flag
#: CCD_POLISH=4 CCD_POLISH=10``, load 3-5 on 2 cores): worst edge at the end of frames 7-16
#: 29.3 / 14.6 / 72.0 / 31.0 / 15.5 / 4.8 / 11.3 / 18.1 / 19.4 / 61.0 % -> 29.3 / 14.6 / 10.6 /
#: 10.8 / 7.3 / 4.9 / 4.6 / 22.6 / 18.1 / 22.6 % (10: 9.8 / 8.9 / 6.5 / 1.7 / 8.1 / 21.0 / 15.8 /
#: 17.0 % from frame 9); CPU per frame against the static drop 1.81 -> 1.83x (mean of frames
#: 2-16; 1.81x with 10); 0 intersecting pairs and 0 vertices inside in every frame. What is
#: left there is the global step's (frames 7-8 and 14-16: it stops at its 20 passes with
#: 15-33 % left). The static drop has no CCD hit: unchanged. Not paid (measured in the same
#: way): no pass over the rows in the safe step (frames 9-11 10.4 / 7.9 / 12.7 %, but 1,116-2,770
#: intersecting pairs in frames 12-14: the impact zones cannot hold a cloth against a spinning
#: ball), the rows' targets capped at their gap at the safe step's entry (41.9 / 9.6 / 9.2 %,
#: 12.0 % in frame 12; with polish 4 frame 12 29.1 %), the contacts at the time of impact
#: pushing their pair apart only to its start distance (with polish 4: frame 12 9.8 %).
#: With the opt-in ``SLIDE_APART`` 3 (``--moving-flag SLIDE_APART=3``, 14 frames, same run as
#: the defaults' 29.3 / 14.6 / 10.6 / 10.8 / 7.3 / 4.9 / 4.6 / 22.6 %): frames 7-14 3.0 / 1.5 /
#: 9.2 / 9.7 / 13.3 / 1.3 / 1.6 / 1.5 % (2.7 / 1.6 / 14.1 / 17.0 / 11.6 / 1.4 % without polish)
#: at 1.68x the static drop's mean CPU (the defaults 1.82x), 0 pairs, 0 vertices inside.
CCD_POLISH = 4


_EMPTY_ITERS = np.zeros(0, np.int64)
#: below this many pairs the CCD runs on one thread (no parallel launch or barrier)
CCD_PARALLEL_MIN = 512


@njit(cache=True)
def _ccd_serial(x, p, rows, sel, dsel, is_vf, toi):
    """The narrow phase's conservative CCD of the rows ``sel`` on one thread."""
    C, eps, fw, box, meta, heap, free = _alloc_ws()
    for k in range(sel.shape[0]):
        r = sel[k]
        if is_vf:
            S, finite, vf = _set_coeffs_vf(C, eps, x, p, rows[r, 0], rows[r, 1], rows[r, 2],
                                           rows[r, 3])
        else:
            S, finite = _set_coeffs_ee(C, eps, x, p, rows[r, 0], rows[r, 1], rows[r, 2],
                                       rows[r, 3])
            vf = False
        toi[k] = _ccd_query(C, eps, fw, S, np.bool_(finite), np.bool_(vf), np.float64(dsel[k]),
                            np.float64(1e-6), np.float64(1e-10), np.int64(10_000), box, meta,
                            heap, free)[0]


def _ccd_hits(work, rows, nrm, target, is_vf, x, p, frac):
    """CCD of the eligible rows over x -> p: (row numbers of the hits, their toi, their d)."""
    n = len(rows)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    work.ensure(n)
    k = _ccd_select(rows, nrm, target, is_vf, x, p, frac, work.sel, work.dsel)
    if k == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    sel = work.sel[:k]
    toi = work.toi[:k]
    if k < CCD_PARALLEL_MIN:
        _ccd_serial(x, p, rows, sel, work.dsel[:k], is_vf, toi)
    elif is_vf:
        vf_ccd_batch_kernel(x, p, rows[sel, 0], rows[sel, 1:], work.dsel[:k], 1e-6, 1e-10,
                            10_000, toi, _EMPTY_ITERS)
    else:
        ee_ccd_batch_kernel(x, p, rows[sel, :2], rows[sel, 2:], work.dsel[:k], 1e-6, 1e-10,
                            10_000, toi, _EMPTY_ITERS)
    hit = toi <= 1.0
    return sel[hit].copy(), toi[hit].copy(), work.dsel[:k][hit].copy()


def _toi_contacts(c, work, sel, toi, is_vf, x, p):
    """Contacts of the hits with their normal at the time of impact (rows, normals, targets,
    friction, strength[, one-sided]) taken from the detected rows ``sel``."""
    n = np.zeros((len(sel), 3))
    if is_vf:
        _toi_normals(c.vf, c.vf_n, True, x, p, sel, toi, n)
        return (c.vf[sel], n, c.vf_target[sel], c.vf_mu[sel], c.strength[sel],
                c.vf_onesided[sel])
    _toi_normals(c.ee, c.ee_n, False, x, p, sel, toi, n)
    return c.ee[sel], n, c.ee_target[sel], c.ee_mu[sel], c.ee_strength[sel]


def _set_infl_min(c):
    if c.infl_min < 0.0:
        c.infl_min = min(float((np.maximum(g.th_out, g.th_in) + _half_margin(g))[g.verts].min())
                         if len(g.verts) else np.inf for g in c.groups)


def _rows_cover(c, x, p, frac) -> bool:
    """Do the packed rows (detected over x -> c.det_ref with boxes inflated by at least
    c.infl_min) hold every pair whose motion x -> p can come within its CCD distance? Yes when
    no vertex moved more than (2 infl_min - d_max) / 2 since that detection."""
    ref = c.det_ref
    if ref is None or ref.shape != p.shape:
        return False
    _set_infl_min(c)
    return _max_move(ref, p) <= c.infl_min - 0.5 * frac * _target_max(c)


def _target_max(c) -> float:
    """The largest target [m] of the packed rows, at least 0 (0 when there are none)."""
    return max([0.0] + [float(t.max()) for t in (c.vf_target, c.ee_target) if len(t)])


@njit(cache=True)
def _box_excess(x, ref, p):
    """Largest distance [m] along an axis by which a vertex of ``p`` lies outside the box of
    its detected motion ``x -> ref`` (0 when every vertex is inside its box)."""
    m = 0.0
    for i in range(p.shape[0]):
        for k in range(3):
            lo = min(x[i, k], ref[i, k])
            hi = max(x[i, k], ref[i, k])
            e = max(lo - p[i, k], p[i, k] - hi)
            if e > m:
                m = e
    return m


def _rows_hold(c, x, p) -> bool:
    """Do the packed rows (boxes of the motion x -> c.det_ref inflated by at least
    c.infl_min) still hold every pair that can be within its target at ``p``? Yes while no
    vertex is farther than infl_min - target_max / 2 outside its box: two primitives whose
    boxes were apart by more than twice the inflation are then still apart by more than
    their target. The rows it is asked about (``CollisionDetect``'s and the iterations' own
    detections) come from swept boxes; for space-time rows (``SPACETIME_PREDICTED``) it would
    be a heuristic: a missing self pair is only far apart along the linear motion."""
    _set_infl_min(c)
    return _box_excess(x, c.det_ref, p) <= c.infl_min - 0.5 * _target_max(c)


def _relative_setup(c, v, h, slack):
    """Per group the check's bound and largest target of ``SPACETIME_RELATIVE`` for rows
    detected with boxes inflated by ``slack`` more (see ``_relative_flags``): a target is at
    most twice the largest thickness plus the restitution's 2 restitution |v|_max h."""
    c.rel_slack = slack
    c.rel_bounds = []
    c.rel_extra = []
    c.rel_vn = {}
    for g in c.groups:
        if not len(g.verts):
            c.rel_bounds.append((0.0, 0.0))
            continue
        th = np.maximum(g.th_out, g.th_in)[g.verts]
        t_max = 2.0 * float(th.max())
        if g.restitution > 0.0:
            vg = v[g.verts]
            t_max += 2.0 * g.restitution * h * float(np.sqrt((vg * vg).sum(axis=1).max()))
        infl_min = float((np.maximum(g.th_out, g.th_in) + _half_margin(g))[g.verts].min())
        infl_min += slack
        c.rel_bounds.append((2.0 * infl_min - t_max, t_max))


@njit(cache=True)
def _relative_flags(x, p, ref, verts, kin, edges, bound, t_max, mn, mx, kex, flags, which=3):
    """Dynamic vertices of ``verts`` (flags[k] = True for verts[k]) at risk at the iterate
    ``p`` for rows detected over x -> ref (``SPACETIME_RELATIVE``); returns their count.
    ``kin``: per entry of ``verts``, kinematic; ``mn``, ``mx`` (M, 3), ``kex`` (M,): scratch,
    M a power of two; ``which`` (bits, for diagnostics): 1 the test against dynamic
    vertices, 2 the one against kinematic vertices (3: both). A dynamic vertex is at risk when its deviation d = p - ref differs on
    some axis by more than ``bound`` from that of a dynamic vertex in a neighbouring cell of
    a grid over ``p``, or when it lies outside the box of its motion x -> ref by more than
    ``bound`` less the largest such excess of a kinematic vertex in a neighbouring cell.

    Why this suffices (every box inflated by at least r = infl_min + slack, ``bound`` =
    2 r - t_max, t_max >= every target; u = ref - x). Pairs of two dynamic primitives A and B
    are tested in space-time: dropped only when on some axis (say A above B) the swept boxes
    are apart, min_a min(x_a, ref_a) - r_A > max_b max(x_b, ref_b) + r_B, or the space-time
    ones are (``broadphase._st_overlap``), min_a x_a - r_A - max_b x_b - r_B > max(0, max_b
    u_b - min_a u_a). Both give, with p = ref + d, min_a p_a - max_b p_b > r_A + r_B - (max_b
    d_b - min_a d_a) on that axis, a lower bound of the pair's distance at p: the dropped
    pair is farther than its target at p unless max_b d_b - min_a d_a > ``bound`` for a
    vertex a of A and b of B. Pairs with a kinematic primitive B keep their swept boxes
    (``_st_group``): dropped only when the swept boxes are apart on an axis, which gives
    min_a p_a - max_b p_b > r_A + r_B - e_a - e_b with e the excess of p outside the box of
    x -> ref, so they are at risk only when e_a + e_b > ``bound``. A pair within t_max at p
    has its vertices within 2 L + t_max of each other on every axis (L: the largest extent of
    an edge along an axis at p, so of any primitive), so with cells that wide a and b lie in
    neighbouring cells and a (and b, when dynamic) is flagged (hash collisions only merge
    cells). No flag: every pair that can be within its target at p is among the rows (pairs
    the filters drop are dropped whichever boxes found them), and a re-detection needs only
    the flagged vertices' primitives against every primitive."""
    ext = 0.0
    for e in range(edges.shape[0]):
        a, b = edges[e, 0], edges[e, 1]
        for k in range(3):
            ext = max(ext, abs(p[a, k] - p[b, k]))
    cell = (2.0 * ext + t_max) * (1.0 + 1e-9) + 1e-12
    inv = 1.0 / cell
    m = mn.shape[0]
    mask = m - 1
    for i in range(m):
        kex[i] = -np.inf
        for k in range(3):
            mn[i, k] = np.inf
            mx[i, k] = -np.inf
    for q in range(verts.shape[0]):
        v = verts[q]
        hsh = bp._hash3(np.int64(np.floor(p[v, 0] * inv)), np.int64(np.floor(p[v, 1] * inv)),
                        np.int64(np.floor(p[v, 2] * inv)), mask)
        if kin[q]:
            kex[hsh] = max(kex[hsh], max(0.0, _excess(x, ref, p, v)))
        else:
            for k in range(3):
                dv = p[v, k] - ref[v, k]
                mn[hsh, k] = min(mn[hsh, k], dv)
                mx[hsh, k] = max(mx[hsh, k], dv)
    count = 0
    for q in range(verts.shape[0]):
        flags[q] = False
        if kin[q]:
            continue
        v = verts[q]
        ci = np.int64(np.floor(p[v, 0] * inv))
        cj = np.int64(np.floor(p[v, 1] * inv))
        ck = np.int64(np.floor(p[v, 2] * inv))
        lo0 = lo1 = lo2 = np.inf
        hi0 = hi1 = hi2 = -np.inf
        ke = -np.inf
        for di in range(-1, 2):
            for dj in range(-1, 2):
                for dk in range(-1, 2):
                    hsh = bp._hash3(ci + di, cj + dj, ck + dk, mask)
                    lo0 = min(lo0, mn[hsh, 0])
                    lo1 = min(lo1, mn[hsh, 1])
                    lo2 = min(lo2, mn[hsh, 2])
                    hi0 = max(hi0, mx[hsh, 0])
                    hi1 = max(hi1, mx[hsh, 1])
                    hi2 = max(hi2, mx[hsh, 2])
                    ke = max(ke, kex[hsh])
        d0, d1, d2 = p[v, 0] - ref[v, 0], p[v, 1] - ref[v, 1], p[v, 2] - ref[v, 2]
        f = (which & 1) != 0 and not (d0 - lo0 <= bound and hi0 - d0 <= bound
                                      and d1 - lo1 <= bound and hi1 - d1 <= bound
                                      and d2 - lo2 <= bound and hi2 - d2 <= bound)  # NaN: flag
        if not f and (which & 2) != 0 and ke >= 0.0:
            f = not (max(0.0, _excess(x, ref, p, v)) + ke <= bound)
        flags[q] = f
        if f:
            count += 1
    return count


@njit(cache=True, inline="always")
def _excess(x, ref, p, v):
    """Largest distance [m] along an axis by which p[v] lies outside the box of x[v] -> ref[v]
    (negative inside)."""
    e = -np.inf
    for k in range(3):
        lo = min(x[v, k], ref[v, k])
        hi = max(x[v, k], ref[v, k])
        e = max(e, max(lo - p[v, k], p[v, k] - hi))
    return e


def _relative_check(c, x, p) -> int:
    """Vertices at risk at the iterate ``p`` for the rows of ``SPACETIME_RELATIVE`` (detected
    over x -> ``c.rel_ref``; ``_relative_flags``), summed over the groups: 0 means the rows
    hold every pair that can be within its target at ``p``."""
    n = 0
    for g, (bound, t_max) in zip(c.groups, c.rel_bounds):
        nv = len(g.verts)
        if not nv:
            continue
        w = c.rel_work.get(g.name)
        if w is None or len(w[3]) != nv:
            m = 1 << max(4, int(2 * nv - 1).bit_length())
            w = c.rel_work[g.name] = (np.empty((m, 3)), np.empty((m, 3)), np.empty(m),
                                      np.zeros(nv, np.bool_),
                                      g.kinematic_el[g.vert_elem[g.verts]].copy())
        n += _relative_flags(x, p, c.rel_ref, g.verts, w[4], g.edges, bound, t_max, w[0], w[1],
                             w[2], w[3])
    return n


def _half_margin(g):
    """Half the detection margin [m] of group ``g``: a scalar, or per global vertex
    (``MARGIN_EDGE``)."""
    return 0.5 * (g.margin if g.margin_v is None else g.margin_v)


def _edge_margin(q0, edges, n, margin, scale):
    """``MARGIN_EDGE``: per vertex of ``n``, ``scale`` times the shortest edge at it in the
    positions ``q0`` (bind time), at most ``margin`` (vertices without edges: ``margin``)."""
    out = np.full(n, float(margin))
    if len(edges):
        ln = scale * np.linalg.norm(q0[edges[:, 1]] - q0[edges[:, 0]], axis=1)
        np.minimum.at(out, edges[:, 0], ln)
        np.minimum.at(out, edges[:, 1], ln)
    return out


def _infl(g, slack=0.0):
    """Per-vertex box inflation [m] of group ``g``'s detections, ``slack`` [m] more."""
    infl = np.maximum(g.th_out, g.th_in) + _half_margin(g)
    if slack:
        infl += slack
    # vertices recently pushed through a kinematic sheet search 4x wider so that the
    # contact pulling them back is not lost when they are deeper than the contact band
    if g.recover.any():
        recent = (g.crossed >= g.stamp - SIDE_MEMORY).any(axis=1)
        infl[recent] *= 4.0
    return infl


@njit(cache=True, inline="always")
def _prim_st(x, ref, prim, r, out):
    """Start box (lo, hi, inflated by the largest ``r`` of its vertices), displacement box and
    swept box (inflated) of one primitive (a row of vertex indices): out[0:3] lo0, [3:6] hi0,
    [6:9] dlo, [9:12] dhi, [12:15] swept lo, [15:18] swept hi."""
    rr = 0.0
    for c in range(prim.shape[0]):
        rr = max(rr, r[prim[c]])
    for k in range(3):
        out[k] = np.inf
        out[3 + k] = -np.inf
        out[6 + k] = np.inf
        out[9 + k] = -np.inf
        out[12 + k] = np.inf
        out[15 + k] = -np.inf
    for c in range(prim.shape[0]):
        v = prim[c]
        for k in range(3):
            d = ref[v, k] - x[v, k]
            out[k] = min(out[k], x[v, k])
            out[3 + k] = max(out[3 + k], x[v, k])
            out[6 + k] = min(out[6 + k], d)
            out[9 + k] = max(out[9 + k], d)
            out[12 + k] = min(out[12 + k], min(x[v, k], ref[v, k]))
            out[15 + k] = max(out[15 + k], max(x[v, k], ref[v, k]))
    for k in range(3):
        out[k] -= rr
        out[3 + k] += rr
        out[12 + k] -= rr
        out[15 + k] += rr


@njit(cache=True)
def _held(x, ref, r, prims_a, prims_b, lab_a, lab_b, cand, keep):
    """keep[i] = False for the candidates (rows of ``cand``: a primitive of ``prims_a``, one
    of ``prims_b``) that the detection over x -> ref with inflation ``r`` surely found: their
    swept boxes overlap and, for one label (both dynamic), their space-time boxes do (as
    ``broadphase._ovl``), each by a margin of 1e-7 m (a pair on the edge is kept: at worst
    projected twice). Returns the count kept."""
    a = np.empty(18)
    b = np.empty(18)
    tol = 1e-7
    n = 0
    for i in range(cand.shape[0]):
        pa, pb = cand[i, 0], cand[i, 1]
        _prim_st(x, ref, prims_a[pa], r, a)
        _prim_st(x, ref, prims_b[pb], r, b)
        held = True
        for k in range(3):
            if a[12 + k] > b[15 + k] - tol or b[12 + k] > a[15 + k] - tol:
                held = False
        if held and lab_a[pa] == lab_b[pb]:
            for k in range(3):
                if a[k] - b[3 + k] + min(0.0, a[6 + k] - b[9 + k]) > -tol:
                    held = False
                if a[3 + k] - b[k] + max(0.0, a[9 + k] - b[6 + k]) < tol:
                    held = False
        keep[i] = not held
        if not held:
            n += 1
    return n


def _relative_extra(c, x, p, v, h) -> int:
    """``RELATIVE_INCREMENTAL``: rows for the primitives of the vertices the last
    ``_relative_check`` flagged, into ``c.rel_extra``; returns their count. Candidates: the
    boxes at ``p`` (inflated as the detection's) of every primitive with a flagged vertex
    against every primitive's, less the pairs the detection over x -> ``c.rel_ref`` surely
    held (``_held``), filtered as a detection's. Every pair within its target at ``p`` is
    then among the packed or these rows: a pair missing from the packed rows and within its
    target has a flagged vertex in one of its primitives (``_relative_flags``), and is within
    twice the inflation at ``p``."""
    c.rel_extra = []
    added = 0
    for g in c.groups:
        w = c.rel_work.get(g.name)
        if w is None or not w[3].any():
            continue
        n = len(x)
        fl = np.zeros(n, np.bool_)
        fl[g.verts[w[3]]] = True
        infl = _infl(g, c.rel_slack)
        kin_el = g.kinematic_el
        vf = ee = None
        buf = g.bufs.get("rel_buf")
        if buf is None:
            buf = g.bufs["rel_buf"] = bp.PairBuffer(1024)
        if g.do_vf and len(g.tris):
            lo_v, hi_v = bp.primitive_boxes(p, g.verts, None, infl)
            lo_t, hi_t = bp.primitive_boxes(p, g.tris, None, infl)
            iv = np.flatnonzero(fl[g.verts])
            it = np.flatnonzero(fl[g.tris].any(axis=1))
            c1 = bp.column_query_pairs(lo_v[iv], hi_v[iv], lo_t, hi_t, g.verts[iv, None],
                                       g.tris, out=buf).copy()
            c1[:, 0] = iv[c1[:, 0]]
            c2 = bp.column_query_pairs(lo_v, hi_v, lo_t[it], hi_t[it], g.verts[:, None],
                                       g.tris[it], out=buf).copy()
            c2[:, 1] = it[c2[:, 1]]
            cand = np.unique(np.concatenate([c1, c2]), axis=0)
            ev = g.vert_elem[g.verts]
            lab_v = np.where(kin_el[ev], ev + 1, 0)
            lab_t = np.where(kin_el[g.tri_elem], g.tri_elem + 1, 0)
            keep = np.empty(len(cand), np.bool_)
            if len(cand):
                _held(x, c.rel_ref, infl, g.verts[:, None], g.tris, lab_v, lab_t, cand, keep)
            cand = np.ascontiguousarray(cand[keep])
            if len(cand):
                m = len(cand)
                rows, nrm, tgt, mu, one = (np.empty((m, 4), np.int64), np.empty((m, 3)),
                                           np.empty(m), np.empty(m), np.empty(m, np.bool_))
                k, _ = _filter_vf(cand, g.verts, g.tris, g.tri_elem, g.vert_elem, g.allow,
                                  g.tolerant, g.th_out, g.th_in, g.friction, g.visible,
                                  g.setmask, g.one_sided, x, v, h, g.restitution, g.margin,
                                  rows, nrm, tgt, mu, one, g.recover, g.side_mem, g.side_seen,
                                  g.crossed, g.stamp, g.near_d, g.near_s)
                vf = (rows[:k], nrm[:k], tgt[:k], mu[:k] * g.friction_scale, one[:k],
                      np.full(k, g.strength))
                added += k
        if g.do_ee and len(g.edges):
            lo_e, hi_e = bp.primitive_boxes(p, g.edges, None, infl)
            ie = np.flatnonzero(fl[g.edges].any(axis=1))
            cand = bp.column_query_pairs(lo_e[ie], hi_e[ie], lo_e, hi_e, g.edges[ie], g.edges,
                                         out=buf).copy()
            cand[:, 0] = ie[cand[:, 0]]
            cand = np.unique(np.sort(cand, axis=1), axis=0)
            cand = cand[cand[:, 0] != cand[:, 1]]
            lab_e = np.where(kin_el[g.edge_elem], g.edge_elem + 1, 0)
            keep = np.empty(len(cand), np.bool_)
            if len(cand):
                _held(x, c.rel_ref, infl, g.edges, g.edges, lab_e, lab_e, cand, keep)
            cand = np.ascontiguousarray(cand[keep])
            if len(cand):
                vn = c.rel_vn.get(g.name)
                if vn is None:
                    vn = c.rel_vn[g.name] = (_vertex_normals(x, g) if g.one_sided.any()
                                             else np.zeros((0, 3)))
                m = len(cand)
                rows, nrm, tgt, mu = (np.empty((m, 4), np.int64), np.empty((m, 3)),
                                      np.empty(m), np.empty(m))
                k, _ = _filter_ee(cand, g.edges, g.edge_elem, g.allow, g.tolerant, g.th_out,
                                  g.friction, g.visible, g.setmask, g.one_sided, x, v, h,
                                  g.restitution, g.margin, rows, nrm, tgt, mu, vn, g.crossed,
                                  g.stamp)
                ee = (rows[:k], nrm[:k], tgt[:k], mu[:k] * g.friction_scale,
                      np.full(k, g.strength))
                added += k
        empty_vf = (np.zeros((0, 4), np.int64),) + (np.zeros((0, 3)),) + (np.zeros(0),) * 2 \
            + (np.zeros(0, np.bool_), np.zeros(0))
        empty_ee = (np.zeros((0, 4), np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros(0),
                    np.zeros(0))
        c.rel_extra.append((vf or empty_vf, ee or empty_ee))
    return added


@njit(cache=True)
def _max_move(a, b):
    m = 0.0
    for i in range(a.shape[0]):
        d = (a[i, 0] - b[i, 0]) ** 2 + (a[i, 1] - b[i, 1]) ** 2 + (a[i, 2] - b[i, 2]) ** 2
        if d > m:
            m = d
    return np.sqrt(m)


def _detected_to(c, p):
    """The rows just detected cover the motion from x to p: remember a copy of p as the end of
    that motion (``det_ref``, which ``_rows_hold``, ``_rows_cover`` and ``_ccd_incremental``
    measure from)."""
    if c.p_det is None or c.p_det.shape != p.shape:
        c.p_det = np.empty_like(p)
    c.p_det[:] = p
    c.det_ref = c.p_det


@njit(cache=True)
def _moved_norms(p, ref, out):
    """|p - ref| per vertex into ``out``; returns the largest (``_max_move``'s value)."""
    m = 0.0
    for i in range(p.shape[0]):
        d = (p[i, 0] - ref[i, 0]) ** 2 + (p[i, 1] - ref[i, 1]) ** 2 + (p[i, 2] - ref[i, 2]) ** 2
        out[i] = np.sqrt(d)
        if d > m:
            m = d
    return np.sqrt(m)


#: the safe step's first check, when the rows of the last final round no longer cover the
#: motion x -> p (``_rows_cover``: some vertex moved more than infl_min - d_max / 2 since their
#: detection), first tries the rows of that detection plus those of an incremental query (the
#: primitives of the vertices that moved that far against every primitive, the same boxes
#: and space-time test as a detection over x -> p, ``_ccd_incremental``): when these give no
#: hit, a full detection gives none either (a pair of two primitives that moved less is held
#: by the old rows, one with a primitive that moved more by the new, with the same row), so the
#: safe step ends as it would have; when they give a hit (or more than ``CCD_INCREMENTAL``
#: of the vertices moved that far, or a group remembers sides of a two-sided kinematic
#: element, which a filter pass updates) the full detection runs as before. Positions bitwise
#: those with 0 (off). Measured on the moving scene (cloth_sphere_moving_128, frames 7-10):
#: 5-35 of the 16,641 cloth vertices moved that far in the final rounds' last passes (the
#: sphere's friction drags them), so the full detection of every such substep (1-2 a frame,
#: ~300 ms each) became a query of a few dozen primitives: ``NUMBA_NUM_THREADS=1
#: peer_collision.py --moving --loki 2x15 --stages --stage-frames 8 12 --frames 12
#: --moving-flag CCD_INCREMENTAL=0.0`` (one interleaved run, load 4-5): the safe step 1,101 ->
#: 288 ms CPU a frame (frames 8-12; 1.8 full detections a frame -> 0), the whole frame 9,822
#: -> 9,664 ms, against the static scene 1.91 -> 1.88x median (1.84 -> 1.81x mean), 0 pairs
#: and 0 vertices inside either way, strain 82.3 % both. Measured and not kept with it: the
#: column grid of those space-time detections over loose boxes in the frame of the group's
#: mean motion (exact, the same rows: a pair that passes the space-time test has overlapping
#: loose boxes [lo0 + min(0, dlo - T), hi0 + max(0, dhi - T)] in every frame T), then the
#: swept-box test: the spinning sphere drags the cloth's parts in different directions, so
#: the mean motion (2, -19, 3 mm in frame 9) shrinks no box, and the loose boxes are larger
#: than the swept ones (grid queries 102 + 168 -> 117 + 206 ms on that detection; whole run
#: 1.02x, bitwise equal)
CCD_INCREMENTAL = 0.05
#: the safe step's check after each round of contacts at the time of impact first tries the
#: rows of the safe step's last detection (over x -> a copy of p then, ``det_ref``) plus an
#: incremental query, as ``CCD_INCREMENTAL``'s first check: when these give no hit the safe
#: step ends (a full detection would give none either); otherwise (a hit, too many moved
#: vertices, side memory) the full detection runs as before. Positions bitwise those of False
#: (hashed: cloth_sphere_moving_128 at 48 x 48, 11 frames; cloth_on_sphere, 10; sleeve_elbow,
#: 24; ``tests/test_collision_moving.py``). On cloth_sphere_moving_128 the safe steps with hits
#: (frames 9-11, the last substep) ended after one round with no hit left: their second full
#: detection (~0.4 s CPU) became the incremental check (~0.15 s). Measured together with
#: ``CCD_INCREMENTAL`` 0.05 (before 0.02: frame 8's first safe step had 454 of 19,203
#: vertices past the bound, 2.4 %, and detected in full, 0.33 s -> 0.15 s) in one interleaved
#: run (``NUMBA_NUM_THREADS=1 python graphs/bench/peer_collision.py --moving --loki 2x15
#: --newton none --frames 12 --stages --stage-frames 7 12 --moving-flag KINEMATIC_END_BOXES
#: --all-flag "CCD_ROUND_INCREMENTAL=False,CCD_INCREMENTAL=0.02"``, load ~3): the moving
#: scene's safe step 996 -> 776 ms CPU a frame (frames 7-12; full detections 1.7 -> 1.0 a
#: frame), its frame 9,577 -> 9,350 ms; against the static drop (its run with the former
#: values; the other static run had a 1.5 s outlier in frame 11's safe step) per-frame CPU
#: ratio median 1.67 -> 1.64, mean 1.82 -> 1.78, ratio of the means 1.73 -> 1.68. The static
#: drop has no hit: its work is unchanged. 0 intersecting pairs, 0 vertices inside, strain
#: unchanged (bitwise).
CCD_ROUND_INCREMENTAL = True


def _ccd_incremental(c, work, x, p, v, h, frac):
    """The safe step's first hits from the rows of the last detection (over x -> c.det_ref)
    and the rows of the pairs with a primitive of a vertex that moved more than infl_min -
    d_max / 2 since (see ``CCD_INCREMENTAL``): True when they give no hit, None when the full
    detection must run (a hit, too many such vertices, side memory)."""
    ref = c.det_ref
    if ref is None or ref.shape != p.shape:
        return None
    for g in c.groups:
        if (g.recover & ~g.one_sided).any():
            return None  # its filter pass updates the side memory: detect in full
    _set_infl_min(c)
    d_max = frac * _target_max(c)
    for g in c.groups:  # the new rows' targets are at most their thicknesses' sum
        if len(g.verts):
            d_max = max(d_max, 2.0 * frac * float(np.maximum(g.th_out, g.th_in)[g.verts].max()))
    buf = _scratch(c.groups[0], "ccd_moved", (len(p),), np.bool_) if c.groups else None
    moved = _moved_mask(ref, p, c.infl_min - 0.5 * d_max,
                        np.empty(len(p), np.bool_) if buf is None else buf)
    nm = int(np.count_nonzero(moved))
    if nm > CCD_INCREMENTAL * sum(len(g.verts) for g in c.groups):
        return None
    for rows, nrm, tgt, is_vf in ((c.vf, c.vf_n, c.vf_target, True),
                                  (c.ee, c.ee_n, c.ee_target, False)):
        if len(_ccd_hits(work, rows, nrm, tgt, is_vf, x, p, frac)[0]):
            return None
    if nm == 0:
        return True
    for g in c.groups:
        for rows, nrm, tgt, is_vf in _incremental_rows(g, moved, x, p, v, h):
            if len(rows) and len(_ccd_hits(work, rows, nrm, tgt, is_vf, x, p, frac)[0]):
                return None
    return True


@njit(cache=True)
def _moved_mask(ref, p, lim, out):
    """out[i] = vertex i is farther than ``lim`` [m] from ``ref``; returns ``out``."""
    lim2 = lim * lim
    for i in range(p.shape[0]):
        out[i] = ((p[i, 0] - ref[i, 0]) ** 2 + (p[i, 1] - ref[i, 1]) ** 2
                  + (p[i, 2] - ref[i, 2]) ** 2) > lim2
    return out


def _incremental_rows(g, moved, x, p, v, h):
    """Rows (rows, normals, targets, is_vf) of group ``g`` over x -> p (space-time, as the
    safe step's detection) of every pair with a primitive that has a ``moved`` vertex: the
    moved vertices against every triangle, the other vertices against the triangles with a
    moved vertex, the edges with a moved vertex against every edge (each pair once). The
    filters see the same candidates as in a full detection (minus the rest), so each row is
    the one that detection would give."""
    out = []
    infl = _infl(g)
    st_on = SPACETIME
    if g.do_vf and len(g.tris):
        vm = moved[g.verts]
        tm = moved[g.tris].any(axis=1)
        iv, it = np.flatnonzero(vm), np.flatnonzero(tm)
        ev = g.vert_elem[g.verts]
        cands = []
        for a_idx, b_idx, drop_moved_a in ((iv, np.arange(len(g.tris)), False),
                                           (np.flatnonzero(~vm), it, True)):
            if not len(a_idx) or not len(b_idx):
                continue
            va, tb = g.verts[a_idx], g.tris[b_idx]
            lo_a, hi_a = bp.primitive_boxes(x, va, p, infl)
            lo_b, hi_b = bp.primitive_boxes(x, tb, p, infl)
            sa = sb = None
            if st_on:
                sa = bp.spacetime_prim_boxes(x, va, p, infl, ~g.kinematic_el[ev[a_idx]],
                                             _st_group(g, ev, True)[a_idx])
                sb = bp.spacetime_prim_boxes(x, tb, p, infl,
                                             ~g.kinematic_el[g.tri_elem[b_idx]],
                                             _st_group(g, g.tri_elem, True)[b_idx])
            cand = bp.column_query_pairs(lo_a, hi_a, lo_b, hi_b, va, tb, st_a=sa, st_b=sb)
            if len(cand):
                cands.append(np.stack([a_idx[cand[:, 0]], b_idx[cand[:, 1]]], axis=1))
        if cands:
            cand = np.ascontiguousarray(np.concatenate(cands))
            n = len(cand)
            rows, nrm, tgt, mu, one = (np.empty((n, 4), np.int64), np.empty((n, 3)),
                                       np.empty(n), np.empty(n), np.empty(n, np.bool_))
            k, _ = _filter_vf(cand, g.verts, g.tris, g.tri_elem, g.vert_elem, g.allow,
                              g.tolerant, g.th_out, g.th_in, g.friction, g.visible, g.setmask,
                              g.one_sided, x, v, h, g.restitution, g.margin, rows, nrm, tgt,
                              mu, one, g.recover, g.side_mem, g.side_seen, g.crossed,
                              g.stamp + 1, g.near_d, g.near_s)
            out.append((rows[:k], nrm[:k], tgt[:k], True))
    if g.do_ee and len(g.edges):
        em = moved[g.edges].any(axis=1)
        ie = np.flatnonzero(em)
        if len(ie):
            ea = g.edges[ie]
            lo_a, hi_a = bp.primitive_boxes(x, ea, p, infl)
            lo_b, hi_b = bp.primitive_boxes(x, g.edges, p, infl)
            sa = sb = None
            if st_on:
                lab = _st_group(g, g.edge_elem, True)
                act = ~g.kinematic_el[g.edge_elem]
                sa = bp.spacetime_prim_boxes(x, ea, p, infl, act[ie], lab[ie])
                sb = bp.spacetime_prim_boxes(x, g.edges, p, infl, act, lab)
            cand = bp.column_query_pairs(lo_a, hi_a, lo_b, hi_b, ea, g.edges, st_a=sa, st_b=sb)
            if len(cand):
                i, j = ie[cand[:, 0]], cand[:, 1]
                keep = ~em[j] | (i < j)  # a pair of two moved edges once
                cand = np.ascontiguousarray(np.stack([np.minimum(i, j), np.maximum(i, j)],
                                                     axis=1)[keep])
                n = len(cand)
                vn = _vertex_normals(x, g) if g.one_sided.any() else np.zeros((0, 3))
                rows, nrm, tgt, mu = (np.empty((n, 4), np.int64), np.empty((n, 3)),
                                      np.empty(n), np.empty(n))
                k, _ = _filter_ee(cand, g.edges, g.edge_elem, g.allow, g.tolerant, g.th_out,
                                  g.friction, g.visible, g.setmask, g.one_sided, x, v, h,
                                  g.restitution, g.margin, rows, nrm, tgt, mu, vn, g.crossed,
                                  g.stamp + 1)
                out.append((rows[:k], nrm[:k], tgt[:k], False))
    return out


def ccd_safe_step(c, x, p, w, v, h, frac, rounds, n_it, joint_step=None, stats=None):
    """The final safe step of a substep (see the section comment): CCD of the motion x -> p,
    ``rounds`` rounds of contacts at the time of impact, then impact zones. Modifies ``p``;
    adds ``ccd_*`` counts to ``stats``."""
    st = stats if stats is not None else {}
    work = getattr(c, "ccd", None)
    if work is None or len(work.parent) != len(x):
        n = len(x)
        work = c.ccd = _CCDWork(np.arange(n), np.zeros(n, np.bool_), np.zeros(n, np.int64),
                                np.zeros((n, 8)), np.zeros((n, 3)))

    def hits(detect=True):
        if detect:
            _detect_all(c, x, p, v, h, SPACETIME)
            st["ccd_detections"] = st.get("ccd_detections", 0) + 1
            if CCD_ROUND_INCREMENTAL:
                _detected_to(c, p)
        hv = _ccd_hits(work, c.vf, c.vf_n, c.vf_target, True, x, p, frac)
        he = _ccd_hits(work, c.ee, c.ee_n, c.ee_target, False, x, p, frac)
        return hv, he

    sl_ccd = slide_mode(False)
    cover = _rows_cover(c, x, p, frac)
    if not cover and CCD_INCREMENTAL > 0.0 and _ccd_incremental(c, work, x, p, v, h, frac):
        st["ccd_incremental"] = st.get("ccd_incremental", 0) + 1
        return st  # no hit: a full detection would find none either
    hv, he = hits(not cover)
    st["ccd_hits"] = st.get("ccd_hits", 0) + len(hv[0]) + len(he[0])
    for _ in range(rounds):
        if not len(hv[0]) and not len(he[0]):
            return st
        cv = _toi_contacts(c, work, hv[0], hv[1], True, x, p) if len(hv[0]) else None
        ce = _toi_contacts(c, work, he[0], he[1], False, x, p) if len(he[0]) else None

        def toi_pass():
            """One pass over the contacts at the time of impact."""
            if cv is not None:
                project_vf(p, x, w, cv[0], cv[1], cv[2], cv[3], cv[4], c.damping, cv[5],
                           sl_ccd if CCD_SLIDE else 0)
            if ce is not None:
                project_ee(p, x, w, ce[0], ce[1], ce[2], ce[3], ce[4], c.damping,
                           sl_ccd if CCD_SLIDE else 0)

        for _it in range(n_it):
            if joint_step is not None:
                joint_step(p)
            toi_pass()
            _project_contacts(c, p, x, w, sl_ccd)
        # polish (``CCD_POLISH``): the strain limit with the contacts at the time of impact
        # alone; the pass over every row above ends each round with the cloth stretched
        for _it in range(CCD_POLISH if joint_step is not None else 0):
            joint_step(p)
            toi_pass()
        if CCD_ROUND_INCREMENTAL and _ccd_incremental(c, work, x, p, v, h, frac):
            st["ccd_round_incremental"] = st.get("ccd_round_incremental", 0) + 1
            return st  # no hit left: a full detection would find none either
        hv, he = hits()
    if not len(hv[0]) and not len(he[0]):
        return st
    # fail-safe: impact zones (Provot 1997; Bridson et al. 2002, section 7.4, here translation
    # only): the vertices of the hits, merged into zones, move as one; a zone with kinematic
    # vertices follows them. Zones grow until no pair collides.
    n = len(x)
    parent, inzone, touched, acc, p_in = work.parent, work.inzone, work.touched, work.acc, \
        work.p_in
    parent[:] = np.arange(n)
    inzone[:] = False
    p_in[:] = p
    nt = zones = 0
    for _it in range(_CCD_ZONE_ITERS):
        grew = False
        for (sel, _t, _d), rows in ((hv, c.vf), (he, c.ee)):
            if len(sel):
                nt, g = _zones_union(rows, sel, parent, inzone, touched, nt)
                grew |= g
        if not grew:
            break  # the same zones again (kinematic vertices in conflict): nothing to gain
        zones = _zones_move(x, p_in, p, w, parent, touched, nt, acc)
        hv, he = hits()
        if not len(hv[0]) and not len(he[0]):
            break
    st["ccd_zone_vertices"] = st.get("ccd_zone_vertices", 0) + nt
    st["ccd_zones"] = st.get("ccd_zones", 0) + zones
    st["ccd_unresolved"] = st.get("ccd_unresolved", 0) + len(hv[0]) + len(he[0])
    return st


class CollisionParams(ConstraintParams):
    final_rounds: int = Field(1, ge=0, le=1000, description="Final collision rounds (re-detection over "
                              "the solved motion, then contacts only). 1 since stop 31 (2 "
                              "before): the second round's detection and passes cost about a "
                              "fifth of the frame and the CCD safe step after the rounds holds "
                              "the intersections either way. Measured in one interleaved run "
                              "each (NUMBA_NUM_THREADS=1, graphs/bench/peer_collision.py --sizes "
                              "64 --newton none --loki 2x15,2x15+collisions.final_rounds=1 "
                              "--stages; --sizes 128 --frames 16): the 64 x 64 drop 570 -> 468 ms "
                              "CPU per frame (median), the 128 x 128 drop 4510 -> 3718 ms, the "
                              "same worst edge strain (1.5 / 1.9 %), 0 intersecting pairs and 0 "
                              "vertices inside in every frame; graphs/bench/cloth_strain.py "
                              "--frames 24 --scenes cloth_on_sphere sleeve_elbow skirt_walk pinch "
                              "--only defaults --set collisions.final_rounds=1: cloth_on_sphere "
                              "1.49 -> 1.50 % at 0.80x the CPU, sleeve_elbow 1.50 -> 1.50 % at "
                              "0.68x, skirt_walk 1.10 -> 1.39 % at 1.00x, pinch 0.86 -> 0.86 %. "
                              "A Nucleus default: the implicit solver (whose projection pass "
                              "runs these rounds) keeps 2 unless the scene sets it: with 1 its "
                              "128 x 128 drop at one substep stretched to 6.18 % in frame 7 "
                              "against 2.84 % with 2 (issue #11's bound 5 %; found by helper A "
                              "at stop 32, measured side by side, 10 frames).")
    final_iterations: int = Field(4, ge=1, le=10000, description="Contact passes per final round.")
    ccd: bool = Field(True, description="Final safe step: continuous collision detection of the "
                      "solved motion of every substep; pairs that would collide get contacts "
                      "with the normal at the time of impact, then impact zones.")
    ccd_rounds: int = Field(2, ge=0, le=100, description="Rounds of contacts at the time of "
                            "impact before the impact zones.")
    ccd_distance: float = Field(0.1, ge=0.0, le=1.0, description="Distance [fraction of the "
                                "pair's thickness, at most half its start distance] that counts "
                                "as an impact in the safe step.")
    redetect: bool = Field(False, description="Detect again (over the motion from the start of "
                           "the substep to the iterate) before a contact pass of the iterations "
                           "when some vertex left the box of the motion the rows were detected "
                           "for by more than the inflation allows (``_rows_hold``): constraints "
                           "that move vertices far (the stretch long-range rows) then cannot "
                           "carry cloth past a pair the detection never saw (measured: the "
                           "stress projectile with 5 long-range levels, 2 sweeps: 78 crossing "
                           "cloth-ball pairs -> 0, measured before the side memory of "
                           "``_filter_vf`` took only a nearest triangle the vertex projects "
                           "onto; since then the rows alone keep the quick projectile free of "
                           "crossings without it). Off by default: on the 64 x 64 drop it "
                           "detects again in most contact passes (2.2x CPU per frame) for a "
                           "worst strain of 7.3 instead of 7.5 % with the long-range rows "
                           "and the inextensible strain limit.")


class CollisionConstraint(ConstraintBehavior):
    """Contacts of every collision group as unilateral constraints in the Nucleus loop."""

    ParamsModel = CollisionParams
    requires = (CollisionGroup,)
    reads = ("contacts",)
    default_importance = 0.5
    default_order = 50

    def bind(self, ctx, elements):
        # one final round is a Nucleus default: other solvers keep two unless set explicitly
        nucleus = getattr(ctx.scene.spec, "solver", "nucleus") == "nucleus"
        self._final_rounds = (self.params.final_rounds if nucleus
                              or "final_rounds" in self.params.model_fields_set else 2)
        return _Ref()

    def begin_substep(self, ctx, d):
        c = ctx.state.fields.get("contacts")
        if c is not None:
            c.det_ref = c.x1  # the rows come from the detection of CollisionDetect.step

    def project(self, ctx, d, p):
        c = ctx.state.fields["contacts"]
        w = ctx.model.particle_inv_mass
        if c.rel_ref is not None:  # ``SPACETIME_RELATIVE``
            ctx.stats["relative_checks"] = ctx.stats.get("relative_checks", 0) + 1
            x = ctx.state.particle_q
            k = _relative_check(c, x, p)
            c.rel_extra = []
            if k and k <= RELATIVE_INCREMENTAL * sum(len(g.verts) for g in c.groups):
                n_add = _relative_extra(c, x, p, ctx.state.particle_qd, ctx.dt)
                ctx.stats["relative_added"] = ctx.stats.get("relative_added", 0) + n_add
            elif k:
                ctx.stats["relative_full"] = ctx.stats.get("relative_full", 0) + 1
                _detect_all(c, x, p, ctx.state.particle_qd, ctx.dt, "relative", c.rel_slack)
                if c.p_rel is None or c.p_rel.shape != p.shape:
                    c.p_rel = np.empty_like(p)
                c.p_rel[:] = p
                c.rel_ref = c.det_ref = c.p_rel
            if k:
                ctx.stats["relative_detections"] = ctx.stats.get("relative_detections", 0) + 1
                ctx.stats["relative_flagged"] = ctx.stats.get("relative_flagged", 0) + k
        elif self.params.redetect and c.det_ref is not None:
            if not _rows_hold(c, ctx.state.particle_q, p):
                _detect_all(c, ctx.state.particle_q, p, ctx.state.particle_qd, ctx.dt)
                _detected_to(c, p)
                ctx.stats["iteration_detections"] = ctx.stats.get("iteration_detections", 0) + 1
        a = _project_contacts(c, p, ctx.state.particle_q, w)
        for vf, ee in c.rel_extra:  # ``RELATIVE_INCREMENTAL``'s rows of this pass
            if len(vf[0]):
                a += project_vf(p, ctx.state.particle_q, w, vf[0], vf[1], vf[2], vf[3], vf[5],
                                c.damping, vf[4])
            if len(ee[0]):
                a += project_ee(p, ctx.state.particle_q, w, ee[0], ee[1], ee[2], ee[3], ee[4],
                                c.damping)
        ctx.stats["max_active_contacts"] = max(ctx.stats.get("max_active_contacts", 0), a)

    def finalize(self, ctx, d, p):
        """Final collision pass (Nucleus: collisions resolved until none is left or a maximum
        number of iterations): candidates are found again over the motion the solver actually
        produced, x -> p, and only contacts are projected, up to ``final_rounds`` rounds."""
        c = ctx.state.fields["contacts"]
        w = ctx.model.particle_inv_mass
        x = ctx.state.particle_q
        active = 0
        joint = [(b, dd) for b, dd in ctx.constraints if hasattr(b, "project_joint")]
        n_it = max([self.params.final_iterations] + [b.joint_iterations() for b, _ in joint])
        if c.rel_ref is not None:  # rows of ``SPACETIME_RELATIVE``: the CCD detects again
            c.det_ref = None
            c.rel_ref = None
            c.rel_extra = []
        else:
            c.det_ref = c.x1  # the rows come from the detection of CollisionDetect.step
        for _ in range(self._final_rounds):
            _detect_all(c, x, p, ctx.state.particle_qd, ctx.dt, SPACETIME)
            _detected_to(c, p)
            for _it in range(n_it):
                for b, dd in joint:  # strain limits solved together with the contacts
                    b.project_joint(ctx, dd, p)
                active = _project_contacts(c, p, x, w)
                if active == 0 and all(b.satisfied(ctx, dd, p) for b, dd in joint):
                    break
            if active == 0:
                break
        ctx.stats["max_final_active"] = max(ctx.stats.get("max_final_active", 0), active)

    def after_finalize(self, ctx, d, p):
        """The final safe step (CCD of the solved motion; see ``ccd_safe_step``)."""
        if not self.params.ccd:
            return
        c = ctx.state.fields["contacts"]
        joint = [(b, dd) for b, dd in ctx.constraints if hasattr(b, "project_joint")]
        n_it = max([self.params.final_iterations] + [b.joint_iterations() for b, _ in joint])

        def joint_step(q):
            for b, dd in joint:
                b.project_joint(ctx, dd, q)

        ccd_safe_step(c, ctx.state.particle_q, p, ctx.model.particle_inv_mass,
                      ctx.state.particle_qd, ctx.dt, self.params.ccd_distance,
                      self.params.ccd_rounds, n_it, joint_step if joint else None, ctx.stats)


@dataclass
class _Ref:
    lam: None = None


class PenetrationCheck(Behavior):
    """Independent intersection check at the end of every frame: counts intersecting triangle
    pairs (and hair segment-triangle pairs) between and within the members of every collision
    group; ``run.json`` records the count per frame."""

    stage = "diagnostics"
    requires = (CollisionGroup,)

    def bind(self, ctx, elements):
        tris, segs = [], []
        for e in elements:
            for x in _members(ctx, e, e.get(CollisionGroup)):
                if x.geometry is None:
                    continue
                if len(x.geometry.triangles):
                    tris.append(x.geometry.triangles + x.vertex_offset)
                elif len(x.geometry.edges):
                    segs.append(x.geometry.edges + x.vertex_offset)
        F = np.unique(np.concatenate(tris), axis=0) if tris else np.zeros((0, 3), np.int64)
        E = np.unique(np.concatenate(segs), axis=0) if segs else None
        return (F, E, bp.PairBuffer(0))

    def frame_end(self, ctx, data):
        from .intersect import find_intersections

        F, E, buf = data
        if not len(F):
            return
        rep = find_intersections(ctx.state.particle_q, F, E, touching=False, out=buf)
        ctx.stats["penetrations"] = rep.count
