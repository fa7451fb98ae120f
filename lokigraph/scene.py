"""Scene files: elements with geometry, channels and components; frames; output.

A scene file::

    lokigraph: 1
    graph: default                # a shipped graph name, or a path to a graph YAML
    solver: nucleus
    frames: {start: 1, end: 48, fps: 24}
    substeps: 4
    gravity: [0, -9.81, 0]        # m/s^2
    elements:
      - name: cloth
        geometry: {generator: grid, params: {size: [1, 1], resolution: [32, 32]}}
        channels: {pin: {vertices: [0, 32], value: 1}}
        components:
          Dynamic: {mass_density: 0.2}
          Pins: {map: pin}
    output: {dir: out/cloth, format: obj}

Every problem of a file is collected and reported at once with file:line:column, element and
field (:class:`~lokigraph.errors.InputError`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

from pydantic import (BaseModel, BeforeValidator, ConfigDict, Field, ValidationError,
                      WithJsonSchema, field_validator, model_validator)

from . import geometry as geo_mod
from .component import ChannelSpec, Component, pydantic_diagnostics
from .errors import Diagnostic, InputError
from .generators import GeneratorParamsError, make_geometry
from .geometry import Geometry, MeshReadError
from .meshfile import read_mesh
from .selection import build_channels, check_component_selections
from .sequence import UsdSource, available_frames, describe_frames, frame_file, map_frame
from .registry import get_registry
from .yamlio import Locations, load_yaml

Vec3 = tuple[float, float, float]

MAX_FRAME = 10_000_000
"""Largest |frame number| accepted (frames, keys)."""
MAX_FRAME_COUNT = 1_000_000
"""Most frames in one scene's range (end - start)."""
MAX_FPS = 1e5
"""Largest frame rate [1/s]."""
MAX_STEP_RATE = 1e7
"""Largest fps * substeps [1/s]: a substep is never shorter than 0.1 microsecond."""

FrameNumber = Annotated[int, Field(ge=-MAX_FRAME, le=MAX_FRAME)]
_Scale = Annotated[float, Field(gt=0, le=1e9)]


def _broadcast_scale(v):
    """``scale: 2`` means ``[2, 2, 2]``."""
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return (v, v, v)
    return v


class Strict(BaseModel):
    """Base of the scene file's models: unknown keys, NaN and infinities are errors."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Frames(Strict):
    start: FrameNumber = Field(1, description="First frame written (the initial state is frame "
                                              "start).")
    end: FrameNumber = Field(48, description="Last frame written.")
    fps: float = Field(24.0, gt=0, le=MAX_FPS, description="Frames per second [1/s].")

    @model_validator(mode="after")
    def _order(self):
        if self.end < self.start:
            raise ValueError(f"end ({self.end}) must be >= start ({self.start})")
        if self.end - self.start > MAX_FRAME_COUNT:
            raise ValueError(f"at most {MAX_FRAME_COUNT} frames in one scene (start {self.start}, "
                             f"end {self.end})")
        return self


class Transform(Strict):
    scale: Annotated[tuple[_Scale, _Scale, _Scale], BeforeValidator(_broadcast_scale),
                     WithJsonSchema({"anyOf": [
                         {"type": "number", "exclusiveMinimum": 0, "maximum": 1e9},
                         {"type": "array", "minItems": 3, "maxItems": 3, "items": {
                             "type": "number", "exclusiveMinimum": 0, "maximum": 1e9}}]})] = Field(
        (1.0, 1.0, 1.0), description="Scale factor(s) > 0: one for every axis, or [x, y, z]; "
                                     "applied after unit conversion.")
    rotate: Vec3 = Field((0.0, 0.0, 0.0), description="Rotation about x, y, z [degrees].")
    translate: Vec3 = Field((0.0, 0.0, 0.0), description="Translation [m].")


_FRAME_SPEC = re.compile(r"^0?[1-9]?[0-9]?d?$")


def check_sequence_pattern(pattern: str) -> str:
    """Check a mesh sequence pattern such as ``anim/body.{frame:04d}.obj``: one or more
    ``{frame}`` fields with an optional zero-padded width (at most 99), nothing else in braces.
    Raises ValueError with a plain message (never an error of ``str.format``)."""
    import string

    try:
        fields = list(string.Formatter().parse(pattern))
    except ValueError as exc:
        raise ValueError(f"bad sequence pattern {pattern!r}: {exc} (write a literal brace as "
                         f"'{{{{' or '}}}}')") from None
    n = 0
    for _, name, spec, conv in fields:
        if name is None:
            continue
        if name != "frame" or conv is not None or not _FRAME_SPEC.match(spec or ""):
            shown = "{" + name + ("!" + conv if conv else "") + (":" + spec if spec else "") + "}"
            raise ValueError(f"bad sequence pattern {pattern!r}: {shown} is not a frame field; "
                             f"use {{frame}}, or {{frame:04d}} for zero-padded numbers")
        n += 1
    if n == 0:
        raise ValueError(f"sequence pattern {pattern!r} has no {{frame}} field (e.g. "
                         f"'anim/body.{{frame:04d}}.obj')")
    try:
        pattern.format(frame=1)
    except Exception as exc:  # noqa: BLE001 - any failure of format is the user's pattern
        raise ValueError(f"bad sequence pattern {pattern!r}: {exc}") from None
    return pattern


class GeometrySpec(Strict):
    file: str | None = Field(None, description="Mesh file (OBJ, PLY, VTK, VTU, MSH ...), "
                                               "relative to the scene file.")
    sequence: str | None = Field(None, description="Per-frame mesh files for a kinematic element, "
                                                   "e.g. 'anim/body.{frame:04d}.obj'.")
    hold: Literal["error", "first", "last", "loop"] = Field(
        "error", description="Sequence frames without a file: 'error' (every frame of the run "
        "must exist), 'first' (outside the sequence show its first file), 'last' (before it the "
        "first file, after it the last: the pose is held), 'loop' (the sequence repeats). Gaps "
        "hold the file before them (all but 'error').")
    generator: Literal["points", "grid", "strands", "sphere", "box", "tube", "tet_box"] | None = (
        Field(None, description="Built-in generator; its parameters, vertex order and named "
              "vertex sets are documented in lokigraph.generators (GENERATOR_MODELS)."))
    params: dict = Field(default_factory=dict, description="Generator parameters (SI units), "
                         "checked against the generator's model.")
    units: Literal["m", "cm", "mm", "km", "in", "ft"] = Field("m", description="Units of the file.")
    transform: Transform | None = None
    usd: str | None = Field(None, description="USD file (.usd, .usda, .usdc, .usdz) holding an "
                            "animated mesh for a kinematic element, relative to the scene file; "
                            "with 'prim'. Frame f reads the prim's points at time code f (times "
                            "the stage's timeCodesPerSecond / fps) in world space, like a "
                            "'sequence' ('hold' applies); topology comes from the prim. The "
                            "stage's metersPerUnit applies unless 'units' is given. Needs "
                            "usd-core (pip install \"lokigraph[usd]\"); see lokigraph.usd.")
    prim: str | None = Field(None, pattern=r"^(/[A-Za-z_][A-Za-z0-9_]*)+$",
                             description="Path of the UsdGeomMesh prim in 'usd', e.g. "
                             "/char/body.")

    @field_validator("sequence")
    @classmethod
    def _pattern(cls, v):
        return v if v is None else check_sequence_pattern(v)

    @model_validator(mode="after")
    def _one_source(self):
        if self.usd is not None or self.prim is not None:
            if self.usd is None or self.prim is None:
                raise ValueError("'usd' and 'prim' go together (geometry: {usd: body.usd, "
                                 "prim: /char/body})")
            if any(x is not None for x in (self.file, self.generator, self.sequence)):
                raise ValueError("'usd' is the geometry's only source: give no 'file', "
                                 "'generator' or 'sequence' with it")
            return self
        n = sum(x is not None for x in (self.file, self.generator))
        if n == 0 and self.sequence is None:
            raise ValueError("geometry needs one of 'file', 'generator', 'sequence' or 'usd'")
        if n > 1:
            raise ValueError("give only one of 'file' and 'generator'")
        if self.hold != "error" and self.sequence is None:
            raise ValueError("'hold' applies to a 'sequence' or 'usd' only")
        return self

    def with_usd_source(self, fps: float) -> "GeometrySpec":
        """A ``usd`` geometry as the mesh sequence it behaves as: a copy whose ``sequence`` is a
        :class:`~lokigraph.sequence.UsdSource` (the USD file, prim and the scene's fps), so that
        the sequence machinery (frame availability, hold, kinematic animation) reads the prim's
        time samples. Other specs are returned unchanged."""
        if self.usd is None or isinstance(self.sequence, UsdSource):
            return self
        return self.model_copy(update={"sequence": UsdSource(self.usd, self.prim, fps)})


class ElementSpec(Strict):
    name: str = Field(pattern=r"^[A-Za-z_][A-Za-z0-9_.\-]*$")
    geometry: GeometrySpec | None = None
    channels: dict[str, ChannelSpec] = Field(
        default_factory=dict, description="Extra per-vertex channels (painted maps), built in "
        "order: {file: ...}, {vertices: [...]}, {select: SELECTION} or {attribute: NAME}.")
    components: dict[str, dict | None] = Field(default_factory=dict)


class Output(Strict):
    dir: str = Field("out", description="Output folder, relative to the current directory. "
                     "Frames go to <dir>/<element>/<frame:04d>.<format>, with <dir>/run.json.")
    format: Literal["obj", "ply", "vtu", "usd"] = Field(
        "obj", description="Format of frames: 'obj', 'ply', 'vtu' (one mesh file per element "
        "per frame: positions, velocities where the format holds them; hair as polylines) or "
        "'usd' (one USD stage per run, <dir>/run.usd, every element a time-sampled prim; needs "
        "usd-core; see lokigraph.usd).")
    overwrite: bool = Field(False, description="Replace another run's output in dir (its "
                            "run.json and frame files are removed first). Without it a run into "
                            "a folder holding another run's frames is refused (CLI: --overwrite).")
    kinematic: bool = Field(False, description="Also write every kinematic (animated) element "
                            "with geometry, at its animated positions, each frame (colliders "
                            "for rendering or checking).")
    elements: list[str] | None = Field(None, description="Elements written, by name (default: "
                                       "every dynamic element, plus every kinematic one when "
                                       "'kinematic' is true). Each must have geometry.")
    checkpoint_every: int = Field(10, ge=0, description="Write a checkpoint (the full "
                                  "simulation state, <dir>/checkpoints/NNNN.npz) every N frames, "
                                  "at the end and when the run stops early; 0: never. `lokigraph "
                                  "run SCENE --resume DIR` continues from the last one. Not for "
                                  "USD output.")
    checkpoint_keep: int = Field(2, ge=1, description="Checkpoints kept (the newest ones).")


class Reference(Strict):
    """Independent truth for ``lokigraph bench`` (``run`` ignores it); see
    lokigraph.bench.references."""

    kind: Literal["free_fall", "spring", "catenary", "elastica", "terminal_velocity", "stored"]
    element: str | None = Field(None, description="Element compared (default: the only dynamic "
                                                  "one).")
    file: str | None = Field(None, description="stored: .npy of positions, next to the scene.")
    settings: dict = Field(default_factory=dict, description="stored: the tight settings the "
                           "file was computed with (substeps, iterations, node.param).")

    @model_validator(mode="after")
    def _file(self):
        if self.kind == "stored" and not self.file:
            raise ValueError("kind 'stored' needs 'file'")
        return self


class InitialState(Strict):
    """Start from a frame of a previous run (Maya's "initial state")."""

    from_: str = Field(alias="from", description="Output folder of the previous run (relative "
                       "to the current directory, like output.dir).")
    frame: int = Field(description="Frame of that run: its checkpoint at that frame gives "
                       "positions and velocities; else the written frame files give positions "
                       "(and velocities from PLY/VTU; zero otherwise, with a warning in "
                       "run.json).")


class SceneSpec(Strict):
    lokigraph: Literal[1] = Field(description="Scene format version.")
    graph: str = Field("default", description="Shipped graph name or path to a graph YAML.")
    solver: str = Field("nucleus", description="Solver behavior to run (the graph may hold "
                                               "several).")
    frames: Frames = Field(default_factory=Frames)
    substeps: int = Field(4, ge=1, le=10000, description="Substeps per frame (fps * substeps "
                          f"<= {MAX_STEP_RATE:g}).")
    gravity: Vec3 = Field((0.0, -9.81, 0.0), description="Gravity [m/s^2].")
    seed: int = Field(0, ge=0, le=2**63 - 1, description="Random seed for any stochastic "
                                                         "behavior.")
    elements: list[ElementSpec] = Field(default_factory=list)
    output: Output = Field(default_factory=Output)
    initial_state: InitialState | None = Field(None, description="Dynamic elements start "
                                               "from a previous run's frame: {from: DIR, "
                                               "frame: N}.")
    preroll: int = Field(0, ge=0, description="Frames simulated before frames.start, not "
                         "written (the run starts at start - preroll).")
    reference: Reference | None = Field(None, description="Reference solution for `lokigraph "
                                        "bench` (ignored by run).")
    graph_overrides: dict[str, dict] = Field(
        default_factory=dict, description="Per graph node name: parameter overrides.")

    @model_validator(mode="after")
    def _step_rate(self):
        rate = self.frames.fps * self.substeps
        if rate > MAX_STEP_RATE:
            raise ValueError(f"fps * substeps = {rate:g} substeps per second; at most "
                             f"{MAX_STEP_RATE:g}")
        return self


@dataclass
class Element:
    """A scene element at compile time: geometry (may be None), channels and components."""

    name: str
    index: int
    geometry: Geometry | None
    components: dict[str, Component]
    source_file: str = ""
    line: int = 0
    column: int = 0
    base_dir: str = "."
    sequence: str | None = None
    spec: GeometrySpec | None = None
    vertex_offset: int = 0  # global numbering (set by compile)

    @property
    def vertex_count(self) -> int:
        return 0 if self.geometry is None else self.geometry.vertex_count

    @property
    def channels(self) -> dict:
        return {} if self.geometry is None else self.geometry.channels

    def has(self, *types) -> bool:
        return all(t.type_id() in self.components for t in types)

    def get(self, ctype, default=None):
        return self.components.get(ctype.type_id(), default)

    @property
    def vertex_slice(self) -> slice:
        return slice(self.vertex_offset, self.vertex_offset + self.vertex_count)


@dataclass
class Scene:
    spec: SceneSpec
    elements: list[Element]
    file: str
    locations: Locations
    base_dir: str
    raw: dict = field(default_factory=dict)
    #: problems found while loading (only with ``partial=True``; compile reports them with its own)
    diagnostics: list = field(default_factory=list)
    #: element name -> the parts of it in error ("*": the element itself, left out of elements)
    failed: dict = field(default_factory=dict)
    #: top-level fields in error (replaced by their defaults)
    failed_fields: set = field(default_factory=set)

    def element(self, name: str) -> Element:
        for e in self.elements:
            if e.name == name:
                return e
        raise KeyError(name)


def _load_geometry(spec: GeometrySpec, base: Path, frame: int | None = None) -> Geometry:
    """Geometry of ``spec`` (units and transform applied): generated (parameters validated,
    :class:`~lokigraph.generators.GeneratorParamsError`), read from ``file``, or frame
    ``frame`` of the ``sequence`` (a missing frame follows ``hold``), or of the ``usd`` prim
    (:mod:`lokigraph.usd`; errors are :class:`~lokigraph.usd.UsdReadError`)."""
    if spec.usd is not None:
        from .usd import load_usd_geometry

        g = load_usd_geometry(spec, base, frame)
    elif spec.generator is not None:
        g = make_geometry(spec.generator, spec.params)
    else:
        path = spec.file
        if path is None:
            f = int(frame if frame is not None else 0)
            path = frame_file(spec.sequence, f)
            if not (base / path).exists():
                avail = available_frames(spec.sequence, base)
                shown = map_frame(f, avail, spec.hold) if avail is not None else None
                if shown is None:
                    raise MeshReadError(
                        f"frame {f} of the sequence: file not found: {base / path} (the sequence "
                        f"has {describe_frames(avail) if avail is not None else 'unknown frames'}"
                        f"; geometry.hold: first, last or loop shows another frame instead)")
                path = frame_file(spec.sequence, shown)
        g = read_mesh_cached(base / path)
        g = g.copy()
    t = spec.transform or Transform()
    g.points = geo_mod.apply_transform(g.points, t.scale, t.rotate, t.translate, spec.units)
    return g


def read_mesh_cached(path: Path) -> Geometry:
    return read_mesh(path)


def load_scene(path: str | Path, *, partial: bool = False) -> Scene:
    """Parse and validate a scene file; load geometry. Raises InputError with every problem.

    With ``partial=True`` a scene with errors is returned instead, holding the valid part and
    the diagnostics (see :func:`scene_from_data`); compile then adds its own and raises once.
    """
    path = Path(path)
    data, locs = load_yaml(path)
    return scene_from_data(data, locs, path, partial=partial)


def scene_from_data(data, locs: Locations, path: Path, *, partial: bool = False) -> Scene:
    """Validate scene data: every top-level field, every element and every component on its
    own, so that one pass reports every problem of the file.

    A top-level field in error falls back to its default; an element whose name, geometry or
    channels are in error is left out; a component in error is left out of its element. With
    ``partial=False`` any problem raises :class:`InputError`; with ``partial=True`` the scene
    of what is valid is returned, with ``diagnostics`` and ``failed`` (element name -> what
    failed, ``"*"`` for the element itself) so that compile can check the rest and report
    everything together, without spurious errors about what was left out.
    """
    file = str(path)
    base = path.parent
    diags: list[Diagnostic] = []
    if not isinstance(data, dict):
        raise InputError(locs.diag((), "a scene file must be a mapping"))
    if "domains" in data and "lokigraph" not in data and "elements" not in data:
        raise InputError(locs.diag((), "this is a behavior graph file, not a scene: name it in a "
                                       "scene with 'graph: <path>' (see graphs/default.yaml)"))
    spec, failed_fields = _validate_scene_spec(data, locs, diags)

    elements: list[Element] = []
    failed: dict[str, set[str]] = {}
    seen: dict[str, int] = {}
    for i, es, raw_comps in _element_specs(data, locs, diags, failed):
        epath = ("elements", i)
        line, col = locs.get(epath)
        duplicate = es.name in seen
        if duplicate:
            diags.append(locs.diag(epath + ("name",), f"duplicate element name (first at "
                                   f"element #{seen[es.name]})", element=es.name))
        else:
            seen[es.name] = i
        comps, bad = _validate_components(raw_comps, epath, es.name, locs, diags)
        if bad:
            failed.setdefault(es.name, set()).update(bad)
        n_diags = len(diags)
        g = None
        # a usd geometry is handled as the sequence it behaves as (GeometrySpec.with_usd_source)
        gspec = es.geometry.with_usd_source(spec.frames.fps) if es.geometry else None
        if es.geometry is not None:
            gpath = epath + ("geometry",)
            try:
                first = spec.frames.start if (es.geometry.sequence or es.geometry.usd) and not (
                    es.geometry.file or es.geometry.generator) else None
                g = _load_geometry(gspec, base, first)
            except GeneratorParamsError as exc:
                for loc, msg in exc.errors:
                    where = ".".join(str(p) for p in ("params",) + tuple(loc))
                    diags.append(locs.diag(gpath + ("params",) + tuple(loc), msg,
                                           element=es.name, field=f"geometry.{where}"))
            except MeshReadError as exc:
                key = getattr(exc, "key", None) or (
                    "file" if es.geometry.file else ("sequence" if es.geometry.sequence
                                                     else "generator"))
                diags.append(locs.diag(gpath + (key,), str(exc), element=es.name,
                                       field=f"geometry.{key}"))
            except KeyError as exc:
                diags.append(locs.diag(gpath, f"cannot format sequence pattern: {exc}",
                                       element=es.name, field="geometry.sequence"))
            if g is not None:
                for prob in g.problems():
                    if prob.startswith("warning:"):
                        continue
                    diags.append(locs.diag(gpath, prob, element=es.name, field="geometry"))
            if g is not None and es.geometry.usd and es.geometry.hold == "error" and comps.get(
                    "Kinematic") is not None:  # every frame of the run needs a time sample
                from .usd import missing_usd_frame

                msg = missing_usd_frame(gspec, base, spec.frames.start, spec.frames.end)
                if msg:
                    diags.append(locs.diag(gpath + ("usd",), msg, element=es.name,
                                           field="geometry.usd"))
        el = Element(es.name, i, g, comps, file, line, col, str(base),
                     sequence=gspec.sequence if gspec else None, spec=gspec)
        if g is not None:  # painted channels, then selections on this element's own vertices
            diags.extend(build_channels(es.channels, g, el, base, locs, epath + ("channels",)))
            diags.extend(check_component_selections(comps, g, el, locs, epath + ("components",)))
        elif es.channels and es.geometry is None:  # (failed geometry: reported above)
            diags.append(locs.diag(epath + ("channels",), "channels need geometry",
                                   element=es.name))
        # a problem of one component (a selection of Pins) leaves that component out; one of
        # the geometry or the channels leaves the whole element out
        for d in diags[n_diags:]:
            head = d.field.split(".")[0]
            if head not in comps:
                failed.setdefault(es.name, set()).add("*")
                break
            failed.setdefault(es.name, set()).add(head)
            comps.pop(head, None)
        if "*" in failed.get(es.name, ()):
            continue
        if duplicate:
            continue
        elements.append(el)
        spec.elements.append(es)
    if diags and not partial:
        raise InputError(diags)
    return Scene(spec, elements, file, locs, str(base), raw=data, diagnostics=diags,
                 failed=failed, failed_fields=failed_fields)


def _kind(value) -> str:
    if value is None:
        return "empty (null)"
    return {list: "a list", dict: "a mapping", str: "a string", bool: "a boolean",
            int: "a number", float: "a number"}.get(type(value), "a " + type(value).__name__)


def _validate_scene_spec(data: dict, locs: Locations, diags: list) -> tuple[SceneSpec, set]:
    """Validate the top-level fields (elements are validated one by one elsewhere). A field in
    error is reported and replaced by its default, so that the rest can still be checked."""
    top = {k: v for k, v in data.items() if k != "elements"}
    failed: set = set()
    found: list[Diagnostic] = []
    for _ in range(len(top) + 3):
        try:
            spec = SceneSpec.model_validate({**top, "elements": []})
            break
        except ValidationError as exc:
            for d in pydantic_diagnostics(exc, locs, (), "", "scene",
                                          known_fields=SceneSpec.model_fields):
                if d.field == "scene":  # a check across fields (fps * substeps)
                    where = ("substeps",) if "substeps" in top else ("frames", "fps")
                    d = locs.diag(where, d.message, field="scene")
                found.append(d)
            bad = {e["loc"][0] if e["loc"] else None for e in exc.errors()}
            if None in bad:
                bad |= {"substeps", "frames"}
                bad.discard(None)
            bad = {b for b in bad if b in top} | ({"lokigraph"} & bad)
            failed |= bad
            for b in bad:
                top.pop(b, None)
            if "lokigraph" in bad:
                top["lokigraph"] = 1
    else:  # pragma: no cover - every pass drops at least one field
        spec = SceneSpec(lokigraph=1)
    if "elements" in data and not isinstance(data["elements"], list):
        found.append(locs.diag(("elements",), f"'elements' is a list of elements (- name: ...), "
                                              f"not {_kind(data['elements'])}", field="scene"))
        failed.add("elements")
    diags.extend(dict.fromkeys(found))
    return spec, failed


def _element_specs(data: dict, locs: Locations, diags: list, failed: dict):
    """Yield (index, ElementSpec, raw components) for every element whose name, geometry and
    channels are valid; report the others (and their components' problems) and record them in
    ``failed`` (name -> {"*"})."""
    raw_elements = data.get("elements")
    if not isinstance(raw_elements, list):
        return
    for i, raw in enumerate(raw_elements):
        epath = ("elements", i)
        if not isinstance(raw, dict):
            diags.append(locs.diag(epath, f"an element is a mapping (name: ..., geometry: ..., "
                                          f"components: ...), not {_kind(raw)}"))
            continue
        name = raw.get("name")
        label = name if isinstance(name, str) and name else f"#{i}"
        comps = raw.get("components")
        if comps is None:
            comps = {}
        elif not isinstance(comps, dict):
            diags.append(locs.diag(epath + ("components",), f"'components' maps component types "
                                   f"to their parameters (Dynamic: {{...}}), not {_kind(comps)}",
                                   element=label))
            failed.setdefault(label, set()).add("*")
            comps = {}
        body = {k: v for k, v in raw.items() if k != "components"}
        try:
            es = ElementSpec.model_validate(body)
        except ValidationError as exc:
            diags.extend(pydantic_diagnostics(
                exc, locs, epath, label, "", known_fields=ElementSpec.model_fields,
                element_for=lambda loc: (label, ".".join(str(p) for p in loc))))
            failed.setdefault(label, set()).add("*")
            # still check the components of an element whose own fields are in error
            es = None
        if es is None:
            _validate_components(comps, epath, label, locs, diags)
            continue
        es.components = {k: v for k, v in comps.items() if v is None or isinstance(v, dict)}
        yield i, es, comps


def _validate_components(raw: dict, epath: tuple, label: str, locs: Locations,
                         diags: list) -> tuple[dict[str, Component], set[str]]:
    """Validate each component of an element on its own; return the valid ones and the names
    of those in error (reported into ``diags``)."""
    reg = get_registry()
    comps: dict[str, Component] = {}
    bad: set[str] = set()
    for cname, cdata in raw.items():
        cpath = epath + ("components", cname)
        cls = reg.components.get(cname) if isinstance(cname, str) else None
        if cls is None:
            diags.append(locs.diag(cpath, f"unknown component type {cname!r}"
                                   f"{reg.suggest(str(cname), 'component')}", element=label))
            bad.add(str(cname))
            continue
        if cdata is not None and not isinstance(cdata, dict):
            diags.append(locs.diag(cpath, f"a component holds its parameters as a mapping "
                                   f"({cname}: {{field: value}}), not {_kind(cdata)}",
                                   element=label, field=cname))
            bad.add(cname)
            continue
        try:
            comps[cname] = cls.model_validate(cdata or {})
        except ValidationError as exc:
            diags.extend(pydantic_diagnostics(exc, locs, cpath, label, cname,
                                              known_fields=cls.model_fields))
            bad.add(cname)
    return comps, bad
