"""Geometry of scene elements: simplicial complexes with named per-vertex channels.

Topology is integers only (points, edges, triangles, tetrahedra may be mixed). Geometry comes
from a mesh file read with meshio (OBJ, PLY, VTK/VTU, Gmsh ...; OBJ ``l`` lines become curve
edges) or from a built-in generator. Units are converted to metres and an optional transform
(scale, then rotate XYZ in degrees, then translate) is applied at load time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "km": 1000.0, "in": 0.0254, "ft": 0.3048}


@dataclass
class Geometry:
    """A simplicial complex.

    points: vertex positions [m], shape (vertex_count, 3).
    edges: (E, 2) int64, curve edges (hair) or explicit 1-simplices.
    triangles: (T, 3) int64.
    tetrahedra: (K, 4) int64.
    channels: name -> per-vertex array (n,) or (n, k) (rest positions, painted maps, mesh
        attributes and colours read from files).
    groups: name -> sorted unique int64 vertex indices: named vertex sets (OBJ groups, sets that
        generators document such as grid sides and strand roots), selectable by name.
    """

    points: np.ndarray
    edges: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    tetrahedra: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))
    channels: dict[str, np.ndarray] = field(default_factory=dict)
    groups: dict[str, np.ndarray] = field(default_factory=dict)

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

    def copy(self) -> "Geometry":
        return Geometry(self.points.copy(), self.edges.copy(), self.triangles.copy(),
                        self.tetrahedra.copy(), {k: v.copy() for k, v in self.channels.items()},
                        {k: v.copy() for k, v in self.groups.items()})

    def problems(self) -> list[str]:
        """Sanity checks (non-finite points, out-of-range indices, degenerate simplices)."""
        out = []
        n = self.vertex_count
        bad = ~np.all(np.isfinite(self.points), axis=1)
        if bad.any():
            out.append(f"{int(bad.sum())} vertices with non-finite coordinates "
                       f"(first at vertex {int(np.argmax(bad))})")
        for name, arr in (("edge", self.edges), ("triangle", self.triangles),
                          ("tetrahedron", self.tetrahedra)):
            if arr.size == 0:
                continue
            oor = np.any((arr < 0) | (arr >= n), axis=1)
            if oor.any():
                i = int(np.argmax(oor))
                out.append(f"{int(oor.sum())} {name}s with vertex indices out of range "
                           f"[0, {n}) (first at {name} {i}: {arr[i].tolist()})")
                continue
            srt = np.sort(arr, axis=1)
            rep = np.any(srt[:, 1:] == srt[:, :-1], axis=1)
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
    P = points[tris]
    return 0.5 * np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1)


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


# Mesh files and generators live in their own modules; re-exported here for existing imports.
from .meshfile import read_mesh, write_mesh  # noqa: E402,F401
from .generators import (GENERATORS, box, grid, icosphere, points, strands, tet_box,  # noqa: E402,F401
                         tube)
