"""``lokigraph bench``: run time per frame and error metrics over a grid of solver settings.

Time per frame is the median over measured frames after a warm-up frame (numba JIT compilation
falls in the warm-up frame, reported separately as ``warmup_s``); ``--repeats`` runs every
setting several times, interleaved, and takes the median over all measured frames. Error metrics:

- ``position_error`` / ``position_rms``: against the scene's ``reference`` (closed form, exact
  discrete solution, BVP solve or a stored tight run; see :mod:`lokigraph.bench.references`) at the
  end of the run, or against a tight run given with ``--reference KEY=V,...``;
- ``discrete_error`` (spring only): against the exact closed form of the discrete recurrence;
- ``max_strain``: the largest edge elongation of stretch constraints (their residual when
  inextensible);
- ``max_penetrations``: the largest per-frame count of intersecting primitive pairs;
- ``energy_change_J``: kinetic plus gravitational energy at the end minus at the start
  (elastic energy is not counted).

Results go to a table on stdout and bench.csv/bench.json/bench.png in the output folder, the
Pareto front (no other setting both faster and more accurate) marked.
``--scaling`` times a cloth drape from 32x32 to 256x256 and fits time ~ vertices^p.
"""

from __future__ import annotations

import csv
import itertools
import json
import time
import tracemalloc
from pathlib import Path

import numpy as np

from ..compile import compile_scene
from .references import evaluate, exact_discrete_spring
from ..run import Simulation
from ..scene import load_scene


def _apply(scene, setting: dict):
    spec = scene.spec
    ov = {k: dict(v) for k, v in spec.graph_overrides.items()}
    upd = {}
    for k, v in setting.items():
        if k == "substeps":
            upd["substeps"] = int(v)
        elif k == "iterations":  # Nucleus iterations (the implicit solver ignores them)
            ov.setdefault("nucleus_solver", {})["iterations"] = int(v)
        elif k == "solver":  # nucleus or implicit, on the same scene
            upd[k] = str(v)
        elif k == "graph":
            upd[k] = str(v)
        else:
            node, _, param = k.partition(".")
            if not param:
                raise ValueError(f"unknown sweep key {k!r} (use substeps, iterations, solver, "
                                 f"graph or node.param)")
            ov.setdefault(node, {})[param] = _num(v)
    upd["graph_overrides"] = ov
    scene.spec = spec.model_copy(update=upd)
    return scene


def _num(v):
    """A sweep value: numbers and booleans as given; text as an int, a float, true/false or
    itself (``int(0.97)`` would silently give 0 for a float passed from Python)."""
    if isinstance(v, (bool, int, float)):
        return v
    for t in (int, float):
        try:
            return t(v)
        except (TypeError, ValueError):
            pass
    return {"true": True, "false": False}.get(v, v)


def worst_strain(compiled, q) -> tuple[float | None, int]:
    """Largest edge elongation (L / L0 - 1) over the stretch constraints (cloth, tet and
    Gauss-Seidel rod edges) and the segments of directly solved rods, and a vertex of that edge;
    (None, -1) without any."""
    out, vertex = None, -1
    rows = [(b.data.idx, b.data.rest) for b in compiled.schedule.find("StretchConstraint")
            if b.data is not None]
    rows += [(b.data.idx, b.data.rest_len) for b in compiled.schedule.find("RodConstraint")
             if b.data is not None]
    for idx, rest in rows:
        if not len(idx):
            continue
        e = np.linalg.norm(q[idx[:, 1]] - q[idx[:, 0]], axis=1) / np.maximum(rest, 1e-300)
        j = int(e.argmax())
        if out is None or e[j] - 1 > out:
            out, vertex = float(e[j] - 1), int(idx[j, 0])
    return out, vertex


def max_strain(compiled, q) -> float:
    s, _ = worst_strain(compiled, q)
    return 0.0 if s is None else max(s, 0.0)


def _energy(compiled, state) -> float:
    m = compiled.model.particle_mass
    g = np.asarray(compiled.scene.spec.gravity, dtype=np.float64)
    ke = 0.5 * float((m * (state.particle_qd ** 2).sum(1)).sum())
    return ke - float((m * (state.particle_q @ g)).sum())


def bench_setting(path, setting: dict, frames: int | None = None,
                  reference: np.ndarray | None = None, repeats: int = 1,
                  use_reference: bool = True) -> tuple[dict, np.ndarray]:
    """Run one setting for ``frames`` frames (the first is the warm-up); returns (row, final q)."""
    scene = _apply(load_scene(path), setting)
    spec = scene.spec
    scene_frames = spec.frames.end - spec.frames.start
    if frames is None:
        frames = scene_frames
    ref_spec = spec.reference if reference is None and use_reference else None
    if ref_spec is not None and ref_spec.kind == "stored" and frames != scene_frames:
        raise ValueError(f"the stored reference is at frame {spec.frames.end}: run "
                         f"{scene_frames} frames, not {frames}")
    times, warm = [], []
    solver_stats: dict = {}
    for _ in range(repeats):
        compiled = compile_scene(scene)
        sim = Simulation(compiled)
        e0 = _energy(compiled, sim.state)
        t0 = time.perf_counter()
        st = sim.step_frame()
        warm.append(time.perf_counter() - t0)
        pen = st.get("penetrations", 0.0)
        for _ in range(frames - 1):
            t = time.perf_counter()
            st = sim.step_frame()
            times.append(time.perf_counter() - t)
            pen = max(pen, st.get("penetrations", 0.0))
            for key in SOLVER_STATS:  # implicit solver: Newton / CG iterations per frame
                if key in st:
                    solver_stats.setdefault(key, []).append(st[key])
    q = sim.state.particle_q
    row = dict(setting)
    row.update({
        "vertices": compiled.model.particle_count,
        "frames": frames,
        "warmup_s": warm[0],
        "ms_per_frame": 1e3 * float(np.median(times)) if times else float("nan"),
        "max_strain": max_strain(compiled, q),
        "energy_change_J": _energy(compiled, sim.state) - e0,
        "finite": bool(np.isfinite(q).all()),
        "max_penetrations": pen,
    })
    row.update({f"{k}_per_frame": float(np.mean(v)) for k, v in solver_stats.items()})
    if reference is not None:
        row.update(_position_errors(q, reference))
    elif ref_spec is not None:
        idx, x = evaluate(compiled, ref_spec, frames / spec.frames.fps)
        row.update(_position_errors(q[idx], x))
        if ref_spec.kind == "spring":
            idx, x = exact_discrete_spring(compiled, ref_spec, compiled.model.dt,
                                           frames * spec.substeps)
            row["discrete_error"] = _position_errors(q[idx], x)["position_error"]
    return row, q


#: per-frame solver statistics averaged into a bench row (``<key>_per_frame``) when present
SOLVER_STATS = ("newton_iterations", "cg_iterations")


def _position_errors(q, ref) -> dict:
    err = np.linalg.norm(q - ref, axis=1)
    return {"position_error": float(err.max()), "position_rms": float(np.sqrt((err ** 2).mean()))}


def make_reference(path, out: Path | None = None) -> Path:
    """Run the scene at its ``reference.settings`` and store the final positions (.npy)."""
    scene = load_scene(path)
    ref = scene.spec.reference
    if ref is None or ref.kind != "stored":
        raise ValueError(f"{path}: --make-reference needs `reference: {{kind: stored, file: ..., "
                         f"settings: ...}}`")
    _, q = bench_setting(path, dict(ref.settings), use_reference=False)
    dest = out or Path(scene.base_dir) / ref.file
    tmp = dest.with_suffix(".tmp.npy")
    np.save(tmp, q)
    tmp.replace(dest)
    return dest


def pareto(rows, err_key):
    """Rows on the time/error Pareto front (no other row is both faster and more accurate)."""
    front = []
    for r in rows:
        if not any(o is not r and o["ms_per_frame"] <= r["ms_per_frame"]
                   and o[err_key] <= r[err_key] and (o["ms_per_frame"] < r["ms_per_frame"]
                                                     or o[err_key] < r[err_key]) for o in rows):
            front.append(r)
    return front


def run_bench(path, sweeps: dict[str, list[str]], frames: int | None, out_dir: Path,
              reference_setting: dict | None = None, repeats: int = 1) -> list[dict]:
    keys = list(sweeps)
    ref = None
    if reference_setting:
        _, ref = bench_setting(path, reference_setting, frames)
    rows = []
    for combo in itertools.product(*[sweeps[k] for k in keys]):
        setting = dict(zip(keys, combo))
        row, _ = bench_setting(path, setting, frames, ref, repeats)
        rows.append(row)
    err_key = "position_error" if "position_error" in rows[0] else "max_strain"
    front = pareto(rows, err_key)
    for r in rows:
        r["pareto"] = r in front
    write_results(rows, out_dir, "bench", keys, err_key)
    return rows


def write_results(rows, out_dir: Path, stem: str, keys, err_key) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    fields = list(dict.fromkeys(k for r in rows for k in r))
    with open(out_dir / f"{stem}.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)
    (out_dir / f"{stem}.json").write_text(json.dumps(rows, indent=1))
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    fig, ax = plt.subplots(figsize=(5, 4))
    x = [r["ms_per_frame"] for r in rows]
    y = [max(r[err_key], 1e-16) for r in rows]
    ax.scatter(x, y, c="grey")
    f = sorted((r for r in rows if r.get("pareto")), key=lambda r: r["ms_per_frame"])
    if f:
        ax.plot([r["ms_per_frame"] for r in f], [max(r[err_key], 1e-16) for r in f], "r-o",
                label="Pareto")
        ax.legend()
    for r, xi, yi in zip(rows, x, y):
        ax.annotate(",".join(str(r[k]) for k in keys), (xi, yi), fontsize=6)
    ax.set_xlabel("ms per frame (median)")
    ax.set_ylabel(err_key)
    ax.set_xscale("log")
    ax.set_yscale("log")
    fig.tight_layout()
    fig.savefig(out_dir / f"{stem}.png", dpi=120)
    plt.close(fig)


SCALING_SCENE = """lokigraph: 1
frames: {{start: 1, end: {frames}, fps: 60}}
substeps: {substeps}
graph_overrides: {{nucleus_solver: {{iterations: {iterations}}}}}
elements:
  - name: cloth
    geometry: {{generator: grid, params: {{size: [1, 1], resolution: [{n}, {n}], plane: xz,
                center: [0, 1, 0]}}}}
    components:
      Dynamic: {{mass_density: 0.15, damping: 0.5}}
      DiscreteShell: {{shear_stiffness: 50.0, bend_resistance: 1.0e-6}}
      Pins: {{vertices: [0, {n}]}}
"""


def run_scaling(out_dir: Path, sizes=(32, 64, 128, 256), frames: int = 6, substeps: int = 2,
                iterations: int = 10) -> dict:
    """Time per frame of a pinned cloth drape against vertex count; fit t ~ n^p."""
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for n in sizes:
        p = out_dir / f"scaling_{n}.yaml"
        p.write_text(SCALING_SCENE.format(n=n, frames=frames + 1, substeps=substeps,
                                          iterations=iterations))
        row, _ = bench_setting(p, {}, frames)
        tracemalloc.start()
        sim = Simulation(compile_scene(load_scene(p)))
        sim.step_frame()
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        rows.append({"resolution": n, "vertices": row["vertices"],
                     "ms_per_frame": row["ms_per_frame"],
                     "us_per_vertex": 1e3 * row["ms_per_frame"] / row["vertices"],
                     "bytes_per_vertex": peak / row["vertices"], "warmup_s": row["warmup_s"]})
    v = np.log([r["vertices"] for r in rows])
    t = np.log([r["ms_per_frame"] for r in rows])
    slope = float(np.polyfit(v, t, 1)[0]) if len(rows) > 1 else float("nan")
    result = {"rows": rows, "exponent": slope, "substeps": substeps, "iterations": iterations}
    (out_dir / "scaling.json").write_text(json.dumps(result, indent=1))
    return result


def format_table(rows) -> str:
    cols = [k for k in rows[0] if k not in ("frames",)]
    cols += list(dict.fromkeys(k for r in rows for k in r if k not in cols and k != "frames"))
    w = {c: max(len(c), *(len(_fmt(r.get(c, ""))) for r in rows)) for c in cols}
    lines = [" | ".join(c.ljust(w[c]) for c in cols)]
    lines.append("-+-".join("-" * w[c] for c in cols))
    for r in rows:
        lines.append(" | ".join(_fmt(r.get(c, "")).ljust(w[c]) for c in cols))
    return "\n".join(lines)


def _fmt(v):
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)
