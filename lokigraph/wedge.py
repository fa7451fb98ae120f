"""Wedges: every combination of parameter values, each its own run, on dask.distributed.

``lokigraph wedge SCENE --vary substeps=1,2,4 --vary cloth.DiscreteShell.bend_resistance=1e-6,1e-5``
runs the cartesian product of the values (here 6 variants), each as a normal run (the code path of
``lokigraph run``, with its ``run.json``) into ``DIR/<variant>/``, on an embedded
:class:`distributed.LocalCluster` (one single-threaded worker process per core) or on an existing
cluster (``--scheduler tcp://HOST:PORT`` or a scheduler file).

Keys of ``--vary``
------------------
- a top-level scene field: ``substeps``, ``solver``, ``gravity``, ``seed``, ``graph``, and the
  fields of ``frames`` and ``output`` as ``frames.fps``;
- ``ELEMENT.COMPONENT.FIELD`` (deeper keys go into the field's mapping), for a component the element
  has; ``ELEMENT.geometry.params.resolution`` and ``ELEMENT.channels...`` reach the element's own
  fields (element names may hold dots: the longest matching name wins);
- ``graph_overrides.NODE.PARAM``.

Values are YAML scalars separated by commas (``1e-6`` is a float, ``true`` a boolean); a list
keeps its commas inside brackets: ``gravity=[0,-9.81,0],[0,-1.62,0]``. Every variant is built and
compiled before anything runs; an unknown key or an invalid value is an input error (exit 2).

Variant folders
---------------
``DIR/<name>/`` with ``name`` = ``KEY=VALUE`` joined by ``__`` in the order of the ``--vary``
options (floats as Python writes them: ``1e-05``), characters other than letters, digits and
``._,=+-`` replaced by ``_``, and a short hash of the full name appended when something was replaced
or the name is longer than 120 characters (so names stay unique and stable). Each holds
``variant.yaml`` (the modified scene, relative paths of mesh, map and graph files made absolute;
the run also resolves any other relative path against the original scene's folder), the frames
and ``run.json``.

Resume: a variant whose ``run.json`` has status ``ok`` for the same ``variant.yaml``, frames and
format is skipped; failed, interrupted (no ``run.json``, e.g. a killed wedge) and changed variants
run again. ``--overwrite`` runs every variant.

Results: ``DIR/wedge.json`` and ``DIR/wedge.csv`` (one row per variant: parameters, status,
exit code, error, wall and CPU time, ms/frame, and the maximum over frames of every numeric
per-frame statistic of ``run.json`` as ``max.<stat>``), rewritten as variants finish, and
``DIR/contact_sheet.png`` (the last written frame of each variant, captioned).

Workers need lokigraph importable and the paths of the scene and ``DIR`` visible (one machine, or
a shared file system). The embedded cluster sets ``NUMBA_NUM_THREADS=1`` (and the BLAS/OpenMP
thread counts) in every worker so that N workers use N cores; give the same environment to the
workers of an external cluster.
"""

from __future__ import annotations

import copy
import csv
import hashlib
import io
import itertools
import json
import math
import os
import re
import sys
import time
import traceback
from pathlib import Path

import yaml

from .errors import EXIT_INPUT, EXIT_OK, EXIT_SIMULATION, InputError, LokigraphError, OutputError

EXTRA_HINT = "pip install 'lokigraph[wedge]' (or: pip install 'dask[distributed]>=2024.1')"
#: environment of the embedded cluster's workers: one thread each, so N workers use N cores
WORKER_ENV = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "OPENBLAS_NUM_THREADS": "1"}
MAX_NAME = 120
_SAFE = re.compile(r"[^A-Za-z0-9._,=+\-]")
_ELEMENT_FIELDS = ("geometry", "channels")


# --------------------------------------------------------------------------------------------
# --vary parsing and variants

def _split_values(text: str) -> list[str]:
    """Split on commas outside brackets: ``1,[0,-9.8,0],3`` -> ``1``, ``[0,-9.8,0]``, ``3``."""
    out, depth, cur = [], 0, []
    for ch in text:
        if ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        if ch == "," and depth == 0:
            out.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    out.append("".join(cur))
    return [s.strip() for s in out]


def parse_value(text: str):
    """A YAML scalar (or flow list/mapping); ``1e-6`` (a string to YAML 1.1) is a float."""
    try:
        v = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"{text!r} is not a YAML value: {str(exc).splitlines()[0]}") from None
    return _numbers(v)


def _numbers(v):
    """YAML 1.1 reads ``1e-6`` and ``-1e300`` as strings; they are numbers here (also in lists)."""
    if isinstance(v, str):
        for conv in (int, float):
            try:
                return conv(v)
            except ValueError:
                pass
    elif isinstance(v, list):
        return [_numbers(x) for x in v]
    elif isinstance(v, dict):
        return {k: _numbers(x) for k, x in v.items()}
    return v


def parse_vary(items) -> list[tuple[str, list]]:
    """``["substeps=1,2", ...]`` (or a mapping key -> values) -> ``[(key, [values]), ...]``."""
    if isinstance(items, dict):
        pairs = [(k, list(v) if isinstance(v, (list, tuple)) else [v]) for k, v in items.items()]
    else:
        pairs = []
        for text in items:
            key, sep, vals = str(text).partition("=")
            key = key.strip()
            if not sep or not key or not vals.strip():
                raise InputError(f"--vary {text!r}: expected KEY=V1,V2,... (e.g. substeps=1,2,4)")
            values = []
            for s in _split_values(vals):
                if not s:
                    raise InputError(f"--vary {text!r}: empty value")
                try:
                    values.append(parse_value(s))
                except ValueError as exc:
                    raise InputError(f"--vary {text!r}: {exc}") from None
            pairs.append((key, values))
    if not pairs:
        raise InputError("wedge: give at least one --vary KEY=V1,V2,...")
    seen = set()
    for key, values in pairs:
        if key in seen:
            raise InputError(f"--vary: key {key!r} given twice; list all its values in one "
                             f"option (KEY=V1,V2,...)")
        seen.add(key)
        if not values:
            raise InputError(f"--vary {key}: no values")
        texts = [format_value(v) for v in values]
        dup = {t for t in texts if texts.count(t) > 1}
        if dup:
            raise InputError(f"--vary {key}: value {sorted(dup)[0]} given twice")
    return pairs


def format_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if v is None:
        return "null"
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (int, str)):
        return str(v)
    if isinstance(v, list) and all(isinstance(x, (int, float, bool, str)) for x in v):
        return ",".join(format_value(x) for x in v)
    return json.dumps(v, separators=(",", ":"))


def variant_name(params: list[tuple[str, object]]) -> str:
    """Readable, stable folder name: ``substeps=2__cloth.DiscreteShell.bend_resistance=1e-05``."""
    full = "__".join(f"{k}={format_value(v)}" for k, v in params)
    safe = _SAFE.sub("_", full)
    if safe != full or len(safe) > MAX_NAME or safe.startswith("."):
        digest = hashlib.sha1(full.encode()).hexdigest()[:8]
        safe = safe.lstrip(".")[:MAX_NAME - 10] + "__" + digest
    return safe


def _suggest(word: str, options) -> str:
    import difflib

    close = difflib.get_close_matches(word, list(options), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def resolve_key(key: str, data: dict) -> tuple:
    """The path into the scene data that ``key`` addresses; InputError for an unknown key."""
    from .registry import get_registry
    from .scene import Frames, Output, SceneSpec

    parts = key.split(".")
    if any(not p for p in parts):
        raise InputError(f"--vary {key}: empty part in the key")
    head = parts[0]
    if head == "graph_overrides":
        if len(parts) < 3:
            raise InputError(f"--vary {key}: expected graph_overrides.NODE.PARAM")
        return tuple(parts)
    elements = data.get("elements") if isinstance(data.get("elements"), list) else []
    names = [e.get("name") for e in elements if isinstance(e, dict)]
    top = {k for k in SceneSpec.model_fields if k not in ("elements", "lokigraph")}
    if head in top and head not in names:
        sub = {"frames": Frames, "output": Output}.get(head)
        if len(parts) > 1:
            if sub is not None and parts[1] not in sub.model_fields:
                raise InputError(f"--vary {key}: {head} has no field {parts[1]!r}"
                                 f"{_suggest(parts[1], sub.model_fields)} (fields: "
                                 f"{', '.join(sub.model_fields)})")
            if sub is None and head not in ("gravity", "reference"):
                raise InputError(f"--vary {key}: {head} is a single value; use --vary {head}=...")
        return tuple(int(p) if p.isdigit() else p for p in parts)
    # ELEMENT.COMPONENT.FIELD: the longest element name that prefixes the key
    match = None
    for i, name in enumerate(names):
        if not isinstance(name, str):
            continue
        n = len(name.split("."))
        if ".".join(parts[:n]) == name and (match is None or n > match[1]):
            match = (i, n)
    if match is None:
        raise InputError(
            f"--vary {key}: unknown key {head!r}: not a scene field "
            f"({', '.join(sorted(top))}), an element ({', '.join(map(str, names)) or 'none'}) "
            f"or graph_overrides.NODE.PARAM{_suggest(head, [*top, *map(str, names)])}")
    index, n = match
    rest = parts[n:]
    ename = names[index]
    if not rest:
        raise InputError(f"--vary {key}: expected {ename}.COMPONENT.FIELD")
    if rest[0] in _ELEMENT_FIELDS:
        if len(rest) < 2:
            raise InputError(f"--vary {key}: give a field of {ename}.{rest[0]}")
        return ("elements", index) + tuple(int(p) if p.isdigit() else p for p in rest)
    comps = elements[index].get("components") or {}
    if rest[0] not in comps:
        reg = get_registry()
        what = "" if rest[0] in reg.components else " (not a component type either)"
        raise InputError(f"--vary {key}: element {ename!r} has no component {rest[0]!r}{what}"
                         f"{_suggest(rest[0], comps) if comps else ''}; it has: "
                         f"{', '.join(comps) or 'none'}")
    if len(rest) < 2:
        raise InputError(f"--vary {key}: expected {ename}.{rest[0]}.FIELD")
    cls = get_registry().components.get(rest[0])
    if cls is not None and rest[1] not in cls.model_fields:
        raise InputError(f"--vary {key}: component {rest[0]} has no field {rest[1]!r}"
                         f"{_suggest(rest[1], cls.model_fields)} (fields: "
                         f"{', '.join(cls.model_fields)})")
    return ("elements", index, "components") + tuple(int(p) if p.isdigit() else p for p in rest)


def set_path(data, path: tuple, value) -> None:
    cur = data
    for i, p in enumerate(path[:-1]):
        nxt = path[i + 1]
        if isinstance(cur, list):
            if not isinstance(p, int) or p >= len(cur):
                raise InputError(f"--vary {'.'.join(map(str, path))}: no item {p}")
            cur = cur[p]
            continue
        if not isinstance(cur, dict):
            raise InputError(f"--vary {'.'.join(map(str, path))}: {p!r} is inside a value that "
                             f"is not a mapping")
        if cur.get(p) is None:
            cur[p] = [] if isinstance(nxt, int) else {}
        cur = cur[p]
    last = path[-1]
    if isinstance(cur, list):
        if not isinstance(last, int) or last >= len(cur):
            raise InputError(f"--vary {'.'.join(map(str, path))}: no item {last}")
    elif not isinstance(cur, dict):
        raise InputError(f"--vary {'.'.join(map(str, path))}: the parent is not a mapping")
    cur[last] = value


def _absolute(value: str, base: Path) -> str:
    return value if os.path.isabs(value) else str((base / value).resolve())


def absolutise_paths(data: dict, base: Path) -> None:
    """Relative input paths -> absolute (so ``variant.yaml`` runs from its own folder):
    ``file``/``sequence`` keys anywhere in an element (geometry, channel and component maps),
    a graph file, ``reference.file``."""
    def walk(node):
        if isinstance(node, dict):
            for k, v in node.items():
                if k in ("file", "sequence") and isinstance(v, str) and v:
                    node[k] = _absolute(v, base)
                else:
                    walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)

    walk(data.get("elements"))
    g = data.get("graph")
    if isinstance(g, str) and Path(g).suffix in (".yaml", ".yml") and (base / g).exists():
        data["graph"] = _absolute(g, base)
    ref = data.get("reference")
    if isinstance(ref, dict) and isinstance(ref.get("file"), str):
        ref["file"] = _absolute(ref["file"], base)


def variant_text(data: dict, scene_file: Path, params) -> str:
    head = (f"# lokigraph wedge variant of {scene_file}\n"
            + "".join(f"#   {k} = {format_value(v)}\n" for k, v in params)
            + f"# relative paths resolve against {scene_file.parent}\n")
    return head + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)


def load_variant(variant_file: str | Path, scene_file: str | Path, text: str | None = None):
    """Scene of a variant: its YAML, with the original scene's folder as base for relative
    paths; ``scene.file`` names the variant file. Raises InputError."""
    from .scene import scene_from_data
    from .yamlio import load_yaml, load_yaml_text

    if text is None:
        data, locs = load_yaml(variant_file)
    else:
        data, locs = load_yaml_text(text, str(variant_file))
    scene = scene_from_data(data, locs, Path(scene_file), partial=True)
    scene.file = str(variant_file)
    return scene


# --------------------------------------------------------------------------------------------
# the task run on a worker

def _summarise(run_json: dict | None) -> dict:
    out = {"frames_written": 0, "ms_per_frame": None, "max": {}}
    if not run_json:
        return out
    out["frames_written"] = len(run_json.get("frames", {}).get("written") or [])
    per = run_json.get("per_frame") or []
    secs = [f.get("seconds") for f in per if isinstance(f.get("seconds"), (int, float))]
    if secs:
        out["ms_per_frame"] = 1e3 * sum(secs) / len(secs)
    mx: dict = {}
    for f in per:
        for k, v in (f.get("stats") or {}).items():
            if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
                mx[k] = max(mx.get(k, -math.inf), v)
    out["max"] = {k: mx[k] for k in sorted(mx)}
    return out


def _read_run_json(folder: Path) -> dict | None:
    try:
        return json.loads((folder / "run.json").read_text())
    except (OSError, ValueError):
        return None


def run_variant(job: dict) -> dict:
    """Run one variant (on a worker): compile its ``variant.yaml`` and run it like ``lokigraph
    run`` into its folder. Never raises: failures come back as the row's status and error."""
    import socket

    t0, c0 = time.perf_counter(), time.process_time()
    row = {"name": job["name"], "status": "failed", "exit_code": None, "error": None}
    try:
        from .compile import compile_scene
        from .run import run

        compiled = compile_scene(load_variant(job["variant_file"], job["scene_file"]))
        run(compiled, frames=tuple(job["frames"]) if job.get("frames") else None,
            out_dir=job["dir"], fmt=job.get("format"), progress=False, overwrite=True)
        row.update(status="ok", exit_code=EXIT_OK)
    except LokigraphError as exc:
        res = getattr(exc, "result", None)
        row.update(status=getattr(res, "status", None) or "failed", exit_code=exc.exit_code,
                   error=str(exc))
    except KeyboardInterrupt as exc:
        row.update(status="interrupted", exit_code=130, error=f"interrupted: {exc}")
    except Exception as exc:  # noqa: BLE001 - a bug in the run: report it, go on with others
        tb = traceback.format_exception(type(exc), exc, exc.__traceback__)
        row.update(status="failed", exit_code=1,
                   error=f"internal error: {type(exc).__name__}: {exc}\n{''.join(tb[-3:])}")
    row["wall_s"] = time.perf_counter() - t0
    row["cpu_s"] = time.process_time() - c0
    row["host"] = socket.gethostname()
    row["pid"] = os.getpid()
    try:
        import numba

        row["numba_threads"] = numba.get_num_threads()
    except Exception:  # noqa: BLE001
        row["numba_threads"] = None
    row.update(_summarise(_read_run_json(Path(job["dir"]))))
    return row


# --------------------------------------------------------------------------------------------
# the driver

def _import_distributed():
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise InputError(f"lokigraph wedge needs dask.distributed, which is not installed: "
                         f"{EXTRA_HINT}") from None
    return distributed


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def _is_complete(folder: Path, text: str, frames, fmt) -> dict | None:
    """run.json of a finished ok run of exactly this variant, or None."""
    info = _read_run_json(folder)
    if not info or info.get("status") != "ok":
        return None
    try:
        if (folder / "variant.yaml").read_text() != text:
            return None
    except OSError:
        return None
    fr = info.get("frames") or {}
    requested = list(frames) if frames else [fr.get("start"), fr.get("end")]
    if fr.get("requested") != requested:
        return None
    if fmt and info.get("format") != fmt:
        return None
    return info


class Wedge:
    """A planned wedge: the variants of a scene, validated; :meth:`run` runs them."""

    def __init__(self, scene: str | Path, vary, out: str | Path | None = None,
                 frames: tuple[int, int] | None = None, fmt: str | None = None,
                 overwrite: bool = False):
        from .compile import compile_scene
        from .run import output_elements
        from .yamlio import load_yaml

        self.scene_file = Path(scene).resolve()
        data, _ = load_yaml(self.scene_file)
        if not isinstance(data, dict):
            raise InputError(f"{scene}: a scene file must be a mapping")
        from .api import compile_file

        compile_file(self.scene_file)  # the original must be valid: its errors, reported once
        self.pairs = parse_vary(vary)
        paths = [resolve_key(k, data) for k, _ in self.pairs]
        self.out = Path(out) if out is not None else Path("wedge_out") / self.scene_file.stem
        self.frames = tuple(frames) if frames else None
        self.fmt = fmt
        self.overwrite = overwrite
        if fmt is not None and fmt not in ("obj", "ply", "vtu", "usd"):
            raise InputError(f"unknown output format {fmt!r} (one of obj, ply, vtu, usd)")
        self.variants = []
        problems = []
        names = set()
        for combo in itertools.product(*(vals for _, vals in self.pairs)):
            params = [(k, v) for (k, _), v in zip(self.pairs, combo)]
            name = variant_name(params)
            if name in names:  # pragma: no cover - format_value is injective per key
                name = name + "__" + hashlib.sha1(repr(params).encode()).hexdigest()[:8]
            names.add(name)
            vdata = copy.deepcopy(data)
            for path, (_, v) in zip(paths, params):
                set_path(vdata, path, v)
            absolutise_paths(vdata, self.scene_file.parent)
            folder = self.out / name
            text = variant_text(vdata, self.scene_file, params)
            try:
                compiled = compile_scene(load_variant(folder / "variant.yaml", self.scene_file,
                                                      text))
                output_elements(compiled)
                spec = compiled.scene.spec
                if self.frames and not spec.frames.start <= self.frames[0] <= self.frames[1] \
                        <= spec.frames.end:
                    raise InputError(f"--frames {self.frames[0]}:{self.frames[1]} is outside "
                                     f"the frame range {spec.frames.start}:{spec.frames.end}")
            except InputError as exc:
                for d in exc.diagnostics:  # (variant.yaml is not written: no line numbers)
                    if d.file == str(folder / "variant.yaml"):
                        d = type(d)(element=d.element, field=d.field, message=d.message)
                    problems.append(f"variant {name}: {d.format()}")
            self.variants.append({"name": name, "params": params, "dir": folder, "text": text})
        if problems:
            raise InputError(problems[0] if len(problems) == 1 else
                             f"{len(problems)} errors:\n" + "\n".join("  " + p for p in problems))

    def job(self, v: dict) -> dict:
        return {"name": v["name"], "dir": str(v["dir"].resolve()),
                "variant_file": str((v["dir"] / "variant.yaml").resolve()),
                "scene_file": str(self.scene_file), "frames": self.frames, "format": self.fmt}

    def _check_out(self) -> None:
        out = self.out
        if out.exists() and not out.is_dir():
            raise OutputError(f"wedge output {out} is a file; give a folder (--out DIR)")
        if out.is_dir() and not (out / "wedge.json").exists() and any(out.iterdir()) \
                and not self.overwrite:
            raise OutputError(f"wedge output {out} holds files but no wedge.json (not a wedge's "
                              f"folder); give another --out, or --overwrite")
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"cannot create {out}: {exc.strerror or exc}") from None

    def run(self, scheduler: str | None = None, workers: int | None = None,
            progress=None) -> dict:
        """Run the variants not already complete; returns the result (also in wedge.json)."""
        from .run import atomic_write

        say = progress or (lambda line: None)
        self._check_out()
        previous = {}
        try:
            for r in json.loads((self.out / "wedge.json").read_text()).get("rows", []):
                previous[r.get("name")] = r
        except (OSError, ValueError, AttributeError):
            pass
        rows: dict[str, dict] = {}
        todo = []
        for v in self.variants:
            info = None if self.overwrite else _is_complete(v["dir"], v["text"], self.frames,
                                                            self.fmt)
            base = {"name": v["name"], **{k: v2 for k, v2 in v["params"]}}
            if info is not None:
                prev = previous.get(v["name"], {})
                row = {"status": "ok", "exit_code": 0, "error": None, "skipped": True,
                       "wall_s": prev.get("wall_s", info.get("total_seconds")),
                       "cpu_s": prev.get("cpu_s")}
                row.update(_summarise(info))
                rows[v["name"]] = {**base, **row}
            else:
                rows[v["name"]] = {**base, "status": "pending", "skipped": False}
                todo.append(v)
        n = len(self.variants)
        done = 0
        info = {"scene": str(self.scene_file), "out": str(self.out.resolve()),
                "vary": {k: vals for k, vals in self.pairs}, "frames": self.frames,
                "format": self.fmt, "cluster": None, "workers": None}
        t0 = time.perf_counter()
        self._write(info, rows, t0)  # first: it marks the folder as a wedge's
        for v in todo:
            try:
                v["dir"].mkdir(parents=True, exist_ok=True)
                atomic_write(v["dir"] / "variant.yaml", lambda p, t=v["text"]: p.write_text(t))
            except OSError as exc:
                raise OutputError(f"cannot write {v['dir'] / 'variant.yaml'}: "
                                  f"{exc.strerror or exc}") from None
        for name, row in rows.items():
            if row.get("skipped"):
                done += 1
                say(f"[{done}/{n}] {name}: skipped (ok in a previous run)")
        if todo:
            self._run_todo(todo, rows, info, scheduler, workers, say, n, done, t0)
        info["seconds"] = time.perf_counter() - t0
        self._write(info, rows, t0, final=True)
        try:
            contact_sheet(self.out, [rows[v["name"]] for v in self.variants],
                          self.out / "contact_sheet.png")
        except Exception as exc:  # noqa: BLE001 - the table stands without the picture
            say(f"warning: contact sheet not written: {type(exc).__name__}: {exc}")
        return self.result(info, rows)

    def _run_todo(self, todo, rows, info, scheduler, workers, say, n, done, t0) -> None:
        _import_distributed()
        from distributed import Client, LocalCluster, as_completed

        cluster = None
        try:
            if scheduler:
                kw = ({"scheduler_file": scheduler} if scheduler.endswith(".json")
                      else {"address": scheduler})
                try:
                    client = Client(timeout="20s", **kw)
                except (OSError, TimeoutError, ValueError) as exc:
                    raise InputError(f"--scheduler {scheduler}: cannot connect: {exc}") from None
                try:
                    client.wait_for_workers(1, timeout=60)
                except TimeoutError:
                    client.close()
                    raise InputError(f"--scheduler {scheduler}: no worker joined within "
                                     f"60 s") from None
                info["cluster"] = scheduler
                try:
                    sinfo = client.scheduler_info(n_workers=-1)
                except TypeError:  # older distributed: every worker is listed
                    sinfo = client.scheduler_info()
                info["workers"] = len(sinfo.get("workers", {}))
            else:
                nw = max(1, min(workers or _cores(), len(todo)))
                cluster = LocalCluster(n_workers=nw, threads_per_worker=1, processes=True,
                                       host="127.0.0.1", dashboard_address=None,
                                       env=dict(WORKER_ENV))
                client = Client(cluster)
                info["cluster"] = "local"
                info["workers"] = nw
            with client:
                futures = client.map(run_variant, [self.job(v) for v in todo], pure=False,
                                     key=[f"lokigraph-wedge-{v['name']}-{os.getpid()}-"
                                          f"{time.time_ns()}" for v in todo])
                fut_name = {f.key: v["name"] for f, v in zip(futures, todo)}
                for fut in as_completed(futures):
                    name = fut_name[fut.key]
                    try:
                        row = fut.result()
                    except Exception as exc:  # noqa: BLE001 - the worker died (KilledWorker)
                        row = {"name": name, "status": "failed", "exit_code": 1,
                               "error": f"worker failed: {type(exc).__name__}: {exc}"}
                    row["skipped"] = False
                    rows[name] = {**rows[name], **row}
                    done += 1
                    say(f"[{done}/{n}] {_line(rows[name])}")
                    self._write(info, rows, t0)
        finally:
            if cluster is not None:
                cluster.close()

    def result(self, info: dict, rows: dict) -> dict:
        table = [rows[v["name"]] for v in self.variants]
        return {**info, "rows": table, "variants": len(table),
                "ok": sum(r.get("status") == "ok" for r in table),
                "failed": sum(r.get("status") != "ok" for r in table),
                "skipped": sum(bool(r.get("skipped")) for r in table),
                "ran": sum(not r.get("skipped") and r.get("status") != "pending" for r in table)}

    def _write(self, info, rows, t0, final: bool = False) -> None:
        from .run import atomic_write

        res = self.result({**info, "seconds": time.perf_counter() - t0, "complete": final}, rows)
        text = json.dumps(res, indent=1, default=str)
        csv_text = _csv(res["rows"], [k for k, _ in self.pairs])
        try:
            atomic_write(self.out / "wedge.json", lambda p: p.write_text(text))
            atomic_write(self.out / "wedge.csv", lambda p: p.write_text(csv_text))
        except OSError as exc:
            raise OutputError(f"cannot write the wedge table in {self.out}: "
                              f"{exc.strerror or exc}", EXIT_SIMULATION) from None


def _line(row: dict) -> str:
    text = f"{row['name']}: {row['status']}"
    if row.get("wall_s") is not None:
        text += f" in {row['wall_s']:.2f} s"
        if row.get("cpu_s") is not None:
            text += f" ({row['cpu_s']:.2f} s CPU"
            if row.get("ms_per_frame") is not None:
                text += f", {row['ms_per_frame']:.1f} ms/frame"
            text += ")"
    if row.get("status") != "ok":
        err = (row.get("error") or "").splitlines()
        text += f" (exit {row.get('exit_code')})" + (f": {err[0]}" if err else "")
    return text


_COLUMNS = ["name", "status", "exit_code", "skipped", "wall_s", "cpu_s", "ms_per_frame",
            "frames_written"]


def _csv(rows: list[dict], keys: list[str]) -> str:
    stats = sorted({k for r in rows for k in (r.get("max") or {})})
    cols = _COLUMNS[:1] + keys + _COLUMNS[1:] + [f"max.{s}" for s in stats] + ["error"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        vals = []
        for c in cols:
            v = (r.get("max") or {}).get(c[4:]) if c.startswith("max.") else r.get(c)
            if c in keys and not isinstance(v, (str, type(None))):
                v = format_value(v)
            if c == "error" and v:
                v = v.splitlines()[0]
            elif isinstance(v, float) and c not in keys:
                v = f"{v:.6g}"
            vals.append("" if v is None else v)
        w.writerow(vals)
    return buf.getvalue()


# --------------------------------------------------------------------------------------------
# contact sheet

def _last_frame_meshes(folder: Path) -> list:
    """(points, triangles, edges) of each written element at the last written frame."""
    from .meshfile import MeshReadError, read_mesh

    info = _read_run_json(folder)
    if not info:
        return []
    written = (info.get("frames") or {}).get("written") or []
    if not written:
        return []
    fmt = info.get("format") or "obj"
    usd_read = None
    if fmt == "usd":  # the variant's stage (lokigraph.preview reads it)
        from .preview import _usd_reader

        try:
            usd_read = _usd_reader(folder, info)
        except (InputError, ImportError):
            return []
    out = []
    for el in (info.get("output") or {}).get("elements") or []:
        path = folder / el / f"{written[-1]:04d}.{fmt}"
        try:
            g = usd_read(el, written[-1]) if usd_read else read_mesh(path)
        except (MeshReadError, OSError):
            continue
        out.append((g.points, g.triangles, g.edges))
    return out


def _view(points, az=35.0, el=25.0):
    """Orthographic camera (y up): screen x, screen y and depth (larger is nearer)."""
    import numpy as np

    a, e = math.radians(az), math.radians(el)
    right = np.array([math.cos(a), 0.0, -math.sin(a)])
    fwd = np.array([math.sin(a) * math.cos(e), math.sin(e), math.cos(a) * math.cos(e)])
    up = np.cross(fwd, right)
    return points @ right, points @ up, points @ fwd, fwd


def render_tile(ax, meshes, bounds=None) -> None:
    """Shaded triangles (painter's order) and curves of one frame into a matplotlib axis."""
    import numpy as np
    from matplotlib.collections import LineCollection, PolyCollection

    ax.set_axis_off()
    ax.set_aspect("equal")
    polys, shades, depth = [], [], []
    lines = []
    light = np.array([0.3, 0.8, 0.5]) / np.linalg.norm([0.3, 0.8, 0.5])
    for pts, tris, edges in meshes:
        pts = np.asarray(pts, float)
        if not len(pts) or not np.isfinite(pts).all():
            continue
        x, y, z, _ = _view(pts)
        if len(tris):
            p = pts[tris]
            n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
            polys.append(np.stack([x[tris], y[tris]], -1))
            shades.append(0.25 + 0.7 * np.abs(n @ light))
            depth.append(z[tris].mean(1))
        if len(edges):
            lines.append(np.stack([x[edges], y[edges]], -1))
    if polys:
        P, S, D = np.concatenate(polys), np.concatenate(shades), np.concatenate(depth)
        order = np.argsort(D)
        cols = np.clip(S[order, None] * np.array([0.55, 0.7, 0.95]), 0, 1)
        ax.add_collection(PolyCollection(P[order], facecolors=cols, edgecolors="none",
                                         antialiased=False))
    if lines:
        ax.add_collection(LineCollection(np.concatenate(lines), colors="#6b4a2b",
                                         linewidths=0.6))
    if bounds is None:
        bounds = _bounds2d(meshes)
    if bounds is not None:
        (x0, x1), (y0, y1) = bounds
        pad = 0.05 * max(x1 - x0, y1 - y0, 1e-9)
        ax.set_xlim(x0 - pad, x1 + pad)
        ax.set_ylim(y0 - pad, y1 + pad)


def _bounds2d(meshes):
    import numpy as np

    xs, ys = [], []
    for pts, _, _ in meshes:
        pts = np.asarray(pts, float)
        if len(pts) and np.isfinite(pts).all():
            x, y, _, _ = _view(pts)
            xs += [x.min(), x.max()]
            ys += [y.min(), y.max()]
    if not xs:
        return None
    return (min(xs), max(xs)), (min(ys), max(ys))


def _preview_image(folder: Path, px: int):
    """The last written frame rendered by :mod:`lokigraph.preview` (colliders, hair shading),
    or None when it is not available or fails (then :func:`render_tile` draws the tile)."""
    import warnings

    import numpy as np

    try:
        from . import preview

        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            return _preview_draw(preview, folder, px)
    except Exception:  # noqa: BLE001 - fall back to the simple renderer
        return None


def _preview_draw(preview, folder: Path, px: int):
    written = ((_read_run_json(folder) or {}).get("frames") or {}).get("written") or []
    if not written:
        return None
    run = preview.load_run(folder, frames=(written[-1], written[-1]))
    return preview.Renderer(run, size=(px, px)).draw(0)


def contact_sheet(out: Path, rows: list[dict], dest: Path, tile: float = 2.4,
                  use_preview: bool = True) -> Path | None:
    """A grid of the last frame of every variant, captioned with its name and status.

    Tiles come from :class:`lokigraph.preview.Renderer` when it is available (each framed to
    its own run), else from :func:`render_tile` (orthographic, shaded; ok variants share one
    scale, failed ones are framed to their own)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from .run import atomic_write

    if not rows:
        return None
    meshes = [_last_frame_meshes(out / r["name"]) for r in rows]
    ok = [m for m, r in zip(meshes, rows) if r.get("status") == "ok"]
    shared = _bounds2d([x for m in ok for x in m]) if ok else None
    n = len(rows)
    ncol = math.ceil(math.sqrt(n))
    nrow = math.ceil(n / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(tile * ncol, (tile + 0.35) * nrow),
                             squeeze=False)
    for ax in axes.flat:
        ax.set_axis_off()
    for ax, r, m in zip(axes.flat, rows, meshes):
        img = _preview_image(out / r["name"], int(tile * 100)) if use_preview and m else None
        if img is not None:
            ax.imshow(img, interpolation="antialiased")
            ax.set_axis_off()
        else:
            render_tile(ax, m, shared if r.get("status") == "ok" else None)
        caption = r["name"].replace("__", "\n")
        if r.get("status") != "ok":
            caption += f"\n{str(r.get('status')).upper()} (exit {r.get('exit_code')})"
        if not m:
            ax.text(0.5, 0.5, "no frame", ha="center", va="center", transform=ax.transAxes,
                    color="grey")
        ax.set_title(caption, fontsize=6.5, color="black" if r.get("status") == "ok"
                     else "#b00000")
    fig.tight_layout()
    atomic_write(dest, lambda p: fig.savefig(p, dpi=100, format="png"))
    plt.close(fig)
    return dest


# --------------------------------------------------------------------------------------------
# API and CLI

def run_wedge(scene, vary, out=None, scheduler=None, workers=None, frames=None, fmt=None,
              overwrite=False, progress=None) -> dict:
    """Plan, validate and run a wedge; returns the result (as in ``wedge.json``).
    ``vary``: ``["KEY=V1,V2", ...]`` or a mapping ``{KEY: [V1, V2]}``."""
    w = Wedge(scene, vary, out, frames, fmt, overwrite)
    return w.run(scheduler=scheduler, workers=workers, progress=progress)


def add_parser(sub) -> None:
    from .cli import _frames

    w = sub.add_parser("wedge", help="run every combination of parameter values (dask)",
                       description="Run every combination of --vary values as its own run "
                       "folder on dask.distributed; writes wedge.csv, wedge.json and "
                       "contact_sheet.png. Exit 0 when every variant is ok, 3 when one failed.")
    w.add_argument("scene")
    w.add_argument("--vary", action="append", default=[], metavar="KEY=V1,V2,...",
                   help="substeps=1,2,4 | frames.fps=24,48 | ELEMENT.COMPONENT.FIELD=... | "
                   "graph_overrides.NODE.PARAM=... (repeat for a cartesian product)")
    w.add_argument("--out", help="wedge folder (default: wedge_out/<scene name>)")
    w.add_argument("--scheduler", help="address of a running dask scheduler (tcp://HOST:PORT) "
                   "or its scheduler file (.json); default: a local cluster")
    w.add_argument("--workers", type=int, help="local cluster: worker processes (default: the "
                   "number of cores), one thread each")
    w.add_argument("--frames", type=_frames, help="write frames A:B of every variant")
    w.add_argument("--format", choices=["obj", "ply", "vtu", "usd"], help="format of frames "
                   "(usd: one stage per variant; needs lokigraph[usd])")
    w.add_argument("--overwrite", action="store_true", help="rerun every variant (default: skip "
                   "variants already complete)")
    w.add_argument("--quiet", action="store_true", help="no line per finished variant")


def dispatch(args) -> int:
    if args.workers is not None and args.workers < 1:
        raise InputError("--workers: give 1 or more")
    if args.scheduler and args.workers is not None:
        print("warning: --workers applies to the local cluster only; ignored with --scheduler",
              file=sys.stderr)
    w = Wedge(args.scene, args.vary, args.out, args.frames, args.format, args.overwrite)
    say = None if args.quiet else (lambda line: print(line, flush=True))
    res = w.run(scheduler=args.scheduler, workers=args.workers, progress=say)
    print(f"{res['ok']}/{res['variants']} variants ok ({res['skipped']} skipped as complete, "
          f"{res['failed']} failed) in {res['seconds']:.1f} s; results in {w.out}/wedge.csv, "
          f"wedge.json, contact_sheet.png")
    return EXIT_OK if res["failed"] == 0 else EXIT_SIMULATION


__all__ = ["Wedge", "run_wedge", "run_variant", "parse_vary", "variant_name", "resolve_key",
           "contact_sheet", "render_tile", "add_parser", "dispatch", "EXIT_INPUT"]
