"""Threading settings of numba's parallel kernels, idle and under load.

Run::

    .venv/bin/python graphs/bench/threads.py [--scene graphs/bench/cloth_sphere_64.yaml]
        [--frames 5] [--from-frame 2] [--cores 0 1] [--repeats 2]
        [--variants passive workqueue]

Every variant runs the scene in a fresh process (threading layer and wait policy are fixed when
the OpenMP runtime starts), pinned to ``--cores`` (default: the first two cores this process may
use), first on otherwise idle cores, then with one CPU-bound process (``while 1: pass``, started
by this script, pinned to the last of those cores and killed afterwards). Per variant: median
wall and CPU ms per frame over frames ``--from-frame`` (default 2) .. N (the scene's
PenetrationCheck left out; the 64 x 64 drop lands around frame 7). Variants:

* ``passive``: lokigraph's default (numba's OpenMP layer, ``OMP_WAIT_POLICY=passive``);
* ``active``: the OpenMP layer spinning at barriers (numba's and OpenMP's own default);
* ``workqueue``: numba's workqueue layer;
* ``1 thread``: ``NUMBA_NUM_THREADS=1``.

Results are in ``graphs/bench/threads.md``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

CHILD = r"""
import sys, time, numpy as np
from lokigraph.compile import compile_scene
from lokigraph.scene import load_scene
from lokigraph.run import Simulation
import numba
sim = Simulation(compile_scene(load_scene(sys.argv[1])))
sim._steps = [b for b in sim._steps if type(b.behavior).__name__ != "PenetrationCheck"]
W, C = [], []
for f in range(int(sys.argv[2])):
    t, c = time.perf_counter(), time.process_time()
    sim.step_frame()
    W.append(time.perf_counter() - t); C.append(time.process_time() - c)
k = int(sys.argv[3]) - 1
print(f"RESULT {1e3 * np.median(W[k:]):.1f} {1e3 * np.median(C[k:]):.1f} "
      f"{numba.threading_layer()} {numba.get_num_threads()}")
"""

VARIANTS = {
    "passive": {"NUMBA_NUM_THREADS": "2"},
    "active": {"NUMBA_NUM_THREADS": "2", "OMP_WAIT_POLICY": "active"},
    "workqueue": {"NUMBA_NUM_THREADS": "2", "NUMBA_THREADING_LAYER": "workqueue"},
    "1 thread": {"NUMBA_NUM_THREADS": "1"},
}


def run_variant(name, scene, frames, cores, from_frame=2):
    env = {k: v for k, v in os.environ.items()
           if k not in ("OMP_WAIT_POLICY", "NUMBA_THREADING_LAYER", "NUMBA_NUM_THREADS")}
    env.update(VARIANTS[name])
    env["NUMBA_NUM_THREADS"] = str(min(int(env["NUMBA_NUM_THREADS"]), len(cores)))
    p = subprocess.run([sys.executable, "-P", "-c", CHILD, str(scene), str(frames),
                        str(from_frame)], env=env,
                       capture_output=True, text=True, cwd=ROOT,
                       preexec_fn=lambda: os.sched_setaffinity(0, cores))
    line = next((x for x in p.stdout.splitlines() if x.startswith("RESULT")), None)
    if line is None:
        raise RuntimeError(f"{name} failed:\n{p.stderr[-2000:]}")
    wall, cpu, layer, threads = line.split()[1:]
    return float(wall), float(cpu), layer, int(threads)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default=str(ROOT / "graphs" / "bench" / "cloth_sphere_64.yaml"))
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--from-frame", type=int, default=2,
                    help="first frame of the medians (the 64 x 64 drop lands around frame 7)")
    ap.add_argument("--cores", type=int, nargs="+", default=None)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS),
                    help="variants to run (default: all); '1 thread' is always run")
    args = ap.parse_args(argv)
    cores = args.cores or sorted(os.sched_getaffinity(0))[:2]
    names = [n for n in VARIANTS if n in args.variants or n == "1 thread"]
    run_variant("1 thread", args.scene, 2, cores, 1)  # warm the kernel cache
    rows = []
    for mode in ("idle", "load"):
        spinner = None
        if mode == "load":
            spinner = subprocess.Popen([sys.executable, "-c", "while 1: pass"],
                                       preexec_fn=lambda: os.sched_setaffinity(0, cores[-1:]))
            time.sleep(0.5)
        try:
            for rep in range(args.repeats):
                for name in names:
                    wall, cpu, layer, thr = run_variant(name, args.scene, args.frames, cores,
                                                        args.from_frame)
                    rows.append((mode, name, rep, wall, cpu, layer, thr))
                    print(f"[threads] {mode} {name}: wall {wall:.0f} ms, CPU {cpu:.0f} ms "
                          f"({layer}, {thr} threads)", flush=True)
        finally:
            if spinner is not None:
                spinner.kill()
                spinner.wait()
    print(f"\ncores {cores}; ms per frame, median over frames {args.from_frame}..{args.frames}")
    print("| machine | variant | wall ms/frame | CPU ms/frame | wall / 1 thread |")
    print("|---|---|---|---|---|")
    for mode in ("idle", "load"):
        one = [r[3] for r in rows if r[0] == mode and r[1] == "1 thread"]
        for name in names:
            w = [r[3] for r in rows if r[0] == mode and r[1] == name]
            c = [r[4] for r in rows if r[0] == mode and r[1] == name]
            print(f"| {mode} | {name} | {' / '.join(f'{x:.0f}' for x in w)} | "
                  f"{' / '.join(f'{x:.0f}' for x in c)} | {min(w) / min(one):.2f} |")


if __name__ == "__main__":
    main()
