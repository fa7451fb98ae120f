"""The run loop: substeps through the schedule, the non-finite guard, frame output, run.json.

Output goes to ``DIR/<element>/<frame:04d>.<ext>`` and ``DIR/run.json``. Before simulating, the
output location is checked: ``DIR`` and every element folder must be (or become) writable folders
(a write probe), and ``DIR`` must not hold another run's output (a ``run.json``, or frame files
``NNNN.obj|ply|vtu`` in a sub-folder) unless ``overwrite`` is set, in which case that run's
``run.json`` and frame files are removed first, so the folder always describes exactly one run.
Those problems raise :class:`~lokigraph.errors.OutputError` with exit code 2, before any frame is
simulated; a write failure during the run (disk full, permission lost) raises it with exit code 3.

Frames are written atomically: each file is written to a hidden temporary
``.<name>.tmp-<pid>`` (never ending in the format's extension, so a ``*.obj`` glob cannot pick
it up) and renamed into place; stale temporaries of that pattern are removed at the start.
SIGINT (Ctrl-C) and SIGTERM stop a run cleanly: the signal is deferred while a frame is being
written, so every frame present is complete and present for every written element, and frames
are contiguous. ``run.json`` is written at the end of every run, with ``status`` ``ok``,
``failed`` (simulation or write error, or a bug) or ``interrupted``, the scene, versions, output
settings, per-frame timings and solver statistics.
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import re
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from .behavior import STAGES, StepContext
from .compile import Compiled, output_diagnostics
from .errors import EXIT_SIMULATION, InputError, OutputError, SimulationError
from .meshfile import write_mesh
from .model import Control, State

FORMATS = ("obj", "ply", "vtu", "usd")  # usd: one stage per run (lokigraph.usd)
#: a frame file written by a run: ``0007.obj``, ``-001.ply``
FRAME_RE = re.compile(r"^-?\d+\.(obj|ply|vtu)$")
#: our temporaries: ``.0007.obj.tmp-123`` (and the older ``.0007.obj.tmp123.obj``)
TEMP_RE = re.compile(r"^\..+\.tmp-?(\d+)(\.[A-Za-z0-9]+)?$")


def temp_path(path: Path) -> Path:
    """The hidden temporary a write of ``path`` goes through (does not end in its extension)."""
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


def atomic_write(path: Path, writer) -> None:
    """Call ``writer(tmp_path)`` then rename onto ``path`` (same folder, so the rename is atomic).

    The temporary is removed on any failure; ``OSError`` from the writer or the rename propagates.
    """
    tmp = temp_path(path)
    try:
        writer(tmp)
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)


class RunInterrupted(KeyboardInterrupt):
    """A run stopped by SIGINT or SIGTERM (a KeyboardInterrupt, so Ctrl-C handling still works).

    ``signum`` is the signal; the CLI exits with ``128 + signum`` (130 for Ctrl-C, 143 for
    SIGTERM).
    """

    def __init__(self, signum: int = signal.SIGINT):
        self.signum = int(signum)
        super().__init__(signal.Signals(self.signum).name)


def _raise_interrupted(signum, _frame):
    raise RunInterrupted(signum)


class _Signals:
    """SIGINT/SIGTERM during a run raise :class:`RunInterrupted`, at once while simulating and
    at the end of a ``deferred()`` block (a frame's writes, run.json). Previous handlers are
    restored on exit. Ignored signals stay ignored; handlers are only installed in the main
    thread."""

    def __init__(self):
        self.critical = 0
        self.pending: int | None = None
        self.old: dict = {}

    def _handle(self, signum, _frame):
        if self.critical:
            self.pending = self.pending or signum
            return
        raise RunInterrupted(signum)

    def __enter__(self):
        if threading.current_thread() is not threading.main_thread():
            return self
        for sig in (signal.SIGINT, signal.SIGTERM):
            cur = signal.getsignal(sig)
            if cur is signal.SIG_IGN or cur is None:
                continue
            self.old[sig] = cur
            signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc):
        for sig, h in self.old.items():
            signal.signal(sig, h)
        self.old.clear()
        return False

    @contextlib.contextmanager
    def deferred(self):
        self.critical += 1
        try:
            yield
        finally:
            self.critical -= 1
        if not self.critical and self.pending is not None:
            sig, self.pending = self.pending, None
            raise RunInterrupted(sig)


def _reason(exc: OSError) -> str:
    return exc.strerror or str(exc)


def output_elements(compiled: Compiled) -> list:
    """Elements written per frame.

    Default: dynamic ones, plus any a behavior marks (compliant surfaces), plus every kinematic
    (animated or static) element with geometry when ``output.kinematic`` is true.
    ``output.elements`` names them explicitly instead (still adding the kinematic ones when
    ``kinematic`` is true). Unknown names and elements without geometry raise InputError.
    """
    scene = compiled.scene
    ospec = scene.spec.output
    diags = output_diagnostics(scene)
    if diags:
        raise InputError(diags)
    chosen = None if ospec.elements is None else set(ospec.elements)
    m = compiled.model
    out = []
    for el in scene.elements:
        if el.geometry is None or el.vertex_count == 0:
            continue
        sl = el.vertex_slice
        is_kin = bool(m.particle_kinematic[sl].all())
        dynamic = not is_kin or m.particle_compliant[sl].any()
        marked = dynamic or any(getattr(type(c), "write_output", False)
                                for c in el.components.values())
        take = marked if chosen is None else el.name in chosen
        if take or (ospec.kinematic and is_kin):
            out.append(el)
    return out


def _input_dirs(compiled: Compiled) -> set[Path]:
    """Folders the scene reads meshes from (never cleared by ``overwrite``)."""
    dirs = set()
    for el in compiled.scene.elements:
        spec = el.spec
        if spec is None:
            continue
        for pattern in (spec.file, spec.sequence):
            if pattern:
                with contextlib.suppress(OSError, ValueError, RuntimeError):
                    dirs.add((Path(el.base_dir) / os.path.dirname(pattern)).resolve())
    return dirs


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return False  # ours: a leftover of this process is stale by definition
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError, OSError):
        return True
    return True


def _clean_temps(folder: Path) -> None:
    """Remove stale temporaries of our pattern (a killed run's), not those of a live process."""
    with contextlib.suppress(OSError), os.scandir(folder) as it:
        for e in it:
            mt = TEMP_RE.match(e.name)
            if mt and e.is_file(follow_symlinks=False) and not _pid_alive(int(mt.group(1))):
                with contextlib.suppress(OSError):
                    os.unlink(e.path)


def previous_run(out: Path) -> dict:
    """Another run's output in ``out``: ``run.json`` (if any) and frame files per sub-folder."""
    from .usd import stage_files

    found = {"run_json": (out / "run.json").exists(), "frames": {}, "stage": stage_files(out)}
    with contextlib.suppress(FileNotFoundError, NotADirectoryError), os.scandir(out) as it:
        for e in it:
            if not e.is_dir(follow_symlinks=False):
                continue
            try:
                with os.scandir(e.path) as sub:
                    files = [f.path for f in sub if FRAME_RE.match(f.name)
                             and f.is_file(follow_symlinks=False)]
            except OSError:
                continue
            if files:
                found["frames"][e.name] = sorted(files)
    return found


def _describe(prev: dict) -> str:
    parts = []
    if prev["run_json"]:
        parts.append("run.json")
    if prev.get("stage"):
        parts.append("a USD stage (run.usd)")
    for name, files in sorted(prev["frames"].items()):
        parts.append(f"{len(files)} frame{'s' if len(files) != 1 else ''} in {name}/")
    return ", ".join(parts)


def prepare_output(out: Path, names: list[str], overwrite: bool = False,
                   protected: set[Path] = frozenset()) -> dict:
    """Check and create the output folders before simulating; returns what was replaced.

    Raises OutputError (exit 2) when ``out`` or an element folder is a file, cannot be created or
    written, or ``out`` holds another run's output and ``overwrite`` is false.
    """
    if out.exists() and not out.is_dir():
        raise OutputError(f"output folder {out} is a file; give a folder (--out DIR or "
                          f"output.dir)")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create output folder {out}: {_reason(exc)}") from None
    _clean_temps(out)
    prev = previous_run(out)
    replaced = {"run_json": False, "frame_files": 0}
    if prev["run_json"] or prev["frames"] or prev["stage"]:
        if not overwrite:
            raise OutputError(f"output folder {out} holds another run's output "
                              f"({_describe(prev)}); use --overwrite (or output: {{overwrite: "
                              f"true}}) to replace it, or another --out")
        for name in prev["frames"]:
            d = out / name
            with contextlib.suppress(OSError):
                if d.resolve() in protected:
                    raise OutputError(f"output folder {d} holds the scene's input meshes; "
                                      f"choose another --out")
        try:
            if prev["run_json"]:
                (out / "run.json").unlink()
                replaced["run_json"] = True
            for f in prev["stage"]:  # a USD run's stage files
                f.unlink()
                replaced["frame_files"] += 1
            for name, files in prev["frames"].items():
                for f in files:
                    os.unlink(f)
                    replaced["frame_files"] += 1
                _clean_temps(out / name)
                if name not in names:
                    with contextlib.suppress(OSError):
                        (out / name).rmdir()  # only when empty
        except OSError as exc:
            raise OutputError(f"cannot replace the previous run in {out}: {exc.filename}: "
                              f"{_reason(exc)}") from None
    for name in names:
        d = out / name
        if d.exists() and not d.is_dir():
            raise OutputError(f"element folder {d} is a file; remove it or choose another --out")
        try:
            d.mkdir(exist_ok=True)
        except OSError as exc:
            raise OutputError(f"cannot create element folder {d}: {_reason(exc)}") from None
        _clean_temps(d)
    for d in [out, *(out / n for n in names)]:
        probe = temp_path(d / "write-probe")
        try:
            with open(probe, "wb") as fh:
                fh.write(b"lokigraph")
        except OSError as exc:
            raise OutputError(f"cannot write in output folder {d}: {_reason(exc)}") from None
        finally:
            with contextlib.suppress(OSError):
                probe.unlink(missing_ok=True)
    return replaced


def prepare_resume(out: Path, names: list[str]) -> None:
    """Output folders of a run being resumed: its frames stay (those after the checkpoint are
    rewritten); stale temporaries are removed; OutputError (exit 2) if they cannot be written."""
    if not out.is_dir():
        raise OutputError(f"cannot resume: {out} is not a folder")
    _clean_temps(out)
    for name in names:
        d = out / name
        try:
            d.mkdir(exist_ok=True)
        except OSError as exc:
            raise OutputError(f"cannot create element folder {d}: {_reason(exc)}") from None
        _clean_temps(d)


def _frame_span(frames: list[int]) -> str:
    if not frames:
        return "no frames"
    if len(frames) == 1:
        return f"frame {frames[0]}"
    return f"frames {frames[0]}..{frames[-1]}"


@dataclass
class RunResult:
    state: State
    frames_written: list = field(default_factory=list)
    frame_seconds: list = field(default_factory=list)
    stats: list = field(default_factory=list)
    out_dir: Path | None = None
    error: BaseException | None = None
    status: str = "ok"
    elements: list = field(default_factory=list)
    format: str = "obj"
    run_json_error: str | None = None
    #: ``--format usd``: {"stage": path of run.usd (None before the first frame), "prims":
    #: element -> prim path} (lokigraph.usd)
    stage: dict | None = None

    def summary(self) -> str:
        """One line: what was written where, and run.json's status (the CLI prints it)."""
        if self.out_dir is None:
            return "nothing written"
        text = (f"{_frame_span(self.frames_written)} of "
                f"{', '.join(self.elements) or 'no element'} in {self.out_dir}")
        if self.stage and self.stage.get("stage"):
            text += f" (USD stage {self.stage['stage']})"
        if self.run_json_error:
            return text + f"; run.json could not be written ({self.run_json_error})"
        return text + f", run.json status {self.status}"


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
        #: the run's output folder (set by :func:`run` when it writes frames), else None
        self.out_dir: Path | None = None
        self.substep_index = 0
        #: ``on_substep(frame, k, substeps, time, seconds, stats)`` after each substep (``-v``)
        self.on_substep = None

    def begin(self, init: dict | None = None, preroll: int = 0,
              checkpoint: dict | None = None) -> int:
        """Set the starting point; returns the first simulated frame. ``checkpoint``: arrays
        of a checkpoint (lokigraph.checkpoint), restored exactly (the run goes on from its
        frame). Else ``init`` (lokigraph.checkpoint.load_initial_state) sets the dynamic
        elements' positions and velocities, and ``preroll`` frames are simulated before the
        scene's start frame (the clock starts ``preroll`` frames earlier)."""
        from . import checkpoint as ckpt

        if checkpoint is not None:
            ckpt.restore(self, checkpoint)
            return self.frame
        if init is not None:
            ckpt.apply_initial_state(self, init)
        if preroll:
            self.frame -= int(preroll)
            self.state.time = -preroll / self.model.fps
            self.control.time = self.state.time
        return self.frame

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
        for k in range(self.model.substeps):
            t0 = time.perf_counter()
            s = self.step_substep()
            if self.on_substep is not None:
                self.on_substep(self.frame + 1, k + 1, self.model.substeps, self.state.time,
                                time.perf_counter() - t0, s)
            for k, v in s.items():
                if isinstance(v, (int, float, np.floating, np.integer)):
                    v = float(v)
                    if k.startswith("max_"):
                        stats[k] = max(stats.get(k, -np.inf), v)
                    else:
                        stats[k] = stats.get(k, 0.0) + v
        self.frame += 1
        ctx = StepContext(self.model, self.state, self.control, self.model.dt, self.state.time,
                          self.substep_index, self.frame, self._constraints, {},
                          out_dir=self.out_dir)
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
        fmt: str | None = None, progress: bool | None = None, write: bool = True,
        overwrite: bool | None = None, verbose: bool = False, resume: bool = False) -> RunResult:
    """Simulate from the scene's start frame to the last requested frame; write frames A..B.

    ``overwrite`` (default: the scene's ``output.overwrite``) replaces another run's output in
    the folder. Raises InputError (bad ``frames`` or ``output.elements``) and OutputError (exit 2,
    a bad output location) before simulating; after the run starts, SimulationError, OutputError
    (exit 3, a write failure) and RunInterrupted (SIGINT/SIGTERM) are raised after run.json is
    written with status "failed" or "interrupted"; frames already written stay. The exception
    carries the :class:`RunResult` as ``.result``.

    Checkpoints (``output.checkpoint_every``, lokigraph.checkpoint) go to ``DIR/checkpoints``;
    ``resume`` continues the run in ``DIR`` from its newest checkpoint (OutputError, exit 2,
    when there is none or it is another scene's). ``initial_state`` and ``preroll`` of the
    scene set where the simulation starts.
    """
    from . import checkpoint as ckpt

    spec = compiled.scene.spec
    start, end = spec.frames.start, spec.frames.end
    a, b = frames if frames is not None else (start, end)
    if not start <= a <= b <= end:
        raise InputError(f"--frames {a}:{b} is outside the scene's frame range {start}:{end} "
                         f"(give A:B with {start} <= A <= B <= {end})")
    fmt = fmt or spec.output.format
    if fmt not in FORMATS:
        raise InputError(f"unknown output format {fmt!r} (one of {', '.join(FORMATS)})")
    if fmt == "usd" and write:
        from .usd import INSTALL_HINT, have_pxr

        if not have_pxr():
            raise InputError(f"--format usd needs usd-core, which is not installed; "
                             f"{INSTALL_HINT}")
    overwrite = bool(spec.output.overwrite if overwrite is None else overwrite)
    out = Path(out_dir if out_dir is not None else spec.output.dir)
    outs = output_elements(compiled)
    resumed = None
    if resume:  # the run's own frames, format and first frame; only the last may change
        if not write:
            raise InputError("--resume needs output (it continues the run written in DIR)")
        resumed = ckpt.resume_point(compiled, out, fmt if fmt != spec.output.format else None,
                                    frames)
        a, b = resumed[1]["requested"][0], (frames[1] if frames is not None
                                            else resumed[1]["requested"][1])
        fmt = resumed[1]["format"]
    init = ckpt.load_initial_state(compiled) if resumed is None else None
    replaced = None
    if write and resumed is not None:
        prepare_resume(out, [el.name for el in outs])
    elif write:
        replaced = prepare_output(out, [] if fmt == "usd" else [el.name for el in outs],
                                  overwrite, _input_dirs(compiled))
        ckpt.clear(out)
    sim = Simulation(compiled)
    sim.out_dir = out if write else None
    first = sim.begin(init, spec.preroll, resumed[0] if resumed else None)
    if resumed is not None:
        first = int(resumed[1]["first"])  # the run's checkpoint schedule goes on
    result = RunResult(sim.state, out_dir=out if write else None,
                       elements=[el.name for el in outs], format=fmt)
    if progress is None:
        progress = sys.stderr.isatty()
    bar = None
    if progress or verbose:  # lokigraph.progress: a bar on a terminal, plain lines otherwise
        from .progress import RunProgress

        bar = RunProgress(start, b, show=bool(progress), verbose=verbose)
        if verbose:
            sim.on_substep = bar.substep
    sigs = _Signals()
    stage = _open_stage(out, outs, spec, a, result) if write and fmt == "usd" else None

    def write_frame(frame: int) -> None:
        if not write:
            return
        with sigs.deferred():  # a signal waits until the frame is complete for every element
            if stage is not None:  # USD: every element into the run's stage
                _write_stage_frame(stage, frame, sim.state, result)
                return
            for el in outs:
                sl = el.vertex_slice
                pts = sim.state.particle_q[sl]
                vel = sim.state.particle_qd[sl]
                path = out / el.name / f"{frame:04d}.{fmt}"
                try:
                    atomic_write(path, lambda p: write_mesh(p, pts, el.geometry, fmt,
                                                            velocities=vel))
                except OSError as exc:
                    raise OutputError(f"cannot write {path}: {_reason(exc)}",
                                      EXIT_SIMULATION) from None
            result.frames_written.append(frame)

    t_start = time.perf_counter()
    record = []
    if resumed is not None:  # the run so far: its written frames and per-frame records
        result.frames_written.extend(resumed[1]["written"])
        record.extend(resumed[1]["record"])
    # no checkpoints for USD output: the stage writer cannot append to a stopped run's stage
    cps = ckpt.Checkpointer(compiled, out, spec.output.checkpoint_every
                            if write and fmt != "usd" else 0,
                            spec.output.checkpoint_keep, fmt, (a, b), first, result, record,
                            resumed_from=sim.frame if resumed else None)
    with sigs:
        try:
            if a == start and sim.frame == start and resumed is None:
                write_frame(start)
            with sigs.deferred():
                cps.after_frame(sim)
            for frame in range(sim.frame + 1, b + 1):
                t0 = time.perf_counter()
                stats = sim.step_frame()
                dt = time.perf_counter() - t0
                result.frame_seconds.append(dt)
                result.stats.append(stats)
                record.append({"frame": frame, "seconds": dt, "stats": stats})
                if frame >= a:
                    write_frame(frame)
                with sigs.deferred():
                    cps.after_frame(sim)
                if bar and frame >= start:
                    bar.update(frame, dt)
        except KeyboardInterrupt as exc:
            result.status, result.error = "interrupted", exc
        except (SimulationError, OutputError) as exc:
            result.status, result.error = "failed", exc
        except Exception as exc:  # a bug: still record the run, then let it propagate
            result.status, result.error = "failed", exc
        finally:
            if bar:
                bar.close()
            if stage is not None:
                stage.close()
            if result.error is not None:
                with contextlib.suppress(OSError, KeyboardInterrupt), sigs.deferred():
                    cps.final()
        if write:
            try:
                with sigs.deferred():  # signals wait until run.json is written
                    _write_run_json(compiled, out, result, record, replaced, overwrite,
                                    (a, b), time.perf_counter() - t_start,
                                    {"resumed_from": resumed[1]["frame"] if resumed else None,
                                     "checkpoints": cps.info(), "preroll": spec.preroll,
                                     "initial_state": None if init is None else {
                                         "source": init["source"],
                                         "frame": spec.initial_state.frame},
                                     "warnings": [] if init is None else init["warnings"]})
            except OSError as exc:
                result.run_json_error = _reason(exc)
                if result.error is None:
                    result.status = "failed"
                    result.error = OutputError(f"cannot write {out / 'run.json'}: "
                                               f"{_reason(exc)}", EXIT_SIMULATION)
            except KeyboardInterrupt:
                pass  # a signal while writing run.json (now written): the run's status stands
    if result.error is not None:
        with contextlib.suppress(AttributeError, TypeError):
            result.error.result = result
        raise result.error
    return result


# -- USD output (lokigraph.usd): one stage per run instead of a file per element per frame --

def _open_stage(out: Path, outs: list, spec, first: int, result: RunResult):
    """The run's :class:`~lokigraph.usd.StageWriter` (prims and topology written); OutputError
    (exit 2) if it cannot be created."""
    from pxr import Tf

    from .usd import StageWriter

    try:
        stage = StageWriter(out, outs, spec.frames.fps, first, {"lokigraph": __version__})
    except (OSError, Tf.ErrorException) as exc:
        raise OutputError(f"cannot create the USD stage in {out}: "
                          f"{' '.join(str(exc).split())}") from None
    result.stage = {"stage": None, "prims": dict(stage.prims)}
    return stage


def _write_stage_frame(stage, frame: int, state, result: RunResult) -> None:
    from pxr import Tf

    try:
        stage.write(frame, state.particle_q, state.particle_qd)
    except (OSError, Tf.ErrorException) as exc:
        raise OutputError(f"cannot write frame {frame} into the USD stage {stage.root_path}: "
                          f"{' '.join(str(exc).split())}", EXIT_SIMULATION) from None
    result.stage["stage"] = str(stage.stage_path)
    result.frames_written.append(frame)


def _write_run_json(compiled, out: Path, result: RunResult, record: list, replaced, overwrite,
                    requested: tuple[int, int], seconds: float,
                    extra: dict | None = None) -> None:
    spec = compiled.scene.spec
    err = result.error
    by = getattr(err, "signum", signal.SIGINT) if isinstance(err, KeyboardInterrupt) else None
    if err is None:
        text = None
    elif by is not None:
        text = f"interrupted by {signal.Signals(by).name}"
    elif isinstance(err, (SimulationError, OutputError)):
        text = str(err)
    else:
        text = f"internal error: {type(err).__name__}: {err}"
    info = {
        "status": result.status,
        "error": text,
        "interrupted_by": None if by is None else signal.Signals(by).name,
        "scene_file": compiled.scene.file,
        "scene": compiled.scene.raw,
        "versions": _versions(),
        "frames": {"start": spec.frames.start, "end": spec.frames.end,
                   "requested": list(requested), "written": result.frames_written,
                   "fps": spec.frames.fps, "substeps": spec.substeps},
        "format": result.format,
        "output": {"dir": str(out), "format": result.format, "elements": result.elements,
                   "kinematic": spec.output.kinematic, "elements_requested": spec.output.elements,
                   "overwrite": overwrite, "replaced": replaced,
                   # velocities reach the writer; PLY, VTU and USD hold them, OBJ cannot
                   "velocities": True,
                   "usd": result.stage},
        "schedule": compiled.schedule.as_dict(),
        "total_seconds": seconds,
        "per_frame": record,
        **(extra or {}),
    }
    data = json.dumps(info, indent=1, default=_json_default)
    atomic_write(out / "run.json", lambda p: p.write_text(data))


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
