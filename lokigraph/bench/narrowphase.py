"""Benchmark of the narrow-phase batch kernels.

Run as ``python -m lokigraph.bench.narrowphase [--n 100000] [--repeats 7]``.

Input: the cloth-funnel CCD queries (frames 227 -> 228 of the Scalable-CCD sample data, see
``tests/data/ccd/README.md``), tiled to about ``n`` candidates of each kind. The queries index
the real mesh (9,450 vertices). Every kernel is called once to JIT-compile (or load from the
cache) before timing. The reported time is the median over ``repeats`` calls, divided by the
number of candidates. The positive fraction of the funnel data (27/92 VF, 107/263 EE) is much
higher than in a typical broad-phase candidate list, so these numbers are pessimistic for
CCD.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numba
import numpy as np

from lokigraph.behaviors.collision import narrowphase as nph

_DATA_NAME = "cloth_funnel_227_228_frames.npz"


def _find_data(path: str | None) -> Path:
    if path:
        return Path(path)
    here = Path(__file__).resolve()
    candidates = [
        here.parents[2] / "tests" / "data" / "ccd" / _DATA_NAME,  # source checkout
        Path.cwd() / "tests" / "data" / "ccd" / _DATA_NAME,
    ]
    for c in candidates:
        if c.exists():
            return c
    raise FileNotFoundError(
        f"{_DATA_NAME} not found (looked in {[str(c) for c in candidates]}); pass --data PATH")


def _median_time(fn, repeats: int) -> tuple[float, float]:
    """Median wall time and median process CPU time (all threads) of ``fn()``."""
    walls, cpus = [], []
    for _ in range(repeats):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fn()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return float(np.median(walls)), float(np.median(cpus))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100_000, help="candidates per kind (approx.)")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--data", default=None, help="path to cloth_funnel_227_228_frames.npz")
    ap.add_argument("--threads", type=int, default=0, help="numba threads (0 = numba default)")
    args = ap.parse_args(argv)
    if args.threads > 0:
        numba.set_num_threads(args.threads)

    z = np.load(_find_data(args.data))
    X0, X1, F = z["V0"], z["V1"], z["F"]
    vidx0, fidx0 = z["vf_vertex"], F[z["vf_face"]]
    ea0, eb0 = z["ee_edge_a"], z["ee_edge_b"]
    rv = -(-args.n // len(vidx0))
    re = -(-args.n // len(ea0))
    vidx = np.ascontiguousarray(np.tile(vidx0, rv))
    fidx = np.ascontiguousarray(np.tile(fidx0, (rv, 1)))
    ea = np.ascontiguousarray(np.tile(ea0, (re, 1)))
    eb = np.ascontiguousarray(np.tile(eb0, (re, 1)))
    nv, ne = len(vidx), len(ea)
    toi_v = np.empty(nv)
    toi_e = np.empty(ne)
    dist_v = np.empty(nv)
    bary_v = np.empty((nv, 3))
    dist_e = np.empty(ne)
    st_e = np.empty((ne, 2))

    rows = []

    def bench(name, n, fn):
        t0 = time.perf_counter()
        fn()  # JIT compile or cache load
        t_first = time.perf_counter() - t0
        wall, cpu = _median_time(fn, args.repeats)
        rows.append((name, n, t_first, wall, 1e9 * wall / n, 1e9 * cpu / n))

    for d in (0.0, 1e-3):
        bench(f"vf_ccd_batch  d={d:g}", nv,
              lambda d=d: nph.vf_ccd_batch(X0, X1, vidx, fidx, d, toi_out=toi_v))
        bench(f"ee_ccd_batch  d={d:g}", ne,
              lambda d=d: nph.ee_ccd_batch(X0, X1, ea, eb, d, toi_out=toi_e))
    bench("vf_proximity_batch", nv, lambda: nph.vf_proximity_batch(X0, vidx, fidx, dist_v, bary_v))
    bench("ee_proximity_batch", ne, lambda: nph.ee_proximity_batch(X0, ea, eb, dist_e, st_e))

    # sanity numbers for the table footer (d = 0)
    nph.vf_ccd_batch(X0, X1, vidx0, fidx0, 0.0, toi_out=(tv := np.empty(len(vidx0))))
    nph.ee_ccd_batch(X0, X1, ea0, eb0, 0.0, toi_out=(te := np.empty(len(ea0))))

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"narrow-phase benchmark: numba {numba.__version__}, threads={numba.get_num_threads()}, "
          f"cpu_count={os.cpu_count()}, load avg {load:.1f}, repeats={args.repeats} (median)")
    print("wall = elapsed time per query; cpu = process CPU time per query summed over threads "
          "(robust to other load on the machine)")
    print(f"{'kernel':<22} {'queries':>9} {'first call s':>13} {'median s':>10} "
          f"{'wall ns/q':>10} {'cpu ns/q':>10}")
    for name, n, t_first, t, ns, cns in rows:
        print(f"{name:<22} {n:>9d} {t_first:>13.3f} {t:>10.4f} {ns:>10.1f} {cns:>10.1f}")
    print(f"funnel d=0 hits: VF {int(np.sum(tv <= 1))}/{len(tv)} (truth {int(z['vf_truth'].sum())}), "
          f"EE {int(np.sum(te <= 1))}/{len(te)} (truth {int(z['ee_truth'].sum())})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
