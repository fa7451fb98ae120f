"""The run loop: substeps through the schedule, the non-finite guard, frame output, run.json.

Frames are written atomically (temporary file + rename), so a failing run keeps every frame
already written and never leaves a half-written file; ``run.json`` is written at the end of a
run, successful or not, with the scene, versions, per-frame timings and solver statistics.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from .behavior import STAGES, StepContext
from .compile import Compiled
from .errors import InputError, SimulationError
from .geometry import write_mesh
from .model import Control, State


def atomic_write(path: Path, writer) -> None:
    """Call ``writer(tmp_path)`` then rename onto ``path`` (same folder, so the rename is atomic)."""
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}{path.suffix}")
    try:
        writer(tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def output_elements(compiled: Compiled) -> list:
    """Elements written per frame: dynamic ones, plus any a behavior marks (compliant surfaces)."""
    m = compiled.model
    out = []
    for el in compiled.scene.elements:
        if el.geometry is None or el.vertex_count == 0:
            continue
        sl = el.vertex_slice
        dynamic = not m.particle_kinematic[sl].all() or m.particle_compliant[sl].any()
        if dynamic or any(getattr(type(c), "write_output", False) for c in el.components.values()):
            out.append(el)
    return out


@dataclass
class RunResult:
    state: State
    frames_written: list = field(default_factory=list)
    frame_seconds: list = field(default_factory=list)
    stats: list = field(default_factory=list)
    out_dir: Path | None = None
    error: SimulationError | None = None


class Simulation:
    """A compiled scene ready to step. ``step_frame()`` advances one frame of substeps."""

    def __init__(self, compiled: Compiled):
        self.compiled = compiled
        self.model = compiled.model
        self.schedule = compiled.schedule
        self.state = State.from_model(self.model)
        self.control = Control(self.model.particle_q0.copy(), self.model.particle_q0.copy())
        self._steps = [b for s in STAGES for b in self.schedule.stages.get(s, [])]
        for b in self._steps:
            b.behavior.init_state(self.model, self.state, b.data)
        self._constraints = [(b.behavior, b.data) for b in self.schedule.constraints]
        # compliant vertices keep their deformed position (the output shows the receded surface)
        self._kinematic = np.flatnonzero(self.model.particle_kinematic
                                         & ~self.model.particle_compliant)
        self.frame = compiled.scene.spec.frames.start
        self.substep_index = 0

    def step_substep(self) -> dict:
        m, st, ctl = self.model, self.state, self.control
        h = m.dt
        st.particle_q_prev[:] = st.particle_q
        st.particle_f[:] = 0.0
        for name in st.accumulators:
            st.fields[name][...] = 0.0
        ctl.kinematic_q_prev[:] = ctl.kinematic_q
        ctl.time = st.time + h
        ctx = StepContext(m, st, ctl, h, st.time, self.substep_index, self.frame,
                          self._constraints, {})
        for b in self._steps:
            b.behavior.step(ctx, b.data)
        kin = self._kinematic
        if len(kin):  # animated vertices end the substep exactly on their animation
            st.particle_q[kin] = ctl.kinematic_q[kin]
            st.particle_qd[kin] = (ctl.kinematic_q[kin] - ctl.kinematic_q_prev[kin]) / h
        st.time += h
        self._guard(ctx)
        self.substep_index += 1
        return ctx.stats

    def _guard(self, ctx) -> None:
        st = self.state
        ok_q = np.isfinite(st.particle_q).all()
        ok_v = np.isfinite(st.particle_qd).all()
        if ok_q and ok_v:
            return
        bad = ~(np.isfinite(st.particle_q).all(1) & np.isfinite(st.particle_qd).all(1))
        v = int(np.argmax(bad))
        name, local = self.model.locate(v)
        what = "position" if not np.isfinite(st.particle_q[v]).all() else "velocity"
        raise SimulationError(f"non-finite {what} ({int(bad.sum())} vertices affected); "
                              f"reduce the time step or check stiffness/mass ratios",
                              element=name, vertex=local, step=self.substep_index,
                              frame=self.frame + 1)

    def step_frame(self) -> dict:
        stats: dict = {}
        for _ in range(self.model.substeps):
            s = self.step_substep()
            for k, v in s.items():
                if isinstance(v, (int, float, np.floating, np.integer)):
                    v = float(v)
                    if k.startswith("max_"):
                        stats[k] = max(stats.get(k, -np.inf), v)
                    else:
                        stats[k] = stats.get(k, 0.0) + v
        self.frame += 1
        ctx = StepContext(self.model, self.state, self.control, self.model.dt, self.state.time,
                          self.substep_index, self.frame, self._constraints, {})
        for b in self._steps:
            b.behavior.frame_end(ctx, b.data)
        stats.update({k: float(v) for k, v in ctx.stats.items()})
        return stats


def _versions() -> dict:
    import meshio
    import networkx
    import numba
    import pydantic
    import scipy

    return {"lokigraph": __version__, "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "numba": numba.__version__, "pydantic": pydantic.__version__,
            "networkx": networkx.__version__, "meshio": meshio.__version__,
            "platform": platform.platform()}


def run(compiled: Compiled, frames: tuple[int, int] | None = None, out_dir: str | Path | None = None,
        fmt: str | None = None, progress: bool | None = None, write: bool = True) -> RunResult:
    """Simulate from the scene's start frame to the last requested frame; write frames A..B.

    Raises SimulationError after writing run.json (status "failed"); frames already written stay.
    """
    spec = compiled.scene.spec
    start, end = spec.frames.start, spec.frames.end
    a, b = frames if frames is not None else (start, end)
    if a < start or b < a:
        raise InputError(f"--frames {a}:{b} must lie within the scene's frames {start}:{end} "
                         f"with A <= B")
    fmt = fmt or spec.output.format
    out = Path(out_dir if out_dir is not None else spec.output.dir)
    sim = Simulation(compiled)
    outs = output_elements(compiled)
    result = RunResult(sim.state, out_dir=out if write else None)
    if progress is None:
        progress = sys.stderr.isatty()
    if write:
        out.mkdir(parents=True, exist_ok=True)
        for el in outs:
            (out / el.name).mkdir(exist_ok=True)

    def write_frame(frame: int) -> None:
        if not write:
            return
        for el in outs:
            pts = sim.state.particle_q[el.vertex_slice]
            path = out / el.name / f"{frame:04d}.{fmt}"
            atomic_write(path, lambda p: write_mesh(p, pts, el.geometry, fmt))
        result.frames_written.append(frame)

    t_start = time.perf_counter()
    record = []
    if a == start:
        write_frame(start)
    try:
        for frame in range(start + 1, b + 1):
            t0 = time.perf_counter()
            stats = sim.step_frame()
            dt = time.perf_counter() - t0
            result.frame_seconds.append(dt)
            result.stats.append(stats)
            record.append({"frame": frame, "seconds": dt, "stats": stats})
            if frame >= a:
                write_frame(frame)
            if progress:
                _progress(frame - start, b - start, time.perf_counter() - t_start)
    except SimulationError as exc:
        result.error = exc
    finally:
        if progress:
            sys.stderr.write("\n")
    if write:
        info = {
            "status": "ok" if result.error is None else "failed",
            "error": None if result.error is None else str(result.error),
            "scene_file": compiled.scene.file,
            "scene": compiled.scene.raw,
            "versions": _versions(),
            "frames": {"start": start, "written": result.frames_written, "fps": spec.frames.fps,
                       "substeps": spec.substeps},
            "format": fmt,
            "schedule": compiled.schedule.as_dict(),
            "total_seconds": time.perf_counter() - t_start,
            "per_frame": record,
        }
        atomic_write(out / "run.json", lambda p: p.write_text(json.dumps(info, indent=1,
                                                                         default=_json_default)))
    if result.error is not None:
        raise result.error
    return result


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def _progress(done: int, total: int, elapsed: float) -> None:
    width = 30
    frac = done / max(total, 1)
    bar = "#" * int(width * frac) + "-" * (width - int(width * frac))
    eta = elapsed / max(frac, 1e-9) - elapsed
    sys.stderr.write(f"\r[{bar}] {done}/{total} frames  {elapsed:6.1f}s elapsed  "
                     f"eta {eta:6.1f}s")
    sys.stderr.flush()
