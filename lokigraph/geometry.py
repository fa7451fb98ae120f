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
    channels: name -> per-vertex array (n,) or (n, k) (rest positions, painted maps).
    """

    points: np.ndarray
    edges: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    tetrahedra: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int64))
    channels: dict[str, np.ndarray] = field(default_factory=dict)

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
                        self.tetrahedra.copy(), {k: v.copy() for k, v in self.channels.items()})

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
    pass


def read_mesh(path: str | Path) -> Geometry:
    """Read a mesh file with meshio. OBJ polylines (``l``) become edges; quads are split."""
    import meshio

    path = Path(path)
    if not path.exists():
        raise MeshReadError(f"mesh file not found: {path}")
    try:
        if path.suffix.lower() == ".obj":
            return _read_obj(path)
        mesh = meshio.read(path)
    except MeshReadError:
        raise
    except Exception as exc:  # noqa: BLE001 - meshio raises many types; report them all
        raise MeshReadError(f"cannot read mesh {path}: {exc}") from exc
    pts = np.asarray(mesh.points, dtype=np.float64)
    if pts.shape[1] == 2:
        pts = np.hstack([pts, np.zeros((len(pts), 1))])
    geo = _from_cells(pts, [(c.type, np.asarray(c.data)) for c in mesh.cells])
    for name, data in mesh.point_data.items():
        arr = np.asarray(data, dtype=np.float64)
        if arr.shape[0] == len(pts):
            geo.channels[name] = arr
    return geo


def _from_cells(pts, cells) -> Geometry:
    edges, tris, tets = [], [], []
    for ctype, data in cells:
        data = data.astype(np.int64)
        if ctype == "line":
            edges.append(data)
        elif ctype == "triangle":
            tris.append(data)
        elif ctype == "quad":
            tris.append(data[:, [0, 1, 2]])
            tris.append(data[:, [0, 2, 3]])
        elif ctype == "tetra":
            tets.append(data)
        elif ctype == "vertex":
            pass
        elif ctype.startswith("polygon"):
            k = data.shape[1]
            for j in range(1, k - 1):  # fan (loop over polygon corners, not over faces)
                tris.append(data[:, [0, j, j + 1]])
    cat = lambda lst, w: np.concatenate(lst) if lst else np.zeros((0, w), np.int64)  # noqa: E731
    return Geometry(pts, cat(edges, 2), cat(tris, 3), cat(tets, 4))


def _read_obj(path: Path) -> Geometry:
    """Small OBJ reader: ``v``, ``f`` (any polygon, ``a/b/c`` forms, negative indices), ``l``.

    meshio's OBJ reader rejects files whose ``vt`` count differs from ``v`` and ignores
    polylines; this one reads positions and topology only.
    """
    verts: list[list[float]] = []
    faces: list[list[int]] = []
    lines: list[list[int]] = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, raw in enumerate(fh, 1):
            parts = raw.split()
            if not parts:
                continue
            tag = parts[0]
            try:
                if tag == "v":
                    verts.append([float(parts[1]), float(parts[2]), float(parts[3])])
                elif tag == "f":
                    idx = [int(p.split("/")[0]) for p in parts[1:]]
                    idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                    faces.append(idx)
                elif tag == "l":
                    idx = [int(p.split("/")[0]) for p in parts[1:]]
                    idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                    lines.append(idx)
            except (ValueError, IndexError):
                raise MeshReadError(f"{path}:{lineno}: cannot parse OBJ line: {raw.strip()!r}") \
                    from None
    pts = np.asarray(verts, dtype=np.float64).reshape(-1, 3)
    tris = []
    for f in faces:
        for j in range(1, len(f) - 1):
            tris.append((f[0], f[j], f[j + 1]))
    edges = []
    for ln in lines:
        edges.extend(zip(ln[:-1], ln[1:]))
    return Geometry(pts,
                    np.asarray(edges, dtype=np.int64).reshape(-1, 2),
                    np.asarray(tris, dtype=np.int64).reshape(-1, 3))


def write_mesh(path: Path, points: np.ndarray, geo: Geometry, fmt: str) -> None:
    """Write one frame. OBJ is written directly (fast, keeps polylines); others via meshio."""
    if fmt == "obj":
        with open(path, "w", encoding="utf-8") as fh:
            np.savetxt(fh, points, fmt="v %.9g %.9g %.9g")
            if len(geo.triangles):
                np.savetxt(fh, geo.triangles + 1, fmt="f %d %d %d")
            if len(geo.edges) and not len(geo.triangles):
                np.savetxt(fh, geo.edges + 1, fmt="l %d %d")
        return
    import meshio

    cells = []
    if len(geo.tetrahedra):
        cells.append(("tetra", geo.tetrahedra))
    if len(geo.triangles):
        cells.append(("triangle", geo.triangles))
    if len(geo.edges):
        cells.append(("line", geo.edges))
    if not cells:
        cells.append(("vertex", np.arange(len(points)).reshape(-1, 1)))
    meshio.write(path, meshio.Mesh(points, cells), file_format={"ply": "ply", "vtu": "vtu"}[fmt],
                 **({"binary": True} if fmt == "ply" else {}))


# ----------------------------------------------------------------------------- generators

def grid(size=(1.0, 1.0), resolution=(16, 16), plane: str = "xz", center=(0, 0, 0),
         diagonal: str = "alternate") -> Geometry:
    """A rectangular cloth of (rx+1) x (ry+1) vertices, triangulated.

    Channels: ``u`` and ``v`` in [0, 1] along the two grid axes (handy for paint rules).
    Vertex (i, j) has index j * (rx + 1) + i. Corners: 0, rx, ry*(rx+1), (ry+1)*(rx+1)-1.
    """
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
    return Geometry(pts, triangles=tris, channels={"u": uu.ravel().copy(), "v": vv.ravel().copy()})


def strands(count=(1, 1), spacing=0.01, length=0.2, segments=10, direction=(0, -1, 0),
            center=(0, 0, 0)) -> Geometry:
    """Straight hair strands rooted on a grid; channel ``s`` is arclength/length (root = 0)."""
    cx, cy = int(count[0]), int(count[1])
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
    return Geometry(pts, edges=edges, channels={"s": np.tile(s, nstr),
                                                "root": np.tile((s == 0).astype(float), nstr)})


def icosphere(radius=0.5, subdivisions=3, center=(0, 0, 0)) -> Geometry:
    """A closed triangulated sphere (outward normals by right-hand rule)."""
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


def box(size=(1.0, 1.0, 1.0), center=(0, 0, 0)) -> Geometry:
    """A closed box of 12 triangles, outward normals."""
    s = np.asarray(size, dtype=np.float64) / 2
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64) * s
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], np.int64)
    return Geometry(v + np.asarray(center, dtype=np.float64), triangles=f)


def tube(radius=0.1, length=0.5, segments=(24, 10), axis: str = "x", center=(0, 0, 0),
         capped: bool = False) -> Geometry:
    """An open cylinder (sleeve) along ``axis``; ``capped`` closes it (a capsule-like collider)."""
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
    if capped:
        n0 = len(pts)
        pts = np.vstack([pts, [[s[0], 0, 0], [s[-1], 0, 0]]])
        k = np.arange(na)
        cap0 = np.stack([np.full(na, n0), (k + 1) % na, k], 1)
        cap1 = np.stack([np.full(na, n0 + 1), nl * na + k, nl * na + (k + 1) % na], 1)
        tris = np.concatenate([tris, cap0, cap1]).astype(np.int64)
    perm = {"x": [0, 1, 2], "y": [1, 0, 2], "z": [2, 1, 0]}[axis]
    pts = pts[:, perm]
    if axis == "y":  # keep right-handed orientation after the swap
        tris = tris[:, [0, 2, 1]]
    if axis == "z":
        tris = tris[:, [0, 2, 1]]
    return Geometry(pts + np.asarray(center, dtype=np.float64), triangles=tris)


def tet_box(size=(0.2, 0.2, 0.2), resolution=(2, 2, 2), center=(0, 0, 0)) -> Geometry:
    """A box of tetrahedra (6 per cube cell) with its boundary triangles."""
    nx, ny, nz = (int(r) for r in resolution)
    xs = [np.linspace(-0.5, 0.5, n + 1) * s for n, s in zip((nx, ny, nz), size)]
    X, Y, Z = np.meshgrid(*xs, indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1) + np.asarray(center, np.float64)

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
    return Geometry(pts, triangles=tris, tetrahedra=tets.astype(np.int64))


def boundary_triangles(tets: np.ndarray) -> np.ndarray:
    """Faces of positively oriented tets used by exactly one tet, oriented outward."""
    f = np.concatenate([tets[:, [0, 2, 1]], tets[:, [0, 1, 3]], tets[:, [0, 3, 2]],
                        tets[:, [1, 2, 3]]])
    key = np.sort(f, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return f[counts[inv.ravel()] == 1].astype(np.int64)


def points(positions=((0.0, 0.0, 0.0),)) -> Geometry:
    """Free points (particles) at the given positions [m]."""
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    return Geometry(p)


GENERATORS = {"points": points, "grid": grid, "strands": strands, "sphere": icosphere, "box": box, "tube": tube,
              "tet_box": tet_box}


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
