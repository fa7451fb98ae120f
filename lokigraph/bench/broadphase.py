"""Broad-phase benchmark: build, refit and self-collision queries on cloth-like meshes.

Run ``python -m lokigraph.bench.broadphase [--sizes 10000 50000 200000]
[--repeats 5]``.

Scene: an N x N grid sheet (about 2 N^2 triangles, unit width) rolled into an Archimedean spiral
whose layers are half an edge length apart, with a small wave across the width, so most of the cloth
has a neighbouring layer within reach (real near contacts). One step moves every vertex by
at most about 0.15 edge lengths (the roll tightens and twists a little). Thickness 0.1 edge length per
vertex (contact distance 0.2 edge length), swept boxes over the step.

Timed, each as the median over ``repeats`` runs after a JIT warm-up run:

* build: vertex, edge and triangle boxes plus the three BVH builds;
* refit: new swept boxes for the next step plus the three in-place refits;
* query: self vertex-triangle (:func:`query_self_vf`) plus self edge-edge (:func:`query_self_ee`) on
  the refit trees, output into reused :class:`PairBuffer`\\ s (so every timed query is the
  single-pass traversal: the warm-up run sized the buffers' scratch);
* refit+query: the per-substep cost of detection with trees kept between substeps;
* sorted column grid: the same queries without trees (:func:`column_query_pairs`,
  :func:`column_query_self` on the boxes of the next step, into reused buffers), timed in the
  same runs, interleaved with the BVH's; its pair counts must equal the BVH's. "boxes" is the
  box computation alone (the grid has no tree to refit), compared with the BVH's refit;
  "z-sort" the Morton ranks and the Z-order sort (:func:`zsort_pairs`) of both pair sets that
  the contacts add to the grid's candidates (``contacts.GRID_ORDER``), timed apart.

``--ab-grid "COLUMN_CELL=1.0"``: instead, the sorted column grid's
boxes+query with those settings of the broad phase ("A") against the defaults ("B"), each of
``repeats`` rounds running both in alternating order (ABBA), so machine load hits both alike:
median CPU (process time, all threads) and wall ms of each, the median of the per-round CPU
and wall ratios B / A, and whether both give the same candidate sets (and the same rows in the same order).

``--ab-module before.py``: as ``--ab-grid``, with "A" the broad-phase module in that file
(another version, e.g. ``git show REV:behaviors/collision/broadphase.py > before.py``) imported
apart, its own kernels on the same boxes.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lokigraph.behaviors.collision import broadphase as bp


def rolled_sheet(n: int, t: float = 0.0):
    """Vertices (n*n, 3) and triangles of a unit sheet rolled into a spiral; ``t`` animates it."""
    h = 1.0 / (n - 1)
    gap = 0.5 * h
    # arc-length parameterisation of r(theta) = 0.06 + gap * theta / (2 pi) at t = 0
    theta = np.linspace(0.0, 200.0, 400001)
    r = 0.06 + gap * theta / (2 * np.pi)
    ds = np.sqrt(r**2 + (gap / (2 * np.pi)) ** 2)
    s = np.concatenate([[0.0], np.cumsum(0.5 * (ds[1:] + ds[:-1]) * np.diff(theta))])
    su = np.linspace(0.0, 1.0, n)
    th = np.interp(su, s, theta)
    r0 = 0.06 - 0.1 * h * t  # the roll tightens by 0.1 edge length per step
    rr = r0 + gap * th / (2 * np.pi)
    v = np.linspace(0.0, 1.0, n)
    TH, VV = np.meshgrid(th, v, indexing="ij")
    RR, _ = np.meshgrid(rr, v, indexing="ij")
    twist = (0.1 * h / 0.06) * t * VV  # and twists by up to about 0.1 edge length per step
    wave = 0.3 * gap * np.sin(2 * np.pi * 3 * VV + TH)
    X = np.stack([(RR + wave) * np.cos(TH + twist), VV, (RR + wave) * np.sin(TH + twist)], axis=-1)
    X = X.reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    b = a + n
    F = np.concatenate([np.stack([a, b, a + 1], 1), np.stack([a + 1, b, b + 1], 1)]).astype(np.int64)
    return X, F, h


def _sheet(n_tri: int):
    """The rolled sheet of about ``n_tri`` triangles at steps 0, 1 and 2, its triangles, edge
    length, edges, vertex indices, box thickness, and arrays for the vertex, edge and triangle
    boxes (lo, hi)."""
    n = int(round(np.sqrt(n_tri / 2.0))) + 1
    X0, F, h = rolled_sheet(n, 0.0)
    X1, _, _ = rolled_sheet(n, 1.0)
    X2, _, _ = rolled_sheet(n, 2.0)
    E = bp.mesh_edges(F)
    nv = X0.shape[0]
    boxes = tuple(np.empty((m, 3)) for m in (nv, nv, len(E), len(E), len(F), len(F)))
    return (X0, X1, X2), F, h, E, np.arange(nv, dtype=np.int64), np.full(nv, 0.1 * h), boxes


def _boxes(Xa, Xb, verts, E, F, thick, boxes):
    """The vertex, edge and triangle boxes of the motion Xa -> Xb into ``boxes``."""
    lo_v, hi_v, lo_e, hi_e, lo_f, hi_f = boxes
    bp.primitive_boxes(Xa, verts, Xb, thick, lo_v, hi_v)
    bp.primitive_boxes(Xa, E, Xb, thick, lo_e, hi_e)
    bp.primitive_boxes(Xa, F, Xb, thick, lo_f, hi_f)


def _grid_pairs(verts, E, F, boxes, buf_vf, buf_ee):
    """The column grid's self VF and EE candidates of ``boxes``."""
    return _vf_ee(bp, verts, E, F, boxes, buf_vf, buf_ee)


def _vf_ee(m, verts, E, F, boxes, buf_vf, buf_ee):
    """Both queries of the broad-phase module ``m``: side by side (``column_queries``) where it
    has them, else one after the other."""
    lo_v, hi_v, lo_e, hi_e, lo_f, hi_f = boxes
    vf_q = (m.column_query_pairs, (lo_v, hi_v, lo_f, hi_f, verts, F), {"out": buf_vf})
    ee_q = (m.column_query_self, (lo_e, hi_e, E), {"out": buf_ee})
    if hasattr(m, "column_queries"):
        return tuple(m.column_queries(vf_q, ee_q))
    return tuple(fn(*a, **k) for fn, a, k in (vf_q, ee_q))


def bench_one(n_tri: int, repeats: int):
    (X0, X1, X2), F, h, E, verts, thick, boxes = _sheet(n_tri)
    nv = len(verts)
    step_move = float(np.max(np.linalg.norm(X1 - X0, axis=1)) / h)
    lo_v, hi_v, lo_e, hi_e, lo_f, hi_f = boxes
    buf_vf, buf_ee = bp.PairBuffer(), bp.PairBuffer()

    def build():
        _boxes(X0, X1, verts, E, F, thick, boxes)
        return bp.build_bvh(lo_v, hi_v), bp.build_bvh(lo_e, hi_e), bp.build_bvh(lo_f, hi_f)

    def refit(trees):
        _boxes(X1, X2, verts, E, F, thick, boxes)
        bp.refit_bvh(trees[0], lo_v, hi_v)
        bp.refit_bvh(trees[1], lo_e, hi_e)
        bp.refit_bvh(trees[2], lo_f, hi_f)

    def query(trees):
        vf = bp.query_self_vf(trees[0], trees[2], F, out=buf_vf)
        ee = bp.query_self_ee(trees[1], E, out=buf_ee)
        return vf.shape[0], ee.shape[0]

    col_vf, col_ee = bp.PairBuffer(), bp.PairBuffer()

    def col_boxes():
        _boxes(X1, X2, verts, E, F, thick, boxes)

    def col_query():
        vf, ee = _grid_pairs(verts, E, F, boxes, col_vf, col_ee)
        return vf.shape[0], ee.shape[0]

    rank_v, rank_e, rank_f = (np.empty(len(a), np.int64) for a in (verts, E, F))

    def col_sort():
        # the contacts' order of the grid's candidates (contacts.GRID_ORDER "zorder")
        bp.zsort_pairs(col_vf.data[:col_counts[0]], bp.morton_rank(lo_v, hi_v, rank_v),
                       bp.morton_rank(lo_f, hi_f, rank_f), False, col_vf)
        bp.zsort_pairs(col_ee.data[:col_counts[1]], bp.morton_rank(lo_e, hi_e, rank_e),
                       rank_e, True, col_ee)

    tb, tr, tq, tcb, tcq, cpu_bvh, cpu_col = [], [], [], [], [], [], []
    tcs, cpu_sort = [], []
    counts = col_counts = None
    for rep in range(repeats + 1):  # run 0 is the JIT warm-up; BVH and columns interleaved
        t0 = time.perf_counter()
        trees = build()
        t1 = time.perf_counter()
        c1 = time.process_time()
        refit(trees)
        t2 = time.perf_counter()
        counts = query(trees)
        t3 = time.perf_counter()
        c2 = time.process_time()
        col_boxes()
        t4 = time.perf_counter()
        col_counts = col_query()
        t5 = time.perf_counter()
        c3 = time.process_time()
        col_sort()
        t6 = time.perf_counter()
        c4 = time.process_time()
        if rep:
            tb.append(t1 - t0)
            tr.append(t2 - t1)
            tq.append(t3 - t2)
            tcb.append(t4 - t3)
            tcq.append(t5 - t4)
            cpu_bvh.append(c2 - c1)
            cpu_col.append(c3 - c2)
            tcs.append(t6 - t5)
            cpu_sort.append(c4 - c3)
    if col_counts != counts:
        raise RuntimeError(f"column grid found {col_counts} pairs, the BVH {counts}")
    trees = build()
    cost_build = bp.bvh_cost(trees[2])
    refit(trees)
    cost_refit = bp.bvh_cost(trees[2])
    return dict(tris=len(F), verts=nv, edges=len(E), build=1e3 * np.median(tb),
                refit=1e3 * np.median(tr), query=1e3 * np.median(tq), vf=counts[0], ee=counts[1],
                move=step_move, cost=cost_refit / cost_build, col_boxes=1e3 * np.median(tcb),
                col_query=1e3 * np.median(tcq), cpu_bvh=1e3 * np.median(cpu_bvh),
                cpu_col=1e3 * np.median(cpu_col), col_sort=1e3 * np.median(tcs),
                cpu_sort=1e3 * np.median(cpu_sort))


def _load_module(path: str):
    """The broad-phase module in the file ``path`` (another version of it, e.g. from
    ``git show REV:behaviors/collision/broadphase.py > before.py``), imported apart."""
    import importlib.util

    import sys

    spec = importlib.util.spec_from_file_location("lokigraph_broadphase_ab", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # importable by name: numba's cached kernels refer to it
    spec.loader.exec_module(mod)
    return mod


def ab_grid(n_tri: int, repeats: int, settings: str = "", module: str = ""):
    """The column grid's boxes+query with the broad-phase ``settings`` ("NAME=value,...", as
    "A") or with the broad-phase module in the file ``module`` (as "A"), against the defaults
    ("B"), interleaved; see the module docstring."""
    (_, X1, X2), F, _, E, verts, thick, boxes = _sheet(n_tri)
    mod_a = _load_module(module) if module else bp
    alt = {}
    for kv in (settings.split(",") if settings else []):
        k, v = (t.strip() for t in kv.split("="))
        cur = getattr(bp, k)
        alt[k] = v == "True" if isinstance(cur, bool) else type(cur)(float(v))
    default = {k: getattr(bp, k) for k in alt}
    bufs = {"A": (mod_a.PairBuffer(), mod_a.PairBuffer()), "B": (bp.PairBuffer(), bp.PairBuffer())}
    cpu = {"A": [], "B": []}
    wall = {"A": [], "B": []}
    sets = {}
    rows = {}

    def run(a):
        for k in alt:
            setattr(bp, k, alt[k] if a == "A" else default[k])
        m = mod_a if a == "A" else bp
        lo_v, hi_v, lo_e, hi_e, lo_f, hi_f = boxes
        w0, c0 = time.perf_counter(), time.process_time()
        m.primitive_boxes(X1, verts, X2, thick, lo_v, hi_v)
        m.primitive_boxes(X1, E, X2, thick, lo_e, hi_e)
        m.primitive_boxes(X1, F, X2, thick, lo_f, hi_f)
        vf, ee = _vf_ee(m, verts, E, F, boxes, bufs[a][0], bufs[a][1])
        return time.process_time() - c0, time.perf_counter() - w0, vf, ee

    try:
        for rep in range(repeats + 2):  # two warm-up rounds (JIT, buffers)
            for a in ("AB" if rep % 2 == 0 else "BA"):
                c, w, vf, ee = run(a)
                if rep >= 2:
                    cpu[a].append(c)
                    wall[a].append(w)
                if rep == 1:
                    sets[a] = (set(map(tuple, vf.tolist())), set(map(tuple, ee.tolist())))
                    rows[a] = (vf.copy(), ee.copy())
    finally:
        for k, v in default.items():
            setattr(bp, k, v)
    ca, cb = np.array(cpu["A"]), np.array(cpu["B"])
    wa, wb = np.array(wall["A"]), np.array(wall["B"])
    same_rows = all(np.array_equal(x, y) for x, y in zip(rows["A"], rows["B"]))
    return dict(tris=len(F), cpu_a=1e3 * np.median(ca), cpu_b=1e3 * np.median(cb),
                wall_a=1e3 * np.median(wa), wall_b=1e3 * np.median(wb),
                cpu_ratio=float(np.median(cb / ca)), wall_ratio=float(np.median(wb / wa)),
                same=sets["A"] == sets["B"], same_rows=same_rows, vf=len(sets["B"][0]),
                ee=len(sets["B"][1]))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10_000, 50_000, 200_000],
                    help="approximate triangle counts")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--ab-grid", default="", metavar="NAME=VALUE,...",
                    help="the column grid with these broad-phase settings against the defaults, "
                    "interleaved (see the module docstring)")
    ap.add_argument("--ab-module", default="", metavar="FILE",
                    help="the column grid of the broad-phase module in FILE (another version) "
                    "against this one's, interleaved (see the module docstring)")
    args = ap.parse_args(argv)
    try:
        import numba

        threads = numba.get_num_threads()
    except Exception:  # pragma: no cover
        threads = -1
    if args.ab_grid or args.ab_module:
        what = args.ab_grid or args.ab_module
        print(f"sorted column grid, boxes+query (rolled sheet, self VF + EE), numba threads = "
              f"{threads}: A = {what}, B = defaults, {args.repeats} interleaved rounds")
        hdr = (f"{'triangles':>10} {'CPU ms A':>9} {'CPU ms B':>9} {'CPU B/A':>8} "
               f"{'wall ms A':>10} {'wall ms B':>10} {'wall B/A':>9} {'same sets':>10} "
               f"{'same rows':>10}")
        print(hdr)
        print("-" * len(hdr))
        for s in args.sizes:
            r = ab_grid(s, args.repeats, args.ab_grid, args.ab_module)
            print(f"{r['tris']:>10d} {r['cpu_a']:>9.2f} {r['cpu_b']:>9.2f} {r['cpu_ratio']:>8.3f} "
                  f"{r['wall_a']:>10.2f} {r['wall_b']:>10.2f} {r['wall_ratio']:>9.3f} "
                  f"{str(r['same']):>10} {str(r['same_rows']):>10}")
        print("(median over the rounds; ratios: median of the per-round ratios)")
        return 0
    print(f"lokigraph broad phase benchmark: rolled cloth sheet, self VF + EE, numba threads = {threads}")
    print("times: median of", args.repeats, "runs after JIT warm-up; build/refit include box computation")
    hdr = (f"{'triangles':>10} {'vertices':>9} {'build ms':>9} {'refit ms':>9} {'query ms':>9} "
           f"{'refit+query':>12} {'VF cand':>10} {'EE cand':>10} {'SAH refit/build':>16}")
    print(hdr)
    print("-" * len(hdr))
    rows = []
    for s in args.sizes:
        r = bench_one(s, args.repeats)
        rows.append(r)
        print(f"{r['tris']:>10d} {r['verts']:>9d} {r['build']:>9.2f} {r['refit']:>9.2f} {r['query']:>9.2f} "
              f"{r['refit'] + r['query']:>12.2f} {r['vf']:>10d} {r['ee']:>10d} {r['cost']:>16.3f}")
    print("sorted column grid (column_query_pairs / column_query_self, no trees; same pair "
          "counts), interleaved with the BVH runs above:")
    hdr = (f"{'triangles':>10} {'boxes ms':>9} {'query ms':>9} {'boxes+query':>12} "
           f"{'BVH CPU ms':>11} {'grid CPU ms':>12} {'CPU ratio':>10} {'z-sort ms':>10} "
           f"{'sort CPU ms':>12}")
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        print(f"{r['tris']:>10d} {r['col_boxes']:>9.2f} {r['col_query']:>9.2f} "
              f"{r['col_boxes'] + r['col_query']:>12.2f} {r['cpu_bvh']:>11.2f} "
              f"{r['cpu_col']:>12.2f} {r['cpu_col'] / r['cpu_bvh']:>10.3f} "
              f"{r['col_sort']:>10.2f} {r['cpu_sort']:>12.2f}")
    print("(CPU: process time of the BVH's refit+query and of the grid's boxes+query, all threads; "
          "ratio grid / BVH; z-sort: the Morton ranks and the Z-order sort of both pair sets, "
          "the contacts' order of the grid's candidates, not in boxes+query)")
    print("max vertex motion per step [edge lengths]: "
          + ", ".join(f"{r['move']:.3f}" for r in rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
