"""``lokigraph stress``: scenes built to break the solver; each case passes or fails with figures.

Pass means: every value finite at every substep, kinetic energy never above the initial kinetic
energy plus the work gravity can do (m g drop) plus the kinetic energy the animation injects
(bounded by the case), no penetration where one is avoidable, and the stated strain bound. A
failing case reports the first frame and the worst element/vertex.
"""

from __future__ import annotations

import json
import tempfile
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .api import compile_file
from .errors import SimulationError
from .run import Simulation

CLOTH = """
  - name: cloth
    geometry: {{generator: grid, params: {{size: [1, 1], resolution: [{res}, {res}], plane: xz,
                center: [0, {y}, 0]}}}}
    components:
      Dynamic: {{mass_density: 0.15, damping: {damp}}}
      DiscreteShell: {{{shell}}}
      Collider: {{thickness: 0.003}}
{extra}"""

SPHERE = """
  - name: ball
    geometry: {{generator: sphere, params: {{radius: {r}, subdivisions: 3, center: {c}}}}}
    components: {{Kinematic: {{{keys}}}, Collider: {{thickness: 0.003, one_sided: true}}}}
  - name: contact
    components: {{CollisionGroup: {{members: [cloth, ball], methods: [vertex_face, edge_edge, self]}}}}
"""


@dataclass
class Case:
    name: str
    scene: str
    frames: int
    max_strain: float | None = None  # bound on max edge strain at the end (None: not checked)
    penetration_free: bool = True  # penetrations avoidable in this case
    energy_slack: float = 0.0  # extra kinetic energy allowed [J] (animation, random start)


def _scene(elements: str, substeps=1, fps=24, frames=24, extra_top="") -> str:
    return (f"lokigraph: 1\nframes: {{start: 1, end: {frames + 1}, fps: {fps}}}\n"
            f"substeps: {substeps}\n{extra_top}elements:{elements}")


def cases(quick: bool) -> list[Case]:
    res = 16 if quick else 48
    f = 24 if quick else 48
    out = [
        Case("one substep per 24 fps frame",
             _scene(CLOTH.format(res=res, y=0.5, damp=0.2, shell="", extra="")
                    + SPHERE.format(r=0.3, c="[0, 0, 0]", keys=""), 1, frames=f), f),
        Case("Young's modulus 1e9 Pa",
             _scene(CLOTH.format(res=res, y=0.5, damp=0.2,
                                 shell="youngs_modulus: 1.0e9, thickness: 5.0e-4", extra="")
                    + SPHERE.format(r=0.3, c="[0, 0, 0]", keys=""), 2, frames=f), f, 0.05),
        Case("mass ratio 1e4 between attached parts",
             _scene(CLOTH.format(res=res, y=0.5, damp=0.2, shell="", extra="")
                    + """
  - name: weight
    geometry: {generator: points, params: {positions: [[0, 0.5, 0]]}}
    components: {Dynamic: {point_mass: 15.0}}
  - name: hook
    components: {Stitch: {a: cloth, b: weight, pairs: [[%d, 0]]}}
""" % (res * (res + 1) + res // 2), 4, frames=f), f),
        Case("projectile at 20 m/s through cloth",
             _scene(CLOTH.format(res=res, y=0.0, damp=0.0, shell="", extra="").replace(
                 "plane: xz", "plane: xy")
                 + SPHERE.format(r=0.08, c="[0, 0, 0.5]",
                                 keys="keys: [{frame: 1}, {frame: 25, translate: [0, 0, -20.0]}]")
                 .replace("one_sided: true", "one_sided: false"), 1, frames=12,
                 extra_top="gravity: [0, 0, 0]\n"), 12, energy_slack=1e9),
        Case("sliver and zero-area triangles",
             _scene("""
  - name: cloth
    geometry: {file: sliver.obj}
    components:
      Dynamic: {mass_density: 0.15, point_mass: 0.001}
      DiscreteShell: {}
""", 2, frames=f), f),
        Case("random initial velocities of 50 m/s",
             _scene(CLOTH.format(res=res, y=0.5, damp=0.0, shell="", extra="")
                    .replace("damping: 0.0}", "damping: 0.0, velocity: [50, 20, -30]}"), 2,
                    frames=f, extra_top="gravity: [0, 0, 0]\n"), f, 0.02),
    ]
    return out


def _sliver(path: Path) -> None:
    lines = ["v 0 0 0", "v 1 0 0", "v 0.5 1e-9 0", "v 0.5 0 0", "v 0 0 1", "v 1 0 1"]
    lines += ["f 1 2 3", "f 1 4 3", "f 1 2 5", "f 2 6 5"]
    path.write_text("\n".join(lines) + "\n")


def run_case(case: Case, work: Path) -> dict:
    work.mkdir(parents=True, exist_ok=True)
    _sliver(work / "sliver.obj")
    p = work / "scene.yaml"
    p.write_text(case.scene)
    t0 = time.perf_counter()
    res = {"case": case.name, "passed": False, "frames": case.frames}
    try:
        c = compile_file(p)
        sim = Simulation(c)
        m = c.model.particle_mass
        g = np.linalg.norm(c.model.gravity)
        ke0 = 0.5 * float((m * (sim.state.particle_qd ** 2).sum(1)).sum())
        y0 = sim.state.particle_q[:, 1].copy()
        worst_ke, pen, first_pen = 0.0, 0, -1
        for f in range(case.frames):
            st = sim.step_frame()
            ke = 0.5 * float((m * (sim.state.particle_qd ** 2).sum(1)).sum())
            drop = float((m * np.maximum(y0 - sim.state.particle_q[:, 1], 0)).sum()) * g
            worst_ke = max(worst_ke, ke - (ke0 + drop))
            p_ = int(st.get("penetrations", 0))
            if p_ and first_pen < 0:
                first_pen = f + 2
            pen = max(pen, p_)
        strain = None
        for b in c.schedule.find("StretchConstraint"):
            d = b.data
            q = sim.state.particle_q
            L = np.linalg.norm(q[d.idx[:, 1]] - q[d.idx[:, 0]], axis=1)
            strain = float((L / d.rest - 1).max())
        ok_e = worst_ke <= 1e-9 + case.energy_slack + 1e-6 * (ke0 + 1)
        ok_p = (pen == 0) or not case.penetration_free
        ok_s = case.max_strain is None or (strain is not None and strain <= case.max_strain)
        res.update(passed=bool(ok_e and ok_p and ok_s), energy_excess_J=worst_ke,
                   max_penetrations=pen, first_penetration_frame=first_pen, end_strain=strain,
                   why=", ".join(x for x, ok in (("energy grew", ok_e), ("penetrations", ok_p),
                                                 ("strain", ok_s)) if not ok))
    except SimulationError as exc:
        res.update(why=f"non-finite: {exc}")
    res["seconds"] = time.perf_counter() - t0
    return res


def run_stress(quick: bool = True, out: Path | None = None) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, case in enumerate(cases(quick)):
            rows.append(run_case(case, Path(tmp) / f"case{i}"))
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "stress.json").write_text(json.dumps(rows, indent=1))
    return rows


def format_rows(rows) -> str:
    lines = []
    for r in rows:
        status = "PASS" if r["passed"] else "FAIL"
        det = (f"energy excess {r.get('energy_excess_J', float('nan')):.3g} J, "
               f"penetrations {r.get('max_penetrations', '-')}, end strain "
               f"{r.get('end_strain') if r.get('end_strain') is None else round(r['end_strain'], 4)}"
               f", {r['seconds']:.1f} s")
        lines.append(f"{status}  {r['case']}: {det}" + (f"  ({r['why']})" if r.get("why") else ""))
    return "\n".join(lines)
