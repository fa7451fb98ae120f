"""Build-time topology for the Nucleus constraint kernels.

Everything here runs once, when a model is compiled: it turns the integer topology of a
simplicial complex (triangles, curve edges, tetrahedra) into the constraint tuples that the
projection kernels (in the modules of :mod:`lokigraph.behaviors.materials` and
:mod:`lokigraph.behaviors.attachments`) consume, and it colours those tuples so that a coloured
Gauss-Seidel sweep can run in parallel.

Conventions
-----------
- Vertex indices and topology arrays are ``int64``; rows are constraint tuples.
- An edge is stored sorted, ``edges[e, 0] < edges[e, 1]``, and the edge list is sorted
  lexicographically, so every builder is deterministic (the same input gives the same output).
- A bend quad is ``(i, j, k, l)``: ``(i, j)`` is the hinge edge, ``k`` the vertex opposite the
  edge in the first triangle (in which the edge runs ``i -> j`` in winding order), ``l`` the
  vertex opposite in the second triangle.
- A corner triplet is ``(apex, a, b)``: the angle at ``apex`` between the edges ``apex -> a``
  and ``apex -> b``.
- Tetrahedra are expected positively oriented (``(x1-x0) . ((x2-x0) x (x3-x0)) > 0``); use
  :func:`orient_tets` to fix a mesh that is not.

References
----------
J. Stam, "Nucleus: Towards a Unified Dynamics Solver for Computer Graphics", CAD/Graphics 2009,
sections 5-6 (constraint types 1-3 on 1-, 2- and 3-simplices).

Limitations
-----------
- Non-manifold edges (three or more triangles) produce no bend quad; they are counted in
  ``TriangleTopology.edge_triangle_count`` so a caller can report them.
- The colouring is greedy (first fit in input order); it is valid but not minimal.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from lokigraph.behavior import register_bind_cache

__all__ = [
    "TriangleTopology",
    "TetTopology",
    "triangle_topology",
    "triangle_edges",
    "boundary_edges",
    "is_closed",
    "bend_quads",
    "triangle_corner_triplets",
    "strand_edges",
    "curve_bend_triplets",
    "curve_skip_pairs",
    "curve_torsion_quads",
    "tet_topology",
    "tet_edges",
    "orient_tets",
    "color_constraints",
    "coloring_conflicts",
    "grid_mesh",
    "icosphere",
    "tet_box",
]


# ----------------------------------------------------------------------------------------------
# small helpers
# ----------------------------------------------------------------------------------------------
def _as_index_array(a, ncols: int | None, name: str) -> np.ndarray:
    arr = np.ascontiguousarray(np.asarray(a), dtype=np.int64)
    if arr.size == 0 and ncols is not None:
        arr = arr.reshape(0, ncols)
    if ncols is not None and (arr.ndim != 2 or arr.shape[1] != ncols):
        raise ValueError(f"{name}: expected shape (m, {ncols}), got {arr.shape}")
    if arr.size and arr.min() < 0:
        raise ValueError(f"{name}: negative vertex index {int(arr.min())}")
    return arr


def _unique_sorted_rows(keys_2d: np.ndarray):
    """Unique rows of a non-negative int64 array (rows already sorted within), in lexicographic
    order, with the inverse map.

    When the rows fit one int64 key (``base ** k <= 2**62`` with ``base = max + 1``) they are
    packed into it and sorted as scalars, which gives the same result as ``np.unique(axis=0)``
    about 20 times faster (a 10^6-vertex mesh's edges in 0.5 s instead of 9 s).
    """
    if keys_2d.shape[0] == 0:
        return keys_2d.copy(), np.zeros(0, dtype=np.int64)
    k = keys_2d.shape[1]
    base = int(keys_2d.max()) + 1
    if int(keys_2d.min()) >= 0 and base ** k <= 2 ** 62:
        key = keys_2d[:, 0].astype(np.int64)
        for c in range(1, k):
            key = key * base + keys_2d[:, c]
        ukey, inverse = np.unique(key, return_inverse=True)
        uniq = np.empty((ukey.shape[0], k), dtype=np.int64)
        for c in range(k - 1, -1, -1):  # unpack the last column first
            uniq[:, c] = ukey % base
            ukey = ukey // base
        return uniq, inverse.reshape(-1).astype(np.int64)
    uniq, inverse = np.unique(keys_2d, axis=0, return_inverse=True)
    return np.ascontiguousarray(uniq, dtype=np.int64), inverse.reshape(-1).astype(np.int64)


# ----------------------------------------------------------------------------------------------
# triangles
# ----------------------------------------------------------------------------------------------
class TriangleTopology(NamedTuple):
    """Edge structure of a triangle mesh.

    edges: unique edges, sorted (``edges[:, 0] < edges[:, 1]``, lexicographic), shape (E, 2).
    edge_tris: the first two triangles adjacent to each edge (``-1`` where there is none), in
        increasing triangle order, shape (E, 2).
    edge_triangle_count: how many triangles share each edge (1 boundary, 2 interior, >2
        non-manifold), shape (E,).
    tri_edges: for triangle t, local edge k runs from corner k to corner (k+1) % 3; its edge
        index, shape (T, 3).
    """

    edges: np.ndarray
    edge_tris: np.ndarray
    edge_triangle_count: np.ndarray
    tri_edges: np.ndarray


# Results kept for the next call with the same mesh (the stretch, bend and tether binds of one
# element ask for the same topology): callers get copies, so the kept arrays never change.
_TOPOLOGY_CACHE: list = []  # [(private copy of tris, TriangleTopology)], most recent first
_QUAD_CACHE: list = []  # [(TriangleTopology kept in _TOPOLOGY_CACHE, quads, inner edges)]


def triangle_topology(tris) -> TriangleTopology:
    """Unique edges of a triangle mesh with edge-triangle and triangle-edge adjacency.

    tris: vertex indices, shape (T, 3).

    The result for the last large mesh is kept: a call with equal triangles gets a
    copy of the kept result (a copy costs a few per cent of a rebuild).
    """
    tris = _as_index_array(tris, 3, "tris")
    topo = _kept_topology(tris)
    if topo is not None:
        return TriangleTopology(*(a.copy() for a in topo))
    topo = _triangle_topology(tris)
    if tris.shape[0] >= 4096:  # small meshes are cheap to rebuild: keep only large ones
        _TOPOLOGY_CACHE.insert(0, (tris.copy(), TriangleTopology(*(a.copy() for a in topo))))
        del _TOPOLOGY_CACHE[1:]
        del _QUAD_CACHE[1:]
    return topo


def clear_topology_cache() -> None:
    """Drop the kept topology of the last large mesh (about 300 MB for 10^6 vertices); compile
    calls this once every behaviour is bound (registered with register_bind_cache)."""
    _TOPOLOGY_CACHE.clear()
    _QUAD_CACHE.clear()


register_bind_cache(clear_topology_cache)


def _kept_topology(tris: np.ndarray):
    for key, topo in _TOPOLOGY_CACHE:
        if key.shape == tris.shape and np.array_equal(key, tris):
            return topo
    return None


def _triangle_topology(tris: np.ndarray) -> TriangleTopology:
    t = tris.shape[0]
    a = tris[:, [0, 1, 2]].reshape(-1)
    b = tris[:, [1, 2, 0]].reshape(-1)
    half = np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)
    edges, inverse = _unique_sorted_rows(half)
    tri_edges = inverse.reshape(t, 3) if t else np.zeros((0, 3), dtype=np.int64)
    count = np.bincount(inverse, minlength=edges.shape[0]).astype(np.int64)
    edge_tris = np.full((edges.shape[0], 2), -1, dtype=np.int64)
    if t:
        half_tri = np.repeat(np.arange(t, dtype=np.int64), 3)
        # by edge, then by triangle: half_tri is non-decreasing, so a stable sort by edge is
        # the same permutation as np.lexsort((half_tri, inverse)), and several times faster
        order = np.argsort(inverse, kind="stable")
        sorted_edge = inverse[order]
        start = np.concatenate([[0], np.cumsum(count)[:-1]])
        first = order[start]
        edge_tris[:, 0] = half_tri[first]
        has2 = count >= 2
        second = order[start[has2] + 1]
        edge_tris[has2, 1] = half_tri[second]
        assert np.all(sorted_edge[start] == np.arange(edges.shape[0]))
    return TriangleTopology(edges, edge_tris, count, np.ascontiguousarray(tri_edges))


def triangle_edges(tris) -> np.ndarray:
    """Unique sorted edges of a triangle mesh, shape (E, 2)."""
    return triangle_topology(tris).edges


def is_closed(triangles) -> bool:
    """Every undirected edge of the triangle mesh is shared by exactly two triangles."""
    t = np.asarray(triangles, np.int64)
    if len(t) == 0:
        return False
    e = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool((counts == 2).all())


def boundary_edges(tris, oriented: bool = False) -> np.ndarray:
    """Edges used by exactly one triangle, shape (B, 2).

    With ``oriented=False`` they are sorted pairs in edge order; with ``oriented=True`` each
    edge runs in the winding direction of its triangle (so a boundary loop of a consistently
    oriented mesh is traversed head to tail).
    """
    tris = _as_index_array(tris, 3, "tris")
    topo = triangle_topology(tris)
    bnd = np.flatnonzero(topo.edge_triangle_count == 1)
    if not oriented:
        return np.ascontiguousarray(topo.edges[bnd])
    out = np.empty((bnd.size, 2), dtype=np.int64)
    for r, e in enumerate(bnd):  # build time, boundary only
        t = topo.edge_tris[e, 0]
        k = int(np.flatnonzero(topo.tri_edges[t] == e)[0])
        out[r, 0] = tris[t, k]
        out[r, 1] = tris[t, (k + 1) % 3]
    return out


def bend_quads(tris, return_edge: bool = False):
    """Bend (type 3) quads ``(i, j, k, l)`` for every interior manifold edge, shape (Q, 4).

    ``(i, j)`` is the hinge, oriented as it runs in the first adjacent triangle (lower triangle
    index); ``k`` is that triangle's third vertex and ``l`` the third vertex of the other one.
    With this ordering the kernel's signed dihedral angle is 0 for a flat sheet and its sign
    follows the winding of the first triangle. With ``return_edge`` also returns the edge index of
    each quad (into :func:`triangle_topology`'s ``edges``), shape (Q,).
    """
    tris = _as_index_array(tris, 3, "tris")
    kept = _kept_topology(tris)
    for t, quads, inner in _QUAD_CACHE:  # the bend and tether binds ask for the same mesh
        if t is kept:
            return (quads.copy(), inner.copy()) if return_edge else quads.copy()
    topo = triangle_topology(tris)
    kept = _kept_topology(tris)
    inner = np.flatnonzero(topo.edge_triangle_count == 2)
    ta = topo.edge_tris[inner, 0]
    tb = topo.edge_tris[inner, 1]
    # local position of the edge in triangle ta: tri_edges[ta, k] == edge
    ka = np.argmax(topo.tri_edges[ta] == inner[:, None], axis=1)
    kb = np.argmax(topo.tri_edges[tb] == inner[:, None], axis=1)
    i = tris[ta, ka]
    j = tris[ta, (ka + 1) % 3]
    k = tris[ta, (ka + 2) % 3]
    l = tris[tb, (kb + 2) % 3]
    quads = np.ascontiguousarray(np.stack([i, j, k, l], axis=1), dtype=np.int64)
    if kept is not None:
        _QUAD_CACHE.insert(0, (kept, quads.copy(), inner.astype(np.int64)))
        del _QUAD_CACHE[1:]
    if return_edge:
        return quads, inner.astype(np.int64)
    return quads


def triangle_corner_triplets(tris, corners=(0, 1, 2)) -> np.ndarray:
    """Shear (type 2 on 2-simplices) triplets ``(apex, a, b)``: the angle of a triangle corner.

    corners: which local corners of every triangle get a constraint. The three angles of a
        triangle sum to pi, so any two determine the third; the default takes all three (a
        redundant but consistent set, symmetric in the vertices). Pass ``(0, 1)`` for the
        non-redundant choice.
    Returns shape (T * len(corners), 3), grouped by corner then triangle.
    """
    tris = _as_index_array(tris, 3, "tris")
    rows = []
    for c in corners:
        c = int(c)
        if c not in (0, 1, 2):
            raise ValueError(f"corners: local corner must be 0, 1 or 2 (got {c})")
        rows.append(tris[:, [c, (c + 1) % 3, (c + 2) % 3]])
    if not rows:
        return np.zeros((0, 3), dtype=np.int64)
    return np.ascontiguousarray(np.concatenate(rows, axis=0), dtype=np.int64)


# ----------------------------------------------------------------------------------------------
# curves (1-simplices)
# ----------------------------------------------------------------------------------------------
def strand_edges(strand_ptr) -> np.ndarray:
    """Edges of strands stored contiguously: strand s owns vertices
    ``strand_ptr[s] .. strand_ptr[s+1]-1`` joined in order. Shape (E, 2)."""
    ptr = np.asarray(strand_ptr, dtype=np.int64)
    if ptr.ndim != 1 or ptr.size < 1 or np.any(np.diff(ptr) < 0):
        raise ValueError("strand_ptr: expected a non-decreasing 1-d offset array")
    idx = np.arange(ptr[0], ptr[-1], dtype=np.int64)
    last = np.zeros(idx.size, dtype=bool)
    ends = ptr[1:] - 1 - ptr[0]
    last[ends[(ends >= 0) & (np.diff(ptr) > 0)]] = True
    a = idx[~last]
    return np.ascontiguousarray(np.stack([a, a + 1], axis=1))


@njit(cache=True)
def _csr_adjacency(edges, n):
    deg = np.zeros(n + 1, dtype=np.int64)
    for e in range(edges.shape[0]):
        deg[edges[e, 0] + 1] += 1
        deg[edges[e, 1] + 1] += 1
    ptr = np.cumsum(deg)
    fill = ptr[:-1].copy()
    nbr = np.empty(ptr[-1], dtype=np.int64)
    for e in range(edges.shape[0]):
        a = edges[e, 0]
        b = edges[e, 1]
        nbr[fill[a]] = b
        fill[a] += 1
        nbr[fill[b]] = a
        fill[b] += 1
    for v in range(n):  # sort each neighbour list: deterministic output
        nbr[ptr[v]:ptr[v + 1]] = np.sort(nbr[ptr[v]:ptr[v + 1]])
    return ptr, nbr


@njit(cache=True)
def _triplets_from_adjacency(ptr, nbr):
    n = ptr.shape[0] - 1
    count = 0
    for v in range(n):
        d = ptr[v + 1] - ptr[v]
        count += d * (d - 1) // 2
    out = np.empty((count, 3), dtype=np.int64)
    r = 0
    for v in range(n):
        for s in range(ptr[v], ptr[v + 1]):
            for t in range(s + 1, ptr[v + 1]):
                out[r, 0] = nbr[s]
                out[r, 1] = v
                out[r, 2] = nbr[t]
                r += 1
    return out


def _curve_edges(edges, n):
    edges = _as_index_array(edges, 2, "edges")
    if edges.size and np.any(edges[:, 0] == edges[:, 1]):
        raise ValueError("edges: an edge joins a vertex to itself")
    if n is None:
        n = int(edges.max()) + 1 if edges.size else 0
    return edges, int(n)


def curve_bend_triplets(edges, vertex_count: int | None = None,
                        apex_first: bool = False) -> np.ndarray:
    """Consecutive edge pairs of a curve network as triplets ``(a, b, c)``: edges ``(a, b)`` and
    ``(b, c)`` meet at the centre ``b``. Shape (P, 3), C-contiguous.

    For a polyline every interior vertex gives one triplet; a vertex of degree d gives all
    d (d - 1) / 2 pairs. With ``apex_first`` the rows are ``(b, a, c)``, the layout of the angle
    kernel (type-2 curve bend); :func:`curve_skip_pairs` gives the stretch-kernel alternative.
    """
    edges, n = _curve_edges(edges, vertex_count)
    ptr, nbr = _csr_adjacency(edges, n)
    trip = _triplets_from_adjacency(ptr, nbr)
    if apex_first:
        trip = np.ascontiguousarray(trip[:, [1, 0, 2]])
    return trip


def curve_skip_pairs(edges, vertex_count: int | None = None) -> np.ndarray:
    """"Skip-one" pairs ``(a, c)`` (sorted) joining the two ends of every consecutive edge pair,
    shape (P, 2). A distance constraint on these pairs is the twist-free hair bend."""
    trip = curve_bend_triplets(edges, vertex_count)
    pairs = np.stack([np.minimum(trip[:, 0], trip[:, 2]), np.maximum(trip[:, 0], trip[:, 2])], 1)
    return np.ascontiguousarray(pairs, dtype=np.int64)


def curve_torsion_quads(edges, vertex_count: int | None = None) -> np.ndarray:
    """Quads for the type-3 constraint on 1-simplices (Nucleus "twist"), shape (Q, 4).

    For three consecutive edges ``a - b - c - d`` the quad is ``(b, c, a, d)``: the dihedral
    angle across the middle edge ``(b, c)`` between the planes ``(a, b, c)`` and ``(b, c, d)``.
    This is the discrete torsion of the centre line (a geometric quantity), not the material twist
    of a rod, which needs a frame per edge. It is undefined (and skipped by the kernel) where
    three consecutive vertices are collinear.
    """
    edges, n = _curve_edges(edges, vertex_count)
    ptr, nbr = _csr_adjacency(edges, n)
    rows = []
    for e in range(edges.shape[0]):  # build time; curves have few edges per vertex
        b, c = int(edges[e, 0]), int(edges[e, 1])
        for a in nbr[ptr[b]:ptr[b + 1]]:
            if a == c:
                continue
            for d in nbr[ptr[c]:ptr[c + 1]]:
                if d == b or d == a:
                    continue
                rows.append((b, c, int(a), int(d)))
    if not rows:
        return np.zeros((0, 4), dtype=np.int64)
    return np.asarray(rows, dtype=np.int64)


# ----------------------------------------------------------------------------------------------
# tetrahedra (3-simplices)
# ----------------------------------------------------------------------------------------------
_TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)
# outward-facing faces of a positively oriented tet (0,1,2,3); face f is opposite corner f
_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]], dtype=np.int64)


class TetTopology(NamedTuple):
    """Edge and face structure of a tetrahedral mesh.

    edges: unique sorted edges, shape (E, 2).
    faces: unique faces as sorted vertex triples, shape (F, 3).
    face_tets: the (up to two) tets sharing each face, ``-1`` where none, shape (F, 2).
    boundary_faces: faces used by exactly one tet, wound outward for positively oriented tets,
        shape (B, 3).
    tet_faces: face index of the face opposite each corner, shape (T, 4).
    """

    edges: np.ndarray
    faces: np.ndarray
    face_tets: np.ndarray
    boundary_faces: np.ndarray
    tet_faces: np.ndarray


def tet_edges(tets) -> np.ndarray:
    """Unique sorted edges of a tetrahedral mesh (the stretch constraints of a 3-simplex)."""
    tets = _as_index_array(tets, 4, "tets")
    e = tets[:, _TET_EDGES].reshape(-1, 2)
    e = np.stack([e.min(axis=1), e.max(axis=1)], axis=1)
    return _unique_sorted_rows(e)[0]


def tet_topology(tets) -> TetTopology:
    """Edges, faces, face adjacency and outward boundary faces of a tetrahedral mesh."""
    tets = _as_index_array(tets, 4, "tets")
    t = tets.shape[0]
    if t == 0:
        z3 = np.zeros((0, 3), dtype=np.int64)
        return TetTopology(np.zeros((0, 2), dtype=np.int64), z3, np.zeros((0, 2), np.int64),
                           z3.copy(), np.zeros((0, 4), dtype=np.int64))
    oriented = tets[:, _TET_FACES].reshape(-1, 3)  # (4T, 3), outward winding
    keys = np.sort(oriented, axis=1)
    faces, inverse = _unique_sorted_rows(keys)
    count = np.bincount(inverse, minlength=faces.shape[0])
    if np.any(count > 2):
        raise ValueError(f"tets: {int(np.sum(count > 2))} faces shared by more than two tets")
    face_tets = np.full((faces.shape[0], 2), -1, dtype=np.int64)
    owner = np.repeat(np.arange(t, dtype=np.int64), 4)
    order = np.argsort(inverse, kind="stable")  # == lexsort((owner, inverse)): owner ascends
    start = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64)
    face_tets[:, 0] = owner[order[start]]
    two = count == 2
    face_tets[two, 1] = owner[order[start[two] + 1]]
    once = count[inverse] == 1
    boundary = np.ascontiguousarray(oriented[once], dtype=np.int64)
    return TetTopology(tet_edges(tets), faces, face_tets, boundary,
                       np.ascontiguousarray(inverse.reshape(t, 4)))


def orient_tets(x, tets) -> np.ndarray:
    """Copy of ``tets`` with corners 2 and 3 swapped where the signed volume at ``x`` is negative.

    x: positions [m], shape (n, 3); tets: shape (T, 4).
    """
    tets = _as_index_array(tets, 4, "tets").copy()
    x = np.asarray(x, dtype=np.float64)
    d1 = x[tets[:, 1]] - x[tets[:, 0]]
    d2 = x[tets[:, 2]] - x[tets[:, 0]]
    d3 = x[tets[:, 3]] - x[tets[:, 0]]
    vol = np.einsum("ij,ij->i", d1, np.cross(d2, d3))
    neg = vol < 0
    tets[neg, 2], tets[neg, 3] = tets[neg, 3].copy(), tets[neg, 2].copy()
    return tets


# ----------------------------------------------------------------------------------------------
# colouring
# ----------------------------------------------------------------------------------------------
@njit(cache=True)
def _greedy_colors(elems, active, n):
    m = elems.shape[0]
    k = elems.shape[1]
    deg = np.zeros(n, dtype=np.int64)
    for c in range(m):
        for s in range(k):
            v = elems[c, s]
            if active[v]:
                deg[v] += 1
    bound = 1
    for c in range(m):
        b = 1
        for s in range(k):
            v = elems[c, s]
            if active[v]:
                b += deg[v] - 1
        if b > bound:
            bound = b
    nwords = bound // 64 + 1
    used = np.zeros((n, nwords), dtype=np.uint64)
    colors = np.empty(m, dtype=np.int64)
    one = np.uint64(1)
    for c in range(m):
        col = -1
        for wd in range(nwords):
            acc = np.uint64(0)
            for s in range(k):
                v = elems[c, s]
                if active[v]:
                    acc |= used[v, wd]
            if acc != ~np.uint64(0):
                free = ~acc
                bit = 0
                while (free >> np.uint64(bit)) & one == np.uint64(0):
                    bit += 1
                col = wd * 64 + bit
                break
        colors[c] = col
        wd = col // 64
        mask = one << np.uint64(col % 64)
        for s in range(k):
            v = elems[c, s]
            if active[v]:
                used[v, wd] |= mask
    return colors


def color_constraints(elems, w=None, vertex_count: int | None = None):
    """Greedy colouring of constraints so that no two constraints of one colour share a vertex.

    elems: the vertex tuple of every constraint, shape (m, k), int.
    w: optional inverse masses [1/kg], shape (n,). When given, vertices with ``w == 0`` (pinned
        or kinematic, never written by the kernels) do not count as conflicts, which gives fewer,
        larger colours. The colouring is then only valid while those vertices stay at
        ``w == 0``: recolour when a pin is released. When ``w`` is None every vertex counts.
    vertex_count: n when ``w`` is not given (default: max index + 1).

    Returns ``(perm, color_ptr)``: ``perm`` (m,) int64 orders constraints by colour (stable, so
    the input order is kept inside a colour); store every per-constraint array as
    ``arr[perm]``. Colour c then owns rows ``color_ptr[c] .. color_ptr[c+1]-1``;
    ``color_ptr`` has shape (ncolors + 1,) with ``color_ptr[0] = 0`` and ``color_ptr[-1] = m``.
    """
    elems = _as_index_array(elems, None, "elems")
    if elems.ndim != 2:
        raise ValueError(f"elems: expected shape (m, k), got {elems.shape}")
    m = elems.shape[0]
    if w is not None:
        w = np.asarray(w, dtype=np.float64)
        n = w.shape[0]
        active = w > 0.0
    else:
        n = int(vertex_count) if vertex_count is not None else (int(elems.max()) + 1 if m else 0)
        active = np.ones(n, dtype=np.bool_)
    if m and elems.max() >= n:
        raise ValueError(f"elems: vertex index {int(elems.max())} out of range for {n} vertices")
    if m == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(1, dtype=np.int64)
    colors = _greedy_colors(elems, active, n)
    perm = np.argsort(colors, kind="stable").astype(np.int64)
    counts = np.bincount(colors)
    color_ptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return perm, color_ptr


def coloring_conflicts(elems, color_ptr, w=None) -> int:
    """Number of (colour, vertex) conflicts in an already permuted constraint array: how many
    times a vertex (with ``w > 0`` when ``w`` is given) appears more than once inside one
    colour. 0 means the colouring is valid."""
    elems = _as_index_array(elems, None, "elems")
    color_ptr = np.asarray(color_ptr, dtype=np.int64)
    bad = 0
    for c in range(color_ptr.size - 1):  # loop over colours, vectorised inside
        v = elems[color_ptr[c]:color_ptr[c + 1]].reshape(-1)
        if w is not None:
            v = v[np.asarray(w)[v] > 0.0]
        _, cnt = np.unique(v, return_counts=True)
        bad += int(np.sum(cnt - 1))
    return bad


# ----------------------------------------------------------------------------------------------
# example meshes (tests, benchmarks, example scenes)
# ----------------------------------------------------------------------------------------------
def grid_mesh(nu: int, nv: int, size_u: float = 1.0, size_v: float = 1.0):
    """A flat ``nu x nv`` quad grid in the xz plane (y = 0), each quad split into two triangles
    along alternating diagonals. Returns positions [m] shape ((nu+1)(nv+1), 3) and triangles
    shape (2 nu nv, 3) wound so their normals point +y. Vertex ``(i, j)`` is ``i * (nv+1) + j``.
    """
    if nu < 1 or nv < 1:
        raise ValueError(f"grid_mesh: nu and nv must be >= 1 (got {nu}, {nv})")
    u = np.linspace(0.0, size_u, nu + 1)
    v = np.linspace(0.0, size_v, nv + 1)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    x = np.stack([uu.ravel(), np.zeros(uu.size), vv.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    i = i.ravel()
    j = j.ravel()
    v00 = i * (nv + 1) + j
    v10 = v00 + nv + 1
    v01 = v00 + 1
    v11 = v10 + 1
    flip = ((i + j) % 2).astype(bool)
    # normal +y with x = u, z = v: (v01 - v00) x (v10 - v00) = z x x = +y
    t1 = np.where(flip[:, None], np.stack([v00, v01, v11], 1), np.stack([v00, v01, v10], 1))
    t2 = np.where(flip[:, None], np.stack([v00, v11, v10], 1), np.stack([v01, v11, v10], 1))
    tris = np.concatenate([t1, t2], axis=0).astype(np.int64)
    return np.ascontiguousarray(x), np.ascontiguousarray(tris)


def icosphere(subdivisions: int = 2, radius: float = 1.0):
    """A closed, outward-wound triangulated sphere. Returns positions [m] (V, 3) and triangles
    (T, 3) with V = 10 * 4**s + 2 and T = 20 * 4**s."""
    t = (1.0 + 5.0 ** 0.5) / 2.0
    x = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
                  [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
                 dtype=np.float64)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9],
                  [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2],
                  [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10],
                  [8, 6, 7], [9, 8, 1]], dtype=np.int64)
    for _ in range(int(subdivisions)):
        topo = triangle_topology(f)
        mid = 0.5 * (x[topo.edges[:, 0]] + x[topo.edges[:, 1]])
        base = x.shape[0]
        x = np.concatenate([x, mid], axis=0)
        m = topo.tri_edges + base  # midpoint of local edge k (corner k -> k+1)
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        mab, mbc, mca = m[:, 0], m[:, 1], m[:, 2]
        f = np.concatenate([np.stack([a, mab, mca], 1), np.stack([b, mbc, mab], 1),
                            np.stack([c, mca, mbc], 1), np.stack([mab, mbc, mca], 1)], axis=0)
    x = radius * x / np.linalg.norm(x, axis=1, keepdims=True)
    return np.ascontiguousarray(x), np.ascontiguousarray(f, dtype=np.int64)


def tet_box(nx: int, ny: int, nz: int, size: float = 1.0):
    """A box of ``nx x ny x nz`` cubes, each split into 6 positively oriented tets sharing the
    cube diagonal (a conforming mesh). Returns positions [m] ((nx+1)(ny+1)(nz+1), 3) and tets
    (6 nx ny nz, 4)."""
    g = np.stack(np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(nz + 1),
                             indexing="ij"), axis=-1).reshape(-1, 3)
    x = g.astype(np.float64) * size

    def vid(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    i, j, k = i.ravel(), j.ravel(), k.ravel()
    c = [vid(i + (b & 1), j + ((b >> 1) & 1), k + ((b >> 2) & 1)) for b in range(8)]
    # Kuhn triangulation: the 6 monotone paths from corner 0 to corner 7
    paths = [(1, 2, 4), (1, 4, 2), (2, 1, 4), (2, 4, 1), (4, 1, 2), (4, 2, 1)]
    tets = []
    for p in paths:
        s1 = p[0]
        s2 = p[0] | p[1]
        tets.append(np.stack([c[0], c[s1], c[s2], c[7]], axis=1))
    tets = np.concatenate(tets, axis=0).astype(np.int64)
    return np.ascontiguousarray(x), orient_tets(x, tets)
