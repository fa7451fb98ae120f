"""Geometry of scene elements: simplicial complexes with named per-vertex channels.

Topology is integers only (points, edges, triangles, tetrahedra may be mixed). Geometry comes
from a mesh file read with meshio (OBJ, PLY, VTK/VTU, Gmsh ...; OBJ ``l`` lines become curve
edges) or from a built-in generator. Units are converted to metres and an optional transform
(scale, then rotate XYZ in degrees, then translate) is applied at load time.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "km": 1000.0, "in": 0.0254, "ft": 0.3048}


@dataclass
class Geometry:
    """A simplicial complex.

    points: vertex positions [m], shape (n, 3).
    edges: (E, 2) int64, curve edges (hair) or explicit 1-simplices.
    triangles: (T, 3) int64.
    tetrahedra: (K, 4) int64.
    channels: name -> per-vertex array (n,) or (n, k) (rest positions, painted maps, mesh
        attributes read from files). Colours read from files are ``color``, shape (n, 3), as
        written in the file (OBJ ``v x y z r g b``, usually in [0, 1]) or scaled to [0, 1]
        (PLY ``red green blue`` stored as integers).
    groups: name -> sorted unique int64 vertex indices: named vertex sets (OBJ ``g``/``o``
        groups: the vertices of that group's faces and lines; sets that generators document
        such as grid sides and strand roots), selectable by name.
    uv: texture coordinates [1], shape (U, 2), and tri_uv: for every triangle corner, its row
        in ``uv``, shape (T, 3) int64. Texture coordinates are *face-varying*: one vertex on a
        UV seam has several rows. A file with per-vertex coordinates (PLY ``s t``/``u v``)
        gives ``uv`` of shape (n, 2) and ``tri_uv == triangles``. Both are empty (shapes
        (0, 2) and (0, 3)) when the input had none; ``tri_uv`` is either empty or has one row
        per triangle.
    normals: unit normals [1], shape (M, 3), and tri_normals: each triangle corner's row in
        ``normals``, shape (T, 3) int64, with the same face-varying layout as ``uv`` (a hard
        edge has two rows per vertex). They record the input's normal layout; the writers
        recompute the values from the written (deformed) positions.
    """

    points: np.ndarray
    edges: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    tetrahedra: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))
    channels: dict[str, np.ndarray] = field(default_factory=dict)
    groups: dict[str, np.ndarray] = field(default_factory=dict)
    uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    tri_uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    tri_normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))

    @property
    def vertex_count(self) -> int:
        return int(self.points.shape[0])

    @property
    def dimension(self) -> int:
        if len(self.tetrahedra):
            return 3
        if len(self.triangles):
            return 2
        if len(self.edges):
            return 1
        return 0

    @property
    def has_uv(self) -> bool:
        """True when every triangle corner has a texture coordinate."""
        return len(self.triangles) > 0 and self.tri_uv.shape == self.triangles.shape

    @property
    def has_normals(self) -> bool:
        """True when every triangle corner has a normal row (the input carried normals)."""
        return len(self.triangles) > 0 and self.tri_normals.shape == self.triangles.shape

    def vertex_uv(self) -> np.ndarray | None:
        """Per-vertex texture coordinates, shape (n, 2), or None when there are none or when a
        vertex has different coordinates in different triangles (a UV seam). Vertices in no
        triangle get 0."""
        if not self.has_uv:
            return None
        out = np.zeros((self.vertex_count, 2))
        out[self.triangles.ravel()] = self.uv[self.tri_uv.ravel()]
        if not np.array_equal(out[self.triangles], self.uv[self.tri_uv], equal_nan=True):
            return None
        return out

    def copy(self) -> "Geometry":
        return Geometry(self.points.copy(), self.edges.copy(), self.triangles.copy(),
                        self.tetrahedra.copy(), {k: v.copy() for k, v in self.channels.items()},
                        {k: v.copy() for k, v in self.groups.items()}, self.uv.copy(),
                        self.tri_uv.copy(), self.normals.copy(), self.tri_normals.copy())

    def problems(self) -> list[str]:
        """Sanity checks (non-finite points, out-of-range indices, degenerate simplices)."""
        out = []
        n = self.vertex_count
        if not np.isfinite(self.points.sum()):  # fast path: one pass when all are finite
            bad = ~np.all(np.isfinite(self.points), axis=1)
            if bad.any():
                out.append(f"{int(bad.sum())} vertices with non-finite coordinates "
                           f"(first at vertex {int(np.argmax(bad))})")
        for name, arr in (("edge", self.edges), ("triangle", self.triangles),
                          ("tetrahedron", self.tetrahedra)):
            if arr.size == 0:
                continue
            if arr.min() < 0 or arr.max() >= n:
                oor = np.any((arr < 0) | (arr >= n), axis=1)
                i = int(np.argmax(oor))
                out.append(f"{int(oor.sum())} {name}s with vertex indices out of range "
                           f"[0, {n}) (first at {name} {i}: {arr[i].tolist()})")
                continue
            k = arr.shape[1]
            rep = np.zeros(len(arr), bool)
            for a in range(k):  # loop over the k(k-1)/2 column pairs, vectorised over rows
                for b in range(a + 1, k):
                    rep |= arr[:, a] == arr[:, b]
            if rep.any():
                i = int(np.argmax(rep))
                out.append(f"{int(rep.sum())} degenerate {name}s with a repeated vertex "
                           f"(first at {name} {i}: {arr[i].tolist()})")
        if len(self.triangles) and not out:
            area = triangle_areas(self.points, self.triangles)
            scale = max(float(np.ptp(self.points, axis=0).max()), 1e-300)
            tiny = area <= 1e-14 * scale * scale
            if tiny.any():
                i = int(np.argmin(area))
                out.append(f"warning: {int(tiny.sum())} degenerate triangles "
                           f"(smallest area {area[i]:.3g} m^2 at triangle {i})")
        for name, arr in self.channels.items():
            if arr.shape[0] != n:
                out.append(f"channel {name!r} has {arr.shape[0]} values, expected {n}")
        for name, table, corners in (("texture coordinate", self.uv, self.tri_uv),
                                     ("normal", self.normals, self.tri_normals)):
            if corners.size == 0:
                continue
            if corners.shape != self.triangles.shape:
                out.append(f"{name} corners: {corners.shape[0]} rows, expected one per triangle "
                           f"({len(self.triangles)})")
            elif corners.min() < 0 or corners.max() >= len(table):
                out.append(f"{name} indices out of range [0, {len(table)})")
        return out


# ----------------------------------------------------------------------------- transforms

def rotation_matrix_xyz(degrees) -> np.ndarray:
    """Rotation about x, then y, then z (degrees): R = Rz @ Ry @ Rx."""
    ax, ay, az = np.radians(np.asarray(degrees, dtype=np.float64))
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def apply_transform(points: np.ndarray, scale=1.0, rotate=(0, 0, 0), translate=(0, 0, 0),
                    units: str = "m") -> np.ndarray:
    """Convert file ``units`` to metres, then scale, rotate (XYZ degrees), translate [m]."""
    with np.errstate(invalid="ignore", over="ignore"):  # non-finite input: problems() says so
        out = points * (UNITS[units] * np.asarray(scale, dtype=np.float64))
        out = out @ rotation_matrix_xyz(rotate).T
    return out + np.asarray(translate, dtype=np.float64)


# ----------------------------------------------------------------------------- mesh files

class MeshReadError(Exception):
    """A mesh file or generator could not give geometry (the message says why)."""


def boundary_triangles(tets: np.ndarray) -> np.ndarray:
    """Faces of positively oriented tets used by exactly one tet, oriented outward."""
    f = np.concatenate([tets[:, [0, 2, 1]], tets[:, [0, 1, 3]], tets[:, [0, 3, 2]],
                        tets[:, [1, 2, 3]]])
    key = np.sort(f, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return f[counts[inv.ravel()] == 1].astype(np.int64)


def triangle_areas(points: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Area of every triangle [m^2], shape (T,)."""
    p0, p1, p2 = points[tris[:, 0]], points[tris[:, 1]], points[tris[:, 2]]
    a = p1 - p0
    b = p2 - p0
    # the cross product by components, in np.cross's order of operations (bitwise equal)
    cx = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    cy = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    cz = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return 0.5 * np.sqrt(cx * cx + cy * cy + cz * cz)


def vertex_measure(geo: Geometry, points: np.ndarray | None = None) -> np.ndarray:
    """Lumped per-vertex measure of the highest-dimensional simplices present.

    Volume/4 per tet vertex [m^3] if there are tets, else area/3 per triangle vertex [m^2], else
    length/2 per edge vertex [m], else zeros. Used for lumped masses and painted densities.
    """
    p = geo.points if points is None else points
    n = len(p)
    out = np.zeros(n)
    if len(geo.tetrahedra):
        t = geo.tetrahedra
        P = p[t]
        vol = np.abs(np.einsum("ij,ij->i", np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]),
                               P[:, 3] - P[:, 0])) / 6.0
        np.add.at(out, t.ravel(), np.repeat(vol / 4.0, 4))
    elif len(geo.triangles):
        t = geo.triangles
        np.add.at(out, t.ravel(), np.repeat(triangle_areas(p, t) / 3.0, 3))
    elif len(geo.edges):
        e = geo.edges
        ln = np.linalg.norm(p[e[:, 1]] - p[e[:, 0]], axis=1)
        np.add.at(out, e.ravel(), np.repeat(ln / 2.0, 2))
    return out
