"""Built-in geometry generators (``geometry: {generator: NAME, params: {...}}``)."""

from __future__ import annotations

import numpy as np

from .geometry import Geometry, boundary_triangles


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


def points(positions=((0.0, 0.0, 0.0),)) -> Geometry:
    """Free points (particles) at the given positions [m]."""
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    return Geometry(p)


GENERATORS = {"points": points, "grid": grid, "strands": strands, "sphere": icosphere, "box": box,
              "tube": tube,
              "tet_box": tet_box}
