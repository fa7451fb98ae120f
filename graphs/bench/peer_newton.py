"""Peer benchmark: lokigraph against NVIDIA Newton's CPU cloth solvers on the same cloth drape.

Run (Newton lives in its own virtual environment, never imported by lokigraph)::

    python -m venv --system-site-packages .venv-peer && .venv-peer/bin/pip install newton
    .venv-peer/bin/python graphs/bench/peer_newton.py [--out DIR] [--quick]
    .venv-peer/bin/python graphs/bench/peer_newton.py --collision [peer_collision options]

``--collision`` runs the collision benchmark instead (cloth dropped on a sphere with
self-collision, lokigraph against SolverStyle3D; see ``graphs/bench/peer_collision.py``).

Prints a markdown table and writes ``peer_newton.json`` to ``--out`` (default
``bench_out/peer``). Without Newton (or with a solver that fails on CPU) the affected rows are
skipped with the reason; the lokigraph rows are always run.

What is compared
----------------
The scene is ``graphs/bench/drape_ref.yaml``: a 1 m x 1 m cloth of 32 x 32 quads (33 x 33
vertices, alternating diagonals) at y = 1 in the xz plane, pinned at vertices 0 and 32, gravity
-9.81 along y, 0.15 kg/m^2, no damping, E t = 2e6 Pa x 5e-4 m = 1000 N/m, nu = 0.3,
D = 1e-6 N m, 30 frames at 60 fps. Positions, triangles, lumped masses, pins and material
constants are all read from that file through lokigraph, and every Newton model is built with
``add_cloth_mesh`` on exactly these vertices and triangles (same vertex order), gravity -y.

For every setting (substeps per frame x solver iterations) of every framework the table gives the
median ms per frame over frames 2..30 (frame 1 is a warm-up, timed separately: it includes
numba / warp kernel compilation, or loading from the kernel caches when warm), the ratio to the
lokigraph 4x15 setting, the max and RMS over vertices of |q - q_ref| at t = 0.5 s, and whether
all positions stayed finite. The reference is ``graphs/bench/drape_ref.npy`` (lokigraph at very
tight settings); if it is missing a lokigraph stand-in at 32 substeps x 100 iterations is computed
(cached in the output folder) and flagged as such.

Material mapping (lokigraph -> Newton 1.8); the models are NOT identical
------------------------------------------------------------------------
lokigraph (DiscreteShell): XPBD edge springs k_e = E t A_e / L^2 (A_e: a third of the adjacent
triangle areas), corner-angle shear with G t, hinge bending k_theta = 3 D L^2 / (A1 + A2) on the
dihedral angle (discrete shells), float64.

Newton, per solver (mu = E t / (2 (1 + nu)) = 384.6 N/m, lambda = E t nu / (1 - nu^2) =
329.7 N/m, the plane-stress Lame constants of the membrane):

* SolverSemiImplicit (explicit symplectic Euler): stable Neo-Hookean triangles, whose
  ``tri_ka`` is the Neo-Hookean lambda, so tri_ke = mu, tri_ka = lambda + mu (same linearisation).
  Bending force is -ke L theta d with d = 2A grad(theta) (not an energy gradient in general; on
  this mesh both triangles of a hinge have the same area), so ke = k_theta / (L (A1 + A2)).
* SolverVBD: the same stable Neo-Hookean membrane but ``tri_ka`` is the Lame lambda (converted
  internally), so tri_ke = mu, tri_ka = lambda. Bending energy 1/2 ke L0 theta^2, so
  ke = k_theta / L0 = 3 D L / (A1 + A2) (the same hinge energy as lokigraph).
* SolverXPBD: no triangle (FEM) constraint; the membrane is one spring per mesh edge with
  lokigraph's stiffness E t A_e / L^2 (no shear term: softer in shear than lokigraph). Its
  bending constraint uses d = 2A grad(theta) as gradient, so ke = k_theta / (A1 + A2).
* SolverStyle3D (projective dynamics + PCG): Baraff-Witkin membrane with (weft, warp, shear)
  stiffness (E t, E t, G t) (no Poisson coupling), Bergou quadratic bending whose coefficient
  is D itself (3 D |e|^2 theta^2 / (A1 + A2) for small angles). Its velocity update multiplies
  by 0.998 every substep (built-in damping, absent from the scene).

All Newton runs are float32 on device "cpu" (warp runs CPU kernels serially), no damping, no
contacts (particle radius 0, SemiImplicit triangle contact and Style3D self-collision off). The
error of a Newton solver at its tightest setting measures mostly the model difference (the
"floor"), not the time-integration error. Two caveats seen on this scene: Newton's XPBD applies
its Jacobi spring corrections without relaxation, so at few substeps the light (1.5e-4 kg),
stiff springs diverge; at many substeps its per-substep corrections shrink to a few float32
ulps of the positions and the result drifts away again (the drift grows when the cloth is
moved away from the origin). Style3D's built-in 0.998 velocity factor per substep damps the
swing more the more substeps it takes.
"""

from __future__ import annotations

import argparse
import inspect
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

SCENE = ROOT / "graphs" / "bench" / "drape_ref.yaml"
REFERENCE = ROOT / "graphs" / "bench" / "drape_ref.npy"
STANDIN = {"substeps": 32, "iterations": 100}
BASELINE = {"substeps": 4, "iterations": 15}

# (substeps per frame, iterations); the last one of each solver is its tightest setting
LOKI_SETTINGS = [(2, 10), (4, 15), (8, 30)]
# (explicit SemiImplicit needs ~50+ substeps to be stable; Newton's XPBD is a Jacobi solve without
# relaxation for springs and needs many substeps before the light, stiff springs converge)
NEWTON_SETTINGS = {
    "SolverSemiImplicit": [(64, 1), (128, 1), (256, 1), (512, 1)],
    "SolverXPBD": [(4, 15), (32, 4), (64, 2), (128, 2), (256, 2)],
    "SolverVBD": [(4, 15), (8, 15), (16, 20)],
    "SolverStyle3D": [(4, 15), (8, 15), (16, 20)],
}
QUICK_SETTINGS = {"SolverSemiImplicit": [(64, 1)], "SolverXPBD": [(32, 4)],
                  "SolverVBD": [(4, 15)], "SolverStyle3D": [(4, 15)]}
DIVERGED_M = 10.0  # a vertex this far from its start after 0.5 s (free fall: 1.2 m) = diverged


# ------------------------------------------------------------------------------------ the scene

class Drape:
    """The shared scene, read from the YAML through lokigraph (float64)."""

    def __init__(self, path: Path = SCENE):
        from lokigraph.compile import compile_scene
        from lokigraph.scene import load_scene

        compiled = compile_scene(load_scene(path))
        m = compiled.model
        (el,) = m.elements
        shell, dyn, pins = (el.components[k] for k in ("DiscreteShell", "Dynamic", "Pins"))
        self.points = np.asarray(m.particle_q0, dtype=np.float64)
        self.triangles = np.asarray(el.geometry.triangles, dtype=np.int64)
        self.mass = np.asarray(m.particle_mass, dtype=np.float64)
        self.pins = [int(v) for v in pins.vertices]
        self.density = float(dyn.mass_density)
        self.gravity = tuple(float(g) for g in m.gravity)
        self.fps = float(m.fps)
        spec = compiled.scene.spec
        self.frames = int(spec.frames.end - spec.frames.start)
        self.Et = float(shell.youngs_modulus * shell.thickness)
        self.nu = float(shell.poisson_ratio)
        self.D = float(shell.bend_resistance)
        self.mu = self.Et / (2.0 * (1.0 + self.nu))
        self.lam = self.Et * self.nu / (1.0 - self.nu ** 2)
        self.path = path

    def tri_area(self, tris) -> np.ndarray:
        X = self.points
        t = np.asarray(tris)
        return 0.5 * np.linalg.norm(np.cross(X[t[:, 1]] - X[t[:, 0]], X[t[:, 2]] - X[t[:, 0]]),
                                    axis=1)

    def edges(self):
        """Unique mesh edges (E, 2) and their lumped area A_e (a third of adjacent triangles)."""
        t = self.triangles
        e = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
        edges, inv = np.unique(e, axis=0, return_inverse=True)
        area = np.tile(self.tri_area(t) / 3.0, 3)
        return edges, np.bincount(inv.ravel(), area, minlength=len(edges))

    def hinge_data(self, edge_indices):
        """For Newton edges (o0, o1, v0, v1): rest length L, A1 + A2, lokigraph k_theta."""
        ei = np.asarray(edge_indices, dtype=np.int64)
        X = self.points
        L = np.linalg.norm(X[ei[:, 3]] - X[ei[:, 2]], axis=1)
        inner = (ei[:, 0] >= 0) & (ei[:, 1] >= 0)
        A = np.zeros(len(ei))
        for side in (0, 1):
            o = np.where(inner, ei[:, side], ei[:, 2])
            A += 0.5 * np.linalg.norm(np.cross(X[ei[:, 2]] - X[o], X[ei[:, 3]] - X[o]), axis=1)
        A = np.maximum(A, 1e-300)
        k_theta = np.where(inner, 3.0 * self.D * L * L / A, 0.0)
        return L, A, k_theta


def errors(q, ref, q0) -> dict:
    """Max and RMS over vertices of |q - ref| [m], finiteness and a divergence flag."""
    q = np.asarray(q, dtype=np.float64)
    if not np.isfinite(q).all():
        return {"finite": False, "diverged": True, "max_error_m": float("nan"),
                "rms_error_m": float("nan")}
    d = np.linalg.norm(q - ref, axis=1)
    return {"finite": True,
            "diverged": bool(np.linalg.norm(q - q0, axis=1).max() > DIVERGED_M),
            "max_error_m": float(d.max()), "rms_error_m": float(np.sqrt((d ** 2).mean()))}


# ----------------------------------------------------------------------------------- lokigraph

def run_lokigraph(setting: dict, frames: int, ref=None):
    """One lokigraph setting via lokigraph.bench.sweep.bench_setting: (row, final positions)."""
    from lokigraph.bench.sweep import bench_setting

    params = inspect.signature(bench_setting).parameters
    kw = {"frames": frames}
    if "reference" in params:  # an explicit reference keeps bench_setting off the stored file
        kw["reference"] = ref if ref is not None else np.zeros((1, 3))
    row, q = bench_setting(str(SCENE), dict(setting), **kw)
    if row.get("frames", frames) != frames:
        raise RuntimeError(f"bench_setting ran {row.get('frames')} frames, wanted {frames}")
    return row, np.asarray(q, dtype=np.float64)


def load_reference(out_dir: Path, drape: Drape):
    """drape_ref.npy when present, else a cached or freshly computed lokigraph stand-in."""
    if REFERENCE.exists():
        ref = np.load(REFERENCE)
        src = f"{REFERENCE.relative_to(ROOT)}"
    else:
        cache = out_dir / f"drape_ref_standin_{STANDIN['substeps']}x{STANDIN['iterations']}.npy"
        if cache.exists():
            ref = np.load(cache)
        else:
            print(f"[peer] {REFERENCE.relative_to(ROOT)} is missing: computing a lokigraph "
                  f"stand-in at {STANDIN['substeps']}x{STANDIN['iterations']} ...", flush=True)
            _, ref = run_lokigraph(STANDIN, drape.frames)
            out_dir.mkdir(parents=True, exist_ok=True)
            np.save(cache, ref)
        src = (f"STAND-IN (lokigraph {STANDIN['substeps']}x{STANDIN['iterations']}, "
               f"{cache.relative_to(ROOT) if cache.is_relative_to(ROOT) else cache}): "
               f"{REFERENCE.name} was missing")
    ref = np.asarray(ref, dtype=np.float64)
    if ref.shape != drape.points.shape:
        raise ValueError(f"reference shape {ref.shape} != {drape.points.shape}")
    return ref, src


# -------------------------------------------------------------------------------------- Newton

def import_newton():
    """(newton, warp) or raise ImportError with a useful message."""
    import warp as wp

    wp.config.quiet = True
    import newton

    wp.init()
    return newton, wp


def build_newton(newton, wp, drape: Drape, solver: str):
    """A Newton model of the drape for one solver (see the module docstring for the mapping)."""
    b = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=drape.gravity)
    verts = [wp.vec3(*p) for p in drape.points]
    common = dict(pos=wp.vec3(0.0, 0.0, 0.0), rot=wp.quat_identity(), vel=wp.vec3(0.0, 0.0, 0.0),
                  vertices=verts, indices=drape.triangles.ravel().tolist(),
                  density=drape.density, tri_kd=0.0, edge_kd=0.0, particle_radius=0.0)
    if solver == "SolverStyle3D":
        from newton.solvers import style3d

        newton.solvers.SolverStyle3D.register_custom_attributes(b)
        b.default_edge_ke = drape.D  # Bergou bending coefficient = D (isotropic)
        # panel (rest) coordinates: the cloth's own (x, z), counter-clockwise for our triangles
        panel = [wp.vec2(float(p[0]), float(p[2])) for p in drape.points]
        style3d.add_cloth_mesh(b, **common, panel_verts=panel,
                               tri_aniso_ke=wp.vec3(drape.Et, drape.Et, drape.mu), tri_ka=0.0)
    else:
        tri_ka = {"SolverSemiImplicit": drape.lam + drape.mu, "SolverVBD": drape.lam}.get(solver,
                                                                                         0.0)
        tri_ke = drape.mu if solver != "SolverXPBD" else 0.0
        b.add_cloth_mesh(**common, scale=1.0, tri_ke=tri_ke, tri_ka=tri_ka, edge_ke=0.0)
        # per-hinge bending stiffness matching lokigraph's k_theta = 3 D L^2 / (A1 + A2)
        L, A, k_theta = drape.hinge_data(b.edge_indices)
        ke = {"SolverSemiImplicit": k_theta / (L * A), "SolverVBD": k_theta / L,
              "SolverXPBD": k_theta / A}[solver]
        b.edge_bending_properties = [(float(k), 0.0) for k in ke]
        if solver == "SolverXPBD":
            edges, Ae = drape.edges()
            L = np.linalg.norm(drape.points[edges[:, 1]] - drape.points[edges[:, 0]], axis=1)
            for (i, j), k in zip(edges, drape.Et * Ae / L ** 2):
                b.add_spring(int(i), int(j), float(k), 0.0, control=0.0)
    # exactly lokigraph's lumped masses (add_cloth_mesh computes the same) and pins
    if not np.allclose(b.particle_mass, drape.mass, rtol=1e-5, atol=0):
        raise RuntimeError("Newton's lumped masses differ from lokigraph's")
    b.particle_mass = [float(m) for m in drape.mass]
    inactive = ~int(newton.ParticleFlags.ACTIVE)
    for v in drape.pins:
        b.particle_mass[v] = 0.0
        b.particle_flags[v] = int(b.particle_flags[v]) & inactive
    if solver == "SolverVBD":
        b.color(include_bending=True)
    return b.finalize(device="cpu")


def make_solver(newton, model, solver: str, iterations: int):
    S = newton.solvers
    if solver == "SolverSemiImplicit":
        return S.SolverSemiImplicit(model, enable_tri_contact=False)  # brute-force O(N T)
    if solver == "SolverXPBD":
        return S.SolverXPBD(model, iterations=iterations)
    if solver == "SolverVBD":
        return S.SolverVBD(model, iterations=iterations)
    if solver == "SolverStyle3D":
        s = S.SolverStyle3D(model, config=S.SolverStyle3D.Config(iterations=iterations))
        s.collision = None  # the scene has no collisions
        return s
    raise ValueError(solver)


def _kernel_cache(wp) -> set:
    d = Path(wp.config.kernel_cache_dir or "")
    return set(p.name for p in d.iterdir()) if d.is_dir() else set()


def run_newton(newton, wp, drape: Drape, solver: str, substeps: int, iterations: int):
    """Build, warm up (frame 1) and time one Newton setting: (result dict, final positions)."""
    cache0 = _kernel_cache(wp)
    t0 = time.perf_counter()
    model = build_newton(newton, wp, drape, solver)
    sim = make_solver(newton, model, solver, iterations)
    s0, s1, ctrl = model.state(), model.state(), model.control()
    setup_s = time.perf_counter() - t0
    dt = 1.0 / (drape.fps * substeps)
    times = []
    for _ in range(drape.frames):
        t = time.perf_counter()
        for _ in range(substeps):
            s0.clear_forces()
            sim.step(s0, s1, ctrl, None, dt)
            s0, s1 = s1, s0
        q = s0.particle_q.numpy()  # synchronises (CPU) and is part of a frame's cost
        times.append(time.perf_counter() - t)
    compiled = sorted(_kernel_cache(wp) - cache0)
    return {"setup_s": setup_s, "warmup_s": times[0],
            "ms_per_frame": 1e3 * float(np.median(times[1:])),
            "warp_modules_compiled": compiled}, q.astype(np.float64)


# ------------------------------------------------------------------------------------- driver

def fmt(v, spec):
    return "n/a" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, spec)


def table(rows) -> str:
    head = ("| framework | solver | substeps x iters | ms/frame | time / loki 4x15 | "
            "max err [m] | RMS err [m] | finite | frame 1 [s] | setup [s] |")
    lines = [head, "|" + "---|" * 10]
    for r in rows:
        if r.get("skipped"):
            lines.append(f"| {r['framework']} | {r['solver']} | {r['setting']} | skipped: "
                         f"{r['skipped']} | | | | | | |")
            continue
        finite = ("NO" if not r["finite"] else "yes, DIVERGED" if r["diverged"] else "yes")
        lines.append(
            f"| {r['framework']} | {r['solver']} | {r['setting']} | {fmt(r['ms_per_frame'], '.1f')}"
            f" | {fmt(r['ratio'], '.2f')} | {fmt(r['max_error_m'], '.2e')} | "
            f"{fmt(r['rms_error_m'], '.2e')} | {finite} | {fmt(r['warmup_s'], '.1f')} | "
            f"{fmt(r.get('setup_s'), '.1f')} |")
    return "\n".join(lines)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else list(argv)
    if "--collision" in argv:  # the collision benchmark (graphs/bench/peer_collision.py)
        argv.remove("--collision")
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        import peer_collision

        return peer_collision.main(argv)
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="bench_out/peer", help="output folder for peer_newton.json")
    ap.add_argument("--quick", action="store_true", help="one setting per Newton solver")
    args = ap.parse_args(argv)
    out_dir = Path(args.out)
    if not out_dir.is_absolute():
        out_dir = Path.cwd() / out_dir
    t_start = time.perf_counter()

    drape = Drape()
    ref, ref_src = load_reference(out_dir, drape)
    print(f"[peer] reference: {ref_src}", flush=True)

    rows = []
    for sub, it in LOKI_SETTINGS:
        row, q = run_lokigraph({"substeps": sub, "iterations": it}, drape.frames, ref)
        rows.append({"framework": "lokigraph", "solver": "nucleus", "substeps": sub,
                     "iterations": it, "setting": f"{sub}x{it}", "warmup_s": row["warmup_s"],
                     "ms_per_frame": row["ms_per_frame"], **errors(q, ref, drape.points)})
        print(f"[peer] lokigraph {sub}x{it}: {row['ms_per_frame']:.1f} ms/frame", flush=True)
    base = next(r["ms_per_frame"] for r in rows
                if (r["substeps"], r["iterations"]) == tuple(BASELINE.values()))

    import numba

    versions = {"python": platform.python_version(), "numba": numba.__version__,
                "numba_threads": numba.config.NUMBA_NUM_THREADS}
    try:
        newton, wp = import_newton()
        versions.update(newton=newton.__version__, warp=wp.__version__)
    except Exception as exc:  # noqa: BLE001 - report any import failure
        newton = wp = None
        reason = (f"newton not importable ({type(exc).__name__}: {exc}); run with the python of "
                  f"a venv that has `pip install newton` (see the docstring)")
        print(f"[peer] {reason}", flush=True)
        rows.append({"framework": "newton", "solver": "all", "setting": "-", "skipped": reason})

    if newton is not None:
        settings = QUICK_SETTINGS if args.quick else NEWTON_SETTINGS
        for solver, grid in settings.items():
            if not hasattr(newton.solvers, solver):
                rows.append({"framework": "newton", "solver": solver, "setting": "-",
                             "skipped": f"not in newton {newton.__version__}"})
                continue
            for sub, it in grid:
                label = f"{sub}x{it}" if solver != "SolverSemiImplicit" else f"{sub}x-"
                try:
                    res, q = run_newton(newton, wp, drape, solver, sub, it)
                except Exception as exc:  # noqa: BLE001 - a solver that cannot run is reported
                    reason = f"{type(exc).__name__}: {exc}".splitlines()[0][:200]
                    print(f"[peer] newton {solver} {label} skipped: {reason}", flush=True)
                    rows.append({"framework": "newton", "solver": solver, "substeps": sub,
                                 "iterations": it, "setting": label, "skipped": reason})
                    break
                rows.append({"framework": "newton", "solver": solver, "substeps": sub,
                             "iterations": None if solver == "SolverSemiImplicit" else it,
                             "setting": label, **res, **errors(q, ref, drape.points)})
                print(f"[peer] newton {solver} {label}: {res['ms_per_frame']:.1f} ms/frame, "
                      f"warm-up {res['warmup_s']:.1f} s", flush=True)

    for r in rows:
        if not r.get("skipped"):
            r["ratio"] = r["ms_per_frame"] / base
    # model-difference floor: each Newton solver at its tightest (last) setting that ran sanely
    # (and, as tightest is not always most accurate, each solver's best setting)
    floor, best, compiled = {}, {}, {}
    keys = ("setting", "max_error_m", "rms_error_m")
    for r in rows:
        if r["framework"] == "newton" and not r.get("skipped"):
            compiled.setdefault(r["solver"], []).extend(r["warp_modules_compiled"])
            if r["finite"] and not r["diverged"]:
                floor[r["solver"]] = {k: r[k] for k in keys}
                if r["max_error_m"] < best.get(r["solver"], {}).get("max_error_m", np.inf):
                    best[r["solver"]] = {k: r[k] for k in keys}

    md = table(rows)
    print()
    print(f"Cloth drape {drape.points.shape[0]} vertices, {drape.frames} frames at "
          f"{drape.fps:g} fps; reference: {ref_src}")
    print(f"Versions: {versions}")
    print()
    print(md)
    print()
    print("Model-difference floor (each Newton solver at its tightest setting vs the reference):")
    if not floor:
        print("- (no Newton solver ran)")
    for s, f in floor.items():
        b = best[s]
        print(f"- {s} {f['setting']}: max {f['max_error_m']:.3e} m, RMS {f['rms_error_m']:.3e} m"
              f" (most accurate setting run: {b['setting']}, max {b['max_error_m']:.3e} m)")
    print("\nms/frame: median over frames 2..30. Frame 1 is the warm-up frame (numba / warp "
          "kernel compilation or cache loading); setup: Newton model build + solver init "
          "(n/a for lokigraph). Warp modules compiled in this run (cold kernel cache):")
    for s, mods in compiled.items():
        print(f"- {s}: {', '.join(mods) if mods else 'none (all cached)'}")
    total = time.perf_counter() - t_start
    print(f"\ntotal {total:.0f} s")

    out_dir.mkdir(parents=True, exist_ok=True)
    doc = {"scene": str(SCENE.relative_to(ROOT)), "reference": ref_src, "frames": drape.frames,
           "fps": drape.fps, "baseline": BASELINE, "versions": versions,
           "platform": platform.platform(), "material": {
               "Et_N_per_m": drape.Et, "nu": drape.nu, "D_Nm": drape.D,
               "mu_N_per_m": drape.mu, "lambda_N_per_m": drape.lam},
           "notes": "Newton: float32, device cpu, warp CPU kernels single-threaded; models "
                    "differ (see the script docstring for the mapping).",
           "rows": rows, "newton_floor": floor, "newton_best": best, "total_s": total}
    (out_dir / "peer_newton.json").write_text(json.dumps(doc, indent=1))
    print(f"wrote {out_dir / 'peer_newton.json'}")


if __name__ == "__main__":
    main()
