"""Mesh files: reading (OBJ directly, everything else through meshio) and writing frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .geometry import Geometry, MeshReadError


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
