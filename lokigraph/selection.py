"""Vertex selections: authoring pins, attachments and painted maps without vertex indices.

A selection names a set of vertices of one element. In YAML it is a mapping with exactly one of
these keys (or a bare string, short for ``{group: NAME}``)::

    {group: waist}                                   # a named set: OBJ g/o group, or a set a
                                                     # generator documents (grid 'top', strands
                                                     # 'root', tube 'end', box 'ymax' ...)
    {vertices: [0, 5, 9]}                            # explicit 0-based indices
    {channel: color, component: 0, above: 0.5}       # mesh attribute / channel threshold:
                                                     # value > above and/or value < below
    {box: {min: [-1, 0.9, -1], max: [1, 2, 1]}}      # region, inclusive [m]
    {sphere: {center: [0, 1, 0], radius: 0.1}}       # |x - center| <= radius [m]
    {plane: {point: [0, 1, 0], normal: [0, 1, 0]}}   # (x - point) . normal >= 0 [m]
    {union: [S1, S2, ...]}                           # in any of them
    {intersection: [S1, S2, ...]}                    # in all of them
    {difference: [S1, S2, ...]}                      # in S1 and in none of the others

Regions are tested against the element's initial positions (after units and transform), in
metres, in scene space. A selection that selects no vertex at all is an error (it is almost
always a region in the wrong place or a misspelt threshold).

Painted maps (:data:`lokigraph.component.Paintable`, and ``channels:`` of an element) can be
made from a selection, ``{select: S, value: 1, default: 0}``, or from a mesh attribute or
colour, ``{attribute: color, component: 0, remap: {from: [0, 1], to: [0, 2]}}``.
"""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Annotated, Optional, Union

import numpy as np
from pydantic import (BaseModel, ConfigDict, Discriminator, Field, Tag, field_validator,
                      model_validator)

from .errors import Diagnostic, InputError

MAX_INDEX = 2**31 - 1
"""Largest vertex index accepted anywhere in a scene (indices are int64 internally; this bound
keeps every index arithmetic far from overflow and is checked by validation, not at run time)."""

VertexIndex = Annotated[int, Field(ge=0, le=MAX_INDEX)]
"""A 0-based vertex index as written in a scene file."""

Vec3 = tuple[float, float, float]


class SelectionError(ValueError):
    """A selection cannot be resolved on an element (the message says why)."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Box(_Strict):
    """An axis-aligned box, bounds inclusive [m]."""

    min: Vec3 = Field(description="Lower corner [m].")
    max: Vec3 = Field(description="Upper corner [m].")

    @model_validator(mode="after")
    def _order(self):
        if any(a > b for a, b in zip(self.min, self.max)):
            raise ValueError(f"box min {list(self.min)} must be <= max {list(self.max)} on "
                             f"every axis")
        return self


class Sphere(_Strict):
    """A ball: vertices with |x - center| <= radius."""

    center: Vec3 = Field(description="Centre [m].")
    radius: float = Field(gt=0, description="Radius [m].")


class Plane(_Strict):
    """A half-space: vertices with (x - point) . normal >= 0 (the side the normal points to)."""

    point: Vec3 = Field((0.0, 0.0, 0.0), description="A point on the plane [m].")
    normal: Vec3 = Field(description="Normal pointing to the selected side (any length).")

    @field_validator("normal")
    @classmethod
    def _nonzero(cls, v):
        if not np.linalg.norm(v) > 0:
            raise ValueError("must not be zero")
        return v


_KINDS = ("group", "vertices", "channel", "box", "sphere", "plane", "union", "intersection",
          "difference")


class Selection(_Strict):
    """A set of vertices of one element: exactly one of ``group``, ``vertices``, ``channel``,
    ``box``, ``sphere``, ``plane``, ``union``, ``intersection``, ``difference``. A bare string is
    short for ``{group: NAME}``."""

    group: Optional[str] = Field(None, description="A named vertex set of the geometry: an OBJ "
                                 "'g'/'o' group or a set a generator documents (grid left/right/"
                                 "bottom/top/corners/border, strands root/tip, tube start/end/"
                                 "ends, box and tet_box xmin..zmax).")
    vertices: Optional[list[VertexIndex]] = Field(None, description="0-based vertex indices.")
    channel: Optional[str] = Field(None, description="A channel or mesh attribute (e.g. 'color'"
                                   "); selects where its value is > above and/or < below.")
    component: Optional[int] = Field(None, ge=0, description="Component of a multi-component "
                                     "channel (e.g. 0 = red of 'color').")
    above: Optional[float] = Field(None, description="With channel: select value > above.")
    below: Optional[float] = Field(None, description="With channel: select value < below.")
    box: Optional[Box] = Field(None, description="Vertices inside an axis-aligned box [m].")
    sphere: Optional[Sphere] = Field(None, description="Vertices inside a ball [m].")
    plane: Optional[Plane] = Field(None, description="Vertices on the normal's side of a "
                                   "plane [m].")
    union: Optional[list[SelectionLike]] = Field(None, min_length=1, description="Vertices in any "
                                               "of these selections.")
    intersection: Optional[list[SelectionLike]] = Field(None, min_length=1, description="Vertices "
                                                      "in all of these selections.")
    difference: Optional[list[SelectionLike]] = Field(None, min_length=2, description="Vertices "
                                                    "of the first selection in none of the "
                                                    "others.")

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, v):
        if isinstance(v, str):
            return {"group": v}
        return v

    @model_validator(mode="after")
    def _one_kind(self):
        given = [k for k in _KINDS if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("a selection needs exactly one of " + ", ".join(_KINDS)
                             + (f" (got {', '.join(given)})" if given else ""))
        if self.channel is None:
            extra = [k for k in ("component", "above", "below") if getattr(self, k) is not None]
            if extra:
                raise ValueError(f"{', '.join(extra)} only go with 'channel'")
        elif self.above is None and self.below is None:
            raise ValueError("a channel selection needs 'above' and/or 'below'")
        return self

    def describe(self) -> str:
        """A short human description (for messages)."""
        k = next(k for k in _KINDS if getattr(self, k) is not None)
        v = getattr(self, k)
        if k in ("group", "channel"):
            return f"{k} {v!r}"
        if k == "vertices":
            return f"{len(v)} listed vertices"
        return k


def _selection_kind(v):
    return "str" if isinstance(v, str) else "Selection"


SelectionLike = Annotated[
    Union[Annotated[str, Tag("str")], Annotated[Selection, Tag("Selection")]],
    Discriminator(_selection_kind)]
"""A :class:`Selection`, or a bare string: the name of a vertex group."""

Selection.model_rebuild()


def _indices_kind(v):
    if isinstance(v, (list, tuple)):
        return "list"
    return "str" if isinstance(v, str) else "Selection"


IndicesOrSelection = Annotated[
    Union[Annotated[list[VertexIndex], Tag("list")], Annotated[str, Tag("str")],
          Annotated[Selection, Tag("Selection")]],
    Discriminator(_indices_kind)]
"""A list of 0-based vertex indices, a group name, or a :class:`Selection`."""


def as_selection(value) -> Selection:
    """A Selection from a Selection, a group name or a mapping (validated)."""
    if isinstance(value, Selection):
        return value
    return Selection.model_validate(value)


# ----------------------------------------------------------------------------- resolving

def _near(name: str, names) -> str:
    names = sorted(names)
    near = difflib.get_close_matches(name, names, n=1)
    if near:
        return f"; did you mean {near[0]!r}?"
    return f"; available: {', '.join(names) if names else 'none'}"


def channel_values(geometry, name: str, component: int | None, what: str = "channel"
                   ) -> np.ndarray:
    """Values of channel ``name`` (one component of a multi-component one) as float64 (n,)."""
    n = geometry.vertex_count
    if name not in geometry.channels:
        raise SelectionError(f"no {what} named {name!r}{_near(name, geometry.channels)}")
    arr = np.asarray(geometry.channels[name])
    if arr.dtype.kind not in "biuf":
        raise SelectionError(f"{what} {name!r} is not numeric")
    arr = arr.reshape(n, -1) if arr.size else arr.reshape(n, 0)
    k = arr.shape[1]
    if component is None:
        if k != 1:
            raise SelectionError(f"{what} {name!r} has {k} components per vertex; give "
                                 f"'component' (0..{k - 1})")
        component = 0
    if component >= k:
        raise SelectionError(f"{what} {name!r} has {k} component{'s' if k != 1 else ''} per "
                             f"vertex; component {component} does not exist")
    out = arr[:, component].astype(np.float64)
    if not np.all(np.isfinite(out)):
        raise SelectionError(f"{what} {name!r} holds non-finite values")
    return out


def vertex_mask(vertices, n: int) -> np.ndarray:
    """Boolean mask (n,) of listed 0-based vertex indices; SelectionError past the last one."""
    idx = np.asarray(vertices, dtype=np.int64)
    if idx.size and idx.max() >= n:
        raise SelectionError(f"vertex index {int(idx.max())} out of range (element has "
                             f"{n} vertices)")
    m = np.zeros(n, bool)
    m[idx] = True
    return m


def _mask(sel: Selection, geometry) -> np.ndarray:
    n = geometry.vertex_count
    p = geometry.points
    if sel.group is not None:
        groups = getattr(geometry, "groups", {}) or {}
        if sel.group not in groups:
            raise SelectionError(f"no vertex group named {sel.group!r}{_near(sel.group, groups)}")
        idx = np.asarray(groups[sel.group], dtype=np.int64)
        m = np.zeros(n, bool)
        m[idx[(idx >= 0) & (idx < n)]] = True
        return m
    if sel.vertices is not None:
        return vertex_mask(sel.vertices, n)
    if sel.channel is not None:
        v = channel_values(geometry, sel.channel, sel.component)
        m = np.ones(n, bool)
        if sel.above is not None:
            m &= v > sel.above
        if sel.below is not None:
            m &= v < sel.below
        return m
    if sel.box is not None:
        lo, hi = np.asarray(sel.box.min), np.asarray(sel.box.max)
        return np.all((p >= lo) & (p <= hi), axis=1)
    if sel.sphere is not None:
        d = p - np.asarray(sel.sphere.center)
        return np.einsum("ij,ij->i", d, d) <= sel.sphere.radius ** 2
    if sel.plane is not None:
        nrm = np.asarray(sel.plane.normal, np.float64)
        return (p - np.asarray(sel.plane.point)) @ (nrm / np.linalg.norm(nrm)) >= 0.0
    if sel.union is not None:
        m = np.zeros(n, bool)
        for s in sel.union:
            m |= _mask(as_selection(s), geometry)
        return m
    if sel.intersection is not None:
        m = np.ones(n, bool)
        for s in sel.intersection:
            m &= _mask(as_selection(s), geometry)
        return m
    if sel.difference is not None:
        m = _mask(as_selection(sel.difference[0]), geometry)
        for s in sel.difference[1:]:
            m &= ~_mask(as_selection(s), geometry)
        return m
    raise SelectionError("empty selection")  # pragma: no cover - prevented by validation


def select_mask(sel, geometry, allow_empty: bool = False) -> np.ndarray:
    """Boolean mask (vertex_count,) of ``sel`` on ``geometry``; raises :class:`SelectionError`."""
    sel = as_selection(sel)
    if geometry is None:
        raise SelectionError("a selection needs an element with geometry")
    m = _mask(sel, geometry)
    if not allow_empty and not m.any():
        n = geometry.vertex_count
        if n:
            lo, hi = geometry.points.min(0), geometry.points.max(0)
            where = (f"; the element's bounding box is [{', '.join(f'{x:.4g}' for x in lo)}] .. "
                     f"[{', '.join(f'{x:.4g}' for x in hi)}] m")
        else:
            where = "; the element has no vertices"
        raise SelectionError(f"the selection ({sel.describe()}) selects no vertices{where}")
    return m


def select_indices(sel, geometry, allow_empty: bool = False) -> np.ndarray:
    """Sorted int64 vertex indices of ``sel`` on ``geometry``."""
    return np.flatnonzero(select_mask(sel, geometry, allow_empty)).astype(np.int64)


def element_diagnostic(element, field_name: str, message: str) -> Diagnostic:
    """A Diagnostic at ``element``'s line (the best place known after loading)."""
    return Diagnostic(file=getattr(element, "source_file", ""), line=getattr(element, "line", 0),
                      column=getattr(element, "column", 0), element=getattr(element, "name", ""),
                      field=field_name, message=message)


def resolve_selection(sel, element, field_name: str, allow_empty: bool = False) -> np.ndarray:
    """Sorted local vertex indices of ``sel`` (a selection, a group name or a list of indices)
    on ``element``; raises InputError (file:line, element, field) when it cannot be resolved."""
    try:
        if isinstance(sel, (list, tuple, np.ndarray)):
            sel = Selection(vertices=list(sel)) if len(sel) else None
            if sel is None:
                return np.zeros(0, np.int64)
        return select_indices(sel, element.geometry, allow_empty)
    except SelectionError as exc:
        raise InputError(element_diagnostic(element, field_name, str(exc))) from None


# ----------------------------------------------------------------------------- painted maps

class Remap(_Strict):
    """Linear remap of attribute values: ``from: [a, b]`` goes to ``to: [c, d]``."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False,
                              populate_by_name=True)
    from_: tuple[float, float] = Field((0.0, 1.0), alias="from", description="Input values "
                                       "mapped to the two ends of 'to'.")
    to: tuple[float, float] = Field((0.0, 1.0), description="Output values.")
    clamp: bool = Field(True, description="Clamp to the 'to' range outside 'from'.")

    @model_validator(mode="after")
    def _ok(self):
        if self.from_[0] == self.from_[1]:
            raise ValueError("remap 'from' needs two different values")
        return self

    def apply(self, x: np.ndarray) -> np.ndarray:
        a, b = self.from_
        c, d = self.to
        t = (x - a) / (b - a)
        if self.clamp:
            t = np.clip(t, 0.0, 1.0)
        return c + t * (d - c)


class MapSelection(_Strict):
    """A per-vertex map painted by a selection: ``value`` on it, ``default`` elsewhere."""

    select: SelectionLike = Field(description="The painted vertices (see lokigraph.selection).")
    value: float = Field(1.0, description="Value on the selected vertices.")
    default: float = Field(0.0, description="Value on every other vertex.")


class MapAttribute(_Strict):
    """A per-vertex map from a mesh attribute or colour (a channel of the geometry), e.g.
    ``{attribute: color, component: 0, remap: {from: [0, 1], to: [0, 50]}}``."""

    attribute: str = Field(description="Channel name: a mesh vertex attribute or colour read "
                           "from the file (e.g. 'color'), or a channel painted earlier.")
    component: Optional[int] = Field(None, ge=0, description="Component of a multi-component "
                                     "attribute (0 = red of 'color'); required if it has several.")
    remap: Optional[Remap] = Field(None, description="Linear remap of the values (default: as "
                                   "is).")


def map_from_vertices(spec, n: int) -> np.ndarray:
    """A :class:`~lokigraph.component.MapVertices` painted on ``n`` vertices: ``value`` on the
    listed ones, ``default`` elsewhere."""
    out = np.full(n, float(spec.default))
    out[vertex_mask(spec.vertices, n)] = spec.value
    return out


def map_from_selection(spec: MapSelection, geometry) -> np.ndarray:
    out = np.full(geometry.vertex_count, float(spec.default))
    out[select_mask(spec.select, geometry)] = float(spec.value)
    return out


def map_from_attribute(spec: MapAttribute, geometry) -> np.ndarray:
    v = channel_values(geometry, spec.attribute, spec.component, "attribute")
    return spec.remap.apply(v) if spec.remap is not None else v


def build_channels(channels: dict, geometry, element, base: Path, locs, path: tuple) -> list:
    """Fill ``geometry.channels`` from an element's ``channels:`` specs, in order (a later map
    may use an earlier one). Returns diagnostics located at each channel's line."""
    from .component import MapFile, MapVertices, load_map_file

    diags = []
    for chname, chspec in channels.items():
        chpath = path + (chname,)
        field = f"channels.{chname}"
        try:
            if isinstance(chspec, MapFile):
                arr = load_map_file(base / chspec.file, geometry.vertex_count, element, field)
            elif isinstance(chspec, MapVertices):
                arr = map_from_vertices(chspec, geometry.vertex_count)
            elif isinstance(chspec, MapSelection):
                arr = map_from_selection(chspec, geometry)
            elif isinstance(chspec, MapAttribute):
                arr = map_from_attribute(chspec, geometry)
            else:  # pragma: no cover - prevented by validation
                raise SelectionError(f"not a channel specification: {chspec!r}")
            geometry.channels[chname] = arr
        except SelectionError as exc:
            sub = {MapSelection: ("select",), MapAttribute: ("attribute",)}.get(type(chspec), ())
            diags.append(locs.diag(chpath + sub, str(exc), element=element.name, field=field))
        except InputError as exc:
            for d in exc.diagnostics:
                diags.append(locs.diag(chpath, d.message, element=element.name, field=field))
    return diags


def check_component_selections(components: dict, geometry, element, locs, path: tuple) -> list:
    """Resolve, at load time, every selection and painted map of ``components`` that refers to
    this element's own geometry, so that a wrong group name or an empty region is reported at
    its own line (with every other error of the file). Returns diagnostics."""
    diags = []
    for cname, comp in components.items():
        for fname in type(comp).model_fields:
            if fname in getattr(type(comp), "foreign_selections", ()):
                continue  # selects on another element (e.g. Attachment.vertices)
            v = getattr(comp, fname, None)
            fpath = path + (cname, fname)
            field = f"{cname}.{fname}"
            try:
                if isinstance(v, (Selection, str)) and fname in getattr(
                        type(comp), "selection_fields", ()):
                    select_mask(v, geometry)
                elif isinstance(v, MapSelection):
                    map_from_selection(v, geometry)
                elif isinstance(v, MapAttribute):
                    map_from_attribute(v, geometry)
            except SelectionError as exc:
                diags.append(locs.diag(fpath, str(exc), element=element.name, field=field))
    return diags
