"""Inextensible cloth in motion and contact (issues #12, #13): worst edge strain per frame and
cost at the defaults and at the settings around them, every setting stepped frame by frame in
turn in one process (machine load hits all alike):

* ``before``: the defaults before issue #13, ``stretch: {long_range_levels: 0, sweeps: 1,
  inextensible_compression: null}``, ``strain_limit: {inextensible_max_strain: null}`` (the
  solver before the long-range rows, bitwise);
* ``long_range``: ``stretch: {long_range_levels: 5, sweeps: 3}`` alone (no strain limit, edges
  hard in compression);
* ``in_contact_hard``: that plus ``strain_limit: {inextensible_max_strain: 0.05,
  inextensible_joint_iterations: 10}`` (edges hard in compression);
* ``old_defaults``: that plus ``stretch: {inextensible_compression: 10}`` (edges near
  contacts compliant in compression; the defaults of stops 24-28, explicit: bitwise those);
* ``defaults``: the defaults since stop 29, setting B below with 10 joint passes, 40 in the
  substeps whose contacts pinch the cloth between two collider surfaces
  (``strain_limit.inextensible_pinch_iterations``) and there the long-range rows in the joint
  passes too (``stretch.joint_long_range: pinch``);
* ``defaults+redetect``: that plus ``collisions: {redetect: true}``;
* ``tight``: old_defaults with ``stretch: {joint_long_range: true}``, ``strain_limit:
  {inextensible_max_strain: 0.02, inextensible_joint_iterations: 40}``.

* ``B``: setting B of strain_limit.py's global_chord (opt-in before stop 29): the 1 % limit with
  3 joint passes and the global strain step once a frame ('rows', 2 pivots, 40 sweeps, fast LU,
  chord passes), no pinch passes, no long-range rows in the joint passes;
* ``P``: the defaults explicit.

``--abba`` runs every setting twice, the repeats in reverse order. Measured (stop 29,
NUMBA_NUM_THREADS=1, ``--frames 24 --scenes cloth_on_sphere skirt_walk sleeve_elbow --only
old_defaults defaults --abba``), worst strain and CPU ms per frame over the second half,
old_defaults / defaults:
cloth_on_sphere 6.63 / 1.50 %, 341 / 506 ms (1.49x); skirt_walk 5.00 / 1.10 %, 44 / 45 ms;
sleeve_elbow 13.16 / 1.50 %, 219 / 312 ms (1.42x; 60 frames 13.16 / 1.50 %, medians 197 / 260
ms); ``--peer 64 128 --frames 12``: 64 x 64 6.6 / 1.5 % at 231 / 379 ms (medians), 128 x 128
15.9 / 1.9 % at 1138 / 3871 ms (3.4x). Measured (stop 28, one run
per line, NUMBA_NUM_THREADS=1, load 5-6 on 2 cores; ``--frames 24 --scenes cloth_on_sphere
skirt_walk sleeve_elbow --only defaults B --abba``, then ``--frames 12 --scenes
graphs/bench/cloth_sphere_64.yaml``), worst strain and CPU ms per frame over the second half,
defaults / B (each the mean of its two runs): cloth_on_sphere 6.63 / 1.50 %, 498 / 669 ms
(1.34x); skirt_walk 5.00 / 1.41 %, 54 / 55 ms (1.01x); sleeve_elbow 23.91 / 33.47 %, 339 / 371
ms (1.09x; 244 / 233 intersecting pairs); cloth_sphere_64 (12 frames) 6.63 / 1.50 %, 645 / 804
ms (1.25x; medians over frames 2-12 285 / 425 ms, 1.49x). No penetrations on the drops.

Run::

    .venv/bin/python graphs/bench/cloth_strain.py [--frames 24] [--scenes cloth_on_sphere ...]
    .venv/bin/python graphs/bench/cloth_strain.py --only before defaults \
        --set stretch.sweeps=2 \
        --set strain_limit.inextensible_joint_iterations=20 ...   # some settings, extra ones
    /tmp/venv-peer/bin/python graphs/bench/cloth_strain.py --peer 64 [128] [--frames 23]

``--peer N`` runs the peer collision scene (``cloth_sphere_N.yaml``) through
``peer_collision.py``'s runners: lokigraph at each setting above at the scene's substeps and
Style3D at its settings when Newton is importable, with the shared intersection counter.

Per setting: worst edge strain over the frames (max over edges of ``|e| / L0 - 1``), the frame
where it happens, the last frame's strain, the penetration count (max over frames), CPU and wall
ms per frame (medians over frames 2..N) and the mean CPU ms per frame over the second half of
the frames (the drops are in contact there).

Where the strain comes from::

    .venv/bin/python graphs/bench/cloth_strain.py --stages cloth_on_sphere [--set ...]
    .venv/bin/python graphs/bench/cloth_strain.py --girth [--frames 48]

``--stages``: per frame, the worst edge strain of the substeps after the interleaved
iterations, after the final collision rounds (joint contact + strain-limit passes), after the
CCD safe step and at the frame's end, with the contacts still active after the final rounds.
``--substages SCENE``: per substep, the worst edge after the iterations, the final rounds, the
global step (where it runs) and the CCD safe step, the global step's passes, the CCD's hits, and
where the worst edge and the edges over 5 % lie against a moving 'ball' (gap to it, cosine with
its motion and with up). ``--row-kinds SCENE --at F ...``: in those frames, one contact pass of
each kind of rows alone after the final rounds (ball / cloth, vertex-face and edge-edge, cloth /
cloth), and the worst edge after each call inside the CCD safe step. ``--contacts-flag
NAME=VALUE`` sets a contacts module flag for the run (``SLIDE_APART=1``; the global step's
contact rows follow it too, ``strain_limit_global.contact_rows``; helper runs took that change
as a wrapper, ``--slide-global``, since built in). Measured on cloth_sphere_moving_128 (issue #12,
NUMBA_NUM_THREADS=1, ``--substages graphs/bench/cloth_sphere_moving_128.yaml --frames 12``): at
the defaults the final rounds raise the worst edge (frame 7: 57 -> 63 %, 69 -> 77 %; on the
static drop they lower it, 14 -> 8 %), the global step (last substep only) stops at its 20 passes
with 7-21 % left, and the CCD takes frames 10-11 from 10.7 / 7.5 % to 34.7 / 86.6 %; neither
friction (CollisionResponse friction_scale 0) nor self-collision (left out) is the cause, nor
is the step running every substep (global_every substep: 1.9-26.6 % after it, frames 7-12). ``--row-kinds``
(frame 7): one pass of the ball-cloth edge-edge rows alone takes the worst edge from 24 to 90 %
(ball-vertex / cloth-face rows: to 74 %; the others leave it): 252 of the 263 acting rows were
'crossed' by their start normal's sign while 10 mm apart across it (``contacts.SLIDE_APART``).
With ``--contacts-flag SLIDE_APART=1``: the final rounds lower the worst edge
(64 -> 18 %), the global step converges (1.3-3.1 % after it, frames 6-14), frame ends 1.3-3.1 %
but for frames 10, 11 and 14 (33.6 / 22.7 / 26.5 %, the CCD's contacts; ``--row-kinds --at 10``: the hits at the time of
impact are cloth-cloth pairs within a quad, 1.5 -> 28 %, and its pass over every row moves 1,132
vertices, cloth-cloth rows, to 122 %).

``--passes SCENE``: the global strain-limit step's passes in each frame for each ``--set``
(interleaved) and the worst relative excess over the limit after each pass::

    .venv/bin/python graphs/bench/cloth_strain.py --passes cloth_on_sphere --frames 14 \
        --set strain_limit.global_passes=20 ... --set ... strain_limit.global_smooth=40

``--fast-exact SCENE``: strain_limit_global.FAST_EXACT off and on, two runs at the defaults
stepped in turn (ABBA by frame), CPU per frame and in the global step, and the positions'
bitwise equality after every frame::

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/cloth_strain.py \
        --fast-exact graphs/bench/cloth_sphere_128.yaml --frames 12

``--girth``: sleeve_elbow, per frame, the circumferential rings over the elbow (8, 9, 10) and at
the wrist (16): girth strain, worst ring edge strain, and the strain the arm forces on the ring
(the perimeter of the convex hull of the arm's section -- upper arm, forearm, elbow cap at
their current positions -- by a plane through the ring's centre plus 2 pi times the collision
distance, the smallest over planes tilted up to 40 degrees from the ring's own plane, against
the ring's rest girth; in the ring's plane the part of the section inside the ring, in a tilted
one the part within 1.2 ring radii of the centre), and the sleeve
vertices inside the arm (winding number).

``--where``: sleeve_elbow, per frame and --set, where the worst edge is and what it touches.
Measured (30 frames; defaults, A + S, B of strain_limit.py's global_chord): with the 1 % limit
the sleeve holds 1.1-1.4 % to frame 12; from frame 13 the worst edge is a ring edge of ring 8-9
(1 cm before to 2.5 cm past the joint) on the inner elbow (8-68 deg from +y), its vertices
touching both the upper arm and the forearm (pinched in the closing crease) while the arm does
not force the ring (its girth -8.6 .. -1.3 % of the ring's rest girth to frame 21); from
frame 22 to 28 the arm forces +0.2 .. +4.9 % on ring 9, which no setting can hold under 2 %
without crossing the arm. The edges over 2 % stay in rings 5-14 (12-63 edges) with the 1 %
limit, all rings (150-333 edges) at the defaults' 5 %, which share the forced girth: the
defaults' worst is 23.9 %, A + S 37.9 %, B 33.5 % (ring girth +8.7 % against +2.8-3.2 %
forced at frame 24). What holds it is the joint passes, not the global step: B with
inextensible_joint_iterations 40 7.92 % over 26 frames (10: 21.6 %; 3: 33.5 %; B with
global_passes 40 at tolerance 1e-3 19.5 % over 21 frames, as B), at 1.46x the defaults' CPU
there and 1.99x on cloth_on_sphere (1.49 %).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: the Nucleus defaults before issue #13 (the solver before the long-range rows, bitwise)
BEFORE = {"stretch": {"long_range_levels": 0, "sweeps": 1, "inextensible_compression": None},
          "strain_limit": {"inextensible_max_strain": None}}
LONG_RANGE = {"stretch": {"long_range_levels": 5, "sweeps": 3, "inextensible_compression": None,
                          "joint_long_range": False},
              "strain_limit": {"inextensible_max_strain": None}}
#: the strain-limit defaults before stop 29, explicit: the 5 % inextensible strain limit with 10
#: joint passes, Gauss-Seidel only (without global_passes the step's other parameters are never
#: read), no pinch passes, no long-range rows in the joint passes
BEFORE_GLOBAL = {"strain_limit": {"inextensible_max_strain": 0.05,
                                  "inextensible_joint_iterations": 10, "global_passes": 0,
                                  "inextensible_pinch_iterations": None},
                 "stretch": {"joint_long_range": False}}
IN_CONTACT_HARD = {"strain_limit": BEFORE_GLOBAL["strain_limit"],
                   "stretch": {"inextensible_compression": None, "joint_long_range": False}}
#: the defaults of stops 24-28 (the former opt-in 'in_contact'): long-range rows 5 levels, 3
#: sweeps, the 5 % inextensible strain limit with 10 joint passes, edges near contacts
#: compliant in compression at 10 N/m (bitwise those defaults)
OLD_DEFAULTS = BEFORE_GLOBAL
#: the defaults now (stop 29): OLD_DEFAULTS with the 1 % limit, the global strain step once a
#: frame (setting B's), 40 joint passes in the substeps whose contacts pinch the cloth between
#: two collider surfaces (strain_limit.inextensible_pinch_iterations) and in those the
#: long-range rows in the joint passes (stretch.joint_long_range 'pinch')
DEFAULTS = {}
#: setting B of strain_limit.py's global_chord (opt-in before stop 29): the 1 % limit with 3
#: joint passes and the global strain step once a frame, without the pinch passes and the
#: long-range rows in the joint passes
B = {"strain_limit": {"inextensible_max_strain": 0.01, "inextensible_joint_iterations": 3,
                      "global_passes": 20, "global_near": 0.005, "global_contacts": "rows",
                      "global_tolerance": 0.005, "global_pivots": 2, "global_every": "frame",
                      "global_smooth": 40, "global_alpha": 1e-4, "global_fast_lu": True,
                      "global_chord": 3, "global_chord_rate": 0.8,
                      "inextensible_pinch_iterations": None},
     "stretch": {"joint_long_range": False}}
#: the defaults explicit (stop 29): B with 10 joint passes, 40 where pinched, and there the
#: long-range rows in the joint passes
P = {"strain_limit": {**B["strain_limit"], "inextensible_joint_iterations": 10,
                      "inextensible_pinch_iterations": 40},
     "stretch": {"joint_long_range": "pinch"}}
REDETECT = {"collisions": {"redetect": True}}
TIGHT = {"stretch": {"joint_long_range": True},
         "strain_limit": {"inextensible_max_strain": 0.02, "inextensible_joint_iterations": 40,
                          "global_passes": 0, "inextensible_pinch_iterations": None}}
SETTINGS = [("before", BEFORE), ("long_range", LONG_RANGE),
            ("in_contact_hard", IN_CONTACT_HARD), ("old_defaults", OLD_DEFAULTS),
            ("defaults", DEFAULTS), ("defaults+redetect", REDETECT), ("tight", TIGHT),
            ("B", B), ("P", P)]
SCENES = ("cloth_on_sphere", "skirt_walk", "sleeve_elbow", "cloth_pinned", "flag_wind")


def _variant(path: Path, overrides: dict, tmp: Path) -> Path:
    """A copy of the scene with graph overrides in ``tmp``, beside links to the other files of
    the scene's folder (relative map paths stay valid)."""
    s = yaml.safe_load(path.read_text())
    go = s.setdefault("graph_overrides", {})
    for node, params in overrides.items():
        go.setdefault(node, {}).update(params)
    s["output"] = {"dir": str(tmp / "out")}
    for f in path.parent.iterdir():
        link = tmp / f.name
        if f.suffix != ".yaml" and f.is_file() and not link.is_symlink():
            link.symlink_to(f)
    out = tmp / f"{path.stem}_{len(list(tmp.glob('*.yaml')))}.yaml"
    out.write_text(yaml.safe_dump(s))
    return out


class _Run:
    def __init__(self, label, path):
        from lokigraph.api import compile_file
        from lokigraph.run import Simulation

        c = compile_file(path)
        self.label = label
        self.d = c.schedule.find("StretchConstraint")[0].data
        self.sim = Simulation(c)
        self.worst, self.pen, self.cpu, self.wall = [], [], [], []

    def step(self):
        t, c = time.perf_counter(), time.process_time()
        st = self.last = self.sim.step_frame()
        self.wall.append(time.perf_counter() - t)
        self.cpu.append(time.process_time() - c)
        self.worst.append(float(self.strain(self.sim.state.particle_q).max()))
        self.pen.append(float(st.get("penetrations", 0) or 0))

    def strain(self, q):
        """Per stretch edge |e| / rest - 1 at positions ``q``."""
        d = self.d
        return np.linalg.norm(q[d.idx[:, 1]] - q[d.idx[:, 0]], axis=1) / d.rest - 1.0

    def row(self, scene):
        w = np.array(self.worst)
        return (f"| {scene} | {self.label} | {100 * w.max():.2f} | {int(w.argmax()) + 1} | "
                f"{100 * w[-1]:.2f} | {int(max(self.pen))} | {1e3 * np.median(self.cpu[1:]):.0f} | "
                f"{1e3 * np.median(self.wall[1:]):.0f} | "
                f"{1e3 * np.mean(self.cpu[len(self.cpu) // 2:]):.0f} |")


def _parse_set(items):
    out = {}
    for it in items or []:
        key, val = it.split("=", 1)
        node, param = key.split(".", 1)
        out.setdefault(node, {})[param] = yaml.safe_load(val)
    return out


def scenes_table(names, frames, extras, only=None, abba=False):
    print("| scene | setting | worst strain % | frame | last % | max pen | CPU ms/frame | "
          "wall ms/frame | CPU ms/frame, 2nd half |")
    print("|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            path = _scene_path(name)
            name = path.stem
            settings = [s for s in SETTINGS if not only or s[0] in only]
            for extra in extras:
                settings.append((" ".join(f"{n}.{k}={v}" for n, p in extra.items()
                                          for k, v in p.items()), extra))
            if abba:  # each setting again, in reverse order
                settings += [(lbl + " (repeat)", ov) for lbl, ov in settings[::-1]]
            files = [_variant(path, ov, Path(tmp)) for _, ov in settings]
            runs = [_Run(lbl, f) for (lbl, _), f in zip(settings, files)]
            for _ in range(frames):
                for r in runs:
                    r.step()
            for r in runs:
                print(r.row(name), flush=True)


def peer(sizes, frames, only=None):
    sys.path.insert(0, str(ROOT / "graphs" / "bench"))
    import peer_collision as pc

    try:
        newton, wp = pc.import_newton()
    except Exception as exc:  # noqa: BLE001
        newton = wp = None
        print(f"[peer] Newton not importable ({type(exc).__name__}); lokigraph rows only")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            sc = pc.ClothSphere(pc.SCENES[n])
            runs = [pc.LokiRun(pc.ClothSphere(_variant(pc.SCENES[n], ov, Path(tmp))),
                               sc.substeps, 15, label=" " + lbl) for lbl, ov in SETTINGS
                    if not only or lbl in only]
            if newton is not None:
                for s, i in pc.NEWTON_SETTINGS:
                    runs.append(pc.NewtonRun(newton, wp, sc, s, i, 1000.0, "frame", None))
            rr = pc.run_interleaved(runs, frames or sc.frames)
            best = min((r["cpu_ms"] for r in rr if r["framework"] == "newton"
                        and r.get("cpu_ms") is not None and r["finite"]), default=None)
            for r in rr:
                r["ratio"] = (r["cpu_ms"] / best) if best and r.get("cpu_ms") else None
            rows += rr
    print(pc.table(rows))


def _scene_path(name):
    return (Path(name).resolve() if name.endswith(".yaml")
            else ROOT / "graphs" / "examples" / f"{name}.yaml")


def stages(name, frames, extras):
    """Worst edge strain after each stage of the substeps, per frame (see the module doc)."""
    from lokigraph.behaviors.collision import contacts as C

    cls = C.CollisionConstraint
    fin0, aft0 = cls.finalize, cls.after_finalize
    rec = {}

    def strain(p):
        return float(run.strain(p).max())

    def fin(self, ctx, d, p):
        rec.setdefault("iter", []).append(strain(p))
        fin0(self, ctx, d, p)
        rec.setdefault("final", []).append(strain(p))

    def aft(self, ctx, d, p):
        aft0(self, ctx, d, p)
        rec.setdefault("ccd", []).append(strain(p))

    ov = extras[0] if extras else {}
    cls.finalize, cls.after_finalize = fin, aft
    try:
        with tempfile.TemporaryDirectory() as tmp:
            run = _Run("", _variant(_scene_path(name), ov, Path(tmp)))
            print("| frame | after iterations % | after final rounds % | after CCD % | frame end % "
                  "| active contacts after the final rounds (max over substeps) |")
            print("|---|---|---|---|---|---|")
            for k in range(frames):
                rec.clear()
                run.step()
                m = {key: 100 * max(v) if v else float("nan") for key, v in rec.items()}
                print(f"| {k + 1} | {m.get('iter', np.nan):.2f} | {m.get('final', np.nan):.2f} | "
                      f"{m.get('ccd', np.nan):.2f} | {100 * run.worst[-1]:.2f} | "
                      f"{int(run.last.get('max_final_active', 0))} |",
                      flush=True)
    finally:
        cls.finalize, cls.after_finalize = fin0, aft0


def _ball(sim):
    """The vertex slice of the scene's kinematic collider (the element named 'ball'), or None."""
    els = {e.name: e for e in sim.compiled.scene.elements}
    return els["ball"].vertex_slice if "ball" in els else None


def substages(name, frames, extras, over=0.05):
    """Per substep: the worst edge strain after the interleaved iterations, after the final
    collision rounds, after the global strain step (where it runs), after the CCD safe step,
    the global step's passes, and where the worst edge and the edges over ``over`` are at the
    substep's end against the moving ball (see the module doc)."""
    from lokigraph.behaviors.collision import contacts as C
    from lokigraph.behaviors.materials import strain_limit as SL

    cls, scls = C.CollisionConstraint, SL.StrainLimitConstraint
    fin0, aft0, sfin0 = cls.finalize, cls.after_finalize, scls.finalize
    rec = {}

    def strain(p):
        return run.strain(p)

    def fin(self, ctx, d, p):
        rec.clear()
        rec["iter"] = strain(p).max()
        rec["x"] = ctx.state.particle_q.copy()
        fin0(self, ctx, d, p)
        rec["final"] = strain(p).max()
        rec["joint_n"] = max(b.joint_iterations() for b, _ in ctx.constraints
                             if hasattr(b, "project_joint"))

    def sfin(self, ctx, d, p):
        g = d.glob if d is not None else None
        n0 = g.stats["passes"] if g is not None else 0
        sfin0(self, ctx, d, p)
        if g is not None and g.stats["passes"] > n0:
            rec["global"] = strain(p).max()
            rec["passes"] = g.stats["passes"] - n0

    def aft(self, ctx, d, p):
        keys = ("ccd_hits", "ccd_zone_vertices")
        s0 = [ctx.stats.get(k, 0) for k in keys]
        aft0(self, ctx, d, p)
        ccd = [ctx.stats.get(k, 0) - v for k, v in zip(keys, s0)]
        e = strain(p)
        rec["ccd"] = e.max()
        sub = ctx.substep
        row = f"| {frame} | {sub + 1} | " + " | ".join(
            f"{100 * rec[k]:.2f}" if k in rec else "-" for k in ("iter", "final", "global", "ccd"))
        row += f" | {rec.get('passes', '-')} | {rec['joint_n']} | {ccd[0]} / {ccd[1]} |"
        if ball is not None:
            dd = run.d
            c1 = p[ball].mean(axis=0)
            R = float(np.linalg.norm(p[ball] - c1, axis=1).mean())
            vb = c1 - rec["x"][ball].mean(axis=0)
            mid = 0.5 * (p[dd.idx[:, 0]] + p[dd.idx[:, 1]])
            rel = mid - c1
            rn = np.linalg.norm(rel, axis=1)
            gap = rn - R
            j = int(e.argmax())
            sp = float(np.linalg.norm(vb))
            lead = float(rel[j] @ vb / (rn[j] * sp)) if sp > 1e-12 else float("nan")
            hot = e > over
            row += (f" {1e3 * sp:.1f} | {1e3 * gap[j]:.1f} | {lead:+.2f} | "
                    f"{rel[j, 1] / rn[j]:+.2f} | {int(hot.sum())} | "
                    f"{int((hot & (gap < 0.005)).sum())} / {int((hot & (gap >= 0.005) & (gap < 0.03)).sum())}"
                    f" / {int((hot & (gap >= 0.03)).sum())} |")
        print(row, flush=True)

    ov = extras[0] if extras else {}
    cls.finalize, cls.after_finalize, scls.finalize = fin, aft, sfin
    try:
        with tempfile.TemporaryDirectory() as tmp:
            run = _Run("", _variant(_scene_path(name), ov, Path(tmp)))
            ball = _ball(run.sim)
            print("| frame | substep | after iterations % | after final rounds % | after global "
                  "step % | after CCD % | global passes | joint passes | CCD hits / zone vertices "
                  "| ball motion mm | worst "
                  "edge: gap to ball mm | along motion (cos) | up (cos) | edges > "
                  f"{100 * over:.0f} % | of them gap < 5 mm / 5-30 mm / > 30 mm |")
            print("|---" * 15 + "|")
            for frame in range(1, frames + 1):
                run.step()
    finally:
        cls.finalize, cls.after_finalize, scls.finalize = fin0, aft0, sfin0


def _row_kinds(c, ball_mask):
    """The packed contact rows by kind against the ball (``ball_mask``: its vertices): vertex-
    face cloth vertex / ball face, ball vertex / cloth face, cloth / cloth; edge-edge ball /
    cloth, cloth / cloth. Returns {label: (is_vf, row indices)}."""
    vf, ee = c.vf, c.ee
    b = ball_mask
    return {"vf cloth v / ball face": (True, np.flatnonzero(~b[vf[:, 0]] & b[vf[:, 1]])),
            "vf ball v / cloth face": (True, np.flatnonzero(b[vf[:, 0]] & ~b[vf[:, 1]])),
            "vf cloth / cloth": (True, np.flatnonzero(~b[vf[:, 0]] & ~b[vf[:, 1]])),
            "ee ball / cloth": (False, np.flatnonzero(b[ee[:, 0]] ^ b[ee[:, 2]])),
            "ee cloth / cloth": (False, np.flatnonzero(~b[ee[:, 0]] & ~b[ee[:, 2]]))}


def _kind_pass(c, kinds, q0, x, w, strain, slide=None):
    """One contact pass of each kind of rows alone from ``q0`` (copies): rows, active rows, worst
    strain after, largest move and vertices moved over 1 mm; printed. ``slide``: the pass's
    ``SLIDE_APART`` mode (None: the solver passes', ``contacts.slide_mode(True)``)."""
    from lokigraph.behaviors.collision import contacts as C

    sl = C.slide_mode(True) if slide is None else slide
    for k, (is_vf, sel) in kinds.items():
        q = q0.copy()
        if is_vf:
            a = C.project_vf(q, x, w, c.vf[sel], c.vf_n[sel], c.vf_target[sel], c.vf_mu[sel],
                             c.strength[sel], c.damping, c.vf_onesided[sel], sl)
        else:
            a = C.project_ee(q, x, w, c.ee[sel], c.ee_n[sel], c.ee_target[sel], c.ee_mu[sel],
                             c.ee_strength[sel], c.damping, sl)
        mv = np.linalg.norm(q - q0, axis=1)
        print(f"    {k}: {len(sel)} rows, {a} active, worst edge after {100 * strain(q):.1f} %, "
              f"largest move {1e3 * mv.max():.1f} mm, vertices moved > 1 mm "
              f"{int((mv > 1e-3).sum())}", flush=True)


def row_kinds(name, frames, extras, at):
    """On a scene with a moving 'ball', in the substeps of the frames ``at``: which contact rows
    stretch the cloth. After the final rounds (and 10 more strain-limit sweeps, so that only
    what the contacts do is left): one contact pass of each kind of rows alone. In the CCD safe
    step: the worst edge after each call (the joint strain-limit and stretch passes, the
    contacts at the time of impact, the pass over every contact row), the first pass over every
    row split by kind as above (see the module doc)."""
    from lokigraph.behaviors.collision import contacts as C
    from lokigraph.behaviors.materials import strain_limit as SL
    from lokigraph.behaviors.materials import stretch as ST

    st = {"on": False, "log": [], "first": False}

    def strain(p):
        return float(run.strain(p).max())

    def logged(tag, fn, pos):
        def f(*a, **k):
            if not st["on"]:
                return fn(*a, **k)
            p = a[pos]
            q = p.copy()
            out = fn(*a, **k)
            mv = np.linalg.norm(p - q, axis=1)
            st["log"].append((tag, strain(p), mv.max(), int((mv > 1e-3).sum())))
            return out
        return f

    saved = [(C, "project_vf"), (C, "project_ee"), (C, "_project_contacts"),
             (C.CollisionConstraint, "finalize"), (C.CollisionConstraint, "after_finalize"),
             (SL.StrainLimitConstraint, "project_joint"), (ST.StretchConstraint, "project_joint")]
    saved = [(o, n, getattr(o, n)) for o, n in saved]
    pc0, fin0, aft0 = C._project_contacts, C.CollisionConstraint.finalize, \
        C.CollisionConstraint.after_finalize

    def pc(c, p, x, w, slide=None):
        on, st["on"] = st["on"], False  # the passes below are not the CCD's own calls
        try:
            if on and st["first"]:
                st["first"] = False
                print("  the CCD's first pass over every contact row, by kind:")
                _kind_pass(c, _row_kinds(c, ball_mask), p.copy(), x, w, strain, slide)
            return pc0(c, p, x, w, slide)
        finally:
            st["on"] = on

    def fin(self, ctx, d, p):
        fin0(self, ctx, d, p)
        if frame[0] not in at:
            return
        c, w = ctx.state.fields["contacts"], ctx.model.particle_inv_mass
        sl = next(dd for b, dd in ctx.constraints if isinstance(b, SL.StrainLimitConstraint))
        q0 = p.copy()
        for _ in range(10):
            SL.project_strain_limit(q0, w, sl.edges, sl.limit, sl.color_ptr)
        print(f"frame {frame[0]} substep {ctx.substep + 1}: after the final rounds "
              f"{100 * strain(p):.1f} %, after 10 more strain-limit sweeps {100 * strain(q0):.1f} "
              f"%; one contact pass from there, each kind of rows alone:")
        _kind_pass(c, _row_kinds(c, ball_mask), q0, ctx.state.particle_q, w, strain)

    def aft(self, ctx, d, p):
        st["on"] = frame[0] in at
        st["log"], st["first"] = [], True
        p0 = strain(p)
        aft0(self, ctx, d, p)
        if st["on"] and st["log"]:
            print(f"frame {frame[0]} substep {ctx.substep + 1}: the CCD safe step, worst edge "
                  f"{100 * p0:.1f} % before; after each call: worst edge % / largest move mm / "
                  "vertices moved > 1 mm")
            for tag, e, m, n in st["log"]:
                print(f"    {tag}: {100 * e:.1f} / {1e3 * m:.1f} / {n}")
        st["on"] = False

    C.project_vf = logged("contacts at the time of impact (vf)", C.project_vf, 0)
    C.project_ee = logged("contacts at the time of impact (ee)", C.project_ee, 0)
    C._project_contacts = logged("every contact row", pc, 1)
    C.CollisionConstraint.finalize, C.CollisionConstraint.after_finalize = fin, aft
    for cls, tag in ((SL.StrainLimitConstraint, "strain limit (joint)"),
                     (ST.StretchConstraint, "stretch (joint)")):
        cls.project_joint = logged(tag, cls.project_joint, 3)
    frame = [0]
    try:
        with tempfile.TemporaryDirectory() as tmp:
            run = _Run("", _variant(_scene_path(name), extras[0] if extras else {}, Path(tmp)))
            ball_mask = np.zeros(len(run.sim.state.particle_q), np.bool_)
            ball_mask[_ball(run.sim)] = True
            for k in range(1, min(frames, max(at)) + 1):
                frame[0] = k
                run.step()
    finally:
        for o, n, v in saved:
            setattr(o, n, v)


def install_global_self():
    """Experiment: the global strain step's contact rows ('rows' with pivots) from every
    contact row, cloth-cloth too, not only those with a kinematic vertex (``_collider_subsets``
    and ``_contact_set`` wrapped: every row, ``collider_only`` off); each vertex of a row then
    gets the one-sided plane of its most closed row as a collider's vertex does. Measures
    whether the CCD's re-projection of the cloth-cloth contacts the step moved the cloth into
    is what leaves the strain on the moving scene. Measured, not kept (the moving scene, 14
    frames, SLIDE_APART 1 in the global step too, NUMBA_NUM_THREADS=1): the step diverges where
    cloth-cloth contacts join it (after the step 86-237 % in frames 8-12, frame ends 4.4-86 %):
    the two layers' planes, one per vertex, face each other. Nor does the step without pivots
    pay (``--set strain_limit.global_pivots=0``, whose 'rows' are pair rows of every kind):
    4,500-8,100 CCD hits in a substep, frame ends 19.7-120 %."""
    from lokigraph.behaviors.materials import strain_limit_global as SLG

    G = SLG.GlobalStrainStep
    if getattr(G, "self_rows", False):
        return
    cs0 = G._contact_set

    def subsets(self, w, contacts, kinds):
        out = {}
        for k in kinds:
            rows = getattr(contacts, k)
            one = (contacts.vf_onesided[:len(rows)] if k == "vf"
                   else np.zeros(len(rows), np.bool_))
            out[k] = (rows, getattr(contacts, k + "_n")[:len(rows)],
                      getattr(contacts, k + "_target")[:len(rows)], np.ascontiguousarray(one),
                      np.zeros(len(rows), np.bool_))
        return out

    def contact_set(self, p, w, contacts, kinds, margin, collider_only, sub=None):
        return cs0(self, p, w, contacts, kinds, margin, collider_only and sub is None, sub)

    G._collider_subsets, G._contact_set, G.self_rows = subsets, contact_set, True


def _hull_perimeter(P):
    from scipy.spatial import ConvexHull

    if len(P) < 3:
        return 0.0
    H = P[ConvexHull(P).vertices]
    return float(np.linalg.norm(np.roll(H, -1, 0) - H, axis=1).sum())


def _section(meshes, cen, nrm):
    """Points [m] where the plane (cen, nrm) cuts the triangle meshes, in plane coordinates."""
    u = np.cross(nrm, [0.0, 0.0, 1.0])
    if np.linalg.norm(u) < 1e-6:
        u = np.cross(nrm, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(nrm, u)
    pts = [np.zeros((0, 3))]
    for V, F in meshes:
        s = (V - cen) @ nrm
        for a, b in ((0, 1), (1, 2), (2, 0)):
            ia, ib = F[:, a], F[:, b]
            x = s[ia] * s[ib] < 0
            t = s[ia][x] / (s[ia][x] - s[ib][x])
            pts.append(V[ia[x]] + t[:, None] * (V[ib[x]] - V[ia[x]]))
    P = np.concatenate(pts) - cen
    return np.stack([P @ u, P @ v], 1), u, v


def _inside_polygon(P, poly):
    """Crossing-number test of the points P (k, 2) against the closed polygon poly (n, 2)."""
    a, b = poly, np.roll(poly, -1, 0)
    y = P[:, 1:2]
    cross = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xi = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return (np.count_nonzero(cross & (P[:, :1] < xi), axis=1) % 2) == 1


#: sleeve_elbow: tube segments around the sleeve, collision distance sleeve-arm [m] (thicknesses)
SLEEVE_AROUND, SLEEVE_GAP = 24, 0.002 + 0.002


def ring_girth(q, X, sleeve, arm, ring):
    """Ring ``ring`` of the sleeve_elbow sleeve at positions q: ``(girth strain, worst ring
    edge strain, forced strain)`` [-], the forced strain being the smallest arm girth around the
    ring (see the module doc) against the ring's rest girth. X: rest positions [m]; sleeve: its
    element; arm: (positions, triangles) of the arm's pieces."""
    idx = sleeve.vertex_offset + ring * SLEEVE_AROUND + np.arange(SLEEVE_AROUND)
    R0, R = X[idx], q[idx]
    rest = np.linalg.norm(np.roll(R0, -1, 0) - R0, axis=1)
    cur = np.linalg.norm(np.roll(R, -1, 0) - R, axis=1)
    cen = R.mean(0)
    _, _, vt = np.linalg.svd(R - cen)
    rmax = np.linalg.norm(R - cen, axis=1).max()
    best = np.inf
    for tilt in np.radians(np.arange(0, 41, 5)):
        for az in np.radians(np.arange(0, 360, 30) if tilt > 0 else [0.0]):
            n = np.cos(tilt) * vt[2] + np.sin(tilt) * (vt[0] * np.cos(az) + vt[1] * np.sin(az))
            P, u, v = _section(arm, cen, n)
            if tilt == 0:  # the ring's plane: the part inside the ring
                P = P[_inside_polygon(P, np.stack([(R - cen) @ u, (R - cen) @ v], 1))]
            else:  # a tilted plane: the part near the ring
                P = P[np.linalg.norm(P, axis=1) < 1.2 * rmax]
            best = min(best, _hull_perimeter(P) + 2 * np.pi * SLEEVE_GAP)
    return cur.sum() / rest.sum() - 1, (cur / rest - 1).max(), best / rest.sum() - 1


def inside_arm(q, sleeve, arm):
    """Sleeve vertices inside a piece of the arm (|winding number| > 1/2)."""
    from lokigraph.bench.stress import _winding

    P = np.ascontiguousarray(q[sleeve.vertex_slice])
    w, ins = np.empty(len(P)), np.zeros(len(P), bool)
    for V, F in arm:
        _winding(P, np.ascontiguousarray(V), np.ascontiguousarray(F, dtype=np.int64), w)
        ins |= np.abs(w) > 0.5
    return int(ins.sum())


def sleeve_parts(sim):
    """(sleeve element, arm pieces as (positions, triangles)) of a sleeve_elbow simulation."""
    els = {e.name: e for e in sim.compiled.scene.elements}
    q = sim.state.particle_q
    return els["sleeve"], [(q[els[n].vertex_slice], els[n].geometry.triangles)
                           for n in ("upper_arm", "forearm", "elbow")]


def girth(frames, extras, rings=(8, 9, 10, 16)):
    """sleeve_elbow: ring girths against the arm's girth, per frame (see the module doc)."""
    ov = extras[0] if extras else {}
    with tempfile.TemporaryDirectory() as tmp:
        run = _Run("", _variant(_scene_path("sleeve_elbow"), ov, Path(tmp)))
        X = run.sim.state.particle_q.copy()
        print("| frame | worst edge % | " + " | ".join(
            f"ring {r}: girth % / worst ring edge % / forced %" for r in rings)
            + " | sleeve vertices inside the arm |")
        print("|---|---|" + "---|" * len(rings) + "---|")
        for k in range(frames):
            run.step()
            q = run.sim.state.particle_q
            sleeve, arm = sleeve_parts(run.sim)
            cells = []
            for r in rings:
                g, e, f = ring_girth(q, X, sleeve, arm, r)
                cells.append(f"{100 * g:+.1f} / {100 * e:.1f} / {100 * f:+.1f}")
            print(f"| {k + 1} | {100 * run.worst[-1]:.2f} | " + " | ".join(cells)
                  + f" | {inside_arm(q, sleeve, arm)} |", flush=True)


_NEAR = []


def _part_distances(P, arm):
    """Distance [m] of each point P to each arm piece (brute force over its triangles)."""
    if not _NEAR:
        _NEAR.append(_near_kernel())
    near = _NEAR[0]
    out = np.zeros((len(P), len(arm)))
    for k, (V, F) in enumerate(arm):
        col = np.zeros(len(P))
        near(np.ascontiguousarray(P), np.ascontiguousarray(V),
             np.ascontiguousarray(F, dtype=np.int64), col)
        out[:, k] = col
    return out


def _near_kernel():
    from numba import njit

    from lokigraph.behaviors.collision.narrowphase import _pt_tri_sq

    @njit
    def near(P, V, F, out):
        for i in range(P.shape[0]):
            best = np.inf
            for t in range(F.shape[0]):
                a, b, c = F[t, 0], F[t, 1], F[t, 2]
                d2 = _pt_tri_sq(P[i, 0], P[i, 1], P[i, 2], V[a, 0], V[a, 1], V[a, 2],
                                V[b, 0], V[b, 1], V[b, 2], V[c, 0], V[c, 1], V[c, 2])[0]
                best = min(best, d2)
            out[i] = np.sqrt(best)

    return near


#: sleeve_elbow: a vertex within this distance [m] of an arm piece touches it (collision
#: distance 4 mm plus 2 mm)
TOUCH = 0.006


def where(frames, extras, over=0.02):
    """sleeve_elbow, per frame and --set (interleaved): the worst sleeve edge (its ring,
    position around the ring -- 0 deg at +y, the inner elbow, 90 deg at +z, the top --, kind:
    ring / axial / diagonal), the arm pieces its vertices touch (within ``TOUCH``: u upper arm,
    f forearm, e elbow cap), the edges over ``over`` (count, rings spanned, how many have a
    vertex touching two pieces: pinched), and the girth the arm forces on the worst ring
    (``ring_girth``)."""
    names = "ufe"
    with tempfile.TemporaryDirectory() as tmp:
        runs = []
        for ex in extras or [{}]:
            lbl = " ".join(f"{k}={v}" for p in ex.values() for k, v in p.items()) or "defaults"
            runs.append(_Run(lbl, _variant(_scene_path("sleeve_elbow"), ex, Path(tmp))))
        X = runs[0].sim.state.particle_q.copy()
        sleeve = sleeve_parts(runs[0].sim)[0]
        off = sleeve.vertex_offset
        E = runs[0].d.idx
        keep = (E[:, 0] >= off) & (E[:, 0] < off + sleeve.vertex_count)
        E, rest = E[keep], runs[0].d.rest[keep]
        ra, rb = (E[:, 0] - off) // SLEEVE_AROUND, (E[:, 1] - off) // SLEEVE_AROUND
        aa, ab = (E[:, 0] - off) % SLEEVE_AROUND, (E[:, 1] - off) % SLEEVE_AROUND
        kind = np.where(ra == rb, "ring", np.where(aa == ab, "axial", "diagonal"))
        print("| frame | setting | worst % | ring (x cm) | around deg | kind | touches | "
              f"edges > {100 * over:.0f} % | their rings | pinched | ring girth % / forced % |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for k in range(frames):
            for r in runs:
                r.step()
                q = r.sim.state.particle_q
                _, arm = sleeve_parts(r.sim)
                e = np.linalg.norm(q[E[:, 1]] - q[E[:, 0]], axis=1) / rest - 1.0
                j = int(e.argmax())
                hot = np.flatnonzero(e > over)
                vs = np.unique(np.concatenate([E[hot].ravel(), E[j]]))
                dist = _part_distances(q[vs], arm)
                touch = {v: "".join(names[i] for i in np.flatnonzero(dd < TOUCH))
                         for v, dd in zip(vs, dist)}
                pinched = sum(1 for h in hot if max(len(touch[E[h, 0]]), len(touch[E[h, 1]])) > 1)
                ring = min(ra[j], rb[j])
                ang = 360.0 * 0.5 * (aa[j] + ab[j] + (SLEEVE_AROUND if abs(aa[j] - ab[j]) > 1
                                                      else 0)) / SLEEVE_AROUND % 360
                g, _, forced = ring_girth(q, X, sleeve, arm, ring)
                rings = (f"{min(ra[hot].min(), rb[hot].min())}-{max(ra[hot].max(), rb[hot].max())}"
                         if len(hot) else "-")
                print(f"| {k + 1} | {r.label} | {100 * e[j]:.1f} | {ring} "
                      f"({100 * X[off + ring * SLEEVE_AROUND, 0]:.0f}) | {ang:.0f} | {kind[j]} | "
                      f"{touch[E[j, 0]] or '-'} / {touch[E[j, 1]] or '-'} | {len(hot)} | {rings} | "
                      f"{pinched} | {100 * g:+.1f} / {100 * forced:+.1f} |", flush=True)


def global_passes(name, frames, extras):
    """The global strain-limit step's passes per frame, each --set in turn (interleaved), and
    the worst relative excess over the limit after each pass (see the module doc)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = _scene_path(name)
        runs = []
        for ex in extras:
            lbl = " ".join(f"{k}={v}" for p in ex.values() for k, v in p.items())
            r = _Run(lbl, _variant(path, ex, Path(tmp)))
            st = r.sim.compiled.schedule.find("StrainLimitConstraint")[0].data
            g = getattr(st, "glob", None) if st is not None else None
            r.trace, r.tot = [], [0, 0.0]
            if g is not None:
                move = g._move

                def traced(p, w, tol, worst, dx, guard, g=g, move=move, r=r):
                    move(p, w, tol, worst, dx, guard)
                    r.trace.append(g.worst(p, w, tol))

                g._move = traced
                grun = g.run

                def timed(*a, g=g, grun=grun, r=r, **k):
                    t = time.process_time()
                    out = grun(*a, **k)
                    r.step_cpu += time.process_time() - t
                    return out

                g.run = timed
            r.step_cpu = 0.0
            runs.append(r)
        for k in range(frames):
            for i, r in enumerate(runs):
                r.trace.clear()
                s0 = r.step_cpu
                r.step()
                r.tot[0] += len(r.trace)
                r.tot[1] += r.cpu[-1]
                if k:  # the first frame compiles
                    r.tot.append(r.cpu[-1])
                if r.trace:
                    print(f"frame {k + 1} setting {i}: {len(r.trace)} passes, worst edge "
                          f"{100 * r.worst[-1]:.2f} %, CPU {1e3 * r.cpu[-1]:.0f} ms (the step "
                          f"{1e3 * (r.step_cpu - s0):.0f} ms); excess after each pass % "
                          + " ".join(f"{100 * x:.2f}" for x in r.trace), flush=True)
        for i, r in enumerate(runs):
            print(f"setting {i} ({r.label}): {r.tot[0]} passes, worst "
                  f"{100 * max(r.worst):.2f} %, CPU {r.tot[1]:.1f} s over {frames} frames "
                  f"(frames 2-{frames}: {sum(r.tot[2:]):.1f} s), the step {r.step_cpu:.1f} s")


def fast_exact(name, frames):
    """strain_limit_global.FAST_EXACT off / on: two runs of the scene at the defaults stepped
    frame by frame in turn (which goes first alternates: ABBA), CPU ms per frame and in the
    global step, and whether the positions are bitwise equal after every frame."""
    import hashlib

    from lokigraph.behaviors.materials import strain_limit_global as G

    runs = []
    for flag in (False, True):
        r = _Run(f"FAST_EXACT={flag}", _scene_path(name))
        g = r.sim.compiled.schedule.find("StrainLimitConstraint")[0].data.glob
        r.flag, r.gcpu, r.g = flag, [], g
        grun = g.run

        def timed(*a, grun=grun, r=r, **k):
            t = time.process_time()
            out = grun(*a, **k)
            r.gcpu[-1] += time.process_time() - t
            return out

        g.run = timed
        runs.append(r)
    print("| frame | off CPU ms | on CPU ms | off step ms | on step ms | worst % | equal |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for k in range(frames):
        for r in (runs if k % 2 == 0 else runs[::-1]):
            G.FAST_EXACT = r.flag
            r.gcpu.append(0.0)
            r.step()
        G.FAST_EXACT = True
        h = [hashlib.sha256(r.sim.state.particle_q.tobytes()).hexdigest()[:12] for r in runs]
        a, b = runs
        print(f"| {k + 1} | {1e3 * a.cpu[-1]:.0f} | {1e3 * b.cpu[-1]:.0f} | "
              f"{1e3 * a.gcpu[-1]:.0f} | {1e3 * b.gcpu[-1]:.0f} | {100 * b.worst[-1]:.2f} | "
              f"{h[0] == h[1]} {h[1]} |", flush=True)
    a, b = runs
    for lbl, f in (("sum frames 2-N", np.sum), ("median frames 2-N", np.median)):
        ca, cb, ga, gb = (f(x[1:]) for x in (a.cpu, b.cpu, a.gcpu, b.gcpu))
        print(f"{lbl}: CPU off {1e3 * ca:.0f} / on {1e3 * cb:.0f} ms ({cb / ca:.3f}x), the step "
              f"off {1e3 * ga:.0f} / on {1e3 * gb:.0f} ms ({gb / max(ga, 1e-9):.3f}x)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--scenes", nargs="+", default=list(SCENES),
                    help="example names (graphs/examples/NAME.yaml) or .yaml paths, e.g. "
                    "graphs/bench/cloth_sphere_128.yaml")
    ap.add_argument("--set", nargs="+", action="append", default=[],
                    help="an extra setting NODE.PARAM=VALUE ... (repeat --set for more)")
    ap.add_argument("--peer", type=int, nargs="*", help="peer collision scene sizes")
    ap.add_argument("--only", nargs="*", help="only these of the built-in settings")
    ap.add_argument("--abba", action="store_true", help="each setting run twice, the repeats "
                    "in reverse order (A B B A), stepped in turn frame by frame")
    ap.add_argument("--stages", metavar="SCENE", help="worst strain after each stage of the "
                    "substeps, per frame, at the defaults (or the first --set)")
    ap.add_argument("--substages", metavar="SCENE", help="per substep: worst strain after "
                    "each stage (the global step included), the global step's passes and "
                    "where the worst edge is against the moving ball, at the defaults (or "
                    "the first --set)")
    ap.add_argument("--row-kinds", metavar="SCENE", help="which contact rows stretch the "
                    "cloth after the final rounds and in the CCD safe step, in the frames --at "
                    "(a scene with a 'ball')")
    ap.add_argument("--at", type=int, nargs="+", default=[7, 10], help="--row-kinds' frames")
    ap.add_argument("--passes", metavar="SCENE", help="the global step's passes per frame "
                    "and the excess after each pass, for each --set")
    ap.add_argument("--fast-exact", metavar="SCENE", help="strain_limit_global.FAST_EXACT "
                    "off / on, interleaved: CPU per frame and bitwise equality")
    ap.add_argument("--girth", action="store_true", help="sleeve_elbow: ring girths against "
                    "the girth the arm forces, per frame")
    ap.add_argument("--where", action="store_true", help="sleeve_elbow: where the worst edge "
                    "is, what it touches, the edges over 2 %%, per frame and --set")
    ap.add_argument("--contacts-flag", nargs="+", default=[], metavar="NAME=VALUE",
                    help="set module flags of behaviors/collision/contacts.py for the whole run "
                    "(e.g. SLIDE_APART=1)")
    ap.add_argument("--global-self", action="store_true", help="experiment: the global "
                    "step's contact rows from the cloth-cloth contacts too (install_global_self)")
    args = ap.parse_args(argv)
    extras = [_parse_set(x) for x in args.set]
    if args.contacts_flag:
        from lokigraph.behaviors.collision import contacts as C

        for it in args.contacts_flag:
            name, val = it.split("=", 1)
            if not hasattr(C, name):
                ap.error(f"contacts has no {name}")
            setattr(C, name, yaml.safe_load(val))
    if args.global_self:
        install_global_self()
    if args.stages:
        stages(args.stages, args.frames, extras)
    elif args.row_kinds:
        row_kinds(args.row_kinds, args.frames, extras, args.at)
    elif args.substages:
        substages(args.substages, args.frames, extras)
    elif args.fast_exact:
        fast_exact(args.fast_exact, args.frames)
    elif args.passes:
        global_passes(args.passes, args.frames, extras)
    elif args.girth:
        girth(args.frames, extras)
    elif args.where:
        where(args.frames, extras)
    elif args.peer:
        peer(args.peer, args.frames, args.only)
    else:
        scenes_table(args.scenes, args.frames, extras, args.only, args.abba)


if __name__ == "__main__":
    main()
