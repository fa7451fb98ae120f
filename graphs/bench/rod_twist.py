"""Twist of Rod strands (a material frame per segment, behaviors/materials/rod.py): the torsional
period of a strand turned at its root against the closed form, and the cost of the twist on the
hair scenes, settings measured interleaved in one run.

    .venv/bin/python graphs/bench/rod_twist.py period   # fixed-free shaft: T = 4 L / c
    .venv/bin/python graphs/bench/rod_twist.py cost     # hair scenes, twist on (default) / off
    .venv/bin/python graphs/bench/rod_twist.py kernel   # the twist step alone, 200 strands
    .venv/bin/python graphs/bench/rod_twist.py share    # time inside the twist step per frame

period: a straight strand (L = 0.2 m, linear density 0.01 kg/m, r = 1 mm, GJ = 3.2e-9 N m^2,
so c = sqrt(GJ / (lam r^2 / 2)) = 0.8 m/s and T = 4 L / c = 1 s) whose root is turned by
0.5 rad at t = 0 and held; the period of the tip's twist from its zero crossings about 0.5 rad
(after the first half period), 3 s simulated.

cost: ms/frame (median over frames after the first, wall and CPU ``time.process_time`` of this
process) of hair_strands, hair_head_gusts and its 200-strand version with the default twist and
with ``twist_resistance: 0`` (no material frame), alternated twice (on a shared machine compare
ratios, not absolutes); positions are bit-identical between the two (checked).

kernel: the twist step alone (``twist_step`` and ``twist_step_seq``, one call per substep) on the
state of the 200-strand hair_head_gusts after 3 frames, mean of 200 calls, wall and CPU.

share: the same three hair scenes with the default twist, the time spent inside
``RodConstraint.after_finalize`` (the whole twist step, Python included) per frame against the
whole frame, in one run (less noisy than comparing two runs on a shared machine).
"""

from __future__ import annotations

import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lokigraph.api import compile_file
from lokigraph.run import Simulation

HERE = Path(__file__).resolve().parent
EXAMPLES = HERE.parent / "examples"
TMP = Path(tempfile.mkdtemp(prefix="rod_twist_"))


def strand(n: int, substeps: int, frames: int) -> Path:
    p = TMP / f"strand_{n}_{substeps}.yaml"
    p.write_text(f"""
lokigraph: 1
frames: {{start: 1, end: {frames + 1}, fps: 24}}
substeps: {substeps}
gravity: [0, 0, 0]
elements:
  - name: strand
    geometry: {{generator: strands, params: {{count: [1, 1], length: 0.2, segments: {n},
                direction: [0, -1, 0]}}}}
    components:
      Dynamic: {{mass_density: 0.01}}
      Rod: {{radius: 1.0e-3, twist_resistance: 3.2e-9, root_twist: 0.5}}
      Pins: {{vertices: [0]}}
""")
    return p


def period():
    T = 4 * 0.2 / math.sqrt(3.2e-9 / (0.01 * 1e-6 / 2))
    print(f"closed form T = 4 L / c = {T:.4f} s")
    print("| segments | substeps | measured T [s] | error | tip max / 2 Theta |")
    print("|---|---|---|---|---|")
    frames = 72
    for n in (10, 20, 40):
        for sub in (1, 2, 4, 8):
            c = compile_file(strand(n, sub, frames))
            sim = Simulation(c)
            tw = c.schedule.find("RodConstraint")[0].data.twist
            t, y = [0.0], [-0.5]
            for f in range(frames):
                sim.step_frame()
                t.append((f + 1) / 24)
                y.append(tw.theta[-1] - 0.5)
            t, y = np.array(t), np.array(y)
            i = np.flatnonzero(np.sign(y[:-1]) != np.sign(y[1:]))
            z = t[i] - y[i] * (t[i + 1] - t[i]) / (y[i + 1] - y[i])
            Tm = 2 * np.mean(np.diff(z)[1:])
            print(f"| {n} | {sub} | {Tm:.4f} | {(Tm / T - 1) * 100:+.2f} % | "
                  f"{(y.max() + 0.5) / 1.0:.3f} |", flush=True)


def run(path: Path, frames: int):
    c = compile_file(path)
    sim = Simulation(c)
    wall, cpu = [], []
    for _ in range(frames):
        t, c0 = time.perf_counter(), time.process_time()
        sim.step_frame()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c0)
    return np.median(wall[1:]) * 1e3, np.median(cpu[1:]) * 1e3, sim.state.particle_q.copy()


def cost():
    gusts = EXAMPLES / "hair_head_gusts.yaml"
    scenes = [("hair_strands (64 x 20)", (EXAMPLES / "hair_strands.yaml").read_text(), 47),
              ("hair_head_gusts (64 x 20)", gusts.read_text(), 71),
              ("hair_head_gusts 200 strands",
               gusts.read_text().replace("count: [8, 8], spacing: 0.007",
                                         "count: [20, 10], spacing: 0.0035"), 71)]
    print("| scene | twist | ms/frame wall | ms/frame CPU | CPU ratio on / off |")
    print("|---|---|---|---|---|")
    for label, text, frames in scenes:
        res = {"off": [], "on": []}
        q = {}
        for rep in range(2):
            for mode in ("off", "on"):
                p = TMP / f"{abs(hash(label)) % 10**8}_{mode}.yaml"
                extra = "twist_resistance: 0, " if mode == "off" else ""
                p.write_text(text.replace("Rod: {", "Rod: {" + extra))
                w, c, q[mode] = run(p, frames)
                res[mode].append((w, c))
        assert np.array_equal(q["on"], q["off"])  # the twist never moves the strands
        best = {m: (min(x[0] for x in v), min(x[1] for x in v)) for m, v in res.items()}
        for mode in ("off", "on"):
            w, c = best[mode]
            ratio = f"{best['on'][1] / best['off'][1]:.3f}" if mode == "on" else ""
            print(f"| {label} | {mode} | {w:.2f} | {c:.2f} | {ratio} |", flush=True)


def kernel():
    from lokigraph.behaviors.materials.rod import twist_step, twist_step_seq

    text = (EXAMPLES / "hair_head_gusts.yaml").read_text().replace(
        "count: [8, 8], spacing: 0.007", "count: [20, 10], spacing: 0.0035")
    p = TMP / "gusts200.yaml"
    p.write_text(text)
    c = compile_file(p)
    sim = Simulation(c)
    for _ in range(3):
        sim.step_frame()
    d = c.schedule.find("RodConstraint")[0].data
    t = d.twist
    q = sim.state.particle_q.copy()
    args = (q, c.model.particle_inv_mass, d.verts, d.vptr, t.on, t.d1, t.tan, t.theta, t.omega,
            t.winv, t.reft, t.alpha, t.root, t.bdir, t.bphi, t.damp, t.tp, t.cp, t.dl, c.model.dt)
    print("| kernel | segments | us/call wall | us/call CPU | ns/segment wall |")
    print("|---|---|---|---|---|")
    for fn in (twist_step, twist_step_seq):
        fn(*args)
        w0, c0 = time.perf_counter(), time.process_time()
        for _ in range(200):
            fn(*args)
        w = (time.perf_counter() - w0) / 200 * 1e6
        cu = (time.process_time() - c0) / 200 * 1e6
        print(f"| {fn.__name__} | {len(t.theta)} | {w:.0f} | {cu:.0f} | "
              f"{w * 1e3 / len(t.theta):.0f} |", flush=True)


def share():
    from lokigraph.behaviors.materials.rod import RodConstraint

    acc = [0.0, 0.0]
    orig = RodConstraint.after_finalize

    def timed(self, ctx, d, p):
        w0, c0 = time.perf_counter(), time.process_time()
        orig(self, ctx, d, p)
        acc[0] += time.perf_counter() - w0
        acc[1] += time.process_time() - c0

    RodConstraint.after_finalize = timed
    gusts = EXAMPLES / "hair_head_gusts.yaml"
    p200 = TMP / "gusts200_share.yaml"
    p200.write_text(gusts.read_text().replace("count: [8, 8], spacing: 0.007",
                                              "count: [20, 10], spacing: 0.0035"))
    print("| scene | frame ms wall | frame ms CPU | twist ms wall | twist ms CPU | twist share "
          "of CPU |")
    print("|---|---|---|---|---|---|")
    try:
        for label, path, frames in (("hair_strands", EXAMPLES / "hair_strands.yaml", 47),
                                    ("hair_head_gusts", gusts, 71),
                                    ("hair_head_gusts 200 strands", p200, 71)):
            c = compile_file(path)
            sim = Simulation(c)
            sim.step_frame()  # JIT
            acc[:] = [0.0, 0.0]
            w0, c0 = time.perf_counter(), time.process_time()
            for _ in range(frames - 1):
                sim.step_frame()
            n = frames - 1
            W, C = (time.perf_counter() - w0) / n * 1e3, (time.process_time() - c0) / n * 1e3
            tw, tc = acc[0] / n * 1e3, acc[1] / n * 1e3
            print(f"| {label} | {W:.2f} | {C:.2f} | {tw:.3f} | {tc:.3f} | {tc / C * 100:.1f} % |",
                  flush=True)
    finally:
        RodConstraint.after_finalize = orig


if __name__ == "__main__":
    what = sys.argv[1] if len(sys.argv) > 1 else "all"
    if what in ("period", "all"):
        period()
    if what in ("cost", "all"):
        cost()
    if what in ("kernel", "all"):
        kernel()
    if what in ("share", "all"):
        share()
