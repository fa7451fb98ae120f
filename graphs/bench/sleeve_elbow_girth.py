"""sleeve_elbow (issue #13): does the arm force the sleeve's rings over the 2 % strain limit? A
geometric bound, per frame and ring: the shortest closed loop around the bent arm (upper arm,
forearm, elbow cap) in a plane near the ring, against the ring's rest girth.

In a plane the shortest loop around a region is the perimeter of its convex hull; a loop kept
the collision distance ``GAP`` away adds 2 pi GAP. The loop must go around the arm the way a
ring of the sleeve does: it must enclose the arm's centreline (shoulder -> joint -> wrist) a net
once. The plane's section of the arm is split into blobs (section components closer than 2 GAP
merged); a blob qualifies when the centreline's signed crossings of the plane inside it do not
cancel (a plane across both the upper arm and the forearm near the bend crosses the centreline
twice in opposite directions: no sleeve ring can sit in it). The bound for a ring is the smallest
qualifying blob's hull perimeter + 2 pi GAP over a family of planes; a ring whose bound exceeds
its rest girth by more than 2 % cannot be under 2 % edge strain in that family (the ring's
perimeter is the sum of its 24 edges, so its worst edge is at least the mean).

The arm: by default as simulated (the scene run at the defaults or ``--set`` overrides; the
unpainted vertices are checked to be on the animation, the painted compliant ones have receded
where the sleeve pushed them: the measured recession); with ``--animated`` as animated, without
simulating (stiff skin; recession can only shorten a section's hull, so the simulated bound is
the lower one). Two families of planes:

* kinematic: through the arm's centreline within ``--slide`` metres (default 0.0175, half a
  ring spacing) of the ring's rest position along it (the forearm's rings carried round with
  it), the normals within ``--tilt`` degrees (default 40) of the centreline's direction there
  (within 5 cm of the joint the direction turns from the upper arm's to the forearm's: a fan);
* with a simulation also: through the simulated ring's centre, the normals within ``--tilt`` of
  its best-fit plane ("the plane the ring occupies"), beside the ring's own girth strain and
  worst ring edge strain.

Run::

    .venv/bin/python graphs/bench/sleeve_elbow_girth.py [--scene graphs/examples/sleeve_elbow.yaml]
        [--frames 1-48] [--rings 4-13] [--animated | --set strain_limit.global_passes=20 ...]

Columns: per frame (the state after that many steps, graphs/bench/cloth_strain.py's numbering)
the bend angle and, per ring, the bounds' strain against the ring's rest girth [%] (``*`` over
2 %: that ring cannot be under 2 % in that family of planes).

The crease pinch, settings stepped in turn frame by frame in one process (``skin=S`` scales the
painted compliant stiffness)::

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/sleeve_elbow_girth.py --frames 1-30 \
        --pinch '' --pinch "$B" --pinch "$B strain_limit.inextensible_joint_iterations=40"

per frame and setting the worst sleeve edge (strain, ring, degrees from +y -- 0 is the inner
elbow --, kind, the arm pieces its two vertices touch: u upper arm, f forearm, e elbow cap),
CPU ms and intersecting pairs; then per frame range (1-12, 13-21 the closing crease, 22-28
full bend, 29-48, 49-60).

``--write-sleeve PATH`` writes the scene's sleeve mesh (:func:`sleeve_mesh`).

Measured at the defaults (frames 1-30, rings 7-11; the simulated rings lie within 0-14 mm of
their best-fit planes, so a plane is a fair model of a ring; ``--frames 1-30 --rings 7-11``):

* the sleeve before issue #13 (a 0.056 m tube centred on the arm): nothing forced to frame 21
  (ring 9 at most +1.3 % in the planes it occupies, -1.8 % to frame 20); frames 22-28 ring 9
  +3.2 .. +5.9 % in its own planes (ring 8 +2.4 .. +4.5 % in the kinematic planes of frames
  23-27): no setting can hold it under 2 % there without crossing the arm; the worst edge
  23.9 % (frame 22), the ring's girth +10.2 .. +11.3 %, its worst edge 14.5-23.9 %;
* the shipped sleeve (0.060 m to 13 cm past the joint; frames 18-30 measured): at most +0.9 %
  (ring 9, frame 25; +0.8 % at frame 24), the worst edge 13.2 % (frame 24);
* a 0.064 m sleeve: every ring at least 4.8 % under its rest girth in every frame (1-30), the
  worst edge 9.8 % (frame 22); not shipped: tests/test_elbow.py's crease speed (0.755 m/s at
  14 solver iterations, bound 0.73).

The crease pinch on the shipped sleeve (``--frames 1-28``; B = the global strain step's setting
of strain_limit.global_chord's doc at a 1 % limit with 3 joint passes; J40 = 40 joint passes),
worst edge % (frame, ring, where, touching) / CPU ms per frame / intersecting pairs, one run,
settings stepped in turn, 1 thread:

=============  =========================  ==========================  ========================
setting        frames 1-12                frames 13-21 (the crease)   frames 22-28 (full bend)
=============  =========================  ==========================  ========================
defaults       5.00 / 254 / 0             10.41 (21, r9 pinched u+f)  13.16 (24, r9 u+f) / 266
                                          / 236 / 0                   / 0
B              1.42 / 226 / 0             18.62 (21, r9 pinched) /    20.60 (25, r9) / 304 / 0
                                          265 / 0
B + J40        1.45 / 301 / 0             1.29 (21, r8 axial, free)   3.85 (23, r9 pinched) /
                                          / 310 / 0                   373 / 0
B + J40 +      1.48 / 318 / 0             1.50 (13, r16 hem) / 323    1.18 (24, r9 outer) /
joint_long_                               / 0                         388 / 0
range
B + J40 +      1.40 / 318 / 0             1.16 (18, r8 axial, free)   1.21 (22, r8 axial) /
skin x 0.25                               / 310 / 0                   368 / 0
=============  =========================  ==========================  ========================

What holds the pinch is the joint passes (contacts and strain limits projected together after
the iterations): with B's 3 the pinched ring edges reach 18.6 %, with 40 1.3 %; at full bend 40
passes leave 3.3-3.9 % on ring 9 pinched between the upper arm and the forearm (frames 22-23),
which the long-range rows in the joint passes or a 4x softer compliant skin (the inner elbow
recedes further) take out. The whole run (``--frames 1-60``, another run): B + J40 +
joint_long_range 1.50 % worst over 60 frames (frames 29-48 1.43 %, 49-60 1.04 %) at 278-393
CPU ms per frame, B + J40 + skin x 0.25 1.40 % (1.20 %, 1.01 %) at 277-363 ms, the defaults
13.16 % (7.95 %, 4.07 %) at 202-285 ms; 0 intersecting pairs in every frame of all three.

Since stop 29 the defaults are B with 10 joint passes, 40 in the substeps whose contacts pinch
the cloth between two collider surfaces (strain_limit.inextensible_pinch_iterations) and there
the long-range rows in the joint passes (stretch.joint_long_range 'pinch'); ``--pinch ''`` runs
those; the 'defaults' row above is stop 28's (``--pinch "strain_limit.inextensible_max_strain=
0.05 strain_limit.global_passes=0 strain_limit.inextensible_pinch_iterations=null
stretch.joint_long_range=false"``), and B there is without the pinch passes and rows
(``strain_limit.inextensible_pinch_iterations=null stretch.joint_long_range=false`` on top).
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "graphs" / "bench"))
try:
    import cloth_strain as cs  # the scene copies, the convex sections, the sleeve's parts
finally:
    sys.path.pop(0)

#: collision distance sleeve-arm [m] (the two Collider thicknesses)
GAP = 0.002 + 0.002
#: vertices around a ring of the sleeve
AROUND = 24
ARM = ("upper_arm", "forearm", "elbow")
SCENE = ROOT / "graphs" / "examples" / "sleeve_elbow.yaml"


def _frame_basis(n):
    u = np.cross(n, [0.0, 0.0, 1.0])
    if np.linalg.norm(u) < 1e-6:
        u = np.cross(n, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


def _segments(V, F, c, n, u, v):
    """The plane (c, n)'s section of the closed mesh (V, F): segments (k, 2, 2) in the plane's
    (u, v) coordinates and, per segment, its two mesh-edge keys (for the components)."""
    s = (V - c) @ n
    s = np.where(s == 0.0, 1e-15, s)
    sa, sb, sc = s[F[:, 0]], s[F[:, 1]], s[F[:, 2]]
    cut = ~(((sa > 0) & (sb > 0) & (sc > 0)) | ((sa < 0) & (sb < 0) & (sc < 0)))
    T = F[cut]
    if not len(T):
        return np.zeros((0, 2, 2)), np.zeros((0, 2), np.int64)
    nv = len(V)
    pts, keys = [], []
    for a, b in ((0, 1), (1, 2), (2, 0)):
        # the edge's ends in index order: its point is bitwise the same in both triangles
        ia, ib = np.minimum(T[:, a], T[:, b]), np.maximum(T[:, a], T[:, b])
        x = s[ia] * s[ib] < 0
        t = np.where(x, s[ia] / np.where(x, s[ia] - s[ib], 1.0), 0.0)
        p = V[ia] + t[:, None] * (V[ib] - V[ia]) - c
        pts.append(np.stack([p @ u, p @ v], 1))
        keys.append(np.where(x, ia * nv + ib, -1))
    P, K = np.stack(pts, 1), np.stack(keys, 1)  # (t, 3, 2), (t, 3): two of the three cut
    order = np.argsort(K < 0, axis=1, kind="stable")[:, :2]
    rows = np.arange(len(T))[:, None]
    return P[rows, order], K[rows, order]


def _components(keys):
    """Component label of each segment (segments sharing a mesh edge are connected)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    uk, inv = np.unique(keys.ravel(), return_inverse=True)
    inv = inv.reshape(-1, 2)
    g = coo_matrix((np.ones(len(inv)), (inv[:, 0], inv[:, 1])), shape=(len(uk), len(uk)))
    _, lab = connected_components(g, directed=False)
    return lab[inv[:, 0]]


def _crossings_inside(Q, segs):
    """(len(Q),) bool: the points Q (k, 2) inside the closed curve made of the segments
    (crossing-number test; the segments need no order)."""
    a, b = segs[:, 0], segs[:, 1]
    y = Q[:, 1:2]
    cross = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xi = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return (np.count_nonzero(cross & (Q[:, :1] < xi), axis=1) % 2) == 1


def _seg_distance(P, segs):
    """Smallest distance [m] of the points P (k, 2) to the segments (m, 2, 2)."""
    a, b = segs[:, 0][None], segs[:, 1][None]
    ab = b - a
    t = np.clip(((P[:, None] - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-30), 0, 1)
    return np.linalg.norm(P[:, None] - (a + t[..., None] * ab), axis=-1).min()


def plane_girth(meshes, axis, c, n):
    """The shortest loop [m] around the arm in the plane through c with normal n (see the module
    doc), or inf when no blob of the section holds a net crossing of the centreline ``axis``
    (points (k, 3), a polyline)."""
    u, v = _frame_basis(n)
    comps = []
    for V, F in meshes:
        segs, keys = _segments(V, F, c, n, u, v)
        if not len(segs):
            continue
        lab = _components(keys)
        comps += [segs[lab == k] for k in np.unique(lab)]
    if not comps:
        return math.inf
    # the centreline's signed crossings of the plane
    s = (axis - c) @ n
    ia = np.flatnonzero(s[:-1] * s[1:] < 0)
    t = s[ia] / (s[ia] - s[ia + 1])
    X = axis[ia] + t[:, None] * (axis[ia + 1] - axis[ia]) - c
    Q = np.stack([X @ u, X @ v], 1)
    sign = np.sign(s[ia + 1] - s[ia])
    # blobs: components closer than 2 GAP (or overlapping) merged
    m = len(comps)
    parent = list(range(m))

    def root(i):
        while parent[i] != i:
            i = parent[i]
        return i

    for i in range(m):
        for j in range(i + 1, m):
            if (_seg_distance(comps[i].reshape(-1, 2), comps[j]) < 2 * GAP
                    or _crossings_inside(comps[i][:, 0], comps[j]).any()
                    or _crossings_inside(comps[j][:, 0], comps[i]).any()):
                parent[root(j)] = root(i)
    best = math.inf
    for r in {root(i) for i in range(m)}:
        members = [comps[i] for i in range(m) if root(i) == r]
        inside = np.zeros(len(Q), bool)
        for segs in members:
            inside |= _crossings_inside(Q, segs)
        if sign[inside].sum() == 0:
            continue
        P = np.concatenate([segs.reshape(-1, 2) for segs in members])
        best = min(best, cs._hull_perimeter(P) + 2 * math.pi * GAP)
    return best


def _directions(n0, tilt_deg, step=10, around=12):
    """Unit normals within tilt_deg of n0 (rings of ``around`` every ``step`` degrees)."""
    a, b = _frame_basis(n0)
    out = [n0]
    for t in np.radians(np.arange(step, tilt_deg + 1e-9, step)):
        for az in np.radians(np.arange(0, 360, 360 / around)):
            out.append(np.cos(t) * n0 + np.sin(t) * (np.cos(az) * a + np.sin(az) * b))
    return out


class Arm:
    """The arm of a sleeve_elbow scene without simulating: rest meshes, the forearm's keys
    (rotations about z through its pivot, linear in the frame), the painted vertices."""

    def __init__(self, scene: Path):
        from lokigraph.api import compile_file

        self.scene = scene
        c = compile_file(scene)
        self.compiled = c
        X = c.model.particle_rest
        self.meshes, self.soft = {}, {}
        for name in ARM:
            e = c.scene.element(name)
            self.meshes[name] = (np.array(X[e.vertex_slice]), np.asarray(e.geometry.triangles))
            self.soft[name] = np.asarray(c.model.particle_compliant[e.vertex_slice], bool)
        s = yaml.safe_load(scene.read_text())
        el = {e["name"]: e for e in s["elements"]}
        keys = el["forearm"]["components"]["Kinematic"]["keys"]
        self.key_frames = np.array([k["frame"] for k in keys], float)
        self.key_angles = np.array([k.get("rotate", [0, 0, 0])[2] for k in keys], float)
        self.start = s["frames"]["start"]
        sl = c.scene.element("sleeve")
        self.sleeve = sl
        self.around = AROUND  # the tube's vertex order: ring j, vertex i at j * AROUND + i
        self.along = sl.vertex_count // AROUND - 1
        R = np.array(X[sl.vertex_slice]).reshape(self.along + 1, self.around, 3)
        self.ring_x = R[:, 0, 0].copy()  # rest position along the arm [m] (x; joint at 0)
        self.ring_rest = np.linalg.norm(np.roll(R, -1, 1) - R, axis=2).sum(1)  # girths [m]
        self.ring_radius = np.linalg.norm(R - R.mean(1, keepdims=True), axis=2).mean(1)

    def angle(self, steps):
        """Bend angle [deg] at the end of step ``steps`` (frame start + steps)."""
        return float(np.interp(self.start + steps, self.key_frames, self.key_angles))

    def pose(self, steps):
        """The arm's meshes as animated at the end of step ``steps``, its centreline (past
        both ends) and the forearm's direction."""
        th = math.radians(self.angle(steps))
        Rz = np.array([[math.cos(th), -math.sin(th), 0], [math.sin(th), math.cos(th), 0],
                       [0, 0, 1.0]])
        out = []
        for name in ARM:
            V, F = self.meshes[name]
            V = V.copy()
            if name == "forearm":
                V = V @ Rz.T
            out.append((V, F))
        L = 0.3
        d = Rz @ np.array([1.0, 0, 0])
        axis = np.array([[-L - 0.2, 0, 0], [0, 0, 0], (L + 0.2) * d])  # past the ends
        return out, axis, d


def _centreline(s, d, w=0.05):
    """Point and direction at arc length s [m] from the joint of the polyline (upper arm along
    -x, forearm along d); within w of the joint the direction turns from +x to d."""
    p = np.array([s, 0.0, 0.0]) if s < 0 else s * d
    u = np.clip((s + w) / (2 * w), 0.0, 1.0)
    t = (1 - u) * np.array([1.0, 0, 0]) + u * d
    return p, t / np.linalg.norm(t)


def _ring_family(arm, r, d, slide, tilt):
    """The kinematic planes of ring r: (centre, normal) pairs (see the module doc)."""
    out = []
    for s in np.linspace(arm.ring_x[r] - slide, arm.ring_x[r] + slide, 3):
        c, t = _centreline(s, d)
        out += [(c, n) for n in _directions(t, tilt)]
    return out


def run(arm: Arm, frames, rings, slide, tilt, overrides, animated):
    """Per frame and ring the bound (kinematic planes; with a simulation also the planes
    through the simulated ring) against the ring's rest girth; see the module doc."""
    print(f"scene {arm.scene}: ring rest girths {1000 * arm.ring_rest[rings].min():.1f}-"
          f"{1000 * arm.ring_rest[rings].max():.1f} mm (radius "
          f"{1000 * arm.ring_radius[rings].min():.1f}-{1000 * arm.ring_radius[rings].max():.1f} "
          "mm); "
          f"slide +-{1000 * slide:.1f} mm, tilt <= {tilt:.0f} deg; "
          + ("the arm as animated (no recession, no simulation)" if animated else
             f"simulated ({overrides or 'defaults'}): the arm as simulated (compliant skin "
             "receded), per ring: bound in the kinematic planes % / bound in the planes "
             "through the simulated ring % / ring girth % / worst ring edge % / the ring's largest "
             "distance from its best-fit plane [mm]"))
    head = "| frame | bend deg | " + ("" if animated else "worst edge % | CPU ms | ")
    print(head + " | ".join(f"ring {r} ({100 * arm.ring_x[r]:+.1f} cm)" for r in rings) + " |")
    print("|---|---|" + ("" if animated else "---|---|") + "---|" * len(rings))
    out = {}
    if animated:
        for k in frames:
            meshes, axis, d = arm.pose(k)
            cells = []
            for r in rings:
                f = min(plane_girth(meshes, axis, c, n)
                        for c, n in _ring_family(arm, r, d, slide, tilt)) / arm.ring_rest[r] - 1
                out[(k, r)] = (f,)
                cells.append(f"{100 * f:+.1f}{'*' if f > 0.02 else ''}")
            print(f"| {k} | {arm.angle(k):.0f} | " + " | ".join(cells) + " |", flush=True)
        return out
    from lokigraph.api import compile_file
    from lokigraph.run import Simulation


    with tempfile.TemporaryDirectory() as tmp:
        c = compile_file(cs._variant(arm.scene, overrides, Path(tmp)))
        sim = Simulation(c)
        X = np.array(c.model.particle_rest)
        sl = c.scene.element("sleeve")
        els = [c.scene.element(n) for n in ARM]
        E = c.schedule.find("StretchConstraint")[0].data
        keep = (E.idx[:, 0] >= sl.vertex_offset) & (E.idx[:, 0] < sl.vertex_offset
                                                     + sl.vertex_count)
        ei, er = E.idx[keep], E.rest[keep]
        for k in range(1, max(frames) + 1):
            t0 = time.process_time()
            sim.step_frame()
            cpu = time.process_time() - t0
            if k not in frames:
                continue
            q = sim.state.particle_q
            anim, axis, d = arm.pose(k)
            meshes = [(np.array(q[e.vertex_slice]), np.asarray(e.geometry.triangles))
                      for e in els]
            for (V, _), (A, _), name in zip(meshes, anim, ARM):  # the keys' angle: checked
                hard = ~arm.soft[name]
                assert np.abs(V[hard] - A[hard]).max() < 1e-9, name
            strain = np.linalg.norm(q[ei[:, 1]] - q[ei[:, 0]], axis=1) / er - 1
            cells = []
            for r in rings:
                fk = min(plane_girth(meshes, axis, cc, n)
                         for cc, n in _ring_family(arm, r, d, slide, tilt)) / arm.ring_rest[r] - 1
                idx = sl.vertex_offset + r * arm.around + np.arange(arm.around)
                R, R0 = q[idx], X[idx]
                cur = np.linalg.norm(np.roll(R, -1, 0) - R, axis=1)
                rest = np.linalg.norm(np.roll(R0, -1, 0) - R0, axis=1)
                cen = R.mean(0)
                n0 = np.linalg.svd(R - cen)[2][2]
                fs = min(plane_girth(meshes, axis, cen, n)
                         for n in _directions(n0, tilt)) / rest.sum() - 1
                g, e = cur.sum() / rest.sum() - 1, (cur / rest - 1).max()
                flat = np.abs((R - cen) @ n0).max()
                out[(k, r)] = (fk, fs, g, e, flat)
                cells.append(f"{100 * fk:+.1f}{'*' if fk > 0.02 else ''} / "
                             f"{100 * fs:+.1f}{'*' if fs > 0.02 else ''} / "
                             f"{100 * g:+.1f} / {100 * e:.1f} / {1000 * flat:.0f}")
            print(f"| {k} | {arm.angle(k):.0f} | {100 * strain.max():.2f} | "
                  f"{1000 * cpu:.0f} | " + " | ".join(cells) + " |", flush=True)
    return out


def _scene_variant(scene: Path, overrides: dict, tmp: Path, skin: float = 1.0) -> Path:
    """A copy of the scene in ``tmp`` with graph overrides (``cloth_strain._variant``: its
    meshes and maps linked beside it), the painted maps times ``skin`` (the compliant skin's
    stiffness scaled) when it is not 1."""
    out = cs._variant(scene, overrides, tmp)
    if skin != 1.0:
        for f in scene.parent.glob("*.npy"):
            (tmp / f.name).unlink()
            np.save(tmp / f.name, np.load(f) * skin)
    return out


#: frame ranges of the --pinch summary: the bend's start, the closing crease (the pinch), full
#: bend, straightening, rest
RANGES = ((1, 12), (13, 21), (22, 28), (29, 48), (49, 60))


def pinch(scene: Path, frames, settings, skins):
    """Per setting (stepped in turn, frame by frame, in one process): per frame the worst sleeve
    edge strain, where (ring, degrees from +y: 0 = the inner elbow, kind) and whether its
    vertices touch two arm pieces (pinched), CPU ms, intersecting pairs (sleeve-arm and sleeve
    self, lokigraph.behaviors.collision.intersect); then per frame range the worst, its frame
    and place, the mean CPU ms/frame, the largest pair count and how many frames' worst edges
    were pinched."""
    from lokigraph.api import compile_file
    from lokigraph.behaviors.collision.intersect import intersect_meshes
    from lokigraph.run import Simulation


    names = "ufe"
    with tempfile.TemporaryDirectory() as tmp:
        runs = []
        for i, (label, ov) in enumerate(settings):
            d = Path(tmp) / str(i)
            d.mkdir()
            c = compile_file(_scene_variant(scene, ov, d, skins[i]))
            E = c.schedule.find("StretchConstraint")[0].data
            sl = c.scene.element("sleeve")
            keep = (E.idx[:, 0] >= sl.vertex_offset) & (E.idx[:, 0] < sl.vertex_offset
                                                         + sl.vertex_count)
            runs.append({"label": label, "c": c, "sim": Simulation(c), "sl": sl,
                         "E": E.idx[keep], "rest": E.rest[keep], "rows": []})
        na = AROUND
        print("| frame | " + " | ".join(r["label"] for r in runs) + " |")
        print("|---|" + "---|" * len(runs))
        for k in range(1, frames + 1):
            cells = []
            for r in runs:
                sim, sl, E = r["sim"], r["sl"], r["E"]
                t0 = time.process_time()
                sim.step_frame()
                cpu = time.process_time() - t0
                q = sim.state.particle_q
                e = np.linalg.norm(q[E[:, 1]] - q[E[:, 0]], axis=1) / r["rest"] - 1
                j = int(e.argmax())
                a, b = E[j] - sl.vertex_offset
                ring = min(a // na, b // na)
                kind = "ring" if a // na == b // na else ("axial" if a % na == b % na
                                                          else "diagonal")
                ang = 360.0 * 0.5 * (a % na + b % na + (na if abs(a % na - b % na) > 1
                                                        else 0)) / na % 360
                arm = [(q[r["c"].scene.element(n).vertex_slice],
                        r["c"].scene.element(n).geometry.triangles) for n in ARM]
                dist = cs._part_distances(q[E[j]], arm)
                touch = ["".join(names[i] for i in np.flatnonzero(dd < cs.TOUCH)) for dd in dist]
                cloth = (q[sl.vertex_slice], sl.geometry.triangles)
                pairs = intersect_meshes([cloth], touching=False)[0]
                for V, F in arm:
                    _, pp = intersect_meshes([cloth, (V, F)], touching=False)
                    pairs += int((pp[:, 0] != pp[:, 2]).sum())
                pinched = max(len(t) for t in touch) > 1
                r["rows"].append((k, e[j], ring, ang, kind, touch, cpu, pairs, pinched))
                cells.append(f"{100 * e[j]:.2f} r{ring} {ang:.0f}deg {kind} "
                             f"{'/'.join(t or '-' for t in touch)} {1000 * cpu:.0f}ms "
                             f"{pairs}p")
            print(f"| {k} | " + " | ".join(cells) + " |", flush=True)
        print("\nper frame range: worst % (frame, ring, degrees from the inner elbow, kind, "
              "touching) / mean CPU ms per frame / largest intersecting pairs / frames whose "
              "worst edge is pinched")
        print("| frames | " + " | ".join(r["label"] for r in runs) + " |")
        print("|---|" + "---|" * len(runs))
        for lo, hi in RANGES:
            if lo > frames:
                break
            cells = []
            for r in runs:
                rows = [x for x in r["rows"] if lo <= x[0] <= hi]
                w = max(rows, key=lambda x: x[1])
                cells.append(f"{100 * w[1]:.2f} (f{w[0]}, r{w[2]}, {w[3]:.0f}deg, {w[4]}, "
                             f"{'/'.join(t or '-' for t in w[5])}) / "
                             f"{1000 * np.mean([x[6] for x in rows]):.0f} / "
                             f"{max(x[7] for x in rows)} / {sum(x[8] for x in rows)}")
            print(f"| {lo}-{min(hi, frames)} | " + " | ".join(cells) + " |", flush=True)


def sleeve_mesh(radius=0.060, wrist=0.056, taper_from=0.125):
    """The sleeve of graphs/examples/sleeve_elbow.yaml (sleeve_elbow_sleeve.obj): the tube
    generator's 24 x 16 tube (0.56 m along x from x = -0.29, the vertex order of
    lokigraph.generators.tube), ``radius`` [m] to x = ``taper_from`` and narrowing linearly to
    ``wrist`` at the hem, each ring lowered (-z) to rest on the top of the arm (upper arm 0.048 m
    for x < 0, forearm 0.045 m) at the collision distance GAP. Returns (points, triangles)."""
    from lokigraph.generators import tube

    g = tube(radius=1.0, length=0.56, segments=(24, 16), axis="x", center=(-0.01, 0.0, 0.0))
    P = np.array(g.points)
    x = P[:, 0]
    r = np.where(x <= taper_from, radius,
                 radius + (wrist - radius) * (x - taper_from) / (x.max() - taper_from))
    P[:, 1:] *= r[:, None]
    P[:, 2] -= r - np.where(x < 0, 0.048, 0.045) - GAP
    return P, np.asarray(g.triangles)


def write_sleeve(path: Path, **kw):
    """Write :func:`sleeve_mesh` as an OBJ file (vertex order kept)."""
    P, F = sleeve_mesh(**kw)
    lines = ["# graphs/examples/sleeve_elbow.yaml's sleeve, written by "
             "graphs/bench/sleeve_elbow_girth.py --write-sleeve (sleeve_mesh)"]
    lines += [f"v {p[0]:.9g} {p[1]:.9g} {p[2]:.9g}" for p in P]
    lines += [f"f {t[0]} {t[1]} {t[2]}" for t in F + 1]
    path.write_text("\n".join(lines) + "\n")


def _range(text):
    out = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b or a) + 1))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", type=Path, default=SCENE)
    ap.add_argument("--frames", default="1-48", help="frames: states after that many steps "
                    "(graphs/bench/cloth_strain.py's numbering)")
    ap.add_argument("--rings", default="4-13")
    ap.add_argument("--slide", type=float, default=0.0175)
    ap.add_argument("--tilt", type=float, default=40.0)
    ap.add_argument("--animated", action="store_true", help="the arm as animated, no "
                    "simulation (stiff skin)")
    ap.add_argument("--set", action="append", default=[], help="node.param=value")
    ap.add_argument("--pinch", action="append", help="a setting: 'node.param=value ... "
                    "[skin=S]' ('' the defaults; skin scales the painted compliant stiffness); "
                    "repeat for more, stepped in turn (see pinch())")
    ap.add_argument("--write-sleeve", type=Path, help="write the scene's sleeve mesh (OBJ) "
                    "and stop")
    a = ap.parse_args(argv)
    if a.write_sleeve:
        write_sleeve(a.write_sleeve)
        return
    arm = Arm(a.scene.resolve())
    frames = _range(a.frames)
    rings = _range(a.rings)
    if a.pinch:
        settings, skins = [], []
        for text in a.pinch:
            items = text.split()
            skin = float(next((it.split("=", 1)[1] for it in items
                               if it.startswith("skin=")), 1.0))
            ov = cs._parse_set([it for it in items if not it.startswith("skin=")])
            settings.append((text if len(text) < 40 else f"setting {len(settings) + 1}", ov))
            skins.append(skin)
            print(f"{settings[-1][0]}: {text or 'defaults'}")
        pinch(a.scene.resolve(), max(frames), settings, skins)
        return
    run(arm, frames, rings, a.slide, a.tilt, cs._parse_set(a.set), a.animated)


if __name__ == "__main__":
    main()
