"""Built-in geometry generators (``geometry: {generator: NAME, params: {...}}``).

Every generator has a strict parameter model in :data:`GENERATOR_MODELS` (SI units, bounds,
finite numbers only, unknown keys rejected); its docstring gives the vertex order and the named
vertex sets it writes into :attr:`Geometry.groups` (select them with ``{group: NAME}``).
:func:`make_geometry` validates the parameters, checks the size against
:data:`MAX_GENERATED_VERTICES` / :data:`MAX_GENERATED_SIMPLICES` *before* allocating anything,
and builds the geometry. The plain functions (``grid(...)`` etc.) do no validation.
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

MAX_GENERATED_VERTICES = 4_000_000
"""Most vertices one generated element may have (about 100 MB of positions and state)."""
MAX_GENERATED_SIMPLICES = 8_000_000
"""Most simplices (edges, triangles or tetrahedra) one generated element may have."""

PosFloat = Annotated[float, Field(gt=0)]
Count = Annotated[int, Field(ge=1)]
Vec3 = tuple[float, float, float]


def _big(x: int) -> float:
    """An int as a float without overflow (counts are only compared with the limits)."""
    return float(min(int(x), 10**30))


def _n(x: int) -> str:
    """A count for a message (huge ones in short scientific notation)."""
    return str(x) if abs(x) < 10**12 else f"{_big(x):.3g}"


def _check_size(what: str, vertices: float, simplices: float = 0.0, kind: str = "simplices"):
    if vertices > MAX_GENERATED_VERTICES:
        raise ValueError(f"{what} would have {vertices:.4g} vertices, more than the limit of "
                         f"{MAX_GENERATED_VERTICES:,} vertices per generated element; lower the "
                         f"resolution or use a mesh file")
    if simplices > MAX_GENERATED_SIMPLICES:
        raise ValueError(f"{what} would have {simplices:.4g} {kind}, more than the limit of "
                         f"{MAX_GENERATED_SIMPLICES:,} per generated element ({vertices:.4g} "
                         f"vertices); lower the resolution")


class GeneratorParams(BaseModel):
    """Base of the generator parameter models: strict, finite numbers only."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)


# ----------------------------------------------------------------------------------- grid

class GridParams(GeneratorParams):
    """A rectangular cloth of (rx+1) x (ry+1) vertices in a coordinate plane, triangulated.

    Vertex order: vertex (i, j), i = 0..rx along the first axis, j = 0..ry along the second, has
    index j*(rx+1) + i (rows of the first axis, one after the other). Axes by ``plane``: xz ->
    (x, z), xy -> (x, y), yz -> (y, z). Channels: ``u`` = i/rx and ``v`` = j/ry in [0, 1].
    Named sets: ``left`` (i = 0), ``right`` (i = rx), ``bottom`` (j = 0), ``top`` (j = ry),
    ``corners`` (the 4 corners) and ``border`` (every boundary vertex). With plane xy, ``top`` is
    the row of largest y.
    """

    size: tuple[PosFloat, PosFloat] = Field((1.0, 1.0), description="Side lengths along the "
                                            "first and second axis [m].")
    resolution: tuple[Count, Count] = Field((16, 16), description="Cells along the first and "
                                            "second axis [-]; (rx+1) x (ry+1) vertices.")
    plane: Literal["xz", "xy", "yz"] = Field("xz", description="Coordinate plane of the grid; "
                                             "its two letters are the first and second axis.")
    center: Vec3 = Field((0.0, 0.0, 0.0), description="Centre of the grid [m].")
    diagonal: Literal["alternate", "uniform"] = Field(
        "alternate", description="Cell diagonals: alternating (a union-jack-like pattern, less "
        "anisotropic) or all the same way.")

    @model_validator(mode="after")
    def _size(self):
        rx, ry = self.resolution
        _check_size(f"grid {_n(rx)} x {_n(ry)}", _big(rx + 1) * _big(ry + 1),
                    2 * _big(rx) * _big(ry), "triangles")
        return self


def grid(size=(1.0, 1.0), resolution=(16, 16), plane: str = "xz", center=(0, 0, 0),
         diagonal: str = "alternate") -> Geometry:
    """A rectangular cloth; see :class:`GridParams` for the vertex order and named sets."""
    rx, ry = int(resolution[0]), int(resolution[1])
    u = np.linspace(0.0, 1.0, rx + 1)
    v = np.linspace(0.0, 1.0, ry + 1)
    uu, vv = np.meshgrid(u, v)
    a = (uu - 0.5) * size[0]
    b = (vv - 0.5) * size[1]
    zero = np.zeros_like(a)
    axes = {"xz": (a, zero, b), "xy": (a, b, zero), "yz": (zero, a, b)}[plane]
    pts = np.stack([ax.ravel() for ax in axes], axis=1) + np.asarray(center, dtype=np.float64)
    i, j = np.meshgrid(np.arange(rx), np.arange(ry))
    i, j = i.ravel(), j.ravel()
    v00 = j * (rx + 1) + i
    v10 = v00 + 1
    v01 = v00 + rx + 1
    v11 = v01 + 1
    if diagonal == "alternate":
        flip = (i + j) % 2 == 1
    else:
        flip = np.zeros_like(i, dtype=bool)
    t1 = np.where(flip[:, None], np.stack([v00, v10, v01], 1), np.stack([v00, v10, v11], 1))
    t2 = np.where(flip[:, None], np.stack([v10, v11, v01], 1), np.stack([v00, v11, v01], 1))
    tris = np.concatenate([t1, t2]).astype(np.int64)
    w = rx + 1
    left = np.arange(ry + 1, dtype=np.int64) * w
    right = left + rx
    bottom = np.arange(w, dtype=np.int64)
    top = bottom + ry * w
    groups = {"left": left, "right": right, "bottom": bottom, "top": top,
              "corners": np.unique([0, rx, ry * w, ry * w + rx]).astype(np.int64),
              "border": np.unique(np.concatenate([left, right, bottom, top]))}
    return Geometry(pts, triangles=tris, channels={"u": uu.ravel().copy(), "v": vv.ravel().copy()},
                    groups=groups)


# -------------------------------------------------------------------------------- strands

class StrandsParams(GeneratorParams):
    """Straight hair strands with roots on a regular grid perpendicular to ``direction``.

    Vertex order: strand k (k = b*cx + a for root (a, b) of the cx x cy root grid) owns the
    consecutive vertices k*(segments+1) .. k*(segments+1) + segments, from root to tip.
    Channels: ``s`` = arclength / length (0 at the root, 1 at the tip) and ``root`` (1 at roots).
    Named sets: ``root`` (first vertex of every strand) and ``tip`` (last vertex).
    """

    count: tuple[Count, Count] = Field((1, 1), description="Strands along the two root-grid "
                                       "axes [-].")
    spacing: float = Field(0.01, ge=0, description="Distance between neighbouring roots [m].")
    length: PosFloat = Field(0.2, description="Strand length [m].")
    segments: Count = Field(10, description="Segments (edges) per strand [-].")
    direction: Vec3 = Field((0.0, -1.0, 0.0), description="Direction from root to tip (any "
                            "length, not zero).")
    center: Vec3 = Field((0.0, 0.0, 0.0), description="Centre of the root grid [m].")

    @field_validator("direction")
    @classmethod
    def _nonzero(cls, v):
        if not np.linalg.norm(v) > 0:
            raise ValueError("must not be zero")
        return v

    @model_validator(mode="after")
    def _size(self):
        n = _big(self.count[0]) * _big(self.count[1])
        _check_size(f"{_n(self.count[0])} x {_n(self.count[1])} strands of "
                    f"{_n(self.segments)} segments",
                    n * (_big(self.segments) + 1), n * _big(self.segments), "edges")
        return self


def strands(count=(1, 1), spacing=0.01, length=0.2, segments=10, direction=(0, -1, 0),
            center=(0, 0, 0)) -> Geometry:
    """Straight hair strands; see :class:`StrandsParams` for the vertex order and named sets."""
    cx, cy = int(count[0]), int(count[1])
    segments = int(segments)
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    # two axes orthogonal to d for the root grid
    t = np.cross(d, [1.0, 0, 0] if abs(d[0]) < 0.9 else [0, 1.0, 0])
    t /= np.linalg.norm(t)
    b = np.cross(d, t)
    ia, ib = np.meshgrid(np.arange(cx) - (cx - 1) / 2, np.arange(cy) - (cy - 1) / 2)
    roots = (ia.ravel()[:, None] * t + ib.ravel()[:, None] * b) * spacing + np.asarray(center)
    s = np.linspace(0.0, 1.0, segments + 1)
    pts = (roots[:, None, :] + s[None, :, None] * length * d).reshape(-1, 3)
    nstr = roots.shape[0]
    base = (np.arange(nstr) * (segments + 1))[:, None]
    e0 = (base + np.arange(segments)[None, :]).ravel()
    edges = np.stack([e0, e0 + 1], 1).astype(np.int64)
    root = (np.arange(nstr, dtype=np.int64) * (segments + 1))
    return Geometry(pts, edges=edges, channels={"s": np.tile(s, nstr),
                                                "root": np.tile((s == 0).astype(float), nstr)},
                    groups={"root": root, "tip": root + segments})


# --------------------------------------------------------------------------------- sphere

class SphereParams(GeneratorParams):
    """A closed icosphere (outward normals by the right-hand rule).

    Vertex order: the 12 icosahedron vertices first, then the edge midpoints added by each
    subdivision in turn; 10*4^s + 2 vertices and 20*4^s triangles for s subdivisions.
    Named sets: none (select parts with a region, e.g. ``{plane: {point: .., normal: ..}}``).
    """

    radius: PosFloat = Field(0.5, description="Radius [m].")
    subdivisions: int = Field(3, ge=0, description="Subdivisions of the icosahedron [-] (each "
                              "multiplies the triangle count by 4).")
    center: Vec3 = Field((0.0, 0.0, 0.0), description="Centre [m].")

    @model_validator(mode="after")
    def _size(self):
        s = min(self.subdivisions, 100)
        _check_size(f"sphere with {_n(self.subdivisions)} subdivisions", 10.0 * 4.0 ** s + 2,
                    20.0 * 4.0 ** s, "triangles")
        return self


def icosphere(radius=0.5, subdivisions=3, center=(0, 0, 0)) -> Geometry:
    """A closed triangulated sphere; see :class:`SphereParams`."""
    t = (1.0 + 5 ** 0.5) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
                  [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
                 dtype=np.float64)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9],
                  [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2],
                  [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10],
                  [8, 6, 7], [9, 8, 1]], dtype=np.int64)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(int(subdivisions)):
        e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(e, axis=0, return_inverse=True)
        mids = v[uniq[:, 0]] + v[uniq[:, 1]]
        mids /= np.linalg.norm(mids, axis=1, keepdims=True)
        m = inv.reshape(3, -1).T + len(v)  # midpoints of edges (01, 12, 20) per face
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        m01, m12, m20 = m[:, 0], m[:, 1], m[:, 2]
        f = np.concatenate([np.stack([a, m01, m20], 1), np.stack([b, m12, m01], 1),
                            np.stack([c, m20, m12], 1), np.stack([m01, m12, m20], 1)])
        v = np.concatenate([v, mids])
    return Geometry(v * radius + np.asarray(center, dtype=np.float64), triangles=f)


# ------------------------------------------------------------------------------------ box

_FACES = ("xmin", "xmax", "ymin", "ymax", "zmin", "zmax")


def _face_groups(pts: np.ndarray, center, size) -> dict:
    """Vertices on each face of an axis-aligned box (exact comparisons on generated points)."""
    lo = np.asarray(center, np.float64) - np.asarray(size, np.float64) / 2
    hi = np.asarray(center, np.float64) + np.asarray(size, np.float64) / 2
    out = {}
    for ax in range(3):
        c = pts[:, ax]
        tol = 1e-12 * max(abs(hi[ax] - lo[ax]), 1e-300)
        out[_FACES[2 * ax]] = np.flatnonzero(np.abs(c - c.min()) <= tol).astype(np.int64)
        out[_FACES[2 * ax + 1]] = np.flatnonzero(np.abs(c - c.max()) <= tol).astype(np.int64)
    return out


class BoxParams(GeneratorParams):
    """A closed axis-aligned box of 8 vertices and 12 triangles (outward normals).

    Vertex order: index 4*ix + 2*iy + iz with ix, iy, iz in {0 (min), 1 (max)}.
    Named sets: ``xmin``, ``xmax``, ``ymin``, ``ymax``, ``zmin``, ``zmax`` (4 vertices each).
    """

    size: tuple[PosFloat, PosFloat, PosFloat] = Field((1.0, 1.0, 1.0), description="Side "
                                                      "lengths along x, y, z [m].")
    center: Vec3 = Field((0.0, 0.0, 0.0), description="Centre [m].")


def box(size=(1.0, 1.0, 1.0), center=(0, 0, 0)) -> Geometry:
    """A closed box; see :class:`BoxParams`."""
    s = np.asarray(size, dtype=np.float64) / 2
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64) * s
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], np.int64)
    pts = v + np.asarray(center, dtype=np.float64)
    return Geometry(pts, triangles=f, groups=_face_groups(v, (0, 0, 0), size))


# ----------------------------------------------------------------------------------- tube

class TubeParams(GeneratorParams):
    """An open cylinder (a sleeve, a skirt) along ``axis``; ``capped`` closes both ends.

    Vertex order: ring j = 0..nl (along the axis, from -length/2 to +length/2), vertex i =
    0..na-1 around it, has index j*na + i, at angle t = 2 pi i / na: (y, z) = r (cos t, sin t)
    for axis x, (x, z) = r (cos t, sin t) for axis y, (y, x) = r (cos t, sin t) for axis z.
    With ``capped`` two more vertices follow: the centre of the start cap, then of the end cap.
    Named sets: ``start`` (ring 0, at centre - length/2 along the axis), ``end`` (ring nl, at
    centre + length/2), ``ends`` (both rings) and, when capped, ``caps`` (the 2 cap centres).
    For a skirt along y, ``end`` is the waist (top) ring and ``start`` the hem.
    """

    radius: PosFloat = Field(0.1, description="Radius [m].")
    length: PosFloat = Field(0.5, description="Length along the axis [m].")
    segments: tuple[Annotated[int, Field(ge=3)], Count] = Field(
        (24, 10), description="Vertices around a ring (na >= 3) and segments along the axis "
        "(nl >= 1) [-]; na*(nl+1) vertices.")
    axis: Literal["x", "y", "z"] = Field("x", description="Axis of the cylinder.")
    center: Vec3 = Field((0.0, 0.0, 0.0), description="Centre [m].")
    capped: bool = Field(False, description="Close both ends with a triangle fan (a collider).")

    @model_validator(mode="after")
    def _size(self):
        na, nl = self.segments
        _check_size(f"tube {_n(na)} x {_n(nl)}", _big(na) * (_big(nl) + 1) + 2,
                    2 * _big(na) * (_big(nl) + 1), "triangles")
        return self


def tube(radius=0.1, length=0.5, segments=(24, 10), axis: str = "x", center=(0, 0, 0),
         capped: bool = False) -> Geometry:
    """An open cylinder; see :class:`TubeParams` for the vertex order and named sets."""
    na, nl = int(segments[0]), int(segments[1])
    th = np.linspace(0, 2 * np.pi, na, endpoint=False)
    s = np.linspace(-0.5, 0.5, nl + 1) * length
    tt, ss = np.meshgrid(th, s)
    ring = np.stack([ss.ravel(), radius * np.cos(tt.ravel()), radius * np.sin(tt.ravel())], 1)
    i, j = np.meshgrid(np.arange(na), np.arange(nl))
    i, j = i.ravel(), j.ravel()
    a = j * na + i
    b = j * na + (i + 1) % na
    c = a + na
    d = b + na
    tris = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int64)
    pts = ring
    start = np.arange(na, dtype=np.int64)
    end = start + nl * na
    groups = {"start": start, "end": end, "ends": np.concatenate([start, end])}
    if capped:
        n0 = len(pts)
        pts = np.vstack([pts, [[s[0], 0, 0], [s[-1], 0, 0]]])
        k = np.arange(na)
        cap0 = np.stack([np.full(na, n0), (k + 1) % na, k], 1)
        cap1 = np.stack([np.full(na, n0 + 1), nl * na + k, nl * na + (k + 1) % na], 1)
        tris = np.concatenate([tris, cap0, cap1]).astype(np.int64)
        groups["caps"] = np.array([n0, n0 + 1], np.int64)
    perm = {"x": [0, 1, 2], "y": [1, 0, 2], "z": [2, 1, 0]}[axis]
    pts = pts[:, perm]
    if axis == "y":  # keep right-handed orientation after the swap
        tris = tris[:, [0, 2, 1]]
    if axis == "z":
        tris = tris[:, [0, 2, 1]]
    return Geometry(pts + np.asarray(center, dtype=np.float64), triangles=tris, groups=groups)


# -------------------------------------------------------------------------------- tet_box

class TetBoxParams(GeneratorParams):
    """A box of tetrahedra (6 per cube cell, Freudenthal split) with its boundary triangles.

    Vertex order: vertex (i, j, k), i = 0..nx along x, j along y, k along z, has index
    (i*(ny+1) + j)*(nz+1) + k (z fastest). Named sets: ``xmin``, ``xmax``, ``ymin``, ``ymax``,
    ``zmin``, ``zmax`` (the vertices of each face) and ``surface`` (every boundary vertex).
    """

    size: tuple[PosFloat, PosFloat, PosFloat] = Field((0.2, 0.2, 0.2), description="Side "
                                                      "lengths along x, y, z [m].")
    resolution: tuple[Count, Count, Count] = Field((2, 2, 2), description="Cells along x, y, "
                                                   "z [-]; 6 tetrahedra per cell.")
    center: Vec3 = Field((0.0, 0.0, 0.0), description="Centre [m].")

    @model_validator(mode="after")
    def _size(self):
        nx, ny, nz = self.resolution
        _check_size(f"tet_box {_n(nx)} x {_n(ny)} x {_n(nz)}",
                    _big(nx + 1) * _big(ny + 1) * _big(nz + 1),
                    6 * _big(nx) * _big(ny) * _big(nz), "tetrahedra")
        return self


def tet_box(size=(0.2, 0.2, 0.2), resolution=(2, 2, 2), center=(0, 0, 0)) -> Geometry:
    """A box of tetrahedra; see :class:`TetBoxParams`."""
    nx, ny, nz = (int(r) for r in resolution)
    xs = [np.linspace(-0.5, 0.5, n + 1) * s for n, s in zip((nx, ny, nz), size)]
    X, Y, Z = np.meshgrid(*xs, indexing="ij")
    local = np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1)
    pts = local + np.asarray(center, np.float64)

    def vid(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    i, j, k = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz),
                                               indexing="ij"))
    c = [vid(i + a, j + b, k + d) for a in (0, 1) for b in (0, 1) for d in (0, 1)]
    # Freudenthal split of a cube (c[0] .. c[7] binary xyz) into 6 tets along the 0-7 diagonal
    paths = [(0, 1, 3, 7), (0, 1, 5, 7), (0, 2, 3, 7), (0, 2, 6, 7), (0, 4, 5, 7), (0, 4, 6, 7)]
    tets = np.concatenate([np.stack([c[p[0]], c[p[1]], c[p[2]], c[p[3]]], 1) for p in paths])
    P = pts[tets]
    vol = np.einsum("ij,ij->i", np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), P[:, 3] - P[:, 0])
    tets[vol < 0] = tets[vol < 0][:, [0, 2, 1, 3]]
    tris = boundary_triangles(tets)
    groups = _face_groups(local, (0, 0, 0), size)
    groups["surface"] = np.unique(tris).astype(np.int64)
    return Geometry(pts, triangles=tris, tetrahedra=tets.astype(np.int64), groups=groups)


# --------------------------------------------------------------------------------- points

class PointsParams(GeneratorParams):
    """Free points (particles). Vertex order: as listed. Named sets: none."""

    positions: list[Vec3] = Field([(0.0, 0.0, 0.0)], min_length=1,
                                  max_length=MAX_GENERATED_VERTICES,
                                  description="Point positions [m], in vertex order.")


def points(positions=((0.0, 0.0, 0.0),)) -> Geometry:
    """Free points (particles) at the given positions [m]."""
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    return Geometry(p)


GENERATORS = {"points": points, "grid": grid, "strands": strands, "sphere": icosphere, "box": box,
              "tube": tube,
              "tet_box": tet_box}

GENERATOR_MODELS: dict[str, type[BaseModel]] = {
    "points": PointsParams, "grid": GridParams, "strands": StrandsParams, "sphere": SphereParams,
    "box": BoxParams, "tube": TubeParams, "tet_box": TetBoxParams}
"""Generator name -> strict parameter model (for validation and the JSON schema)."""


def generator_schemas() -> dict[str, dict]:
    """Generator name -> JSON schema of its ``params`` (descriptions carry units, vertex order
    and named sets)."""
    return {name: model.model_json_schema() for name, model in GENERATOR_MODELS.items()}


# imported here, after GENERATORS exists: lokigraph.geometry re-exports the generators, so either
# module may be imported first
from .geometry import Geometry, MeshReadError, boundary_triangles  # noqa: E402


class GeneratorParamsError(MeshReadError):
    """Invalid generator parameters. ``errors`` holds (path inside ``params``, message) pairs
    so that a scene loader can place each at its own line."""

    def __init__(self, generator: str, errors: list[tuple[tuple, str]]):
        self.generator = generator
        self.errors = errors
        parts = [(".".join(str(p) for p in loc) + ": " if loc else "") + msg
                 for loc, msg in errors]
        super().__init__(f"generator {generator!r}: " + "; ".join(parts))


def validate_params(name: str, params) -> BaseModel:
    """Validate ``params`` of generator ``name``; raise :class:`GeneratorParamsError`."""
    from .component import pydantic_messages

    model = GENERATOR_MODELS.get(name)
    if model is None:
        raise GeneratorParamsError(name, [((), f"unknown generator; known: "
                                           f"{', '.join(sorted(GENERATOR_MODELS))}")])
    if params is None:
        params = {}
    if not isinstance(params, dict):
        raise GeneratorParamsError(name, [((), "params must be a mapping")])
    try:
        return model.model_validate(params)
    except ValidationError as exc:
        raise GeneratorParamsError(name, pydantic_messages(exc, model.model_fields)) from None


def make_geometry(name: str, params) -> Geometry:
    """Validate ``params`` (sizes checked before any allocation) and build generator ``name``.

    Raises :class:`GeneratorParamsError` (a :class:`MeshReadError`) with a clear message.
    """
    p = validate_params(name, params)
    try:
        return GENERATORS[name](**p.model_dump())
    except (ValueError, FloatingPointError, ZeroDivisionError) as exc:  # pragma: no cover
        raise GeneratorParamsError(name, [((), f"cannot build: {exc}")]) from None
