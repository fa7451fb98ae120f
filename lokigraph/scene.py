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

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from . import geometry as geo_mod
from .component import Component, MapFile, MapVertices, load_map_file, pydantic_diagnostics
from .errors import Diagnostic, InputError
from .geometry import Geometry, MeshReadError
from .registry import get_registry
from .yamlio import Locations, load_yaml

Vec3 = tuple[float, float, float]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Frames(Strict):
    start: int = Field(1, description="First frame written (the initial state is frame start).")
    end: int = Field(48, description="Last frame written.")
    fps: float = Field(24.0, gt=0, description="Frames per second [1/s].")

    @model_validator(mode="after")
    def _order(self):
        if self.end < self.start:
            raise ValueError(f"end ({self.end}) must be >= start ({self.start})")
        return self


class Transform(Strict):
    scale: float | Vec3 = Field(1.0, description="Scale factor(s), applied after unit conversion.")
    rotate: Vec3 = Field((0.0, 0.0, 0.0), description="Rotation about x, y, z [degrees].")
    translate: Vec3 = Field((0.0, 0.0, 0.0), description="Translation [m].")


class GeometrySpec(Strict):
    file: str | None = Field(None, description="Mesh file (OBJ, PLY, VTK, VTU, MSH ...), "
                                               "relative to the scene file.")
    sequence: str | None = Field(None, description="Per-frame mesh files for a kinematic element, "
                                                   "e.g. 'anim/body.{frame:04d}.obj'.")
    generator: Literal["points", "grid", "strands", "sphere", "box", "tube", "tet_box"] | None = None
    params: dict = Field(default_factory=dict, description="Generator parameters (SI units).")
    units: Literal["m", "cm", "mm", "km", "in", "ft"] = Field("m", description="Units of the file.")
    transform: Transform | None = None

    @model_validator(mode="after")
    def _one_source(self):
        n = sum(x is not None for x in (self.file, self.generator))
        if n == 0 and self.sequence is None:
            raise ValueError("geometry needs one of 'file', 'generator' or 'sequence'")
        if n > 1:
            raise ValueError("give only one of 'file' and 'generator'")
        return self


class ElementSpec(Strict):
    name: str = Field(pattern=r"^[A-Za-z_][A-Za-z0-9_.\-]*$")
    geometry: GeometrySpec | None = None
    channels: dict[str, MapFile | MapVertices] = Field(
        default_factory=dict, description="Extra per-vertex channels (painted maps).")
    components: dict[str, dict | None] = Field(default_factory=dict)


class Output(Strict):
    dir: str = Field("out", description="Output folder, relative to the current directory.")
    format: Literal["obj", "ply", "vtu"] = "obj"


class Reference(Strict):
    """Independent truth for ``lokigraph bench`` (``run`` ignores it); see lokigraph.references."""

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


class SceneSpec(Strict):
    lokigraph: Literal[1] = Field(description="Scene format version.")
    graph: str = Field("default", description="Shipped graph name or path to a graph YAML.")
    solver: str = Field("nucleus", description="Solver behavior to run (the graph may hold several).")
    frames: Frames = Field(default_factory=Frames)
    substeps: int = Field(4, ge=1, le=10000, description="Substeps per frame.")
    gravity: Vec3 = Field((0.0, -9.81, 0.0), description="Gravity [m/s^2].")
    seed: int = Field(0, description="Random seed for any stochastic behavior.")
    elements: list[ElementSpec] = Field(default_factory=list)
    output: Output = Field(default_factory=Output)
    reference: Reference | None = Field(None, description="Reference solution for `lokigraph "
                                        "bench` (ignored by run).")
    graph_overrides: dict[str, dict] = Field(
        default_factory=dict, description="Per graph node name: parameter overrides.")


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

    def element(self, name: str) -> Element:
        for e in self.elements:
            if e.name == name:
                return e
        raise KeyError(name)


def _load_geometry(spec: GeometrySpec, base: Path, frame: int | None = None) -> Geometry:
    if spec.generator is not None:
        fn = geo_mod.GENERATORS[spec.generator]
        try:
            g = fn(**spec.params)
        except TypeError as exc:
            raise MeshReadError(f"generator {spec.generator!r}: {exc}") from None
        except (ValueError, KeyError, IndexError) as exc:
            raise MeshReadError(f"generator {spec.generator!r}: bad parameters ({exc})") from None
    else:
        path = spec.file
        if path is None:
            path = spec.sequence.format(frame=frame if frame is not None else 0)
        g = read_mesh_cached(base / path)
        g = g.copy()
    t = spec.transform or Transform()
    g.points = geo_mod.apply_transform(g.points, t.scale, t.rotate, t.translate, spec.units)
    return g


def read_mesh_cached(path: Path) -> Geometry:
    return geo_mod.read_mesh(path)


def load_scene(path: str | Path) -> Scene:
    """Parse and validate a scene file; load geometry. Raises InputError with every problem."""
    path = Path(path)
    data, locs = load_yaml(path)
    return scene_from_data(data, locs, path)


def scene_from_data(data, locs: Locations, path: Path) -> Scene:
    file = str(path)
    base = path.parent
    diags: list[Diagnostic] = []
    if not isinstance(data, dict):
        raise InputError(locs.diag((), "a scene file must be a mapping"))
    try:
        spec = SceneSpec.model_validate(data)
    except ValidationError as exc:
        names = {}
        for i, e in enumerate(data.get("elements") or []):
            if isinstance(e, dict):
                names[i] = str(e.get("name", f"#{i}"))

        def element_for(loc):
            if len(loc) >= 2 and loc[0] == "elements" and isinstance(loc[1], int):
                return names.get(loc[1], f"#{loc[1]}"), ".".join(str(p) for p in loc[2:])
            return None

        diags = pydantic_diagnostics(exc, locs, (), "", "scene",
                                     known_fields=SceneSpec.model_fields, element_for=element_for)
        raise InputError(diags) from None

    reg = get_registry()
    elements: list[Element] = []
    seen: dict[str, int] = {}
    for i, es in enumerate(spec.elements):
        epath = ("elements", i)
        line, col = locs.get(epath)
        if es.name in seen:
            diags.append(locs.diag(epath + ("name",), f"duplicate element name (first at "
                                   f"element #{seen[es.name]})", element=es.name))
        seen[es.name] = i
        comps: dict[str, Component] = {}
        for cname, cdata in es.components.items():
            cpath = epath + ("components", cname)
            cls = reg.components.get(cname)
            if cls is None:
                exc = reg.broken_error()
                diags.append(locs.diag(cpath, f"unknown component type {cname!r}"
                                       f"{reg.suggest(cname, 'component')}", element=es.name))
                continue
            try:
                comps[cname] = cls.model_validate(cdata or {})
            except ValidationError as exc:
                diags.extend(pydantic_diagnostics(exc, locs, cpath, es.name, cname,
                                                  known_fields=cls.model_fields))
        g = None
        if es.geometry is not None:
            gpath = epath + ("geometry",)
            try:
                first = spec.frames.start if es.geometry.sequence and not (
                    es.geometry.file or es.geometry.generator) else None
                g = _load_geometry(es.geometry, base, first)
            except MeshReadError as exc:
                key = "file" if es.geometry.file else ("sequence" if es.geometry.sequence
                                                       else "generator")
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
        el = Element(es.name, i, g, comps, file, line, col, str(base),
                     sequence=es.geometry.sequence if es.geometry else None, spec=es.geometry)
        if g is not None:
            for chname, chspec in es.channels.items():
                chpath = epath + ("channels", chname)
                try:
                    if isinstance(chspec, MapFile):
                        g.channels[chname] = load_map_file(base / chspec.file, g.vertex_count, el,
                                                           f"channels.{chname}")
                    else:
                        arr = np.full(g.vertex_count, chspec.default)
                        idx = np.asarray(chspec.vertices, dtype=np.int64)
                        if idx.size and idx.max() >= g.vertex_count:
                            raise InputError(locs.diag(
                                chpath, f"vertex index {int(idx.max())} out of range (element "
                                f"has {g.vertex_count} vertices)", element=es.name,
                                field=f"channels.{chname}"))
                        arr[idx] = chspec.value
                        g.channels[chname] = arr
                except InputError as exc:
                    for d in exc.diagnostics:
                        diags.append(locs.diag(chpath, d.message, element=es.name,
                                               field=f"channels.{chname}"))
        elif es.channels:
            diags.append(locs.diag(epath + ("channels",), "channels need geometry",
                                   element=es.name))
        elements.append(el)
    if diags:
        raise InputError(diags)
    return Scene(spec, elements, file, locs, str(base), raw=data)
