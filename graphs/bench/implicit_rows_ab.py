"""The implicit solver's contact-row passes before / after a commit, interleaved in one process
(issue #11, speed): two simulations of the cloth-on-sphere drop (graphs/bench/implicit_drop.py's
scene at 1 substep), the "before" one running COMMIT's ``implicit/solver.py`` and
``implicit/contact.py`` (written next to them as ``_ab_solver.py`` / ``_ab_contact.py`` while the
script runs, so that their relative imports and numba's cache work; removed at exit), frames
interleaved ABBA, positions and velocities compared bitwise after every frame, CPU time
(``time.process_time``) and wall time per frame and of the phases of ``implicit_drop._timers``.

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/implicit_rows_ab.py 64 10 --ab 4c1e992

Run it twice: the first run compiles the "before" kernels (numba caches them); frame 6, the
first contact frame, also loads the collision kernels in whichever simulation runs first, so
the means over frames 7.. are the comparison.

Measured against 4c1e992 (commit ac3977d: the second lag at x^n through ``lag_rows_sel``,
start_at_rest's extension through ``extend_live`` with ``moved``, skipped for the static ball), 1 thread,
the shared 2-core machine at load 4-6, positions and velocities bitwise equal in every frame;
CPU ms per frame over frames 7..N, before / after (``lag``: the row lags and extensions):

    64 (14 frames)    total 3,188 / 3,137 (0.984), lag 327 / 275
    128 (10 frames)   total 17,908 / 17,462 (0.975), lag 4,520 / 3,565; frame 9 lag 7,626 / 5,962

What remains of ``lag`` is mostly ``extend_live``'s pass over every row in every Newton
iteration (13.1 M rows at frame 9 of the 128 x 128 drop, of which at most ~70 k live after the
first iteration: ~170 ms a pass, 22 passes a substep). Tried and not kept (exact, bitwise the
same rows, in a kernel-level A/B on the 64 x 64 drop's frames 6-11): a per-row certificate
from the per-vertex path length since the row's last test (the row skipped while its last gap
bound exceeds the path its vertices may have covered): it spared 50-66 % of the rows' bounds
but the pass cost the same (0.02-0.44 s per frame either way): the four path gathers and the
row's indices cost what the bound's gathers cost.
"""

from __future__ import annotations

import atexit
import importlib
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import implicit_drop as D  # noqa: E402
from lokigraph.api import compile_file  # noqa: E402
from lokigraph.behaviors.solvers.implicit import solver as S  # noqa: E402
from lokigraph.run import Simulation  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
PKG = ROOT / "behaviors" / "solvers" / "implicit"


def before_solver(commit):
    """COMMIT's ImplicitSolver class (its solver.py importing its contact.py)."""
    files = []
    for name in ("contact", "solver"):
        src = subprocess.run(["git", "-C", str(ROOT), "show",
                              f"{commit}:behaviors/solvers/implicit/{name}.py"],
                             capture_output=True, text=True, check=True).stdout
        src = src.replace("from .contact import", "from ._ab_contact import")
        f = PKG / f"_ab_{name}.py"
        if not f.exists() or f.read_text() != src:
            f.write_text(src)
        files.append(f)
    atexit.register(lambda: [f.unlink() for f in files if f.exists()])
    return importlib.import_module("lokigraph.behaviors.solvers.implicit._ab_solver").ImplicitSolver


def make(n, cls=None):
    import tempfile
    p = Path(tempfile.mkdtemp()) / f"cloth_sphere_{n}.yaml"
    p.write_text(D.scene_text(n, 1, {}))
    sim = Simulation(compile_file(p))
    acc = defaultdict(float)
    if cls is not None:
        sv = [b.behavior for b in sim.schedule.all() if isinstance(b.behavior, S.ImplicitSolver)][0]
        sv.__class__ = cls
        new, S.ImplicitSolver = S.ImplicitSolver, cls  # _timers looks for this class
        try:
            D._timers(sim, acc)
        finally:
            S.ImplicitSolver = new
    else:
        D._timers(sim, acc)
    return sim, acc


def main():
    args = sys.argv[1:]
    commit = args[args.index("--ab") + 1]
    args = [a for i, a in enumerate(args) if a != "--ab" and (i == 0 or args[i - 1] != "--ab")]
    n = int(args[0]) if args else 64
    frames = int(args[1]) if len(args) > 1 else 10
    old = before_solver(commit)
    sims = {"before": make(n, old), "after": make(n)}
    keys = ("detect", "assemble", "energy", "cg", "lag", "project")
    rec = {k: [] for k in sims}
    same = True
    print(f"cloth_sphere_{n}, 1 substep, before = {commit}, after = the tree; CPU ms per frame")
    for f in range(frames):
        order = ("before", "after") if f % 2 == 0 else ("after", "before")
        for k in order:
            sim, acc = sims[k]
            for a in list(acc):
                acc[a] = 0.0
            t0, w0 = time.process_time(), time.perf_counter()
            sim.step_frame()
            rec[k].append((time.process_time() - t0, time.perf_counter() - w0,
                           {a: acc.get(a, 0.0) for a in keys}))
        qa, qb = sims["before"][0].state, sims["after"][0].state
        eq = (np.array_equal(qa.particle_q, qb.particle_q)
              and np.array_equal(qa.particle_qd, qb.particle_qd))
        same &= eq
        ra, rb = rec["before"][-1], rec["after"][-1]
        print(f" frame {f + 1:3d} bitwise {'yes' if eq else 'NO '} | before {1e3 * ra[0]:8.0f} "
              f"(lag {1e3 * ra[2]['lag']:6.0f}) | after {1e3 * rb[0]:8.0f} "
              f"(lag {1e3 * rb[2]['lag']:6.0f})", flush=True)
    print(f"positions bitwise the same in every frame: {same}")
    for lo in (1, 6):
        if frames <= lo:
            continue
        print(f"mean over frames {lo + 1}..{frames} (CPU ms, wall ms, phases):")
        for k in sims:
            r = rec[k][lo:]
            print(f"  {k:6s} CPU {1e3 * np.mean([x[0] for x in r]):8.0f} wall "
                  f"{1e3 * np.mean([x[1] for x in r]):8.0f} | " + " ".join(
                      f"{a} {1e3 * np.mean([x[2][a] for x in r]):.0f}" for a in keys))
        ca = np.mean([x[0] for x in rec['after'][lo:]])
        cb = np.mean([x[0] for x in rec['before'][lo:]])
        print(f"  CPU ratio after / before {ca / cb:.3f}")


if __name__ == "__main__":
    main()
