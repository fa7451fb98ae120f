"""Scaling of the collision scene: time per frame against vertex count, fitted exponent.

Run::

    .venv/bin/python graphs/bench/collision_scaling.py [--sizes 32 64 128 256] [--frames 12]
        [--from-frame 6] [--out bench_out/scaling_collision]

The scene is ``graphs/bench/cloth_sphere_64.yaml`` (cloth dropped on a sphere, self-collision on)
with the cloth's grid resolution replaced by each size (the sphere is unchanged). Every size runs
``--frames`` frames in this process; per size the table gives the median CPU
(``time.process_time``) and wall ms per frame over frames ``--from-frame`` .. ``--frames`` (the
cloth lands on the sphere around frame 6, so these are contact frames) and over frames 2 .. N,
the vertex count, the largest contact counts, and the intersecting triangle pairs of the last
frame (lokigraph's PenetrationCheck, outside the timed region). The exponent p is the
least-squares slope of log(ms per frame) against log(vertex count) (t ~ n^p) over the contact
frames, CPU and wall.

``--ab``: instead, per size, the scene with the collision pipeline's space-time boxes for self
pairs off (``--ab-ref``, default ``off``: swept boxes in every detection) and on (``--ab-mode``:
``known``, the detections over a known motion, i.e. the final rounds and the CCD safe step, as
``contacts.SPACETIME``; ``all``, the detection over the predicted motion too,
``contacts.SPACETIME_PREDICTED``, unsafe: see it), two simulations in this process
stepped frame by frame in alternating order (ABBA), so machine load hits both
alike: median CPU ms per frame of each and the median of the per-frame CPU ratio on/off over
the contact frames, with the intersecting triangle pairs (max over frames) and the largest edge
strain of each. Run with ``NUMBA_NUM_THREADS=1`` for CPU-time comparisons::

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/collision_scaling.py --ab --sizes 64 \
        --frames 20

``--ab --ab-flag NAME``: both at ``--ab-mode`` and the boolean ``contacts.NAME`` False ("off")
against True ("on"), e.g. ``SPLIT_BUFFERS`` (``broadphase.NAME``: a boolean of the broad
phase, e.g. ``broadphase.SEQUENTIAL_ONE_THREAD``; several, comma-separated, switch
together). Whether the last positions of the two are bitwise equal is printed per size, with
the rows of the substeps' first detections per cloth vertex (median over the timed frames) and,
for ``--ab-flag SPACETIME_RELATIVE``, its checks, re-detections and flagged vertices (sums over
the timed frames). ``--ab-set NAME=VALUE ...``: numeric settings of ``contacts`` for both runs
(e.g. ``RELATIVE_SLACK=0``, ``RELATIVE_INCREMENTAL=0``: full re-detections only).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
TEMPLATE = ROOT / "graphs" / "bench" / "cloth_sphere_64.yaml"


def run_size(n: int, frames: int, from_frame: int, folder: Path) -> dict:
    from lokigraph.compile import compile_scene
    from lokigraph.run import Simulation
    from lokigraph.scene import load_scene

    text = TEMPLATE.read_text().replace("resolution: [64, 64]", f"resolution: [{n}, {n}]")
    path = folder / f"cloth_sphere_{n}.yaml"
    path.write_text(text)
    sim = Simulation(compile_scene(load_scene(path)))
    check = [b for b in sim._steps if type(b.behavior).__name__ == "PenetrationCheck"]
    sim._steps = [b for b in sim._steps if b not in check]
    cloth = next(e for e in sim.model.elements if e.name == "cloth")
    wall, cpu, cvf, cee = [], [], 0, 0
    for _ in range(frames):
        w0, c0 = time.perf_counter(), time.process_time()
        st = sim.step_frame()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
        cvf = max(cvf, st.get("contacts_vf", 0))
        cee = max(cee, st.get("contacts_ee", 0))
    from lokigraph.behaviors.collision.intersect import find_intersections

    F = np.concatenate([e.geometry.triangles + e.vertex_offset for e in sim.model.elements
                        if e.geometry is not None and len(e.geometry.triangles)])
    pairs = int(find_intersections(sim.state.particle_q, F, touching=False).count)
    k = from_frame - 1
    return {"resolution": n, "vertices": int(cloth.vertex_count),
            "cpu_ms": 1e3 * float(np.median(cpu[k:])), "wall_ms": 1e3 * float(np.median(wall[k:])),
            "cpu_ms_all": 1e3 * float(np.median(cpu[1:])),
            "wall_ms_all": 1e3 * float(np.median(wall[1:])),
            "frame1_s": wall[0], "max_contacts_vf": cvf, "max_contacts_ee": cee,
            "finite": bool(np.isfinite(sim.state.particle_q).all()), "pairs_last_frame": pairs}


#: settings of ``--ab``: (contacts.SPACETIME, contacts.SPACETIME_PREDICTED)
AB_SETTINGS = {"off": (False, False), "known": (True, False), "all": (True, True)}
_FLAGS = ("SPACETIME", "SPACETIME_PREDICTED")


def run_ab(n: int, frames: int, from_frame: int, folder: Path, mode: str = "known",
           ref: str = "off", flag: str = "") -> dict:
    """The scene at n x n with the space-time setting ``ref`` (as "off") and ``mode`` (as
    "on"), interleaved (see the module docstring); with ``flag`` (a boolean of
    ``contacts``), both at ``mode`` and that flag False ("off") / True ("on")."""
    from lokigraph.behaviors.collision import contacts as C
    from lokigraph.behaviors.collision.intersect import find_intersections
    from lokigraph.compile import compile_scene
    from lokigraph.run import Simulation
    from lokigraph.scene import load_scene

    text = TEMPLATE.read_text().replace("resolution: [64, 64]", f"resolution: [{n}, {n}]")
    path = folder / f"cloth_sphere_{n}.yaml"
    path.write_text(text)

    default = [getattr(C, k) for k in _FLAGS]

    from lokigraph.behaviors.collision import broadphase as B

    flags = [(B if f.startswith("broadphase.") else C, f.split(".")[-1])
             for f in flag.split(",") if f]
    flag_default = [getattr(m, f) for m, f in flags]

    def setting(on):
        for k, val in zip(_FLAGS, AB_SETTINGS[mode if on else ref]):
            setattr(C, k, val)
        for m, f in flags:
            setattr(m, f, on)

    runs = {}
    for on in (False, True):
        setting(on)
        sim = Simulation(compile_scene(load_scene(path)))
        sim._steps = [b for b in sim._steps if type(b.behavior).__name__ != "PenetrationCheck"]
        cloth = next(e for e in sim.model.elements if e.name == "cloth")
        F = np.concatenate([e.geometry.triangles + e.vertex_offset for e in sim.model.elements
                            if e.geometry is not None and len(e.geometry.triangles)])
        from lokigraph.behaviors.topology import triangle_edges

        E = triangle_edges(cloth.geometry.triangles) + cloth.vertex_offset
        L0 = np.linalg.norm(np.diff(sim.state.particle_q[E], axis=1)[:, 0], axis=1)
        runs[on] = {"sim": sim, "F": F, "E": E, "L0": L0, "cpu": [], "pairs": 0, "strain": 0.0,
                    "rows": [], "checks": 0, "redetect": 0, "flagged": 0, "full": 0,
                    "nv": int(cloth.vertex_count), "substeps": int(sim.model.substeps)}
    try:
        for f in range(frames):
            for on in ((False, True) if f % 2 == 0 else (True, False)):
                r = runs[on]
                setting(on)
                c0 = time.process_time()
                st = r["sim"].step_frame()
                r["cpu"].append(time.process_time() - c0)
                r["rows"].append(st.get("contacts_vf", 0) + st.get("contacts_ee", 0))
                if f >= from_frame - 1:
                    r["checks"] += st.get("relative_checks", 0)
                    r["redetect"] += st.get("relative_detections", 0)
                    r["flagged"] += st.get("relative_flagged", 0)
                    r["full"] += st.get("relative_full", 0)
                q = r["sim"].state.particle_q
                r["pairs"] = max(r["pairs"], int(find_intersections(q, r["F"],
                                                                    touching=False).count))
                L = np.linalg.norm(np.diff(q[r["E"]], axis=1)[:, 0], axis=1)
                r["strain"] = max(r["strain"], float(((L - r["L0"]) / r["L0"]).max()))
    finally:
        for k, val in zip(_FLAGS, default):
            setattr(C, k, val)
        for (m, f), val in zip(flags, flag_default):
            setattr(m, f, val)
    k = from_frame - 1
    off, on = (np.array(runs[b]["cpu"]) for b in (False, True))
    return {"resolution": n, "cpu_ms_off": 1e3 * float(np.median(off[k:])),
            "cpu_ms_on": 1e3 * float(np.median(on[k:])),
            "ratio": float(np.median(on[k:] / off[k:])),
            "pairs_off": runs[False]["pairs"], "pairs_on": runs[True]["pairs"],
            "same_positions": bool(np.array_equal(runs[False]["sim"].state.particle_q,
                                                  runs[True]["sim"].state.particle_q)),
            "strain_off": runs[False]["strain"], "strain_on": runs[True]["strain"],
            # rows of the substeps' first detections per cloth vertex (median over the frames)
            **{f"rows_per_vertex_{b}": float(np.median(runs[v]["rows"][k:]))
               / runs[v]["substeps"] / runs[v]["nv"] for b, v in (("off", False), ("on", True))},
            # SPACETIME_RELATIVE: checks, re-detections, flagged vertices (timed frames)
            **{f"{key}_{b}": runs[v][key] for key in ("checks", "redetect", "flagged", "full")
               for b, v in (("off", False), ("on", True))}}


def main_ab(args):
    from lokigraph.behaviors.collision import contacts as C

    for kv in args.ab_set:  # numeric settings of contacts for both runs
        k, v = kv.split("=", 1)
        if not isinstance(getattr(C, k), (int, float)) or isinstance(getattr(C, k), bool):
            raise SystemExit(f"--ab-set: contacts.{k} is not a number")
        setattr(C, k, float(v))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.sizes:
            rows.append(run_ab(n, args.frames, args.from_frame, Path(tmp), args.ab_mode,
                               args.ab_mode if args.ab_flag else args.ab_ref, args.ab_flag))
    if args.ab_flag:
        print(f"frames {args.from_frame}..{args.frames} timed (medians), space-time boxes "
              f"'{args.ab_mode}', {args.ab_flag} False (off) / True (on), interleaved")
    else:
        print(f"frames {args.from_frame}..{args.frames} timed (medians), space-time boxes "
              f"'{args.ab_ref}' (off) / '{args.ab_mode}' (on), interleaved")
    print("| res | CPU ms/frame off | CPU ms/frame on | median per-frame ratio on/off | "
          "pairs off / on (max) | max strain % off / on |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['resolution']} | {r['cpu_ms_off']:.0f} | {r['cpu_ms_on']:.0f} | "
              f"{r['ratio']:.3f} | {r['pairs_off']} / {r['pairs_on']} | "
              f"{100 * r['strain_off']:.1f} / {100 * r['strain_on']:.1f} |")
    print("| res | rows / vertex off / on | relative checks / re-detections (of them full) / "
          "flagged vertices (on) |")
    print("|---|---|---|")
    for r in rows:
        print(f"| {r['resolution']} | {r['rows_per_vertex_off']:.1f} / "
              f"{r['rows_per_vertex_on']:.1f} | {r['checks_on']} / {r['redetect_on']} "
              f"({r['full_on']}) / "
              f"{r['flagged_on']} |")
    for r in rows:
        print(f"{r['resolution']}: last positions bitwise equal: {r['same_positions']}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "scaling_collision_ab.json").write_text(json.dumps(
        {"rows": rows, "argv": sys.argv[1:]}, indent=1))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128, 256])
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--from-frame", type=int, default=6, help="first contact frame timed")
    ap.add_argument("--out", default="bench_out/scaling_collision")
    ap.add_argument("--ab", action="store_true", help="space-time boxes off vs on, "
                    "interleaved (see the module docstring)")
    ap.add_argument("--ab-mode", choices=sorted(AB_SETTINGS), default="known",
                    help="--ab: the setting timed as 'on'")
    ap.add_argument("--ab-ref", choices=sorted(AB_SETTINGS), default="off",
                    help="--ab: the setting timed as 'off'")
    ap.add_argument("--ab-set", nargs="+", default=[], metavar="NAME=VALUE",
                    help="--ab: numeric settings of contacts for both runs (e.g. "
                    "RELATIVE_SLACK=0 RELATIVE_INCREMENTAL=0)")
    ap.add_argument("--ab-flag", default="", help="--ab: a boolean of contacts (e.g. "
                    "SPLIT_BUFFERS; broadphase.NAME: of the broad phase; several comma-separated) "
                    "timed False (off) / True (on), both at --ab-mode")
    args = ap.parse_args(argv)
    if not 2 <= args.from_frame <= args.frames:
        ap.error("--from-frame must be in 2..--frames")
    if args.ab:
        return main_ab(args)
    import numba

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.sizes:
            rows.append(run_size(n, args.frames, args.from_frame, Path(tmp)))
            r = rows[-1]
            print(f"[scaling] {n}x{n}: {r['vertices']} vertices, CPU {r['cpu_ms']:.0f} ms/frame, "
                  f"wall {r['wall_ms']:.0f} ms/frame", flush=True)
    v = np.log([r["vertices"] for r in rows])
    fit = {k: float(np.polyfit(v, np.log([r[k] for r in rows]), 1)[0]) if len(rows) > 1
           else float("nan") for k in ("cpu_ms", "wall_ms")}
    print(f"\nnumba threads {numba.get_num_threads()}, layer {numba.threading_layer()}; "
          f"frames {args.from_frame}..{args.frames} timed (medians)")
    print("| res | vertices | CPU ms/frame | wall ms/frame | CPU us/vertex | CPU ms (2..N) | "
          "max VF | max EE | pairs (last) | finite |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['resolution']} | {r['vertices']} | {r['cpu_ms']:.0f} | {r['wall_ms']:.0f} | "
              f"{1e3 * r['cpu_ms'] / r['vertices']:.1f} | {r['cpu_ms_all']:.0f} | "
              f"{r['max_contacts_vf']:.0f} | {r['max_contacts_ee']:.0f} | {r['pairs_last_frame']} | "
              f"{r['finite']} |")
    print(f"fitted exponent (t ~ n^p): CPU p = {fit['cpu_ms']:.2f}, wall p = {fit['wall_ms']:.2f}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "scaling_collision.json").write_text(json.dumps(
        {"rows": rows, "exponent": fit, "argv": sys.argv[1:]}, indent=1))
    return rows, fit


if __name__ == "__main__":
    main()
