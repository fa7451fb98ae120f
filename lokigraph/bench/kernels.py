"""Benchmark of the Nucleus projection kernels: time per sweep, sequential vs coloured parallel.

Run as ``python -m lokigraph.bench.kernels [--sizes 64 128] [--repeats 200]``.
For every grid size (quads per side) it builds the cloth constraints (stretch on edges, shear on
triangle corners, bend on interior edges), colours them, perturbs the positions a little and
reports the median wall time of one sweep of each kernel after a warm-up (JIT compile and
caches). The machine load is printed with the table: the coloured parallel sweeps synchronise
threads once per colour and suffer most when other processes compete for the cores.
"""
from __future__ import annotations

import argparse
import os
import time

import numba
import numpy as np

from lokigraph.behaviors.materials import bend, shear, stretch
from lokigraph.behaviors import topology as T


def _cloth(n: int, seed: int = 0):
    x, tris = T.grid_mesh(n, n, 1.0, 1.0)
    w = np.ones(x.shape[0])
    out = {}
    for name, elems in (("stretch", T.triangle_edges(tris)),
                        ("shear", T.triangle_corner_triplets(tris)),
                        ("bend", T.bend_quads(tris))):
        perm, ptr = T.color_constraints(elems, w)
        out[name] = (np.ascontiguousarray(elems[perm]), ptr)
    rng = np.random.default_rng(seed)
    p = x + rng.normal(scale=0.05 / n, size=x.shape)
    return x, p, w, out


def _time(fn, repeats: int, warmup: int = 5):
    """(median, minimum) wall time [s] of one call after `warmup` calls."""
    for _ in range(warmup):
        fn()
    t = np.empty(repeats)
    for r in range(repeats):
        t0 = time.perf_counter()
        fn()
        t[r] = time.perf_counter() - t0
    return float(np.median(t)), float(np.min(t))


def bench(sizes=(64, 128), repeats: int = 200):
    """Return rows ``(n, kernel, constraint_count, colors, seq_ms, par_ms, seq_min_ms,
    par_min_ms)``: median and minimum times of one sweep [ms]."""
    rows = []
    h = 1.0 / 240.0
    for n in sizes:
        x, p0, w, sets = _cloth(n)
        edges, eptr = sets["stretch"]
        trip, tptr = sets["shear"]
        quads, qptr = sets["bend"]
        L = stretch.rest_lengths(x, edges)
        gamma = shear.rest_angles(x, trip)
        theta = bend.rest_dihedrals(x, quads)
        ne, nt, nq = len(L), len(gamma), len(theta)
        a_s, a_c = np.full(ne, 1e-7), np.full(ne, 1e-5)
        a_t = np.full(nt, 1e-4)
        a_q, drop = np.full(nq, 1e-2), np.full(nq, 0.5)
        cases = {
            "stretch": (ne, eptr, lambda f, q, lam: f(q, w, edges, L, a_s, a_c, lam, h, eptr),
                        stretch.project_stretch_seq, stretch.project_stretch),
            "shear": (nt, tptr, lambda f, q, lam: f(q, w, trip, gamma, a_t, lam, h, tptr),
                      shear.project_angle_seq, shear.project_angle),
            "bend": (nq, qptr, lambda f, q, lam: f(q, w, quads, theta, a_q, drop, lam, h, qptr),
                     bend.project_dihedral_seq, bend.project_dihedral),
        }
        for name, (m, ptr, call, fseq, fpar) in cases.items():
            med, mn = [], []
            for f in (fseq, fpar):
                q = p0.copy()
                lam = np.zeros(m)
                t_med, t_min = _time(lambda: call(f, q, lam), repeats)
                med.append(1e3 * t_med)
                mn.append(1e3 * t_min)
            rows.append((n, name, m, len(ptr) - 1, med[0], med[1], mn[0], mn[1]))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[64, 128],
                    help="grid sizes (quads per side)")
    ap.add_argument("--repeats", type=int, default=200, help="timed sweeps per kernel")
    args = ap.parse_args(argv)
    load0 = os.getloadavg()[0]
    rows = bench(tuple(args.sizes), args.repeats)
    load1 = os.getloadavg()[0]
    print(f"numba {numba.__version__}, threading layer {numba.threading_layer()}, "
          f"{numba.get_num_threads()} threads, {os.cpu_count()} cpus, "
          f"load average {load0:.2f} -> {load1:.2f}")
    print("| grid | kernel | constraints | colours | sequential ms (median / min) "
          "| coloured parallel ms (median / min) | speed-up (median) |")
    print("|---|---|---|---|---|---|---|")
    for n, name, m, nc, s, p, smin, pmin in rows:
        print(f"| {n}x{n} | {name} | {m} | {nc} | {s:.3f} / {smin:.3f} | {p:.3f} / {pmin:.3f} "
              f"| {s / p:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
