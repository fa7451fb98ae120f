"""Tests of the build-time topology helpers (lokigraph.behaviors.topology)."""
import numpy as np
import pytest

from lokigraph.behaviors import topology as T


def _tri_set(tris):
    """Triangles as a set of cyclically normalised tuples (orientation kept)."""
    out = set()
    for t in tris:
        t = list(int(v) for v in t)
        k = t.index(min(t))
        out.add(tuple(t[k:] + t[:k]))
    return out


@pytest.mark.parametrize("n,m", [(1, 1), (3, 5), (8, 8)])
def test_grid_counts(n, m):
    x, tris = T.grid_mesh(n, m)
    topo = T.triangle_topology(tris)
    V, E, F = x.shape[0], topo.edges.shape[0], tris.shape[0]
    assert V == (n + 1) * (m + 1)
    assert F == 2 * n * m
    assert E == 3 * n * m + n + m
    assert V - E + F == 1  # a disc
    nb = 2 * (n + m)
    assert np.sum(topo.edge_triangle_count == 1) == nb
    assert np.sum(topo.edge_triangle_count == 2) == E - nb
    assert T.boundary_edges(tris).shape == (nb, 2)
    assert T.bend_quads(tris).shape == (E - nb, 4)
    assert T.triangle_corner_triplets(tris).shape == (3 * F, 3)
    assert T.triangle_corner_triplets(tris, corners=(0, 1)).shape == (2 * F, 3)
    # every normal points +y
    nrm = np.cross(x[tris[:, 1]] - x[tris[:, 0]], x[tris[:, 2]] - x[tris[:, 0]])
    assert np.all(nrm[:, 1] > 0)


def test_edges_sorted_unique_and_adjacency_consistent():
    x, tris = T.icosphere(1)
    topo = T.triangle_topology(tris)
    e = topo.edges
    assert np.all(e[:, 0] < e[:, 1])
    assert np.all(np.diff(e[:, 0] * (e.max() + 1) + e[:, 1]) > 0)  # sorted and unique
    for k in range(3):  # tri_edges[t, k] is the edge from corner k to corner k+1
        a, b = tris[:, k], tris[:, (k + 1) % 3]
        np.testing.assert_array_equal(e[topo.tri_edges[:, k]],
                                      np.stack([np.minimum(a, b), np.maximum(a, b)], 1))
    for s in range(2):
        t = topo.edge_tris[:, s]
        assert np.all(t >= 0)
        assert np.all(np.any(topo.tri_edges[t] == np.arange(len(e))[:, None], axis=1))
    assert np.all(topo.edge_tris[:, 0] < topo.edge_tris[:, 1])


@pytest.mark.parametrize("s", [0, 1, 3])
def test_closed_sphere_euler_characteristic(s):
    x, tris = T.icosphere(s)
    topo = T.triangle_topology(tris)
    V, E, F = x.shape[0], topo.edges.shape[0], tris.shape[0]
    assert (V, F) == (10 * 4 ** s + 2, 20 * 4 ** s)
    assert V - E + F == 2
    assert 2 * E == 3 * F
    assert np.all(topo.edge_triangle_count == 2)
    assert T.boundary_edges(tris).shape == (0, 2)
    assert T.bend_quads(tris).shape == (E, 4)
    vol = np.einsum("ij,ij->i", x[tris[:, 0]], np.cross(x[tris[:, 1]], x[tris[:, 2]])).sum() / 6
    assert vol > 0  # outward winding


def test_bend_quads_geometry_and_winding():
    x, tris = T.grid_mesh(4, 3)
    quads, eidx = T.bend_quads(tris, return_edge=True)
    topo = T.triangle_topology(tris)
    tset = _tri_set(tris)
    for (i, j, k, l), e in zip(quads, eidx):
        assert sorted((i, j)) == list(topo.edges[e])
        assert len({i, j, k, l}) == 4
        assert _tri_set([(i, j, k)]) <= tset  # edge runs i -> j in the first triangle
        assert _tri_set([(j, i, l)]) <= tset  # and j -> i in the second (consistent mesh)


def test_non_manifold_edge_gets_no_quad():
    tris = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    topo = T.triangle_topology(tris)
    assert topo.edge_triangle_count.max() == 3
    assert T.bend_quads(tris).shape == (0, 4)


def test_oriented_boundary_forms_a_loop():
    x, tris = T.grid_mesh(3, 2)
    b = T.boundary_edges(tris, oriented=True)
    assert b.shape == (10, 2)
    nxt = dict(zip(b[:, 0].tolist(), b[:, 1].tolist()))
    assert len(nxt) == 10  # every boundary vertex starts exactly one edge
    v, steps = b[0, 0], 0
    while True:
        v = nxt[v]
        steps += 1
        if v == b[0, 0]:
            break
    assert steps == 10


def test_strands_curves_triplets_skip_pairs_and_torsion_quads():
    ptr = np.array([0, 5, 8, 8, 9, 13])  # strands of 5, 3, 0, 1 and 4 vertices
    e = T.strand_edges(ptr)
    assert e.shape == (4 + 2 + 0 + 0 + 3, 2)
    assert np.all(e[:, 1] == e[:, 0] + 1)
    trip = T.curve_bend_triplets(e)
    assert trip.shape == (3 + 1 + 2, 3)
    assert np.all(trip[:, 0] == trip[:, 1] - 1) and np.all(trip[:, 2] == trip[:, 1] + 1)
    apex = T.curve_bend_triplets(e, apex_first=True)
    np.testing.assert_array_equal(apex, trip[:, [1, 0, 2]])
    assert apex.flags.c_contiguous
    pairs = T.curve_skip_pairs(e)
    np.testing.assert_array_equal(pairs, trip[:, [0, 2]])
    quads = T.curve_torsion_quads(e)
    assert quads.shape == (2 + 0 + 1, 4)
    for b, c, a, d in quads:  # a - b - c - d consecutive
        assert (c, a, d) == (b + 1, b - 1, b + 2)
    # a Y junction: the centre of degree 3 gives 3 pairs
    y = np.array([[0, 1], [0, 2], [0, 3]])
    assert T.curve_bend_triplets(y).shape == (3, 3)
    with pytest.raises(ValueError, match="joins a vertex to itself"):
        T.curve_bend_triplets(np.array([[1, 1]]))


def test_tet_mesh_counts_and_boundary():
    nx, ny, nz = 2, 3, 1
    x, tets = T.tet_box(nx, ny, nz, size=0.5)
    topo = T.tet_topology(tets)
    V, E, F, Tn = x.shape[0], topo.edges.shape[0], topo.faces.shape[0], tets.shape[0]
    assert Tn == 6 * nx * ny * nz
    assert V - E + F - Tn == 1  # a ball
    nb = 4 * (nx * ny + ny * nz + nz * nx)
    assert topo.boundary_faces.shape == (nb, 3)
    assert np.sum(topo.face_tets[:, 1] == -1) == nb
    np.testing.assert_array_equal(topo.edges, T.tet_edges(tets))
    # positive tets fill the box; boundary faces point outward and enclose the same volume
    d = [x[tets[:, k]] - x[tets[:, 0]] for k in (1, 2, 3)]
    vol = np.einsum("ij,ij->i", d[0], np.cross(d[1], d[2])) / 6
    assert np.all(vol > 0)
    box = nx * ny * nz * 0.125
    assert vol.sum() == pytest.approx(box)
    f = topo.boundary_faces
    encl = np.einsum("ij,ij->i", x[f[:, 0]], np.cross(x[f[:, 1]], x[f[:, 2]])).sum() / 6
    assert encl == pytest.approx(box)
    # a single tet: 6 edges, 4 faces, all on the boundary
    one = T.tet_topology(np.array([[0, 1, 2, 3]]))
    assert one.edges.shape == (6, 2) and one.faces.shape == (4, 3)
    assert one.boundary_faces.shape == (4, 3)


def test_orient_tets_fixes_negative_tets():
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    fixed = T.orient_tets(x, np.array([[0, 1, 3, 2], [0, 1, 2, 3]]))
    np.testing.assert_array_equal(fixed, [[0, 1, 2, 3], [0, 1, 2, 3]])


def _check_coloring(elems, w=None):
    perm, ptr = T.color_constraints(elems, w)
    assert np.array_equal(np.sort(perm), np.arange(len(elems)))
    assert ptr[0] == 0 and ptr[-1] == len(elems) and np.all(np.diff(ptr) > 0)
    colored = elems[perm]
    assert T.coloring_conflicts(colored, ptr, w) == 0
    return colored, ptr


def test_coloring_is_valid_on_64x64_grid():
    x, tris = T.grid_mesh(64, 64)
    edges = T.triangle_edges(tris)
    trip = T.triangle_corner_triplets(tris)
    quads = T.bend_quads(tris)
    counts = {}
    for name, elems in (("edges", edges), ("trip", trip), ("quads", quads)):
        colored, ptr = _check_coloring(elems)
        counts[name] = len(ptr) - 1
        # the check itself can fail: merging two colours creates conflicts
        merged = np.delete(ptr, 1)
        assert T.coloring_conflicts(colored, merged) > 0
    assert counts["edges"] <= 12 and counts["quads"] <= 24
    # pinned vertices (w == 0) do not conflict: never more colours, still valid w.r.t. w > 0
    w = np.ones(x.shape[0])
    w[:65] = 0.0  # the first row pinned
    colored, ptr = _check_coloring(edges, w)
    assert len(ptr) - 1 <= counts["edges"]
    assert T.coloring_conflicts(colored, ptr) > 0  # it does reuse pinned vertices


def test_coloring_keeps_input_order_inside_a_colour_and_errors():
    elems = np.array([[0, 1], [1, 2], [2, 3], [4, 5]])
    perm, ptr = T.color_constraints(elems)  # first fit: colours 0, 1, 0, 0
    np.testing.assert_array_equal(perm, [0, 2, 3, 1])
    np.testing.assert_array_equal(ptr, [0, 3, 4])
    perm, ptr = T.color_constraints(np.zeros((0, 2), dtype=np.int64), vertex_count=3)
    assert perm.shape == (0,) and list(ptr) == [0]
    with pytest.raises(ValueError, match="out of range"):
        T.color_constraints(elems, w=np.ones(3))
    with pytest.raises(ValueError, match=r"expected shape \(m, 3\)"):
        T.triangle_topology(np.zeros((4, 2), dtype=np.int64))


def test_builders_are_deterministic():
    x, tris = T.grid_mesh(10, 7)
    rng = np.random.default_rng(0)
    shuffled = tris[rng.permutation(len(tris))]
    a = T.triangle_topology(tris).edges
    b = T.triangle_topology(shuffled).edges
    np.testing.assert_array_equal(a, b)  # edges depend only on the set of triangles
    p1 = T.color_constraints(a)
    p2 = T.color_constraints(a)
    np.testing.assert_array_equal(p1[0], p2[0])


def test_empty_inputs_give_empty_outputs():
    t0 = np.zeros((0, 3), dtype=np.int64)
    assert T.triangle_topology(t0).edges.shape == (0, 2)
    assert T.bend_quads(t0).shape == (0, 4)
    assert T.boundary_edges(t0, oriented=True).shape == (0, 2)
    assert T.triangle_corner_triplets(t0).shape == (0, 3)
    assert T.strand_edges([0]).shape == (0, 2)
    assert T.curve_bend_triplets(np.zeros((0, 2), dtype=np.int64)).shape == (0, 3)
    assert T.curve_torsion_quads(np.zeros((0, 2), dtype=np.int64)).shape == (0, 4)
    topo = T.tet_topology(np.zeros((0, 4), dtype=np.int64))
    assert topo.faces.shape == (0, 3) and topo.boundary_faces.shape == (0, 3)
    perm, ptr = T.color_constraints(np.zeros((0, 4), dtype=np.int64), w=np.ones(3))
    assert perm.shape == (0,) and list(ptr) == [0]
