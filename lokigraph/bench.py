"""``lokigraph bench``: run time per frame and error metrics over a grid of solver settings.

Time per frame is the median over measured frames after a warm-up frame (numba JIT compilation is
timed separately as ``warmup_s``). Error metrics that need no reference are always reported (max
edge strain of stretch constraints, max constraint residual, energy); a reference run can be given
for position error. Results go to a table on stdout and CSV/JSON in the output folder.
"""

from __future__ import annotations

import csv
import itertools
import json
import time
from pathlib import Path

import numpy as np

from .compile import compile_scene
from .run import Simulation
from .scene import load_scene


def _apply(scene, setting: dict):
    spec = scene.spec
    ov = {k: dict(v) for k, v in spec.graph_overrides.items()}
    upd = {}
    for k, v in setting.items():
        if k == "substeps":
            upd["substeps"] = int(v)
        elif k == "iterations":
            ov.setdefault("nucleus_solver", {})["iterations"] = int(v)
        elif k == "solver":
            upd["solver"] = str(v)
        else:
            node, _, param = k.partition(".")
            if not param:
                raise ValueError(f"unknown sweep key {k!r} (use substeps, iterations, solver or "
                                 f"node.param)")
            ov.setdefault(node, {})[param] = _num(v)
    upd["graph_overrides"] = ov
    scene.spec = spec.model_copy(update=upd)
    return scene


def _num(v):
    for t in (int, float):
        try:
            return t(v)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(v, v)


def max_strain(compiled, q) -> float:
    out = 0.0
    for b in compiled.schedule.find("StretchConstraint"):
        d = b.data
        L = np.linalg.norm(q[d.idx[:, 1]] - q[d.idx[:, 0]], axis=1)
        out = max(out, float((L / np.maximum(d.rest, 1e-300) - 1).max()))
    return out


def bench_setting(path, setting: dict, frames: int, reference: np.ndarray | None = None) -> dict:
    scene = _apply(load_scene(path), setting)
    compiled = compile_scene(scene)
    sim = Simulation(compiled)
    t0 = time.perf_counter()
    sim.step_frame()
    warm = time.perf_counter() - t0
    times = []
    pen = 0.0
    for _ in range(frames - 1):
        t = time.perf_counter()
        st = sim.step_frame()
        times.append(time.perf_counter() - t)
        pen = max(pen, st.get("penetrations", 0.0))
    q = sim.state.particle_q
    m = compiled.model.particle_mass
    row = dict(setting)
    row.update({
        "vertices": compiled.model.particle_count,
        "frames": frames,
        "warmup_s": warm,
        "ms_per_frame": 1e3 * float(np.median(times)) if times else float("nan"),
        "max_strain": max_strain(compiled, q),
        "kinetic_energy": float(0.5 * (m * (sim.state.particle_qd ** 2).sum(1)).sum()),
        "finite": bool(np.isfinite(q).all()),
        "max_penetrations": pen,
    })
    if reference is not None:
        row["position_error"] = float(np.abs(q - reference).max())
    return row, q


def pareto(rows, err_key):
    """Rows on the time/error Pareto front (no other row is both faster and more accurate)."""
    front = []
    for r in rows:
        if not any(o is not r and o["ms_per_frame"] <= r["ms_per_frame"]
                   and o[err_key] <= r[err_key] and (o["ms_per_frame"] < r["ms_per_frame"]
                                                     or o[err_key] < r[err_key]) for o in rows):
            front.append(r)
    return front


def run_bench(path, sweeps: dict[str, list[str]], frames: int, out_dir: Path,
              reference_setting: dict | None = None) -> list[dict]:
    keys = list(sweeps)
    ref = None
    if reference_setting:
        _, ref = bench_setting(path, reference_setting, frames)
    rows = []
    for combo in itertools.product(*[sweeps[k] for k in keys]):
        setting = dict(zip(keys, combo))
        row, _ = bench_setting(path, setting, frames, ref)
        rows.append(row)
    err_key = "position_error" if ref is not None else "max_strain"
    front = pareto(rows, err_key)
    for r in rows:
        r["pareto"] = r in front
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / "bench.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    (out_dir / "bench.json").write_text(json.dumps(rows, indent=1))
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(5, 4))
        ax.scatter([r["ms_per_frame"] for r in rows], [r[err_key] for r in rows], c="grey")
        f = sorted(front, key=lambda r: r["ms_per_frame"])
        ax.plot([r["ms_per_frame"] for r in f], [r[err_key] for r in f], "r-o", label="Pareto")
        for r in rows:
            ax.annotate(",".join(str(r[k]) for k in keys), (r["ms_per_frame"], r[err_key]),
                        fontsize=6)
        ax.set_xlabel("ms per frame (median)")
        ax.set_ylabel(err_key)
        ax.set_yscale("log")
        ax.legend()
        fig.tight_layout()
        fig.savefig(out_dir / "bench.png", dpi=120)
    except ImportError:
        pass
    return rows


def format_table(rows) -> str:
    cols = [k for k in rows[0] if k not in ("frames",)]
    w = {c: max(len(c), *(len(_fmt(r[c])) for r in rows)) for c in cols}
    lines = [" | ".join(c.ljust(w[c]) for c in cols)]
    lines.append("-+-".join("-" * w[c] for c in cols))
    for r in rows:
        lines.append(" | ".join(_fmt(r[c]).ljust(w[c]) for c in cols))
    return "\n".join(lines)


def _fmt(v):
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)
