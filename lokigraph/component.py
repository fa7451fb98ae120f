"""Scene Element Components (SECs): typed, strict, per-object parameters.

A component is a pydantic model. Every field's description carries its SI unit. A field that may
be painted per vertex is typed :data:`Paintable`: a scalar, the name of a channel on the element's
geometry, or ``{file: path}`` (a ``.npy`` or text file with one value per vertex).
A missing component means the behavior's documented default.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, ClassVar, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from .errors import Diagnostic


MAX_INDEX = 2**31 - 1
"""Largest vertex index accepted anywhere in a scene (indices are int64 internally; this bound
keeps every index arithmetic far from overflow and is checked by validation, not at run time)."""

VertexIndex = Annotated[int, Field(ge=0, le=MAX_INDEX)]
"""A 0-based vertex index as written in a scene file."""


class MapFile(BaseModel):
    """A per-vertex map stored in a file: ``.npy`` (shape (n,)) or text (one value per line)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    file: str = Field(description="Path to the map, relative to the scene file.")


class MapVertices(BaseModel):
    """A per-vertex map painted by listing vertices: ``value`` on them, ``default`` elsewhere."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    vertices: list[VertexIndex] = Field(description="Vertex indices (0-based).")
    value: float = Field(1.0, description="Value on the listed vertices.")
    default: float = Field(0.0, description="Value on every other vertex.")


Paintable = Union[float, str, MapFile, MapVertices]
"""A scalar, a channel name, ``{file: ...}`` or ``{vertices: [...], value: v, default: d}``."""


class Component(BaseModel):
    """Base class of all components. Subclasses set ``type_id`` implicitly by their class name."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, frozen=False)

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
    if isinstance(value, MapVertices):
        out = np.full(n, float(value.default))
        idx = np.asarray(value.vertices, dtype=np.int64)
        if idx.size and idx.max() >= n:
            raise InputError(Diagnostic(file=element.source_file, line=element.line,
                                        element=element.name, field=field_name,
                                        message=f"vertex index {int(idx.max())} out of range "
                                                f"(element has {n} vertices)"))
        out[idx] = value.value
        return out
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
    raise TypeError(f"not a paintable value: {value!r}")


def load_map_file(path: Path, n: int, element, field_name: str) -> np.ndarray:
    from .errors import InputError

    def fail(msg):
        raise InputError(Diagnostic(file=element.source_file, line=element.line,
                                    element=element.name, field=field_name, message=msg))

    if not path.exists():
        fail(f"map file not found: {path}")
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
    "greater_than": "must be > {gt} (got {input})",
    "greater_than_equal": "must be >= {ge} (got {input})",
    "less_than": "must be < {lt} (got {input})",
    "less_than_equal": "must be <= {le} (got {input})",
    "extra_forbidden": "unknown key",
    "missing": "required field is missing",
}


def pydantic_diagnostics(exc: ValidationError, locs, base_path: tuple, element: str,
                         model_name: str, known_fields=None, element_for=None) -> list[Diagnostic]:
    """Turn a pydantic ValidationError into located diagnostics.

    For a union (Paintable) pydantic reports one error per member; we keep the most telling one.
    """
    import difflib

    out: list[Diagnostic] = []
    seen: set[tuple] = set()
    for err in exc.errors():
        loc = tuple(p for p in err["loc"] if not (isinstance(p, str) and (
            p in ("float", "str", "MapFile", "MapVertices") or p.startswith("function-"))))
        key = loc
        if key in seen:
            continue
        seen.add(key)
        etype = err["type"]
        template = _MESSAGES.get(etype)
        ctx = {k: (f"{v:g}" if isinstance(v, float) else v)
               for k, v in dict(err.get("ctx") or {}).items()}
        ctx["input"] = err.get("input")
        msg = template.format(**ctx) if template else err["msg"]
        if etype == "value_error" and msg.startswith("Value error, "):
            msg = msg[len("Value error, "):]
        if etype == "extra_forbidden" and known_fields and loc:
            near = difflib.get_close_matches(str(loc[-1]), list(known_fields), n=1)
            msg = f"unknown key {loc[-1]!r}" + (f"; did you mean {near[0]!r}?" if near else "")
        field = model_name + ("." + ".".join(str(p) for p in loc) if loc else "")
        el = element
        if element_for is not None:
            found = element_for(loc)
            if found is not None:  # (element name, field path inside the element)
                el, field = found
        out.append(locs.diag(base_path + loc, msg, element=el, field=field))
    return out
