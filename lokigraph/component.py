"""Scene Element Components (SECs): typed, strict, per-object parameters.

A component is a pydantic model. Every field's description carries its SI unit. A field that may
be painted per vertex is typed :data:`Paintable`: a scalar, the name of a channel on the element's
geometry, ``{file: path}`` (a ``.npy`` or text file with one value per vertex), ``{vertices:
[...], value: v, default: d}``, ``{select: SELECTION, value: v, default: d}`` (see
:mod:`lokigraph.selection`) or ``{attribute: color, component: 0, remap: {from: [0, 1], to: [a,
b]}}`` (a mesh vertex attribute or colour).
A missing component means the behavior's documented default.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, ClassVar, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag, ValidationError
from pydantic.types import FiniteFloat

from .errors import Diagnostic
from .keys import Keyed, KeyedFloat, _bounded_keyed, keyable, value_at  # noqa: F401
from .selection import (MAX_INDEX, MapAttribute, MapSelection, Selection,  # noqa: F401
                        SelectionError, VertexIndex, map_from_attribute, map_from_selection,
                        map_from_vertices, resolve_selection)


class MapFile(BaseModel):
    """A per-vertex map stored in a file: ``.npy`` (shape (n,)) or text (one value per line)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    file: str = Field(description="Path to the map, relative to the scene file.")


class MapVertices(BaseModel):
    """A per-vertex map painted by listing vertices: ``value`` on them, ``default`` elsewhere."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    vertices: list[VertexIndex] = Field(description="Vertex indices (0-based).")
    value: float = Field(1.0, description="Value on the listed vertices.")
    default: float = Field(0.0, description="Value on every other vertex.")


_MAP_KEYS = (("file", "MapFile"), ("vertices", "MapVertices"), ("select", "MapSelection"),
             ("attribute", "MapAttribute"))
#: names pydantic puts in error locations for the members of a Paintable (hidden in messages)
UNION_TAGS = frozenset({"float", "str", "list", "MapFile", "MapVertices", "MapSelection",
                        "MapAttribute", "Selection", "Keyed", "[key]"})


def _paintable_kind(v):
    if isinstance(v, BaseModel):
        return type(v).__name__
    if isinstance(v, bool):
        return None
    if isinstance(v, (int, float)):
        return "float"
    if isinstance(v, str):
        return "str"
    if isinstance(v, dict):
        for key, tag in _MAP_KEYS:
            if key in v:
                return tag
    return None


Paintable = Annotated[
    Union[Annotated[FiniteFloat, Tag("float")], Annotated[str, Tag("str")],
          Annotated[MapFile, Tag("MapFile")], Annotated[MapVertices, Tag("MapVertices")],
          Annotated[MapSelection, Tag("MapSelection")],
          Annotated[MapAttribute, Tag("MapAttribute")]],
    Discriminator(_paintable_kind, custom_error_type="paintable",
                  custom_error_message="expected a number, a channel name, {file: ...}, "
                  "{vertices: [...]}, {select: ...} or {attribute: ...}")]
"""A per-vertex value: a (finite) scalar, a channel name, ``{file: ...}``, ``{vertices: [...],
value: v, default: d}``, ``{select: SELECTION, value: v, default: d}`` or ``{attribute: NAME,
component: k, remap: {from: [a, b], to: [c, d]}}``."""


def _keyable_paintable_kind(v):
    if isinstance(v, Keyed) or (isinstance(v, dict) and "keys" in v):
        return "Keyed"
    return _paintable_kind(v)


def keyable_paintable(ge=None, gt=None, le=None, lt=None):
    """A :data:`Paintable` that may also be keyed over time (``{keys: {FRAME: VALUE}, interp:
    ...}``, see :mod:`lokigraph.keys`): keys are scalar (the same value on every vertex); maps
    stay static. The bounds apply to the keys' values (a plain value or map is checked by the
    field's own validator, as for :data:`Paintable`). A behavior reading such a field handles
    :class:`~lokigraph.keys.Keyed` itself (``resolve_paintable`` refuses it)."""
    return Annotated[
        Union[Annotated[FiniteFloat, Tag("float")], Annotated[str, Tag("str")],
              Annotated[MapFile, Tag("MapFile")], Annotated[MapVertices, Tag("MapVertices")],
              Annotated[MapSelection, Tag("MapSelection")],
              Annotated[MapAttribute, Tag("MapAttribute")],
              Annotated[_bounded_keyed(ge, gt, le, lt), Tag("Keyed")]],
        Discriminator(_keyable_paintable_kind, custom_error_type="paintable",
                      custom_error_message="expected a number, a channel name, {file: ...}, "
                      "{vertices: [...]}, {select: ...}, {attribute: ...} or {keys: ...}")]


def _channel_kind(v):
    k = _paintable_kind(v)
    return k if k in ("MapFile", "MapVertices", "MapSelection", "MapAttribute") else None


ChannelSpec = Annotated[
    Union[Annotated[MapFile, Tag("MapFile")], Annotated[MapVertices, Tag("MapVertices")],
          Annotated[MapSelection, Tag("MapSelection")],
          Annotated[MapAttribute, Tag("MapAttribute")]],
    Discriminator(_channel_kind, custom_error_type="channel",
                  custom_error_message="a channel is {file: ...}, {vertices: [...]}, "
                  "{select: ...} or {attribute: ...}")]
"""A painted channel of an element (``channels: {NAME: ...}``): a map file, listed vertices, a
selection or a mesh attribute (see :data:`Paintable`)."""


class Component(BaseModel):
    """Base class of all components. Subclasses set ``type_id`` implicitly by their class name."""

    # NaN and infinities are never a meaningful parameter value: rejected in every float field
    model_config = ConfigDict(extra="forbid", validate_assignment=True, frozen=False,
                              allow_inf_nan=False)

    #: element kinds this component may be attached to (None = any)
    applies_to: ClassVar[tuple[str, ...] | None] = None

    @classmethod
    def type_id(cls) -> str:
        return cls.__name__


def resolve_paintable(value, element, field_name: str = "") -> np.ndarray:
    """Resolve a :data:`Paintable` on ``element`` to a float64 array of shape (vertex_count,)."""
    from .errors import InputError  # local: avoid a cycle at import

    n = element.vertex_count
    if value is None:
        raise ValueError("paintable value is None")
    if isinstance(value, (int, float)):
        return np.full(n, float(value))
    if isinstance(value, Keyed):
        raise TypeError(f"{field_name or 'value'} is keyed: evaluate it per substep with "
                        f"lokigraph.keys.value_at")
    if isinstance(value, MapVertices):
        try:
            return map_from_vertices(value, n)
        except SelectionError as exc:
            raise InputError(Diagnostic(file=element.source_file, line=element.line,
                                        element=element.name, field=field_name,
                                        message=str(exc))) from None
    if isinstance(value, str):
        if value not in element.channels:
            import difflib
            near = difflib.get_close_matches(value, list(element.channels), n=1)
            hint = f"; did you mean {near[0]!r}?" if near else (
                f"; available: {', '.join(sorted(element.channels)) or 'none'}")
            raise InputError(Diagnostic(file=element.source_file, line=element.line,
                                        element=element.name, field=field_name,
                                        message=f"no channel named {value!r}{hint}"))
        arr = np.asarray(element.channels[value], dtype=np.float64)
        if arr.ndim != 1:
            arr = arr.reshape(n, -1)[:, 0]
        return arr.copy()
    if isinstance(value, MapFile):
        path = Path(element.base_dir) / value.file
        arr = load_map_file(path, n, element, field_name)
        return arr
    if isinstance(value, (MapSelection, MapAttribute)):
        try:
            if isinstance(value, MapSelection):
                return map_from_selection(value, element.geometry)
            return map_from_attribute(value, element.geometry)
        except SelectionError as exc:
            raise InputError(Diagnostic(file=element.source_file, line=element.line,
                                        column=element.column, element=element.name,
                                        field=field_name, message=str(exc))) from None
    raise TypeError(f"not a paintable value: {value!r}")


def load_map_file(path: Path, n: int, element, field_name: str) -> np.ndarray:
    from .errors import InputError

    def fail(msg):
        raise InputError(Diagnostic(file=element.source_file, line=element.line,
                                    element=element.name, field=field_name, message=msg))

    if not path.exists():
        fail(f"map file not found: {path}")
    if not path.is_file():
        fail(f"map file {path} is not a regular file")
    # a text map holds at most ~40 bytes a value; a .npy its header plus 8 bytes a value
    limit = 1024 + 64 * max(n, 1)
    if path.stat().st_size > limit:
        fail(f"map file {path} is {path.stat().st_size} bytes, too large for {n} values")
    try:
        arr = np.load(path) if path.suffix == ".npy" else np.loadtxt(path, dtype=np.float64)
    except Exception as exc:  # noqa: BLE001 - reported to the user with the file name
        fail(f"cannot read map file {path}: {exc}")
    arr = np.asarray(arr, dtype=np.float64).reshape(-1)
    if arr.shape[0] != n:
        fail(f"map file {path} has {arr.shape[0]} values, element has {n} vertices")
    if not np.all(np.isfinite(arr)):
        fail(f"map file {path} contains non-finite values")
    return arr


_MESSAGES = {
    "finite_number": "must be a finite number (got {input})",
    "greater_than": "must be > {gt} (got {input})",
    "greater_than_equal": "must be >= {ge} (got {input})",
    "less_than": "must be < {lt} (got {input})",
    "less_than_equal": "must be <= {le} (got {input})",
    "extra_forbidden": "unknown key",
    "missing": "required field is missing",
}


_TYPE_WORDS = {
    "dict_type": "must be a mapping ({key: value})",
    "model_type": "must be a mapping ({key: value})",
    "model_attributes_type": "must be a mapping ({key: value})",
    "list_type": "must be a list",
    "tuple_type": "must be a list",
    "string_type": "must be text",
    "bool_type": "must be true or false",
    "bool_parsing": "must be true or false",
}


def _plain_words(etype: str, msg: str) -> str:
    """pydantic's wording ('Input should be a valid dictionary or instance of Frames') without
    Python class names."""
    if etype in _TYPE_WORDS:
        return _TYPE_WORDS[etype]
    msg = re.sub(r" or instance of \w+", "", msg)
    return re.sub(r"^Input should be a valid dictionary", "must be a mapping ({key: value})", msg)


def _nested_keys() -> list[str]:
    from . import selection as S

    keys = []
    for m in (S.Selection, S.Box, S.Sphere, S.Plane, S.MapSelection, S.MapAttribute, MapFile,
              MapVertices):
        keys.extend(m.model_fields)
    return sorted(set(keys) | {"from", "to", "clamp"})


def pydantic_messages(exc: ValidationError, known_fields=None) -> list[tuple[tuple, str]]:
    """(location, message) of every error of ``exc``, in plain words (no raw Python).

    For a union (Paintable) pydantic reports one error per member; we keep the most telling
    one, and drop the member names from locations.
    """
    import difflib

    out: list[tuple[tuple, str]] = []
    seen: set[tuple] = set()
    for err in exc.errors():
        loc = tuple(p for p in err["loc"] if not (isinstance(p, str) and (
            p in UNION_TAGS or p.startswith("function-"))))
        if loc in seen:
            continue
        seen.add(loc)
        etype = err["type"]
        template = _MESSAGES.get(etype)
        ctx = {k: (f"{v:g}" if isinstance(v, float) else v)
               for k, v in dict(err.get("ctx") or {}).items()}
        ctx["input"] = err.get("input")
        try:
            msg = template.format(**ctx) if template else err["msg"]
        except (KeyError, IndexError, ValueError):
            msg = err["msg"]
        if etype == "value_error" and msg.startswith("Value error, "):
            msg = msg[len("Value error, "):]
        msg = _plain_words(etype, msg)
        inp = err.get("input")
        if err["loc"] and err["loc"][-1] == "[key]" and etype in ("float_parsing", "float_type"):
            msg = f"a key's frame must be a number (got {inp!r})"
        if loc and isinstance(inp, dict) and "keys" in inp and etype not in (
                "extra_forbidden", "missing", "value_error"):
            # {keys: ...} on a field that does not take keys (see lokigraph.keys)
            msg = ("cannot be keyed: only fields documented as 'Keyable.' accept "
                   "{keys: {FRAME: VALUE}, interp: ...}")
        if etype == "extra_forbidden" and loc:
            # a key of the model itself, or (nested) of a selection / painted map
            vocab = list(known_fields or ()) + (_nested_keys() if len(loc) > 1 else [])
            near = difflib.get_close_matches(str(loc[-1]), vocab, n=1)
            msg = f"unknown key {loc[-1]!r}" + (f"; did you mean {near[0]!r}?" if near else "")
        out.append((loc, msg))
    return out


def pydantic_diagnostics(exc: ValidationError, locs, base_path: tuple, element: str,
                         model_name: str, known_fields=None, element_for=None) -> list[Diagnostic]:
    """Turn a pydantic ValidationError into located diagnostics (see :func:`pydantic_messages`).
    """
    out: list[Diagnostic] = []
    for loc, msg in pydantic_messages(exc, known_fields):
        field = model_name + ("." + ".".join(str(p) for p in loc) if loc else "")
        el = element
        if element_for is not None:
            found = element_for(loc)
            if found is not None:  # (element name, field path inside the element)
                el, field = found
        out.append(locs.diag(base_path + loc, msg, element=el, field=field))
    return out
