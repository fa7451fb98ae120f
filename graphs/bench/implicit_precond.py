"""What the implicit solver's block-Jacobi preconditioner gains (issue #11): CG iterations per
Newton iteration and CPU time per frame with ``preconditioner: none`` (plain CG),
``block_jacobi`` (the default) and ``amg``, interleaved frame by frame on the same scenes.

    python graphs/bench/implicit_precond.py [--frames 6] [--scenes drape_64 cloth_sphere_64 ...]
        [--preconditioners none block_jacobi amg amg_reuse direct]

Scenes are names under graphs/bench/ or graphs/examples/, run with ``solver: implicit`` at
their own substeps. Per scene and preconditioner: Newton iterations, CG iterations, CG per
Newton, CG iterations that hit the cap (``cg_iterations``), ms/frame CPU, worst CG residual.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from lokigraph.compile import compile_scene
from lokigraph.run import Simulation
from lokigraph.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
PRECONDITIONERS = ("none", "block_jacobi", "amg")


def step_counted(sim, r):
    """Step ``sim`` one frame and add its CPU time and the implicit solver's statistics to the
    accumulator ``r`` (keys cpu, newton, cg: sums; cg_max, res: maxima); returns the frame's
    statistics."""
    c0 = time.process_time()
    st = sim.step_frame()
    r["cpu"] += time.process_time() - c0
    r["newton"] += st.get("newton_iterations", 0)
    r["cg"] += st.get("cg_iterations", 0)
    r["cg_max"] = max(r["cg_max"], st.get("max_cg_iterations", 0))
    r["res"] = max(r["res"], st.get("max_cg_residual", 0.0))
    return st


def _find(name: str) -> Path:
    for d in ("bench", "examples"):
        p = ROOT / d / f"{name}.yaml"
        if p.exists():
            return p
    raise SystemExit(f"no scene {name!r} in graphs/bench or graphs/examples")


def _sim(path: Path, precond: str) -> Simulation:
    sc = load_scene(path)
    ov = {k: dict(v) for k, v in sc.spec.graph_overrides.items()}
    ov.setdefault("implicit_solver", {})["preconditioner"] = precond
    sc.spec = sc.spec.model_copy(update={"solver": "implicit", "graph_overrides": ov})
    return Simulation(compile_scene(sc))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--scenes", nargs="+", default=["drape_64", "cloth_sphere_32"])
    ap.add_argument("--preconditioners", nargs="+", default=list(PRECONDITIONERS),
                    choices=("none", "block_jacobi", "amg", "amg_reuse", "direct"))
    a = ap.parse_args(argv)
    pcs = a.preconditioners
    print(f"{'scene':18} {'preconditioner':14} {'Newton':>7} {'CG':>8} {'CG/Newton':>10} "
          f"{'max CG':>7} {'ms/frame CPU':>13} {'max res':>9}")
    for name in a.scenes:
        path = _find(name)
        runs = {p: _sim(path, p) for p in pcs}
        acc = {p: {"newton": 0.0, "cg": 0.0, "cg_max": 0.0, "cpu": 0.0, "res": 0.0}
               for p in pcs}
        for p, sim in runs.items():  # JIT warm-up frame, not counted
            sim.step_frame()
        for _ in range(a.frames):
            for p, sim in runs.items():
                step_counted(sim, acc[p])
        for p in pcs:
            r = acc[p]
            print(f"{name:18} {p:14} {r['newton']:7.0f} {r['cg']:8.0f} "
                  f"{r['cg'] / max(r['newton'], 1):10.1f} {r['cg_max']:7.0f} "
                  f"{1e3 * r['cpu'] / a.frames:13.0f} {r['res']:9.1e}")


if __name__ == "__main__":
    main()
