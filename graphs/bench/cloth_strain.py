"""Inextensible cloth in motion and contact (issues #12, #13): worst edge strain per frame and
cost at the defaults and at the settings around them, every setting stepped frame by frame in
turn in one process (machine load hits all alike):

* ``before``: the defaults before issue #13, ``stretch: {long_range_levels: 0, sweeps: 1,
  inextensible_compression: null}``, ``strain_limit: {inextensible_max_strain: null}`` (the
  solver before the long-range rows, bitwise);
* ``long_range``: ``stretch: {long_range_levels: 5, sweeps: 3}`` alone (no strain limit, edges
  hard in compression);
* ``in_contact_hard``: that plus ``strain_limit: {inextensible_max_strain: 0.05,
  inextensible_joint_iterations: 10}`` (edges hard in compression);
* ``defaults``: that plus ``stretch: {inextensible_compression: 10}`` (edges near contacts
  compliant in compression; the opt-in 'in_contact' before it became the defaults);
* ``defaults+redetect``: that plus ``collisions: {redetect: true}``;
* ``tight``: the defaults with ``stretch: {joint_long_range: true}``, ``strain_limit:
  {inextensible_max_strain: 0.02, inextensible_joint_iterations: 40}``.

Run::

    .venv/bin/python graphs/bench/cloth_strain.py [--frames 24] [--scenes cloth_on_sphere ...]
    .venv/bin/python graphs/bench/cloth_strain.py --only before defaults \
        --set stretch.sweeps=2 \
        --set strain_limit.inextensible_joint_iterations=20 ...   # some settings, extra ones
    /tmp/venv-peer/bin/python graphs/bench/cloth_strain.py --peer 64 [128] [--frames 23]

``--peer N`` runs the peer collision scene (``cloth_sphere_N.yaml``) through
``peer_collision.py``'s runners: lokigraph at each setting above at the scene's substeps and
Style3D at its settings when Newton is importable, with the shared intersection counter.

Per setting: worst edge strain over the frames (max over edges of ``|e| / L0 - 1``), the frame
where it happens, the last frame's strain, the penetration count (max over frames), CPU and wall
ms per frame (medians over frames 2..N).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: the Nucleus defaults before issue #13 (the solver before the long-range rows, bitwise)
BEFORE = {"stretch": {"long_range_levels": 0, "sweeps": 1, "inextensible_compression": None},
          "strain_limit": {"inextensible_max_strain": None}}
LONG_RANGE = {"stretch": {"long_range_levels": 5, "sweeps": 3, "inextensible_compression": None},
              "strain_limit": {"inextensible_max_strain": None}}
IN_CONTACT_HARD = {"stretch": {"inextensible_compression": None}}
#: the defaults now (the former opt-in 'in_contact'): long-range rows 5 levels, 3 sweeps, the
#: 5 % inextensible strain limit with 10 joint passes, edges near contacts compliant in
#: compression at 10 N/m
DEFAULTS = {}
REDETECT = {"collisions": {"redetect": True}}
TIGHT = {"stretch": {"joint_long_range": True},
         "strain_limit": {"inextensible_max_strain": 0.02, "inextensible_joint_iterations": 40}}
SETTINGS = [("before", BEFORE), ("long_range", LONG_RANGE),
            ("in_contact_hard", IN_CONTACT_HARD), ("defaults", DEFAULTS),
            ("defaults+redetect", REDETECT), ("tight", TIGHT)]
SCENES = ("cloth_on_sphere", "skirt_walk", "sleeve_elbow", "cloth_pinned", "flag_wind")


def _variant(path: Path, overrides: dict, tmp: Path) -> Path:
    """A copy of the scene with graph overrides in ``tmp``, beside links to the other files of
    the scene's folder (relative map paths stay valid)."""
    s = yaml.safe_load(path.read_text())
    go = s.setdefault("graph_overrides", {})
    for node, params in overrides.items():
        go.setdefault(node, {}).update(params)
    s["output"] = {"dir": str(tmp / "out")}
    for f in path.parent.iterdir():
        link = tmp / f.name
        if f.suffix != ".yaml" and f.is_file() and not link.exists():
            link.symlink_to(f)
    out = tmp / f"{path.stem}_{len(list(tmp.glob('*.yaml')))}.yaml"
    out.write_text(yaml.safe_dump(s))
    return out


class _Run:
    def __init__(self, label, path):
        from lokigraph.api import compile_file
        from lokigraph.run import Simulation

        c = compile_file(path)
        self.label = label
        self.d = c.schedule.find("StretchConstraint")[0].data
        self.sim = Simulation(c)
        self.worst, self.pen, self.cpu, self.wall = [], [], [], []

    def step(self):
        t, c = time.perf_counter(), time.process_time()
        st = self.sim.step_frame()
        self.wall.append(time.perf_counter() - t)
        self.cpu.append(time.process_time() - c)
        q, d = self.sim.state.particle_q, self.d
        e = np.linalg.norm(q[d.idx[:, 1]] - q[d.idx[:, 0]], axis=1) / d.rest - 1.0
        self.worst.append(float(e.max()))
        self.pen.append(float(st.get("penetrations", 0) or 0))

    def row(self, scene):
        w = np.array(self.worst)
        return (f"| {scene} | {self.label} | {100 * w.max():.2f} | {int(w.argmax()) + 1} | "
                f"{100 * w[-1]:.2f} | {int(max(self.pen))} | {1e3 * np.median(self.cpu[1:]):.0f} | "
                f"{1e3 * np.median(self.wall[1:]):.0f} |")


def _parse_set(items):
    out = {}
    for it in items or []:
        key, val = it.split("=", 1)
        node, param = key.split(".", 1)
        out.setdefault(node, {})[param] = yaml.safe_load(val)
    return out


def scenes_table(names, frames, extras, only=None):
    print("| scene | setting | worst strain % | frame | last % | max pen | CPU ms/frame | "
          "wall ms/frame |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            path = ROOT / "graphs" / "examples" / f"{name}.yaml"
            settings = [s for s in SETTINGS if not only or s[0] in only]
            for extra in extras:
                settings.append((" ".join(f"{n}.{k}={v}" for n, p in extra.items()
                                          for k, v in p.items()), extra))
            files = [_variant(path, ov, Path(tmp)) for _, ov in settings]
            runs = [_Run(lbl, f) for (lbl, _), f in zip(settings, files)]
            for _ in range(frames):
                for r in runs:
                    r.step()
            for r in runs:
                print(r.row(name), flush=True)


def peer(sizes, frames, only=None):
    sys.path.insert(0, str(ROOT / "graphs" / "bench"))
    import peer_collision as pc

    try:
        newton, wp = pc.import_newton()
    except Exception as exc:  # noqa: BLE001
        newton = wp = None
        print(f"[peer] Newton not importable ({type(exc).__name__}); lokigraph rows only")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            sc = pc.ClothSphere(pc.SCENES[n])
            runs = [pc.LokiRun(pc.ClothSphere(_variant(pc.SCENES[n], ov, Path(tmp))),
                               sc.substeps, 15, label=" " + lbl) for lbl, ov in SETTINGS
                    if not only or lbl in only]
            if newton is not None:
                for s, i in pc.NEWTON_SETTINGS:
                    runs.append(pc.NewtonRun(newton, wp, sc, s, i, 1000.0, "frame", None))
            rr = pc.run_interleaved(runs, frames or sc.frames)
            best = min((r["cpu_ms"] for r in rr if r["framework"] == "newton"
                        and r.get("cpu_ms") is not None and r["finite"]), default=None)
            for r in rr:
                r["ratio"] = (r["cpu_ms"] / best) if best and r.get("cpu_ms") else None
            rows += rr
    print(pc.table(rows))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--scenes", nargs="+", default=list(SCENES))
    ap.add_argument("--set", nargs="+", action="append", default=[],
                    help="an extra setting NODE.PARAM=VALUE ... (repeat --set for more)")
    ap.add_argument("--peer", type=int, nargs="*", help="peer collision scene sizes")
    ap.add_argument("--only", nargs="*", help="only these of the built-in settings")
    args = ap.parse_args(argv)
    if args.peer:
        peer(args.peer, args.frames, args.only)
    else:
        scenes_table(args.scenes, args.frames, [_parse_set(x) for x in args.set], args.only)


if __name__ == "__main__":
    main()
