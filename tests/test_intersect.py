"""Intersection checker: exact predicates, hand-made configurations, real meshes, and agreement
with an independent floating-point reference (Moller-Trumbore) on generic random data."""

from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from lokigraph.behaviors.collision import intersect as it

MESHES = Path(__file__).resolve().parent / "data" / "meshes"


def read_obj(path):
    V, F = [], []
    for line in Path(path).read_text().splitlines():
        p = line.split()
        if not p:
            continue
        if p[0] == "v":
            V.append([float(x) for x in p[1:4]])
        elif p[0] == "f":
            F.append([int(x.split("/")[0]) - 1 for x in p[1:4]])
    return np.array(V), np.array(F, dtype=np.int64)


# ---------------------------------------------------------------------------------------------
# exact predicates
# ---------------------------------------------------------------------------------------------


def o3_exact(a, b, c, d):
    M = [[Fraction(x) - Fraction(y) for x, y in zip(p, d)] for p in (a, b, c)]
    det = (M[0][0] * (M[1][1] * M[2][2] - M[1][2] * M[2][1])
           - M[0][1] * (M[1][0] * M[2][2] - M[1][2] * M[2][0])
           + M[0][2] * (M[1][0] * M[2][1] - M[1][1] * M[2][0]))
    return (det > 0) - (det < 0)


def o2_exact(a, b, c):
    det = ((Fraction(a[0]) - Fraction(c[0])) * (Fraction(b[1]) - Fraction(c[1]))
           - (Fraction(a[1]) - Fraction(c[1])) * (Fraction(b[0]) - Fraction(c[0])))
    return (det > 0) - (det < 0)


def hard_orient3d_cases(rng, n):
    """Random, nearly coplanar (rounded) and exactly coplanar point sets, plus one-ulp shifts."""
    out = []
    for k in range(n):
        a, b, c = rng.standard_normal((3, 3)) * 10.0 ** rng.integers(-3, 4)
        mode = k % 4
        if mode == 0:
            d = rng.standard_normal(3)
        elif mode == 1:  # on the plane up to rounding
            u, v = rng.random(2)
            d = a + u * (b - a) + v * (c - a)
        elif mode == 2:  # exactly coplanar (dyadic grid), possibly nudged by one ulp
            a, b, c = rng.integers(-8, 8, (3, 3)) * 2.0**-3
            u, v = rng.integers(-4, 4, 2)
            d = a + u * (b - a) + v * (c - a)
            i = rng.integers(3)
            if rng.random() < 0.5 and d[i] != 0.0:  # (nudging 0 would give a subnormal)
                d[i] = np.nextafter(d[i], np.inf if rng.random() < 0.5 else -np.inf)
        else:  # far from the origin, small triangle: cancellation
            off = 1e6 * rng.standard_normal(3)
            a, b, c = off + rng.standard_normal((3, 3)) * 1e-3
            u, v = rng.random(2)
            d = a + u * (b - a) + v * (c - a)
        out.append((a, b, c, d))
    return out


def test_orient3d_matches_rational_arithmetic():
    rng = np.random.default_rng(0)
    zeros = 0
    for a, b, c, d in hard_orient3d_cases(rng, 1200):
        r = o3_exact(a, b, c, d)
        zeros += r == 0
        assert it.orient3d(a, b, c, d) == r
        # the expansion arithmetic alone (no float filter) gives the exact sign too
        e = it._orient3d_exact(a, b, c, d)
        assert (e > 0) - (e < 0) == r
    assert zeros > 50  # exact zeros were exercised


def test_orient2d_matches_rational_arithmetic():
    rng = np.random.default_rng(1)
    for k in range(1500):
        a, b = rng.standard_normal((2, 2)) * 10.0 ** rng.integers(-3, 4)
        c = a + rng.random() * (b - a)
        if k % 2:
            c = np.nextafter(c, c + rng.standard_normal(2))
        if k % 5 == 0:
            a, b, c = rng.integers(-4, 4, (3, 2)) * 0.5
        r = o2_exact(a, b, c)
        assert it.orient2d(a, b, c) == r
        e = it._orient2d_exact(a[0], a[1], b[0], b[1], c[0], c[1])
        assert (e > 0) - (e < 0) == r


# ---------------------------------------------------------------------------------------------
# hand-made configurations
# ---------------------------------------------------------------------------------------------

T0 = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])


def two_tri_mesh(t1, t2):
    return np.concatenate([t1, t2]), np.array([[0, 1, 2], [3, 4, 5]])


@pytest.mark.parametrize("touching", [True, False])
def test_two_crossing_triangles(touching):
    t2 = np.array([[0.2, 0.2, -0.5], [0.3, 0.2, 0.5], [0.2, 0.9, 0.4]])
    V, F = two_tri_mesh(T0, t2)
    r = it.find_intersections(V, F, touching=touching)
    assert r.count == 1 and r.tri_pairs.tolist() == [[0, 1]]
    # lifted above the plane: no intersection
    V2, F2 = two_tri_mesh(T0, t2 + [0, 0, 0.6])
    assert it.find_intersections(V2, F2, touching=touching).count == 0


def test_shared_vertex_only_touch_is_skipped_within_a_mesh():
    # two triangles of one mesh meeting only at vertex 0
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0.3], [0, -1, 0.5]])
    F = np.array([[0, 1, 2], [0, 3, 4]])
    assert it.find_intersections(V, F).count == 0
    # the same geometry as two meshes (duplicated vertex): a touching contact
    n, pairs = it.intersect_meshes([(V[:3], F[:1]), (V[[0, 3, 4]], np.array([[0, 1, 2]]))])
    assert n == 1 and pairs.tolist() == [[0, 0, 1, 0]]
    n_strict, _ = it.intersect_meshes([(V[:3], F[:1]), (V[[0, 3, 4]], np.array([[0, 1, 2]]))],
                                      touching=False)
    assert n_strict == 0


@pytest.mark.parametrize("t2,closed,proper", [
    # coplanar, overlapping
    ([[0.2, 0.2, 0], [1.2, 0.2, 0], [0.2, 1.2, 0]], 1, 0),
    # coplanar, one inside the other
    ([[0.1, 0.1, 0], [0.3, 0.1, 0], [0.1, 0.3, 0]], 1, 0),
    # coplanar, disjoint
    ([[0.6, 0.6, 0], [1.6, 0.6, 0], [0.6, 1.6, 0]], 0, 0),
    # coplanar, sharing part of an edge (collinear overlap)
    ([[0.5, 0, 0], [1.5, 0, 0], [1, -1, 0]], 1, 0),
    # vertex resting on the face interior
    ([[0.25, 0.25, 0], [0.3, 0.2, 1], [0.2, 0.3, 1]], 1, 0),
    # edge lying in the face's plane crossing it (other vertex above)
    ([[-0.5, 0.25, 0], [1.5, 0.25, 0], [0.5, 0.25, 1]], 1, 0),
    # perpendicular planes, an edge overlapping the face along a segment in its plane
    ([[0.5, -0.5, 0], [0.5, 0.5, 0], [0.5, 0, 1]], 1, 0),
    # perpendicular planes meeting in a single point, where two edges cross
    ([[0.5, -0.5, -0.5], [0.5, 0.5, 0.5], [0.5, -1, 1]], 1, 0),
    # a proper crossing through the interior
    ([[0.25, 0.25, -1], [0.3, 0.2, 1], [0.2, 0.3, 1]], 1, 1),
    # zero-area (collinear) triangle piercing the face
    ([[0.25, 0.25, -1], [0.25, 0.25, 1], [0.25, 0.25, 0.5]], 1, 1),
    # near miss: 1e-300 above the plane
    ([[0.25, 0.25, 1e-300], [0.3, 0.2, 1], [0.2, 0.3, 1]], 0, 0),
])
def test_touching_semantics(t2, closed, proper):
    t2 = np.array(t2, dtype=float)
    V, F = two_tri_mesh(T0, t2)
    assert it.find_intersections(V, F, touching=True).count == closed
    assert it.find_intersections(V, F, touching=False).count == proper
    # symmetric in the order of the triangles
    assert it.triangles_intersect(t2, T0, touching=True) == bool(closed)
    assert it.triangles_intersect(t2, T0, touching=False) == bool(proper)


def test_one_ulp_decides():
    """A vertex one ulp above / on / one ulp below a face at height 0.5 (decided exactly)."""
    T = T0 + [0, 0, 0.5]
    up, down = np.nextafter(0.5, 1.0), np.nextafter(0.5, 0.0)
    for z, closed, proper in ((up, 0, 0), (0.5, 1, 0), (down, 1, 1)):
        t2 = np.array([[0.25, 0.25, z], [0.3, 0.2, 1.5], [0.2, 0.3, 1.5]])
        assert it.triangles_intersect(T, t2) == bool(closed)
        assert it.triangles_intersect(T, t2, touching=False) == bool(proper)
    # the same on a tilted plane through exactly representable points, nudged by one ulp
    a, b, c = np.array([0.0, 0, 0]), np.array([1.0, 0, 1]), np.array([0.0, 1, 0.5])
    on = 0.25 * a + 0.25 * b + 0.5 * c  # exactly on the plane (dyadic)
    assert it.orient3d(a, b, c, on) == 0
    above = on.copy()
    above[2] = np.nextafter(on[2], 1.0)
    below = on.copy()
    below[2] = np.nextafter(on[2], 0.0)
    assert it.orient3d(a, b, c, above) == -it.orient3d(a, b, c, below) != 0
    tri = np.stack([a, b, c])
    for p, closed in ((on, True), (above, False)):
        t2 = np.stack([p, p + [0.01, 0, 1], p + [0, 0.01, 1]])
        assert it.triangles_intersect(tri, t2) == closed


def test_segment_triangle():
    a, b, c = T0
    assert it.segment_triangle_intersect([0.2, 0.2, -1], [0.2, 0.2, 1], a, b, c)
    assert not it.segment_triangle_intersect([0.8, 0.8, -1], [0.8, 0.8, 1], a, b, c)
    assert it.segment_triangle_intersect([0.5, 0.5, -1], [0.5, 0.5, 1], a, b, c)  # on the hypotenuse
    assert not it.segment_triangle_intersect([0.5, 0.5, -1], [0.5, 0.5, 1], a, b, c, touching=False)
    assert it.segment_triangle_intersect([0.2, 0.2, 0], [0.2, 0.2, 1], a, b, c)  # endpoint on face
    assert not it.segment_triangle_intersect([0.2, 0.2, 0], [0.2, 0.2, 1], a, b, c, touching=False)


# ---------------------------------------------------------------------------------------------
# independent float reference (Moller-Trumbore) for generic random data
# ---------------------------------------------------------------------------------------------


def seg_tri_float(p, q, a, b, c):
    d = q - p
    e1 = b - a
    e2 = c - a
    h = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, h)
    # (nearly) parallel segment and plane: no hit. The float reference is only meant for generic
    # configurations; exact coplanar cases are covered by the hand-made tests.
    scale = np.linalg.norm(d, axis=1) * np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
    ok = np.abs(det) > 1e-9 * scale
    f = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = p - a
    u = f * np.einsum("ij,ij->i", s, h)
    qv = np.cross(s, e1)
    v = f * np.einsum("ij,ij->i", d, qv)
    t = f * np.einsum("ij,ij->i", e2, qv)
    return ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)


def tri_tri_float(A, B):
    """A, B: (n, 3, 3) triangles; True where an edge of one crosses the other."""
    hit = np.zeros(len(A), dtype=bool)
    for T, S in ((A, B), (B, A)):
        for i in range(3):
            hit |= seg_tri_float(T[:, i], T[:, (i + 1) % 3], S[:, 0], S[:, 1], S[:, 2])
    return hit


def reference_pairs(V, F, faces_a, faces_b):
    """Intersecting pairs among faces_a x faces_b (no shared-vertex pairs, no self pairs)."""
    ia, ib = np.meshgrid(faces_a, faces_b, indexing="ij")
    ia, ib = ia.ravel(), ib.ravel()
    keep = (ia != ib) & ~(F[ia][:, :, None] == F[ib][:, None, :]).any(axis=(1, 2))
    ia, ib = ia[keep], ib[keep]
    hit = tri_tri_float(V[F[ia]], V[F[ib]])
    lo, hi = np.minimum(ia[hit], ib[hit]), np.maximum(ia[hit], ib[hit])
    return set(zip(lo.tolist(), hi.tolist()))


def random_soup(rng, n, size):
    centers = rng.random((n, 1, 3))
    V = (centers + size * rng.standard_normal((n, 3, 3))).reshape(-1, 3)
    return V, np.arange(3 * n).reshape(n, 3)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_soup_matches_float_reference(seed):
    rng = np.random.default_rng(seed)
    V, F = random_soup(rng, 250, 0.08)
    ref = reference_pairs(V, F, np.arange(len(F)), np.arange(len(F)))
    assert len(ref) > 20
    r = it.find_intersections(V, F)
    assert set(map(tuple, r.tri_pairs.tolist())) == ref and r.count == len(ref)
    assert r.candidate_count >= r.count
    # generic data has no touching contacts: the strict mode agrees
    assert it.find_intersections(V, F, touching=False).count == len(ref)


def test_segments_against_triangles():
    rng = np.random.default_rng(4)
    V, F = random_soup(rng, 150, 0.08)
    P = rng.random((200, 1, 3)) + 0.1 * rng.standard_normal((200, 2, 3))
    W = np.concatenate([V, P.reshape(-1, 3)])
    E = len(V) + np.arange(400).reshape(200, 2)
    r = it.find_intersections(W, F, E)
    ie, jf = np.meshgrid(np.arange(200), np.arange(150), indexing="ij")
    ie, jf = ie.ravel(), jf.ravel()
    hit = seg_tri_float(W[E[ie, 0]], W[E[ie, 1]], W[F[jf, 0]], W[F[jf, 1]], W[F[jf, 2]])
    ref = set(zip(ie[hit].tolist(), jf[hit].tolist()))
    assert len(ref) > 5
    assert set(map(tuple, r.edge_tri_pairs.tolist())) == ref
    assert r.count == len(ref) + len(r.tri_pairs)


# ---------------------------------------------------------------------------------------------
# real meshes
# ---------------------------------------------------------------------------------------------


def test_flat_grid_has_no_intersections():
    V, F = read_obj(MESHES / "square21.obj")
    assert V.shape == (441, 3) and F.shape == (800, 3) and np.all(V[:, 1] == 0)
    r = it.find_intersections(V, F)
    assert r.count == 0 and r.candidate_count > 0  # exact coplanar neighbours were tested
    # rotated to a general plane: nearly (not exactly) coplanar after rounding, still separate
    q, _ = np.linalg.qr(np.random.default_rng(2).standard_normal((3, 3)))
    assert it.find_intersections(V @ q.T + 0.3, F).count == 0


def test_grid_vertex_pushed_through_second_grid():
    V, F = read_obj(MESHES / "square21.obj")
    upper = V + [0.0123, 0.0517, 0.0071]  # second sheet, shifted to avoid exact degeneracies
    assert it.intersect_meshes([(V, F), (upper, F)])[0] == 0
    pushed = V.copy()
    center = int(np.argmin(((V - [0.0, 0.0, 0.0]) ** 2).sum(1)))
    pushed[center, 1] = 0.13
    n, pairs = it.intersect_meshes([(pushed, F), (upper, F)])
    assert n > 0
    incident = set(np.nonzero((F == center).any(axis=1))[0].tolist())
    assert np.all(pairs[:, 0] == 0) and np.all(pairs[:, 2] == 1)
    assert set(pairs[:, 1].tolist()) <= incident
    # independent reference over all pairs between the two sheets
    W = np.concatenate([pushed, upper])
    G = np.concatenate([F, F + len(V)])
    ref = reference_pairs(W, G, np.arange(len(F)), np.arange(len(F), 2 * len(F)))
    assert {(int(a), int(b) + len(F)) for a, b in pairs[:, [1, 3]]} == ref


def test_closed_sphere_has_no_self_intersections():
    V, F = read_obj(MESHES / "sphere1K.obj")
    assert V.shape == (1239, 3) and F.shape == (2474, 3)
    r = it.find_intersections(V, F)
    assert r.count == 0 and r.candidate_count > 0


@pytest.mark.parametrize("seed", range(4))
def test_random_fold_through_is_detected(seed):
    """Push a random vertex of the sphere through the opposite side; also fold a random vertex of
    the upper layer of a two-layer sheet through the lower layer."""
    rng = np.random.default_rng(seed)
    V, F = read_obj(MESHES / "sphere1K.obj")
    v = int(rng.integers(len(V)))
    c = V.mean(axis=0)
    W = V.copy()
    W[v] = c - (V[v] - c) * rng.uniform(1.2, 1.5) + 0.01 * rng.standard_normal(3)
    r = it.find_intersections(W, F)
    incident = np.nonzero((F == v).any(axis=1))[0]
    assert r.count > 0
    assert np.all(np.isin(r.tri_pairs, incident).any(axis=1))  # every pair involves a moved face
    ref = reference_pairs(W, F, incident, np.arange(len(F)))
    assert set(map(tuple, r.tri_pairs.tolist())) == ref

    G, GF = read_obj(MESHES / "square21.obj")
    top = G + [0.011, 0.03, 0.007]
    S = np.concatenate([G, top])  # one mesh, two layers
    SF = np.concatenate([GF, GF + len(G)])
    assert it.find_intersections(S, SF).count == 0
    interior = np.nonzero((np.abs(top[:, 0]) < 0.4) & (np.abs(top[:, 2]) < 0.4))[0]
    w = len(G) + int(rng.choice(interior))
    S[w] += [0.02 * rng.standard_normal(), -rng.uniform(0.05, 0.1), 0.02 * rng.standard_normal()]
    r = it.find_intersections(S, SF)
    assert r.count > 0
    inc = np.nonzero((SF == w).any(axis=1))[0]
    assert np.all(np.isin(r.tri_pairs, inc).any(axis=1))
    assert set(map(tuple, r.tri_pairs.tolist())) == reference_pairs(S, SF, inc, np.arange(len(SF)))


def test_cloth_funnel_frame_matches_float_reference():
    """Real cloth data: frame 227 of the CCD data set's cloth-funnel scene is *not* free of
    self-intersections (its source simulation did not guarantee that). The exact checker must
    report exactly the pairs an independent float test finds among the broad-phase candidates,
    in both semantics (these crossings are generic, with no touching)."""
    from lokigraph.behaviors.collision import broadphase as bp

    d = np.load(MESHES / "cloth_funnel_227_228_frames.npz")
    V, F = d["V0"], d["F"]
    r = it.find_intersections(V, F)
    cand = bp.query_self(bp.build_bvh(*bp.primitive_boxes(V, F)), F)
    assert r.candidate_count == len(cand)
    hit = tri_tri_float(V[F[cand[:, 0]]], V[F[cand[:, 1]]])
    ref = set(map(tuple, np.sort(cand[hit], axis=1).tolist()))
    assert len(ref) > 0
    assert set(map(tuple, r.tri_pairs.tolist())) == ref
    assert set(map(tuple, it.find_intersections(V, F, touching=False).tri_pairs.tolist())) == ref


def test_input_validation():
    with pytest.raises(ValueError, match="out of range"):
        it.find_intersections(np.zeros((3, 3)), np.array([[0, 1, 3]]))
    with pytest.raises(ValueError, match="finite"):
        it.find_intersections(np.full((3, 3), np.nan), np.array([[0, 1, 2]]))
