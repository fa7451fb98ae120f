"""Checkpoints: the full simulation state of a run at a frame, to resume it bit for bit.

A checkpoint is ``OUT/checkpoints/NNNN.npz`` (the frame, 4 digits as frame files), written
atomically (temporary + rename); a run keeps the newest ``output.checkpoint_keep``. It holds

* ``state/<name>``: the State arrays (positions, velocities, force accumulator, start-of-substep
  positions) and every array in ``State.fields``; ``state/time`` (exact float64);
* ``control/<name>``: Control's animated positions (end and start of the substep) and time;
* ``sim/frame``, ``sim/substep_index``: the Simulation counters;
* ``behavior/<node>/<key>``: each behavior's per-run memory
  (:meth:`~lokigraph.behavior.Behavior.state_arrays`), keyed by the graph node name;
* ``meta``: JSON: format version, the scene hash (:func:`scene_hash`), the frame, the output
  format, the requested frames, the frames written so far and the per-frame records of run.json
  (so a resumed run's run.json describes the whole run).

No behavior draws random numbers at run time (the broad phase's permutation is seeded with a
constant; wind noise is a function of position, time and ``Wind.seed``), so there is no RNG
state; a behavior that adds one stores its generator's state through ``state_arrays``.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
from pathlib import Path

import numpy as np

FORMAT_VERSION = 1
DIR_NAME = "checkpoints"
_NAME_RE = re.compile(r"^(-?\d+)\.npz$")


class CheckpointError(Exception):
    """A checkpoint that cannot be read or does not fit the scene."""


def scene_hash(compiled) -> str:
    """sha256 of the scene file's text, the compiled graph (nodes, parameters, order) and the
    versions of lokigraph and the numerical libraries (a checkpoint resumes only the same run)."""
    import numba

    from . import __version__

    h = hashlib.sha256()
    try:
        h.update(Path(compiled.scene.file).read_bytes())
    except OSError:
        h.update(json.dumps(compiled.scene.raw, sort_keys=True, default=str).encode())
    h.update(json.dumps(compiled.schedule.as_dict(), sort_keys=True, default=str).encode())
    h.update(f"{__version__} {np.__version__} {numba.__version__}".encode())
    return h.hexdigest()


def folder(out: Path) -> Path:
    return Path(out) / DIR_NAME


def path_for(out: Path, frame: int) -> Path:
    return folder(out) / f"{frame:04d}.npz"


def list_checkpoints(out: Path) -> list[tuple[int, Path]]:
    """(frame, path) of the checkpoints in ``out``, oldest first."""
    found = []
    with contextlib.suppress(OSError), os.scandir(folder(out)) as it:
        for e in it:
            mt = _NAME_RE.match(e.name)
            if mt and e.is_file(follow_symlinks=False):
                found.append((int(mt.group(1)), Path(e.path)))
    return sorted(found)


def capture(sim) -> dict[str, np.ndarray]:
    """Copies of every array of ``sim``'s state at a frame boundary."""
    st, ctl = sim.state, sim.control
    arrays = {
        "state/particle_q": st.particle_q, "state/particle_qd": st.particle_qd,
        "state/particle_f": st.particle_f, "state/particle_q_prev": st.particle_q_prev,
        "state/time": np.float64(st.time),
        "control/kinematic_q": ctl.kinematic_q, "control/kinematic_q_prev": ctl.kinematic_q_prev,
        "control/time": np.float64(ctl.time),
        "sim/frame": np.int64(sim.frame), "sim/substep_index": np.int64(sim.substep_index),
    }
    for name, v in st.fields.items():
        if isinstance(v, np.ndarray):
            arrays[f"field/{name}"] = v
    for b in sim.schedule.all():
        for key, v in (b.behavior.state_arrays(b.data) or {}).items():
            arrays[f"behavior/{b.behavior.name}/{key}"] = v
    return {k: np.array(v, copy=True) for k, v in arrays.items()}


def restore(sim, arrays: dict[str, np.ndarray]) -> None:
    """Put ``arrays`` (from :func:`capture` or :func:`load`) into ``sim``, in place.

    Raises CheckpointError when an array is missing or its shape differs."""
    def get(key, like=None):
        if key not in arrays:
            raise CheckpointError(f"the checkpoint has no {key!r}")
        v = arrays[key]
        if like is not None and (v.shape != like.shape):
            raise CheckpointError(f"{key!r} has shape {v.shape}, the scene needs {like.shape}")
        return v

    st, ctl = sim.state, sim.control
    for name in ("particle_q", "particle_qd", "particle_f", "particle_q_prev"):
        cur = getattr(st, name)
        cur[...] = get(f"state/{name}", cur)
    st.time = float(get("state/time"))
    for name in ("kinematic_q", "kinematic_q_prev"):
        cur = getattr(ctl, name)
        cur[...] = get(f"control/{name}", cur)
    ctl.time = float(get("control/time"))
    sim.frame = int(get("sim/frame"))
    sim.substep_index = int(get("sim/substep_index"))
    for name, v in st.fields.items():
        if isinstance(v, np.ndarray):
            v[...] = get(f"field/{name}", v)
    for b in sim.schedule.all():
        prefix = f"behavior/{b.behavior.name}/"
        want = b.behavior.state_arrays(b.data) or {}
        if not want:
            continue
        got = {}
        for key, cur in want.items():
            got[key] = get(prefix + key, np.asarray(cur))
        b.behavior.load_state_arrays(b.data, got)


def save(out: Path, frame: int, arrays: dict[str, np.ndarray], meta: dict, keep: int = 2) -> Path:
    """Write checkpoint ``frame`` atomically, then remove all but the newest ``keep``."""
    from .run import atomic_write

    d = folder(out)
    d.mkdir(exist_ok=True)
    path = path_for(out, frame)
    payload = dict(arrays)
    payload["meta"] = np.array(json.dumps(meta, default=_json_default))

    def writer(tmp):
        with open(tmp, "wb") as fh:
            np.savez(fh, **payload)
            fh.flush()
            os.fsync(fh.fileno())

    atomic_write(path, writer)
    for _f, old in list_checkpoints(out)[:-keep]:
        with contextlib.suppress(OSError):
            old.unlink()
    return path


def load(path: Path) -> tuple[dict[str, np.ndarray], dict]:
    """(arrays, meta) of a checkpoint file; CheckpointError if it cannot be read."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, KeyError, EOFError) as exc:
        raise CheckpointError(f"cannot read checkpoint {path}: {exc}") from None
    try:
        meta = json.loads(str(arrays.pop("meta")))
    except (KeyError, ValueError) as exc:
        raise CheckpointError(f"checkpoint {path} has no valid metadata: {exc}") from None
    if meta.get("version") != FORMAT_VERSION:
        raise CheckpointError(f"checkpoint {path} has format version {meta.get('version')}, "
                              f"this lokigraph reads {FORMAT_VERSION}")
    return arrays, meta


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


# -- writing during a run ------------------------------------------------------------------

class Checkpointer:
    """Checkpoints of one run: a snapshot at every frame boundary (in memory), written to disk
    every ``every`` frames (counted from the first simulated frame), at the last frame, and by
    :meth:`final` when the run stops early (the last complete frame, if its state is finite)."""

    def __init__(self, compiled, out: Path, every: int, keep: int, fmt: str,
                 requested: tuple[int, int], first: int, result, record: list,
                 resumed_from: int | None = None):
        self.out = Path(out)
        self.every = int(every)
        self.keep = int(keep)
        self.enabled = self.every > 0
        self.first = first
        self.last = requested[1]
        self.result, self.record = result, record
        self.base = {"version": FORMAT_VERSION, "scene_hash": scene_hash(compiled) if
                     self.enabled else None, "scene_file": str(compiled.scene.file),
                     "format": fmt, "requested": list(requested), "first": first,
                     "elements": list(result.elements), "elements_layout": layout(compiled)}
        self.snapshot = None
        self.saved: list[int] = []
        self.resumed_from = resumed_from

    def _meta(self, frame: int) -> dict:
        return dict(self.base, frame=frame, written=list(self.result.frames_written),
                    record=list(self.record))

    def after_frame(self, sim) -> None:
        """Call at every frame boundary, after the frame is written."""
        if not self.enabled:
            return
        frame = sim.frame
        self.snapshot = (frame, capture(sim), len(self.result.frames_written), len(self.record))
        if (frame - self.first) % self.every == 0 or frame == self.last:
            self._write()

    def _write(self) -> None:
        frame, arrays, n_written, n_record = self.snapshot
        if frame in self.saved or frame == self.resumed_from:
            return
        meta = dict(self.base, frame=frame, written=list(self.result.frames_written[:n_written]),
                    record=list(self.record[:n_record]))
        save(self.out, frame, arrays, meta, self.keep)
        self.saved.append(frame)

    def final(self) -> None:
        """The run stopped (interrupted or failed): checkpoint its last complete frame if its
        state is finite and not checkpointed yet."""
        if not self.enabled or self.snapshot is None:
            return
        arrays = self.snapshot[1]
        if all(np.isfinite(arrays[k]).all() for k in ("state/particle_q", "state/particle_qd")):
            self._write()

    def info(self) -> dict:
        return {"every": self.every, "keep": self.keep, "written": list(self.saved),
                "folder": str(folder(self.out)) if self.enabled else None}


def clear(out: Path) -> None:
    """Remove the checkpoints of a previous run in ``out`` (a fresh run replaces them)."""
    for _f, p in list_checkpoints(out):
        with contextlib.suppress(OSError):
            p.unlink()


# -- --resume ------------------------------------------------------------------------------

def resume_point(compiled, out: Path, fmt: str | None, frames) -> tuple[dict, dict]:
    """(arrays, meta) of the newest readable checkpoint in ``out`` for ``compiled``'s scene.

    Raises OutputError (exit 2): no checkpoint, a checkpoint of a different scene, another
    format, or USD output (whose stage writer cannot append to an existing stage)."""
    from .errors import OutputError

    out = Path(out)
    if fmt == "usd":
        raise OutputError("--resume does not support --format usd: the USD stage writer starts "
                          "a new stage and cannot append to the stage of a stopped run; rerun "
                          "with --overwrite, or use obj, ply or vtu output to resume")
    found = list_checkpoints(out)
    if not found:
        raise OutputError(f"cannot resume: {folder(out)} holds no checkpoint (output."
                          f"checkpoint_every must be > 0 in the run to resume); run again with "
                          f"--overwrite")
    want = scene_hash(compiled)
    errors = []
    for frame, path in reversed(found):  # the newest readable one
        try:
            arrays, meta = load(path)
        except CheckpointError as exc:
            errors.append(str(exc))
            continue
        if meta.get("scene_hash") != want:
            raise OutputError(
                f"cannot resume {out}: its checkpoint {path.name} is of a different scene "
                f"({meta.get('scene_file')}; the scene file, its graph or the lokigraph/numpy/"
                f"numba versions differ from {compiled.scene.file}); resume with the scene it "
                f"was run with, or start a new run with --overwrite")
        if meta.get("format") == "usd":
            raise OutputError("--resume does not support USD output (see --format usd)")
        if fmt is not None and fmt != meta.get("format"):
            raise OutputError(f"cannot resume {out} with --format {fmt}: the run wrote "
                              f"{meta.get('format')} frames")
        if frames is not None and tuple(frames)[0] != meta["requested"][0]:
            raise OutputError(f"cannot resume {out} with --frames {frames[0]}:{frames[1]}: the "
                              f"run wrote frames from {meta['requested'][0]} (only the last "
                              f"frame may change)")
        if frames is not None and tuple(frames)[1] < frame:
            raise OutputError(f"cannot resume {out} up to frame {frames[1]}: its last "
                              f"checkpoint is at frame {frame}")
        return arrays, meta
    raise OutputError(f"cannot resume {out}: no readable checkpoint ({'; '.join(errors)})")


# -- initial_state --------------------------------------------------------------------------

def load_initial_state(compiled) -> dict | None:
    """The dynamic elements' positions and velocities at ``initial_state``'s frame of a
    previous run: {"q": {element: (n,3)}, "qd": {element: (n,3)}, "source", "warnings"}.

    From that run's checkpoint at the frame if it has one, else from its frame files
    (velocities from PLY/VTU, zero from OBJ with a warning). Raises InputError at the scene's
    ``initial_state`` line: missing folder, frame not written, vertex count mismatch."""
    from .errors import InputError

    scene = compiled.scene
    init = scene.spec.initial_state
    if init is None:
        return None
    locs = scene.locations
    src = Path(init.from_)

    def fail(key, msg):
        raise InputError(locs.diag(("initial_state", key), f"initial_state: {msg}",
                                   field=f"initial_state.{key}"))

    if not src.is_dir():
        fail("from", f"{src} is not a folder (give the output folder of a previous run, "
                     f"relative to the current directory)")
    m = compiled.model
    dyn = [el for el in scene.elements if el.geometry is not None and el.vertex_count
           and not m.particle_kinematic[el.vertex_slice].all()]
    q, qd, warnings = {}, {}, []
    ck = path_for(src, init.frame)
    if ck.is_file():
        try:
            arrays, meta = load(ck)
        except CheckpointError as exc:
            fail("from", str(exc))
        elems = meta.get("elements_layout") or {}
        for el in dyn:
            lay = elems.get(el.name)
            if lay is None:
                fail("from", f"the run in {src} has no element {el.name!r}")
            off, n = lay
            if n != el.vertex_count:
                fail("from", f"element {el.name!r} has {el.vertex_count} vertices, the run in "
                             f"{src} has {n}")
            q[el.name] = arrays["state/particle_q"][off:off + n].copy()
            qd[el.name] = arrays["state/particle_qd"][off:off + n].copy()
        return {"q": q, "qd": qd, "source": str(ck), "warnings": warnings}
    from .meshfile import read_mesh

    for el in dyn:
        d = src / el.name
        files = [d / f"{init.frame:04d}.{ext}" for ext in ("ply", "vtu", "obj")]
        path = next((f for f in files if f.is_file()), None)
        if path is None:
            have = sorted(int(p.stem) for p in d.glob("*.*") if p.stem.lstrip("-").isdigit()) \
                if d.is_dir() else []
            where = (f"{d} has frames {have[0]}..{have[-1]}" if have else
                     f"{d} holds no frame files")
            fail("frame", f"frame {init.frame} of {el.name!r} was not written by the run in "
                          f"{src} ({where})")
        try:
            g = read_mesh(path)
        except Exception as exc:  # noqa: BLE001 - any reader problem is the user's file
            fail("from", f"cannot read {path}: {exc}")
        if g.vertex_count != el.vertex_count:
            fail("from", f"{path} has {g.vertex_count} vertices, element {el.name!r} has "
                         f"{el.vertex_count}")
        q[el.name] = np.asarray(g.points, np.float64)
        ch = g.channels
        v = None
        if "velocity" in ch and np.shape(ch["velocity"]) == (el.vertex_count, 3):
            v = ch["velocity"]
        elif all(c in ch for c in ("vx", "vy", "vz")):
            v = np.stack([np.ravel(ch[c]) for c in ("vx", "vy", "vz")], axis=1)
        if v is None:
            warnings.append(f"initial_state: {path} holds no velocities; {el.name!r} starts "
                            f"at rest")
            v = np.zeros((el.vertex_count, 3))
        qd[el.name] = np.asarray(v, np.float64)
    return {"q": q, "qd": qd, "source": str(src), "warnings": warnings}


def apply_initial_state(sim, init: dict) -> None:
    """Set the dynamic elements' positions and velocities (non-kinematic vertices only)."""
    m = sim.model
    for el in sim.compiled.scene.elements:
        if el.name not in init["q"]:
            continue
        sl = el.vertex_slice
        free = ~m.particle_kinematic[sl]
        for arr, src in ((sim.state.particle_q, init["q"][el.name]),
                         (sim.state.particle_q_prev, init["q"][el.name]),
                         (sim.state.particle_qd, init["qd"][el.name])):
            part = arr[sl]
            part[free] = src[free]
            arr[sl] = part


def layout(compiled) -> dict:
    """element name -> (vertex offset, vertex count), for initial_state from a checkpoint."""
    return {el.name: (el.vertex_offset, el.vertex_count) for el in compiled.scene.elements
            if el.geometry is not None}
