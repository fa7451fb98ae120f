"""The global strain step's factorisations (issues #12, #13): SuperLU with a minimum-degree
ordering per system (``strain_limit.global_factor: superlu``) against QDLDL's LDL^T with an
AMD ordering per system (``qdldl``, behaviors/materials/sparse_ldl.py), on the systems a scene
factorises in one frame, each system timed with both in turn (CPU time), with the factors'
entry counts and the residual of one solve.

    NUMBA_NUM_THREADS=1 python graphs/bench/global_factor.py graphs/bench/cloth_sphere_128.yaml --frame 9
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--frame", type=int, default=9, help="the frame whose systems are timed")
    ap.add_argument("--max", type=int, default=60, help="at most this many systems")
    a = ap.parse_args(argv)

    import cloth_strain as cs
    from lokigraph.api import compile_file
    from lokigraph.behaviors.materials import strain_limit_global as G
    from lokigraph.behaviors.materials.sparse_ldl import LDLFactor
    from lokigraph.run import Simulation

    systems, now = [], [0]
    orig = G.GlobalStrainStep._factorise

    def grab(self, R, idx):
        if now[0] == a.frame and len(systems) < a.max:
            systems.append(self._principal(idx))
        return orig(self, R, idx)

    G.GlobalStrainStep._factorise = grab
    with tempfile.TemporaryDirectory() as tmp:
        scene = cs._variant(cs._scene_path(a.scene), cs._parse_set(["strain_limit.global_factor=qdldl"]),
                            Path(tmp))
        sim = Simulation(compile_file(scene))
        for f in range(1, a.frame + 1):
            now[0] = f
            sim.step_frame()
    G.GlobalStrainStep._factorise = orig
    if not systems:
        print("no systems factorised in that frame")
        return 1
    step = G.GlobalStrainStep(1, np.zeros((0, 2), np.int64), np.zeros(0), [])
    step.fast = True
    rows = []
    for M in systems:
        b = np.random.default_rng(0).random(M.shape[0])
        t0 = time.process_time()
        lu = step._splu(M)
        t1 = time.process_time()
        ld = LDLFactor(M)
        t2 = time.process_time()
        r_lu = np.linalg.norm(M @ lu.solve(b) - b) / np.linalg.norm(b)
        r_ld = np.linalg.norm(M @ ld.solve(b) - b) / np.linalg.norm(b)
        rows.append((M.shape[0], M.nnz, 1e3 * (t1 - t0), 1e3 * (t2 - t1),
                     lu.L.nnz + lu.U.nnz - M.shape[0], 2 * ld._s.factors()[0].nnz + M.shape[0], r_lu, r_ld))
    r = np.array(rows)
    print(f"{len(r)} systems of frame {a.frame} ({a.scene}), {int(r[:, 0].mean())} rows on "
          "average\n")
    print("| | SuperLU (MMD, fast) | QDLDL (AMD) | ratio |")
    print("|---|---|---|---|")
    print(f"| CPU ms per factorisation, mean | {r[:, 2].mean():.1f} | {r[:, 3].mean():.1f} | "
          f"{r[:, 3].mean() / r[:, 2].mean():.2f} |")
    print(f"| CPU ms, sum | {r[:, 2].sum():.0f} | {r[:, 3].sum():.0f} | "
          f"{r[:, 3].sum() / r[:, 2].sum():.2f} |")
    print(f"| factor entries (L + U, L + D + L^T), mean | {r[:, 4].mean():.0f} | "
          f"{r[:, 5].mean():.0f} | {r[:, 5].mean() / r[:, 4].mean():.2f} |")
    print(f"| worst relative residual of a solve | {r[:, 6].max():.1e} | {r[:, 7].max():.1e} "
          "| |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
