"""Direct per-strand Rod solve (``Rod.solve: direct``, the default) against Gauss-Seidel
(``Rod.solve: gauss_seidel``): elastica error and hair strain with their cost, settings measured
interleaved in one run.

    .venv/bin/python graphs/bench/rod_direct.py elastica   # heavy cantilever, q L^3/EI = 3, 1.5
    .venv/bin/python graphs/bench/rod_direct.py hair       # hair_strands, hair_head_gusts, 200

Time per frame: the median over frames after the first (JIT) frame; elastica: wall (``lokigraph
bench``'s figure), hair: wall and CPU (``time.process_time``) of this process. On a shared
machine compare ratios, not absolutes.
"""

from __future__ import annotations

import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lokigraph.api import compile_file
from lokigraph.bench.sweep import bench_setting
from lokigraph.run import Simulation

HERE = Path(__file__).resolve().parent
EXAMPLES = HERE.parent / "examples"
TMP = Path(tempfile.mkdtemp(prefix="rod_direct_"))


def variant(path: Path, solve: str, rod_extra: str = "", overrides: str = "",
            text: str | None = None) -> Path:
    """A copy of a scene with ``Rod.solve`` (and extra Rod fields / graph overrides) set."""
    t = path.read_text() if text is None else text
    t = t.replace("Rod: {", f"Rod: {{solve: {solve}, {rod_extra}" if rod_extra
                  else f"Rod: {{solve: {solve}, ")
    if overrides:
        t = re.sub(r"\nsubsteps: (\d+)\n", rf"\nsubsteps: \1\ngraph_overrides: {overrides}\n", t)
    out = TMP / f"{path.stem}_{abs(hash((solve, rod_extra, overrides, text))) % 10**8}.yaml"
    out.write_text(t)
    return out


def elastica():
    print("| scene | solve | substeps x iterations | error [m] | error / L | ms/frame wall |")
    print("|---|---|---|---|---|---|")
    settings = [("direct", 4, 15, None), ("direct", 8, 15, None),
                ("gauss_seidel", 4, 15, None), ("gauss_seidel", 8, 15, None),
                ("gauss_seidel", 32, 15, None), ("gauss_seidel", 64, 15, None),
                ("gauss_seidel", 128, 4, "1.0"), ("gauss_seidel", 256, 4, "1.0")]
    for name in ("elastica.yaml", "elastica_1p5.yaml"):
        for solve, sub, it, bend_imp in settings:
            p = variant(HERE / name, solve)
            s = {"substeps": sub, "iterations": it}
            if bend_imp:
                s["bend.importance"] = bend_imp
            r, _ = bench_setting(p, s)
            tag = f"{sub} x {it}" + (f", bend importance {bend_imp}" if bend_imp else "")
            print(f"| {name} | {solve} | {tag} | {r['position_error']:.2e} | "
                  f"{r['position_error'] / 0.2 * 100:.2f} % | {r['ms_per_frame']:.2f} |",
                  flush=True)


def strain_run(path: Path, frames: int):
    c = compile_file(path)
    sim = Simulation(c)
    el = [e for e in c.scene.elements if "Rod" in e.components][0]
    e = el.geometry.edges + el.vertex_offset
    X = c.model.particle_rest
    L0 = np.linalg.norm(X[e[:, 1]] - X[e[:, 0]], axis=1)
    worst, wall, cpu = [], [], []
    for _ in range(frames):
        t, c0 = time.perf_counter(), time.process_time()
        sim.step_frame()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c0)
        q = sim.state.particle_q
        worst.append(np.abs(np.linalg.norm(q[e[:, 1]] - q[e[:, 0]], axis=1) / L0 - 1).max())
    return max(worst), np.median(wall[1:]) * 1e3, np.median(cpu[1:]) * 1e3


def hair():
    gusts = EXAMPLES / "hair_head_gusts.yaml"
    scenes = [("hair_strands (64 x 20)", EXAMPLES / "hair_strands.yaml", None, 47),
              ("hair_head_gusts (64 x 20)", gusts, None, 71),
              ("hair_head_gusts 200 strands", gusts,
               gusts.read_text().replace("count: [8, 8], spacing: 0.007",
                                         "count: [20, 10], spacing: 0.0035"), 71)]
    modes = [("direct (default)", "direct", "", ""),
             ("direct, rod importance 0.5", "direct", "", "{rod: {importance: 0.5}}"),
             ("gauss_seidel (+ tethers)", "gauss_seidel", "", ""),
             ("gauss_seidel + max_strain 0.01", "gauss_seidel", "max_strain: 0.01, ", "")]
    print("| scene | solve | max strain, all frames | ms/frame wall | ms/frame CPU |")
    print("|---|---|---|---|---|")
    for label, path, text, frames in scenes:
        for mlabel, solve, extra, ov in modes:
            p = variant(path, solve, extra, ov, text)
            s, w, c = strain_run(p, frames)
            print(f"| {label} | {mlabel} | {s * 100:.3f} % | {w:.1f} | {c:.1f} |", flush=True)


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "all"
    if what in ("elastica", "all"):
        elastica()
    if what in ("hair", "all"):
        hair()
