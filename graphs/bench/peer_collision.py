"""Peer benchmark for collisions: cloth dropped on a sphere with self-collision, lokigraph against
NVIDIA Newton's SolverStyle3D (CPU), both in one run, interleaved frame by frame.

Run (Newton lives in its own virtual environment, never imported by lokigraph)::

    python3 -m venv --system-site-packages /tmp/venv-peer && /tmp/venv-peer/bin/pip install newton
    # make lokigraph importable there (editable, no deps) or add a .pth, then:
    /tmp/venv-peer/bin/python graphs/bench/peer_collision.py [--sizes 64 128] [--frames 23]
    python graphs/bench/peer_newton.py --collision ...      # the same, from the peer script
    .venv/bin/python graphs/bench/peer_collision.py --moving  # lokigraph only, moving collider

Without Newton the Newton rows are skipped with the reason; the lokigraph rows always run.

Scenes: ``graphs/bench/cloth_sphere_64.yaml`` and ``cloth_sphere_128.yaml`` (1 m cloth, 0.15
kg/m^2, inextensible, thickness 2 mm, dropped from y = 0.6 onto a static sphere of radius 0.3,
self-collision on, 24 fps, 23 frames). ``--moving``: ``cloth_sphere_moving_128.yaml``, the same
128 x 128 cloth on a sphere that, once the cloth has landed (frame 6), moves back and forth along
x and spins about y on smooth keys (``Kinematic.interpolation: smooth``; peak speed 2 m/s, surface
speed of the spin at most 1.97 m/s): lokigraph only, against the static scene at the same
resolution, with the CPU ratio to it (median of frames 2..N; mean) and a per-frame table (CPU,
strain, pairs, contact rows, collider and cloth speeds). ``--moving-scenes A.yaml B.yaml`` runs
other moving variants in the same interleaved run; ``--moving-flag NAME`` runs the moving scenes
again with the boolean ``contacts.NAME`` set True around their steps only (e.g.
``SPACETIME_PREDICTED``); ``--rows-at-iterate`` (only) checks whether the rows of the substep's
first detection hold the pairs of the iterate (``rows_at_iterate``); ``--breakdown`` adds the CPU of the collision
detection, the contact projection and the CCD safe step per frame (``install_breakdown``)::

    .venv/bin/python graphs/bench/peer_collision.py --moving --loki 2x15 --breakdown

All settings of both frameworks are created first and then stepped one frame each in turn
(frame-level interleaving), so machine load hits every setting alike. Per setting the table gives:

* CPU and wall ms/frame: medians over frames 2..N (frame 1, with JIT / kernel-cache loading, is
  reported apart). CPU = ``time.process_time`` of this process (all its threads).
* max edge strain: the largest (|e| - L0) / L0 over the cloth's mesh edges, max over frames.
* inside: cloth vertices inside the sphere (closer to its centre than the inscribed radius of
  lokigraph's sphere mesh, i.e. below every face), max over frames.
* pairs: intersecting triangle pairs (proper crossings) among the cloth's triangles and between
  the cloth and the sphere mesh, by ``lokigraph.behaviors.collision.intersect.find_intersections``
  applied to both frameworks' positions; max and number of frames with any.
* finite: all positions finite in every frame.

The lokigraph timing excludes its own per-frame ``PenetrationCheck`` (the same counter is run
outside the timed region for both frameworks).

Newton model (float32, device "cpu", warp CPU kernels single-threaded): ``style3d.add_cloth_mesh``
on exactly lokigraph's vertices and triangles (panel = rest (x, z)), lokigraph's lumped masses,
Baraff-Witkin membrane (weft, warp, shear) = (Et, Et, Et / (2 (1 + nu))) with ``--newton-et``
(default 1000 N/m: lokigraph's cloth is inextensible, which Style3D cannot express), bending D,
particle radius = lokigraph's collider thickness, an analytic static sphere shape (radius 0.3)
collided by Newton's CollisionPipeline once per frame (as in Newton's Style3D example; before
every substep with ``--newton-collide substep``, contact margin ``--newton-margin``), Style3D's
built-in self-collision on (its own contact radius, 3 mm).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

BENCH = ROOT / "graphs" / "bench"
SCENES = {n: BENCH / f"cloth_sphere_{n}.yaml" for n in (32, 64, 128)}
SIZES = (32, 64, 128, 256)  # --sizes: 256 is cloth_sphere_128.yaml at 256 x 256 (_scene_path)


def _scene_path(n: int, folder: Path, cloth_thickness: float | None = None) -> Path:
    """The static scene at ``n`` x ``n``: its YAML, else ``cloth_sphere_128.yaml`` with the
    cloth's resolution replaced, written into ``folder``; with ``cloth_thickness``, the cloth's
    collider thickness [m] replaced too (at 256 x 256 the scenes' 2 mm makes a contact distance
    of 4 mm, over the 3.9 mm edge and the 2.8 mm from a vertex to the nearest triangle without
    it: the flat cloth is in self-contact at rest)."""
    if n in SCENES and cloth_thickness is None:
        return SCENES[n]
    folder.mkdir(parents=True, exist_ok=True)
    text = SCENES[128].read_text().replace("resolution: [128, 128]", f"resolution: [{n}, {n}]")
    name = f"cloth_sphere_{n}.yaml"
    if cloth_thickness is not None:
        old = "Collider: {thickness: 0.002, friction: 0.3}"
        assert old in text, "cloth_sphere_128.yaml: the cloth's collider line changed"
        text = text.replace(old, f"Collider: {{thickness: {cloth_thickness!r}, friction: 0.3}}")
        name = f"cloth_sphere_{n}_t{cloth_thickness:g}.yaml"
    path = folder / name
    path.write_text(text)
    return path
MOVING = BENCH / "cloth_sphere_moving_128.yaml"
# (substeps, iterations); the scene default is 2 x 15 (graph default iterations)
LOKI_SETTINGS = [(1, 15), (2, 15), (4, 15)]
NEWTON_SETTINGS = [(4, 10), (8, 10)]


# ------------------------------------------------------------------------------------ the scene

class ClothSphere:
    """The shared scene, read from the YAML through lokigraph (float64)."""

    def __init__(self, path: Path):
        from lokigraph.compile import compile_scene
        from lokigraph.scene import load_scene

        compiled = compile_scene(load_scene(path))
        m = compiled.model
        els = {e.name: e for e in m.elements}
        cloth, ball = els["cloth"], els["ball"]
        self.cloth_slice, self.ball_slice = cloth.vertex_slice, ball.vertex_slice
        self.points = np.asarray(m.particle_q0, dtype=np.float64)
        self.cloth_q0 = self.points[self.cloth_slice].copy()
        self.tris = np.asarray(cloth.geometry.triangles, dtype=np.int64)
        self.ball_tris = np.asarray(ball.geometry.triangles, dtype=np.int64)
        self.mass = np.asarray(m.particle_mass[self.cloth_slice], dtype=np.float64)
        shell, dyn = cloth.components["DiscreteShell"], cloth.components["Dynamic"]
        self.density = float(dyn.mass_density)
        self.D = float(shell.bend_resistance)
        self.nu = float(shell.poisson_ratio)
        self.thickness = float(cloth.components["Collider"].thickness)
        self.friction = float(cloth.components["Collider"].friction)
        self.gravity = tuple(float(g) for g in m.gravity)
        self.fps = float(m.fps)
        self.substeps = int(m.substeps)
        spec = compiled.scene.spec
        self.frames = int(spec.frames.end - spec.frames.start)
        bq = self.points[self.ball_slice]
        self.center = bq.mean(axis=0)
        self.radius = float(np.linalg.norm(bq - self.center, axis=1).mean())
        self.resolution = int(round(np.sqrt(len(self.tris) / 2)))
        self.path = path
        # cloth mesh edges and rest lengths
        e = np.sort(np.concatenate([self.tris[:, [0, 1]], self.tris[:, [1, 2]],
                                    self.tris[:, [2, 0]]]), axis=1)
        self.edges = np.unique(e, axis=0)
        self.rest = np.linalg.norm(self.cloth_q0[self.edges[:, 1]] - self.cloth_q0[self.edges[:, 0]],
                                   axis=1)
        self.ball_tris_global = self.ball_tris + len(self.cloth_q0)
        self.all_tris = np.concatenate([self.tris, self.ball_tris_global])

    def inscribed_radius(self, ball_q) -> float:
        """Smallest distance from the sphere mesh's centre to its face planes [m]."""
        c = ball_q.mean(axis=0)
        P = ball_q[self.ball_tris]
        n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
        n /= np.linalg.norm(n, axis=1)[:, None]
        return float(np.abs(np.einsum("ij,ij->i", P[:, 0] - c, n)).min())

    def metrics(self, cloth_q, ball_q) -> dict:
        """Strain, vertices inside the sphere, intersecting triangle pairs, finiteness."""
        from lokigraph.behaviors.collision.intersect import find_intersections

        q = np.asarray(cloth_q, dtype=np.float64)
        if not np.isfinite(q).all():
            return {"finite": False, "strain": float("nan"), "inside": -1, "pairs": -1}
        L = np.linalg.norm(q[self.edges[:, 1]] - q[self.edges[:, 0]], axis=1)
        strain = float(np.max((L - self.rest) / self.rest))
        c = ball_q.mean(axis=0)
        inside = int(np.count_nonzero(np.linalg.norm(q - c, axis=1) < self.inscribed_radius(ball_q)))
        V = np.concatenate([q, ball_q])
        pairs = int(find_intersections(V, self.all_tris, touching=False).count)
        return {"finite": True, "strain": strain, "inside": inside, "pairs": pairs}


# ----------------------------------------------------------------------------------- runners

# solver statistics kept per frame (sums over the frame's substeps; max_* the max)
STAT_KEYS = ("contacts_vf", "contacts_ee", "contacts_tolerant", "iteration_detections",
             "max_active_contacts", "max_final_active", "ccd_detections", "ccd_hits",
             "ccd_zones", "ccd_zone_vertices", "ccd_unresolved", "relative_checks",
             "relative_detections", "relative_full", "relative_flagged", "relative_added")
_PROF: dict = {}  # --breakdown: CPU seconds and calls per timed function, reset every frame


def install_breakdown():
    """Wrap the collision functions of ``lokigraph.behaviors.collision.contacts`` (module
    globals, so the calls inside the module go through the wrappers too) with CPU-time counters:
    ``detect`` (``_detect_all``: broad phase + narrow filters, every call: the substep's
    detection, the final rounds' and the CCD step's), ``project`` (``_project_contacts``),
    ``ccd`` (``ccd_safe_step``, its detections included). Reported per frame as ``t_NAME`` [s]
    and ``n_NAME`` (calls)."""
    from lokigraph.behaviors.collision import contacts as C

    def timed(name, fn):
        def w(*a, **k):
            c0 = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                _PROF["t_" + name] = _PROF.get("t_" + name, 0.0) + time.process_time() - c0
                _PROF["n_" + name] = _PROF.get("n_" + name, 0) + 1
        return w

    for name, attr in (("detect", "_detect_all"), ("project", "_project_contacts"),
                       ("ccd", "ccd_safe_step")):
        if hasattr(C, attr) and not hasattr(getattr(C, attr), "__wrapped_peer__"):
            w = timed(name, getattr(C, attr))
            w.__wrapped_peer__ = True
            setattr(C, attr, w)


def _minflt() -> tuple[int, float]:
    """Minor page faults of this process so far (first touches of fresh pages among them) and
    its system CPU [s] (the kernel's share: page faults, zeroing and compacting fresh pages)."""
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_minflt, r.ru_stime


_STAGE = ["other"]  # --stages: the collision stage being run (first / iter / final / ccd)


def install_stages(n_cloth: int):
    """``--stages``: CPU per collision stage and per part of it, per frame, in ``_PROF`` as
    ``s_STAGE.PART`` [s] (and ``c_STAGE.PART`` calls). Stages: ``first`` (the substep's
    detection, ``CollisionDetect.step``), ``iter`` (``CollisionConstraint.project``: the contact
    passes of the iterations, re-detections included), ``final`` (the final rounds: their
    detections and passes), ``ccd`` (the safe step), ``global`` (the global strain step,
    ``GlobalStrainStep.run``: not a collision stage, but the part of the frame that grows
    fastest with resolution; parts ``factor``, its factorisations, and ``sweeps``, its
    smoothing sweeps). Parts: ``boxes`` (primitive and
    space-time boxes), ``broad`` (the column grid's / trees' queries), ``order`` (the Z-order
    sort), ``filter_vf`` / ``filter_ee`` (the narrow filters), ``pack``, ``cull``, ``pass``
    (``_project_contacts``; ``full`` counts the passes over every row), ``ccd_hits``.
    ``f_STAGE.PART`` counts the part's minor page faults (thousands per frame in the table),
    ``y_STAGE.PART`` its system CPU [s] (in the part's ``s_``).
    ``r_STAGE.{vf,ee}_{self,ball}`` sum the rows of the stage's detections (cloth-cloth / with a
    vertex of index >= ``n_cloth``: the collider); their counting is left out of the parts
    but is in the frame's CPU (``s_count`` says how much)."""
    from lokigraph.behaviors.collision import broadphase as bp
    from lokigraph.behaviors.collision import contacts as C

    install_stages.n_cloth[0] = n_cloth  # changeable later (--sizes: one scene after another)
    if getattr(C, "__stages_installed__", False):
        return
    C.__stages_installed__ = True

    def timed(mod, attr, part, after=None):
        fn = getattr(mod, attr)

        def w(*a, **k):
            f0 = _minflt()
            c0 = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                key = f"{_STAGE[0]}.{part}"
                _PROF["s_" + key] = _PROF.get("s_" + key, 0.0) + time.process_time() - c0
                _PROF["c_" + key] = _PROF.get("c_" + key, 0) + 1
                f1 = _minflt()
                _PROF["f_" + key] = _PROF.get("f_" + key, 0) + f1[0] - f0[0]
                _PROF["y_" + key] = _PROF.get("y_" + key, 0.0) + f1[1] - f0[1]
                if after is not None:
                    c1 = time.process_time()
                    after(*a)
                    _PROF["s_count"] = _PROF.get("s_count", 0.0) + time.process_time() - c1
        setattr(mod, attr, w)

    def staged(cls, attr, stage):
        fn = getattr(cls, attr)

        def w(*a, **k):
            keep = _STAGE[0]
            _STAGE[0] = stage
            f0 = _minflt()
            c0 = time.process_time()
            try:
                return fn(*a, **k)
            finally:
                _PROF["s_" + stage] = _PROF.get("s_" + stage, 0.0) + time.process_time() - c0
                _PROF["y_" + stage] = _PROF.get("y_" + stage, 0.0) + _minflt()[1] - f0[1]
                _STAGE[0] = keep
        setattr(cls, attr, w)

    def count_rows(d, *_):
        for kind in ("vf", "ee"):
            rows = getattr(d, kind)
            ball = (int(np.count_nonzero((rows >= install_stages.n_cloth[0]).any(axis=1)))
                    if len(rows) else 0)
            for nm, v in (("self", len(rows) - ball), ("ball", ball)):
                key = f"r_{_STAGE[0]}.{kind}_{nm}"
                _PROF[key] = _PROF.get(key, 0) + v
        _PROF[f"c_{_STAGE[0]}.detect"] = _PROF.get(f"c_{_STAGE[0]}.detect", 0) + 1

    seen = {}  # full passes of each contacts object counted so far

    def full_pass(c, *_):
        key = f"c_{_STAGE[0]}.full"
        _PROF[key] = _PROF.get(key, 0) + c.full_passes - seen.get(id(c), 0)
        seen[id(c)] = c.full_passes

    for attr in ("primitive_boxes", "spacetime_prim_boxes", "spacetime_boxes"):
        timed(bp, attr, "boxes")
    for attr in ("column_query_pairs", "column_query_self", "query_pairs", "query_self",
                 "build_bvh"):
        timed(bp, attr, "broad")
    timed(C, "_ordered", "order")
    timed(C, "_filter_vf", "filter_vf")
    timed(C, "_filter_ee", "filter_ee")
    timed(C, "_vertex_normals", "filter_ee")
    timed(C, "_pack", "pack", after=lambda d, *_: count_rows(d))
    if hasattr(C, "_PackSink"):  # PACK_DIRECT: the filters write the packed rows themselves
        timed(C._PackSink, "commit", "pack")
        timed(C._PackSink, "finish", "pack", after=lambda sink: count_rows(sink.d))
    timed(C, "_cull", "cull")
    timed(C, "_project_contacts", "pass", after=full_pass)
    timed(C, "_ccd_hits", "ccd_hits")
    staged(C.CollisionDetect, "step", "first")
    staged(C.CollisionConstraint, "project", "iter")
    staged(C.CollisionConstraint, "finalize", "final")
    staged(C.CollisionConstraint, "after_finalize", "ccd")
    from lokigraph.behaviors.materials.strain_limit_global import GlobalStrainStep as G

    timed(G, "_factorise", "factor")
    timed(G, "_smooth_sweeps", "sweeps")
    staged(G, "run", "global")


install_stages.n_cloth = [0]


def stages_table(rows, n_cloth: int, frames=None) -> str:
    """``--stages``: per run, CPU ms per frame of every stage and part (mean over ``frames``,
    default 2..N) and the rows per cloth vertex of the stages' detections (summed over the
    frame's detections of that stage, divided by the detections)."""
    keys = sorted({k for r in rows for v in r["per_frame"] for k in v
                   if k.startswith(("s_", "r_", "c_", "f_", "y_"))})
    lines = ["| key | " + " | ".join(r["setting"] for r in rows) + " |",
             "|" + "---|" * (len(rows) + 1)]
    for k in ["cpu_ms"] + keys:
        cells = []
        for r in rows:
            pf = r["per_frame"][1:] if frames is None else [r["per_frame"][f - 1] for f in frames
                                                            if f <= len(r["per_frame"])]
            vals = [v.get(k, 0) for v in pf]
            m = float(np.mean(vals)) if vals else float("nan")
            if k.startswith(("s_", "y_")):
                cells.append(f"{1e3 * m:.0f}")
            elif k.startswith("f_"):
                cells.append(f"{m / 1e3:.1f}k")
            elif k.startswith("r_"):
                det = [v.get("c_" + k[2:].split(".")[0] + ".detect", 0) for v in pf]
                cells.append(f"{np.sum(vals) / max(np.sum(det), 1) / n_cloth:.1f}")
            else:
                cells.append(f"{m:.1f}")
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


class LokiRun:
    """One lokigraph setting, stepped frame by frame (its PenetrationCheck left out of the
    timed frame; the shared counter runs outside)."""

    framework = "lokigraph"

    def __init__(self, scene: ClothSphere, substeps: int, iterations: int, label: str = "",
                 threads: int | None = None, overrides: dict | None = None,
                 flags: dict | None = None):
        from lokigraph.bench.sweep import _apply
        from lokigraph.compile import compile_scene
        from lokigraph.run import Simulation
        from lokigraph.scene import load_scene

        from lokigraph.behaviors.collision import contacts as C

        sc = _apply(load_scene(scene.path), {"substeps": substeps, "iterations": iterations,
                                             **(overrides or {})})
        keep_flags = {k: getattr(*_flag_at(C, k)) for k in (flags or {})}
        for k, v in (flags or {}).items():  # also at bind time (e.g. MARGIN_EDGE)
            setattr(*_flag_at(C, k), v)
        try:
            self.sim = Simulation(compile_scene(sc))
        finally:
            for k, v in keep_flags.items():
                setattr(*_flag_at(C, k), v)
        self.sim._steps = [b for b in self.sim._steps
                           if type(b.behavior).__name__ != "PenetrationCheck"]
        self.scene = scene
        self.threads = threads
        self.overrides = overrides or {}
        self.setting = (f"{substeps}x{iterations}" + (f"@{threads}t" if threads else "")
                        + "".join(f" {k}={v}" for k, v in (overrides or {}).items()) + label)
        self.solver = "nucleus"
        self.flags = flags or {}  # contacts module globals set around this run's steps only

    def step(self):
        from lokigraph.behaviors.collision import contacts as C

        keep_flags = {k: getattr(*_flag_at(C, k)) for k in self.flags}
        for k, v in self.flags.items():
            setattr(*_flag_at(C, k), v)
        try:
            self._step()
        finally:
            for k, v in keep_flags.items():
                setattr(*_flag_at(C, k), v)

    def _step(self):
        _PROF.clear()
        if self.threads:
            import numba

            keep = numba.get_num_threads()
            numba.set_num_threads(self.threads)
            try:
                self.stats = self.sim.step_frame()
            finally:
                numba.set_num_threads(keep)
        else:
            self.stats = self.sim.step_frame()
        self.stats = {k: v for k, v in self.stats.items() if k in STAT_KEYS}
        self.stats.update(_PROF)
        st = self.sim.state
        vcl = np.linalg.norm(st.particle_qd[self.scene.cloth_slice], axis=1)
        self.stats.update(cloth_speed_mean=float(vcl.mean()),
                          cloth_speed_p95=float(np.percentile(vcl, 95)))
        c = st.fields.get("contacts")  # rows of the frame's last detection
        if c is not None:
            b0, b1 = self.scene.ball_slice.start, self.scene.ball_slice.stop
            for kind in ("vf", "ee"):
                rows = getattr(c, kind)
                ball = ((rows >= b0) & (rows < b1)).any(axis=1)
                self.stats[f"last_{kind}_self"] = int(np.count_nonzero(~ball))
                self.stats[f"last_{kind}_ball"] = int(np.count_nonzero(ball))
        vb = st.particle_qd[self.scene.ball_slice]  # the collider's velocity
        vc = vb.mean(axis=0)  # ~ its centre's (the sphere mesh is symmetric)
        self.stats.update(ball_speed=float(np.linalg.norm(vc)),
                          ball_spin_speed=float(np.linalg.norm(vb - vc, axis=1).max()))

    def positions(self):
        q = self.sim.state.particle_q
        return q[self.scene.cloth_slice], q[self.scene.ball_slice]


class NewtonRun:
    """One Newton SolverStyle3D setting on the same cloth, static analytic sphere."""

    framework = "newton"

    def __init__(self, newton, wp, scene: ClothSphere, substeps: int, iterations: int,
                 et: float, collide: str = "frame", margin: float | None = None):
        from newton.solvers import style3d

        self.wp = wp
        t0 = time.perf_counter()
        b = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=scene.gravity)
        newton.solvers.SolverStyle3D.register_custom_attributes(b)
        b.default_edge_ke = scene.D
        q0 = scene.cloth_q0
        panel = [wp.vec2(float(p[0]), float(p[2])) for p in q0]
        mu = et / (2.0 * (1.0 + scene.nu))
        style3d.add_cloth_mesh(b, pos=wp.vec3(0.0, 0.0, 0.0), rot=wp.quat_identity(),
                               vel=wp.vec3(0.0, 0.0, 0.0), vertices=[wp.vec3(*p) for p in q0],
                               indices=scene.tris.ravel().tolist(), density=scene.density,
                               tri_kd=0.0, edge_kd=0.0, particle_radius=scene.thickness,
                               panel_verts=panel, tri_aniso_ke=wp.vec3(et, et, mu), tri_ka=0.0)
        b.particle_mass = [float(m) for m in scene.mass]
        cfg = newton.ModelBuilder.ShapeConfig(mu=0.5)
        b.add_shape_sphere(body=-1, xform=wp.transform(wp.vec3(*scene.center), wp.quat_identity()),
                           radius=scene.radius, cfg=cfg)
        self.model = b.finalize(device="cpu")
        self.model.soft_contact_mu = scene.friction
        S = newton.solvers
        self.solver = S.SolverStyle3D(self.model, config=S.SolverStyle3D.Config(
            iterations=iterations))
        kw = {} if margin is None else {"soft_contact_margin": float(margin)}
        self.pipeline = newton.CollisionPipeline(self.model, **kw)
        self.collide_every_substep = collide == "substep"
        self.contacts = self.pipeline.contacts()
        self.s0, self.s1 = self.model.state(), self.model.state()
        self.ctrl = self.model.control()
        self.dt = 1.0 / (scene.fps * substeps)
        self.substeps = substeps
        self.setup_s = time.perf_counter() - t0
        self.scene = scene
        self.setting = f"{substeps}x{iterations}" + (" coll/substep" if collide == "substep"
                                                     else "") + (f" margin {margin:g}"
                                                                 if margin is not None else "")
        self.ball_q = scene.points[scene.ball_slice]
        self.solver_name = "SolverStyle3D"

    def step(self):
        self.pipeline.collide(self.s0, self.contacts)
        for k in range(self.substeps):
            if k and self.collide_every_substep:
                self.pipeline.collide(self.s0, self.contacts)
            self.s0.clear_forces()
            self.solver.step(self.s0, self.s1, self.ctrl, self.contacts, self.dt)
            self.s0, self.s1 = self.s1, self.s0
        self._q = self.s0.particle_q.numpy()  # synchronises; part of a frame's cost

    def positions(self):
        return self._q.astype(np.float64), self.ball_q


def import_newton():
    import warp as wp

    wp.config.quiet = True
    import newton

    wp.init()
    return newton, wp


# ------------------------------------------------------------------------------------- driver

def run_interleaved(runs, frames: int, log=print) -> list[dict]:
    """Step every run one frame in turn for ``frames`` frames; collect timings and metrics."""
    rec = [{"wall": [], "cpu": [], "m": []} for _ in runs]
    alive = [True] * len(runs)
    for f in range(frames):
        for i, r in enumerate(runs):
            if not alive[i]:
                continue
            w0, c0 = time.perf_counter(), time.process_time()
            try:
                r.step()
            except Exception as exc:  # noqa: BLE001 - a failing setting is reported, not fatal
                rec[i]["error"] = f"{type(exc).__name__}: {exc}".splitlines()[0][:200]
                alive[i] = False
                continue
            rec[i]["wall"].append(time.perf_counter() - w0)
            rec[i]["cpu"].append(time.process_time() - c0)
            m = r.scene.metrics(*r.positions())
            m.update(getattr(r, "stats", {}), cpu_ms=1e3 * rec[i]["cpu"][-1])
            rec[i]["m"].append(m)
        log(f"[peer] frame {f + 1}/{frames}: " + ", ".join(
            f"{r.framework[:4]} {r.setting} {1e3 * rec[i]['wall'][-1]:.0f}ms"
            for i, r in enumerate(runs) if alive[i] and rec[i]["wall"]))
    rows = []
    for r, x in zip(runs, rec):
        m = x["m"]
        row = {"framework": r.framework, "solver": getattr(r, "solver_name", "nucleus"),
               "resolution": r.scene.resolution, "scene": r.scene.path.name,
               "setting": r.setting, "frames": len(m), "error": x.get("error")}
        if len(x["wall"]) > 1:
            row.update(cpu_ms=1e3 * float(np.median(x["cpu"][1:])),
                       wall_ms=1e3 * float(np.median(x["wall"][1:])))
        row.update(frame1_s=x["wall"][0] if x["wall"] else None,
                   setup_s=getattr(r, "setup_s", None),
                   finite=bool(m) and all(v["finite"] for v in m) and not x.get("error"),
                   max_strain=max((v["strain"] for v in m), default=float("nan")),
                   final_strain=m[-1]["strain"] if m else float("nan"),
                   max_inside=max((v["inside"] for v in m), default=-1),
                   max_pairs=max((v["pairs"] for v in m), default=-1),
                   frames_with_pairs=sum(v["pairs"] != 0 for v in m),
                   per_frame=m)
        rows.append(row)
    return rows


def fmt(v, spec):
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "n/a"
    return format(v, spec)


def table(rows) -> str:
    head = ("| res | framework | setting | CPU ms/frame | wall ms/frame | CPU / Style3D best | "
            "max strain % | max inside | max pairs | frames w/ pairs | finite |")
    lines = [head, "|" + "---|" * 11]
    for r in rows:
        if r.get("skipped"):
            lines.append(f"| {r.get('resolution', '')} | {r['framework']} | {r['setting']} | "
                         f"skipped: {r['skipped']} |||||||")
            continue
        fin = "yes" if r["finite"] else ("NO" + (f" ({r['error']})" if r.get("error") else ""))
        lines.append(
            f"| {r['resolution']} | {r['framework']} | {r['setting']} | {fmt(r.get('cpu_ms'), '.0f')}"
            f" | {fmt(r.get('wall_ms'), '.0f')} | {fmt(r.get('ratio'), '.2f')}"
            f"{'; ' + fmt(r['ratio_mean'], '.2f') if r.get('ratio_mean') is not None else ''} | "
            f"{fmt(100 * r['max_strain'], '.1f')} | {r['max_inside']} | {r['max_pairs']} | "
            f"{r['frames_with_pairs']}/{r['frames']} | {fin} |")
    return "\n".join(lines)


def rows_vs_speed(speeds=(0.0, 0.5, 1.0, 2.0, 4.0)) -> str:
    """Why a moving collider costs: the contact rows of ONE detection of the flat 128 x 128 cloth
    (``cloth_sphere_128.yaml`` after its first frame) translated rigidly at speed v along x over
    one substep (no deformation, no relative motion), with the swept boxes of the substep's
    predicted detection (``spacetime`` False, as ``CollisionDetect.step`` detects while
    ``contacts.SPACETIME_PREDICTED`` is False) and with the space-time test of the final rounds
    and the CCD (True). Returns a markdown table."""
    from lokigraph.behaviors.collision import contacts as C
    from lokigraph.compile import compile_scene
    from lokigraph.run import Simulation
    from lokigraph.scene import load_scene

    sim = Simulation(compile_scene(load_scene(SCENES[128])))
    sim.step_frame()  # binds the detection's buffers
    c = sim.state.fields["contacts"]
    x = sim.state.particle_q.copy()
    h = sim.model.dt
    free = ~sim.model.particle_kinematic
    lines = ["| v m/s | motion mm/substep | space-time | vf rows | ee rows | rows / cloth vertex "
             "| detect CPU ms |", "|" + "---|" * 7]
    for st in (False, True):
        for s in speeds:
            v = np.zeros_like(x)
            v[free, 0] = s
            c0 = time.process_time()
            C._detect_all(c, x, x + v * h, v, h, st)
            t = time.process_time() - c0
            lines.append(f"| {s:.2f} | {1e3 * s * h:.1f} | {st} | {len(c.vf)} | {len(c.ee)} | "
                         f"{(len(c.vf) + len(c.ee)) / free.sum():.1f} | {1e3 * t:.0f} |")
    return "\n".join(lines)


def _needed_keys(p, tris, edges, kin, target):
    """Keys of the pairs a detection must hold at the iterate ``p``: vertex-triangle and
    edge-edge pairs closer than ``target`` [m] (not adjacent, not both kinematic), encoded as
    ``_row_keys`` encodes rows, and for each whether it has a kinematic vertex (a pair with
    the collider, which the one-sided filter may drop on purpose). Brute force over static
    boxes of ``p`` inflated by target / 2."""
    from lokigraph.behaviors.collision import broadphase as bp
    from lokigraph.behaviors.collision.narrowphase import _pt_tri_sq, _seg_seg_sq

    n = len(p)
    verts = np.unique(tris)
    r = 0.5 * target
    lo_v, hi_v = bp.primitive_boxes(p, verts, thickness=r)
    lo_t, hi_t = bp.primitive_boxes(p, tris, thickness=r)
    vf, ee, kv, ke = [], [], [], []
    for i, j in bp.column_query_pairs(lo_v, hi_v, lo_t, hi_t, verts, tris).tolist():
        q, t = verts[i], tris[j]
        if q in t or (kin[q] and kin[t].all()):
            continue
        if _pt_tri_sq(*p[q], *p[t[0]], *p[t[1]], *p[t[2]])[0] < target ** 2:
            vf.append(((q * n + t[0]) * n + t[1]) * n + t[2])
            kv.append(bool(kin[q] or kin[t].any()))
    lo_e, hi_e = bp.primitive_boxes(p, edges, thickness=r)
    for i, j in bp.column_query_self(lo_e, hi_e, edges).tolist():
        a, b = edges[i], edges[j]
        if len({*a, *b}) < 4 or (kin[a].all() and kin[b].all()):
            continue
        if _seg_seg_sq(*p[a[0]], *p[a[1]], *p[b[0]], *p[b[1]])[0] < target ** 2:
            k1, k2 = a[0] * n + a[1], b[0] * n + b[1]
            ee.append(min(k1, k2) * n * n + max(k1, k2))
            ke.append(bool(kin[a].any() or kin[b].any()))
    return (np.array(vf, np.int64), np.array(ee, np.int64), np.array(kv, bool),
            np.array(ke, bool))


def _row_keys(vf, ee, n):
    """int64 keys of packed vertex-face rows (p, a, b, c) and edge-edge rows (a0, a1, b0, b1)
    of ``n`` vertices (n^4 < 2^63 up to 55,000 vertices)."""
    kv = ((vf[:, 0] * n + vf[:, 1]) * n + vf[:, 2]) * n + vf[:, 3]
    k1, k2 = ee[:, 0] * n + ee[:, 1], ee[:, 2] * n + ee[:, 3]
    return kv, np.minimum(k1, k2) * n * n + np.maximum(k1, k2)


def rows_at_iterate(frames=(7, 9, 12, 14), slack=0.005) -> str:
    """Do the rows of the substep's first detection hold the pairs of the iterate the
    iterations end at? The moving scene (``cloth_sphere_moving_128.yaml``, default detection)
    is stepped to the largest of ``frames``; at the last substep of each listed frame the start
    x, the predicted end x1 and the iterate p at the end of the iterations (before the final
    rounds) are taken, and the contacts of that substep are detected again (on a copy of the
    group state) over x -> x1 with: the absolute swept boxes (the default), the swept boxes in
    the frame of the collider's translation D (x -> x1 - D: ``COLLIDER_FRAME`` of the patch
    measured in the ``SPACETIME_PREDICTED`` comment; with and without ``slack`` [m] more
    inflation) and the space-time boxes (``SPACETIME_PREDICTED``; with and without ``slack``
    more inflation). Per row set: rows per cloth
    vertex, its CPU, cloth vertices whose p lies outside what the rows hold (swept: the box of
    its motion widened by infl_min - target/2 (+ slack); space-time: farther than that from
    x1 along an axis), and the pairs within their target at p (brute force) that the rows
    miss, cloth-cloth (self) and with the collider (ball; the one-sided filter drops some of
    those on purpose: a vertex that does not project onto the triangle). Returns a markdown
    table."""
    import copy

    from lokigraph.behaviors.collision import contacts as C
    from lokigraph.compile import compile_scene
    from lokigraph.run import Simulation
    from lokigraph.scene import load_scene
    from lokigraph.behaviors.topology import triangle_edges

    sim = Simulation(compile_scene(load_scene(MOVING)))
    cap = {}
    step0, fin0 = C.CollisionDetect.step, C.CollisionConstraint.finalize

    def step(self, ctx, d):
        step0(self, ctx, d)
        cap.update(x=ctx.state.particle_q.copy(), x1=d.x1.copy(), v=ctx.state.particle_qd.copy(),
                   h=ctx.dt, d=d)

    def fin(self, ctx, d, p):
        cap["p"] = p.copy()
        fin0(self, ctx, d, p)

    C.CollisionDetect.step, C.CollisionConstraint.finalize = step, fin
    lines = ["| frame | rows | rows / cloth vertex | detect CPU ms | cloth vertices outside "
             "| needed pairs at p: self / ball | of them missing: self / ball |", "|" + "---|" * 7]
    try:
        for f in range(1, max(frames) + 1):
            sim.step_frame()
            if f not in frames:
                continue
            x, x1, p, v, h, d = (cap[k] for k in ("x", "x1", "p", "v", "h", "d"))
            g = d.groups[0]
            n = len(x)
            kin = sim.model.particle_kinematic
            dyn = g.verts[~kin[g.verts]]
            infl = np.maximum(g.th_out, g.th_in) + 0.5 * g.margin
            th = float(np.maximum(g.th_out, g.th_in)[g.verts].max())
            allow = float(infl[g.verts].min()) - th  # infl_min - target_max / 2
            need_v, need_e, ball_v, ball_e = _needed_keys(p, g.tris, g.edges, kin, 2.0 * th)
            kv = g.verts[kin[g.verts]]
            D = (x1[kv] - x[kv]).mean(axis=0)
            dev = np.linalg.norm(p[dyn] - x1[dyn], axis=1)
            lines.append(f"| {f} | (collider D = {np.round(1e3 * D, 1).tolist()} mm; cloth "
                         f"|x1 - x| mean {1e3 * np.linalg.norm(x1[dyn] - x[dyn], axis=1).mean():.1f}"
                         f" mm; |p - x1| p50 / p90 / max {1e3 * np.median(dev):.1f} / "
                         f"{1e3 * np.percentile(dev, 90):.1f} / {1e3 * dev.max():.1f} mm) |||||")
            sets = [("absolute swept", np.zeros(3), 0.0, False),
                    ("collider frame", D, 0.0, False),
                    (f"collider frame +{1e3 * slack:g} mm", D, slack, False),
                    ("space-time", np.zeros(3), 0.0, True),
                    (f"space-time +{1e3 * slack:g} mm", np.zeros(3), slack, True)]
            for name, S, sl, st in sets:
                g2 = copy.deepcopy(g)
                c0 = time.process_time()
                vf, ee, _ = C._detect_group(g2, x, x1 - S, infl + sl, v, h, st)
                t = time.process_time() - c0
                if st:
                    out = np.abs(p[dyn] - x1[dyn]).max(axis=1) > allow + sl
                else:
                    a, b = x[dyn], x1[dyn] - S
                    q = p[dyn] - S
                    e = np.maximum(np.minimum(a, b) - q, q - np.maximum(a, b)).max(axis=1)
                    out = e > allow + sl
                rv, re = _row_keys(vf[0], ee[0], n)
                mv, me = ~np.isin(need_v, rv), ~np.isin(need_e, re)
                miss = (f"{int((mv & ~ball_v).sum() + (me & ~ball_e).sum())} / "
                        f"{int((mv & ball_v).sum() + (me & ball_e).sum())}")
                lines.append(f"| {f} | {name} | {(len(vf[0]) + len(ee[0])) / len(dyn):.1f} | "
                             f"{1e3 * t:.0f} | {int(out.sum())} / {len(dyn)} | "
                             f"{int((~ball_v).sum() + (~ball_e).sum())} / "
                             f"{int(ball_v.sum() + ball_e.sum())} | {miss} |")
            print(*lines[-len(sets) - 1:], sep="\n", flush=True)
    finally:
        C.CollisionDetect.step, C.CollisionConstraint.finalize = step0, fin0
    return "\n".join(lines)


def per_frame_table(rows) -> str:
    """One line per frame: per run CPU ms, max strain %, intersecting pairs, contacts (vf + ee
    rows of the substeps' detections, summed), the largest final-round active count, the
    collider's centre speed (and its largest surface speed from the spin), the cloth's mean and
    95th-percentile vertex speed at the frame's end, the rows of the frame's last detection
    between cloth primitives / with the collider; with --breakdown the detect / project / ccd
    CPU ms, the number of detections and the CCD hits / impact-zone vertices."""
    lines = []
    cols = ["frame"]
    for r in rows:
        tag = r["setting"]
        cols += [f"{tag} CPU ms", "strain %", "pairs", "contacts", "final active",
                 "ball v (spin) m/s", "cloth v mean / p95", "last rows self / ball"]
        if any("t_detect" in v for v in r["per_frame"]):
            cols += ["detect ms (calls)", "project ms", "ccd ms", "ccd hits / zone verts"]
        if any("relative_checks" in v for v in r["per_frame"]):
            cols += ["relative checks / re-detections (full) / flagged"]
    lines.append("| " + " | ".join(cols) + " |")
    lines.append("|" + "---|" * len(cols))
    n = max(len(r["per_frame"]) for r in rows)
    for f in range(n):
        cells = [str(f + 1)]
        for r in rows:
            pf = r["per_frame"]
            if f >= len(pf):
                cells += ["-"] * 8
                continue
            v = pf[f]
            cells += [f"{v.get('cpu_ms', float('nan')):.0f}", f"{100 * v['strain']:.1f}",
                      str(v["pairs"]),
                      f"{v.get('contacts_vf', 0) + v.get('contacts_ee', 0):.0f}",
                      f"{v.get('max_final_active', 0):.0f}",
                      f"{v.get('ball_speed', 0):.2f} ({v.get('ball_spin_speed', 0):.2f})",
                      f"{v.get('cloth_speed_mean', 0):.2f} / {v.get('cloth_speed_p95', 0):.2f}",
                      f"{v.get('last_vf_self', 0) + v.get('last_ee_self', 0)} / "
                      f"{v.get('last_vf_ball', 0) + v.get('last_ee_ball', 0)}"]
            if any("t_detect" in u for u in pf):
                cells += [f"{1e3 * v.get('t_detect', 0):.0f} ({v.get('n_detect', 0)})",
                          f"{1e3 * v.get('t_project', 0):.0f}",
                          f"{1e3 * v.get('t_ccd', 0):.0f}",
                          f"{v.get('ccd_hits', 0):.0f} / {v.get('ccd_zone_vertices', 0):.0f}"]
            if any("relative_checks" in u for u in pf):
                cells += [f"{v.get('relative_checks', 0):.0f} / "
                          f"{v.get('relative_detections', 0):.0f} "
                          f"({v.get('relative_full', 0):.0f}) / "
                          f"{v.get('relative_flagged', 0):.0f}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def rows_why(frames=(8, 9, 10, 11)) -> str:
    """``--rows-why``: why the moving scene's first detection has more cloth-cloth rows than the
    static one's. At the last substep of ``frames`` (both scenes, 2 x 15), the cloth's
    edge-edge candidates (before the filter) of its swept boxes over x -> x1 (as detected), of
    boxes at x alone and at x1 alone (no sweep), and of space-time boxes (the relative motion);
    the swept rows split by the larger sweep |x1 - x| of their two edges, by their relative
    motion (largest |dx_a - dx_b| over the four vertex pairs) and by whether an edge is within
    20 mm of the ball."""
    from lokigraph.behaviors.collision import broadphase as bp
    from lokigraph.behaviors.collision import contacts as C

    res = {}
    cur = {}

    def probe(tag, d, x, x1, frame):
        g = d.groups[0]
        infl = C._infl(g)
        E = g.edges[g.edge_elem == 0]  # the cloth's edges

        def count(a, b, st=False):
            lo, hi = bp.primitive_boxes(a, E, b, infl)
            se = (bp.spacetime_prim_boxes(a, E, b, infl, np.ones(len(E), bool),
                                          np.zeros(len(E), np.int64)) if st else None)
            return bp.column_query_self(lo, hi, E, st=se)

        sw = count(x, x1)
        nv = int((g.vert_elem == 0).sum())
        mv = np.linalg.norm(x1 - x, axis=1)
        em = np.maximum(mv[E[:, 0]], mv[E[:, 1]])
        pm = np.maximum(em[sw[:, 0]], em[sw[:, 1]]) * 1e3
        bv = g.verts[g.vert_elem[g.verts] == 1]
        cen = x[bv].mean(axis=0)
        near = np.linalg.norm(x - cen, axis=1) < np.linalg.norm(x[bv] - cen, axis=1).max() + 0.02
        en = near[E[:, 0]] | near[E[:, 1]]
        dd = x1 - x
        a, b = E[sw[:, 0]], E[sw[:, 1]]
        rel = np.max([np.linalg.norm(dd[a[:, i]] - dd[b[:, j]], axis=1)
                      for i in (0, 1) for j in (0, 1)], axis=0) * 1e3
        res[(tag, frame)] = [
            f"{len(sw) / nv:.0f}", f"{len(count(x, x)) / nv:.0f}", f"{len(count(x1, x1)) / nv:.0f}",
            f"{len(count(x, x1, True)) / nv:.0f}",
            f"{np.median(mv[:nv]) * 1e3:.1f} / {np.percentile(mv[:nv], 90) * 1e3:.1f}",
            f"{100 * np.mean(pm > 20):.0f} %",
            " / ".join(f"{100 * v:.0f}" for v in (np.mean(rel < 2), np.mean((rel >= 2) & (rel < 10)),
                                                 np.mean(rel >= 10))) + " %",
            f"{100 * np.mean(en[sw[:, 0]] | en[sw[:, 1]]):.0f} %"]

    orig = C.CollisionDetect.step

    def step(self, ctx, d):
        r = orig(self, ctx, d)
        if cur.get("frame") in frames and cur.get("sub") == 1:
            probe(cur["tag"], d, ctx.state.particle_q, d.x1, cur["frame"])
        cur["sub"] = cur.get("sub", 0) + 1
        return r

    C.CollisionDetect.step = step
    try:
        runs = [("static", LokiRun(ClothSphere(SCENES[128]), 2, 15)),
                ("moving", LokiRun(ClothSphere(MOVING), 2, 15))]
        for f in range(1, max(frames) + 1):
            for tag, r in runs:
                cur.update(tag=tag, frame=f, sub=0)
                r.step()
    finally:
        C.CollisionDetect.step = orig
    lines = ["| frame | scene | swept rows / cloth vertex | at x | at x1 | space-time | sweep mm "
             "p50 / p90 | swept rows with a sweep > 20 mm | relative motion < 2 / 2-10 / > 10 mm "
             "| with an edge near the ball |", "|" + "---|" * 10]
    for (tag, f), v in sorted(res.items(), key=lambda kv: (kv[0][1], kv[0][0] != "static")):
        lines.append(f"| {f} | {tag} | " + " | ".join(v) + " |")
    return "\n".join(lines)


def _flag_at(C, name: str):
    """(module, attribute) of a flag name: ``NAME`` in the contacts module ``C``,
    ``broadphase.NAME`` in the broad-phase module."""
    if name.startswith("broadphase."):
        from lokigraph.behaviors.collision import broadphase

        return broadphase, name.split(".", 1)[1]
    return C, name


def _flags(spec: str) -> dict:
    """``--moving-flag`` spec ``NAME`` (True) or ``NAME=VALUE[,NAME=VALUE...]`` (Python
    literals) -> contacts module globals (``broadphase.NAME``: the broad-phase module's)."""
    import ast

    out = {}
    for part in spec.split(","):
        k, _, v = part.partition("=")
        out[k] = ast.literal_eval(v) if v else True
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[64, 128], choices=SIZES,
                    help="cloth resolutions; with several and --stages, also the fitted "
                    "exponent p of CPU ms/frame ~ vertices^p over the --stage-frames")
    ap.add_argument("--frames", type=int, default=None, help="frames per run (default: scene's)")
    ap.add_argument("--cloth-thickness", type=float, default=None, metavar="M",
                    help="--sizes: the cloth's collider thickness [m] instead of the scenes' "
                    "2 mm (e.g. 0.001: a 2 mm contact distance, under the 2.8 mm from a vertex "
                    "to the nearest triangle without it at 256 x 256)")
    ap.add_argument("--loki", default=None, help="lokigraph settings SUBxITER[@THREADS]"
                    "[+NODE.PARAM=VALUE...],... (graph overrides, e.g. "
                    "2x15+collisions.final_rounds=1; default "
                    f"{','.join(f'{s}x{i}' for s, i in LOKI_SETTINGS)})")
    ap.add_argument("--newton", default=None, help="Style3D settings SUBxITER,... (default "
                    f"{','.join(f'{s}x{i}' for s, i in NEWTON_SETTINGS)}); 'none' to skip")
    ap.add_argument("--newton-et", type=float, default=1000.0,
                    help="Style3D membrane stiffness E t [N/m]")
    ap.add_argument("--newton-collide", choices=("frame", "substep"), default="frame",
                    help="run Newton's CollisionPipeline once per frame (as in its Style3D "
                         "example) or before every substep")
    ap.add_argument("--newton-margin", type=float, default=None,
                    help="Newton soft_contact_margin [m] (default: Newton's)")
    ap.add_argument("--moving", action="store_true",
                    help="lokigraph only: moving-collider scene vs static at 128x128")
    ap.add_argument("--moving-scenes", nargs="+", default=None, metavar="YAML",
                    help="with --moving: the moving scenes to run against the static one "
                         f"(default {MOVING.relative_to(ROOT)})")
    ap.add_argument("--moving-flag", nargs="+", default=None, metavar="NAME",
                    help="with --moving: the moving scenes again, each with the boolean "
                         "contacts.NAME set True around its steps only (e.g. "
                         "SPACETIME_PREDICTED; NAME=VALUE,NAME=VALUE sets those values), in "
                         "the same interleaved run")
    ap.add_argument("--all-flag", nargs="+", default=None, metavar="NAME",
                    help="with --moving: every scene (the static one too) again with the "
                         "contacts flags set as --moving-flag's, in the same interleaved run "
                         "(A/B of a flag that must leave the positions unchanged); with "
                         "--sizes: every lokigraph setting again with them, interleaved, "
                         "fitted apart")
    ap.add_argument("--breakdown", action="store_true",
                    help="time the collision functions per frame (detect, project, ccd; "
                         "see install_breakdown) and print a per-frame table")
    ap.add_argument("--stages", action="store_true",
                    help="CPU per collision stage (first detection, iterations, final rounds, "
                         "ccd) and part (boxes, broad, filters, pack, cull, passes) and rows per "
                         "cloth vertex per detection (see install_stages), per run; "
                         "--stage-frames A B: the frames averaged (default 2..N)")
    ap.add_argument("--stage-frames", type=int, nargs=2, default=None, metavar=("FIRST", "LAST"))
    ap.add_argument("--rows-vs-speed", action="store_true",
                    help="only: contact rows of one detection of the flat 128 x 128 cloth "
                         "translated rigidly at 0-4 m/s, swept vs space-time boxes (see "
                         "rows_vs_speed)")
    ap.add_argument("--rows-at-iterate", action="store_true",
                    help="only: on the moving scene, do the rows of the substep's first "
                         "detection (absolute swept, collider frame, space-time) hold the pairs "
                         "of the iterate the iterations end at (see rows_at_iterate)")
    ap.add_argument("--rows-why", action="store_true",
                    help="only: cloth-cloth edge-edge candidates of the first detection per "
                         "cloth vertex, static vs moving, swept / unswept / space-time boxes "
                         "and the swept rows by sweep, relative motion and nearness to the "
                         "ball (see rows_why; --frames N: frames 8..N, default 11)")
    ap.add_argument("--slack", type=float, default=0.005,
                    help="--rows-at-iterate: the extra inflation [m] of the slack rows")
    ap.add_argument("--out", default="bench_out/peer", help="output folder")
    args = ap.parse_args(argv)
    parse = lambda s: [tuple(int(v) for v in x.split("x")) for x in s.split(",")]  # noqa: E731
    loki = ([tuple(int(v) for v in x.split("+")[0].replace("@", "x").split("x"))
             for x in args.loki.split(",")] if args.loki else LOKI_SETTINGS)
    extra = ([dict(kv.split("=", 1) for kv in x.split("+")[1:]) for x in args.loki.split(",")]
             if args.loki else [{}] * len(loki))
    newt = [] if args.newton == "none" else (parse(args.newton) if args.newton
                                             else NEWTON_SETTINGS)
    out_dir = Path(args.out)
    t_start = time.perf_counter()
    if args.rows_vs_speed:
        print(rows_vs_speed())
        return []
    if args.rows_why:
        print(rows_why(tuple(range(8, (args.frames or 11) + 1))))
        return []
    if args.rows_at_iterate:
        print(rows_at_iterate(tuple(range(2, (args.frames or 14) + 1))
                              if args.frames and args.frames < 7 else (7, 9, 12, 14),
                              slack=args.slack))
        return []

    import numba

    versions = {"python": platform.python_version(), "numba": numba.__version__,
                "numba_threads": numba.config.NUMBA_NUM_THREADS,
                "numba_threading_layer": numba.config.THREADING_LAYER}
    newton = wp = None
    skipped = None
    if newt and not args.moving:
        try:
            newton, wp = import_newton()
            versions.update(newton=newton.__version__, warp=wp.__version__)
        except Exception as exc:  # noqa: BLE001
            skipped = (f"newton not importable ({type(exc).__name__}: {exc}); use the python of "
                       f"a venv with `pip install newton`")
            print(f"[peer] {skipped}", flush=True)

    all_rows = []
    if args.breakdown:
        install_breakdown()
    if args.moving:
        moving = [Path(p).resolve() for p in args.moving_scenes] if args.moving_scenes \
            else [MOVING]
        scenes = [ClothSphere(SCENES[128])] + [ClothSphere(p) for p in moving]
        frames = args.frames or scenes[0].frames
        runs = [LokiRun(sc, *st[:2], label=(" static" if sc.path == SCENES[128] else
                                            " moving" if sc.path == MOVING else
                                            f" {sc.path.stem}"),
                        threads=st[2] if len(st) > 2 else None, overrides=ov)
                for st, ov in zip(loki, extra) for sc in scenes]
        for name in args.moving_flag or ():  # the moving scenes again with a contacts flag on
            runs += [LokiRun(sc, *st[:2], label=f" {sc.path.stem} {name}",
                             threads=st[2] if len(st) > 2 else None, flags=_flags(name))
                     for st in loki for sc in scenes[1:]]
        for name in args.all_flag or ():  # every scene again with the flags set
            runs += [LokiRun(sc, *st[:2], label=(" static" if sc.path == SCENES[128] else
                                                 f" {sc.path.stem}") + f" {name}",
                             threads=st[2] if len(st) > 2 else None, flags=_flags(name))
                     for st in loki for sc in scenes]
        if args.stages:
            install_stages(len(scenes[0].cloth_q0))
        rows = run_interleaved(runs, frames)
        # the static run of each setting (its SUBxITER and graph overrides) is the base
        key = [str((run.setting.split(" ")[0], sorted(run.overrides.items())))
               for run in runs]
        for r, k in zip(rows, key):  # CPU per frame against the static scene, same setting
            base = next((b for b, kb in zip(rows, key) if kb == k
                         and b["scene"] == SCENES[128].name), None)
            if base and base.get("cpu_ms") and r.get("cpu_ms"):
                r["ratio"] = r["cpu_ms"] / base["cpu_ms"]
                r["ratio_mean"] = (np.mean([v["cpu_ms"] for v in r["per_frame"][1:]]) /
                                   np.mean([v["cpu_ms"] for v in base["per_frame"][1:]]))
        all_rows += rows
        print()
        print(per_frame_table(rows))
        if args.stages:
            sf = range(args.stage_frames[0], args.stage_frames[1] + 1) if args.stage_frames \
                else None
            print()
            print(stages_table(rows, len(scenes[0].cloth_q0), sf))
    else:
        if args.stages:
            install_stages(0)  # rows are counted per cloth vertex per size below
        fit = []
        for n in args.sizes:
            sc = ClothSphere(_scene_path(n, out_dir, args.cloth_thickness))
            if args.stages:
                install_stages.n_cloth[0] = len(sc.cloth_q0)
            frames = args.frames or sc.frames
            runs = [LokiRun(sc, *st[:2], threads=st[2] if len(st) > 2 else None, overrides=ov)
                    for st, ov in zip(loki, extra)]
            for name in args.all_flag or ():  # every setting again with the flags set
                runs += [LokiRun(sc, *st[:2], label=f" {name}",
                                 threads=st[2] if len(st) > 2 else None, overrides=ov,
                                 flags=_flags(name)) for st, ov in zip(loki, extra)]
            if newton is not None:
                for s, i in newt:
                    try:
                        runs.append(NewtonRun(newton, wp, sc, s, i, args.newton_et,
                                              args.newton_collide, args.newton_margin))
                    except Exception as exc:  # noqa: BLE001
                        all_rows.append({"framework": "newton", "resolution": n,
                                         "setting": f"{s}x{i}",
                                         "skipped": f"{type(exc).__name__}: {exc}"[:200]})
            elif skipped:
                all_rows.append({"framework": "newton", "resolution": n, "setting": "-",
                                 "skipped": skipped})
            rows = run_interleaved(runs, frames)
            best = min((r["cpu_ms"] for r in rows if r["framework"] == "newton"
                        and r.get("cpu_ms") is not None and r["finite"]), default=None)
            for r in rows:
                r["ratio"] = (r["cpu_ms"] / best) if best and r.get("cpu_ms") else None
            all_rows += rows
            if args.stages:
                loki_rows = [r for r in rows if r["framework"] == "lokigraph"]
                sf = range(args.stage_frames[0], args.stage_frames[1] + 1) \
                    if args.stage_frames else None
                print(f"\nstages at {n} x {n} ({len(sc.cloth_q0)} cloth vertices):")
                print(stages_table(loki_rows, len(sc.cloth_q0), sf), flush=True)
                for r in loki_rows:
                    pf = r["per_frame"][1:] if sf is None else [
                        r["per_frame"][f - 1] for f in sf if f <= len(r["per_frame"])]
                    fit.append((r["setting"], len(sc.cloth_q0),
                                float(np.mean([v["cpu_ms"] for v in pf]))))
        for setting in dict.fromkeys(f[0] for f in fit):
            pts = [(nv, ms) for st, nv, ms in fit if st == setting]
            if len(pts) > 1:
                p = np.polyfit(np.log([x[0] for x in pts]), np.log([x[1] for x in pts]), 1)[0]
                print(f"\n{setting}: CPU ms/frame (mean over the stage frames) "
                      + ", ".join(f"{nv} vertices {ms:.0f}" for nv, ms in pts)
                      + f"; fitted exponent p = {p:.2f} (least squares, log ms vs log vertices)")

    md = table(all_rows)
    if args.moving:
        md = md.replace("CPU / Style3D best", "CPU / static: median; mean")
    print()
    print(f"Versions: {versions}")
    print(md)
    print("\nCPU/wall ms per frame: medians over frames 2..N (frame 1 = warm-up); max strain, "
          "inside and pairs: max over all frames.")
    total = time.perf_counter() - t_start
    print(f"total {total:.0f} s")
    out_dir.mkdir(parents=True, exist_ok=True)
    name = "peer_collision_moving.json" if args.moving else "peer_collision.json"
    doc = {"versions": versions, "platform": platform.platform(), "argv": sys.argv[1:],
           "newton_et": args.newton_et, "rows": all_rows, "total_s": total}
    (out_dir / name).write_text(json.dumps(doc, indent=1, default=float))
    print(f"wrote {out_dir / name}")
    return all_rows


if __name__ == "__main__":
    main()
