"""Tests of the Nucleus constraint projection kernels: the XPBD kernels of every effect module
(lokigraph.behaviors.materials.*, lokigraph.behaviors.attachments.goal / .surface) and the shared
primitives of lokigraph.behaviors.solvers.nucleus.xpbd."""
from types import SimpleNamespace

import numpy as np
import pytest

from lokigraph.behaviors import topology as T
from lokigraph.behaviors.attachments import goal, surface
from lokigraph.behaviors.materials import bend, pressure, rigid, shear, stretch, volume
from lokigraph.behaviors.solvers.nucleus import xpbd

#: every kernel by name, wherever its effect module keeps it
K = SimpleNamespace(**{k: v for m in (xpbd, stretch, shear, bend, volume, pressure, rigid, goal,
                                      surface) for k, v in vars(m).items()
                       if not k.startswith("__")})

H = 1.0 / 240.0


# ----------------------------------------------------------------------------------------------
# fixtures and helpers
# ----------------------------------------------------------------------------------------------
def one_color(m):
    return np.array([0, m], dtype=np.int64)


def fd_gradient(cfun, p, eps=1e-6):
    """Central finite differences of a scalar constraint function of all positions."""
    g = np.zeros_like(p)
    for i in range(p.shape[0]):
        for k in range(3):
            a = p.copy()
            b = p.copy()
            a[i, k] += eps
            b[i, k] -= eps
            g[i, k] = (cfun(a) - cfun(b)) / (2.0 * eps)
    return g


def kernel_gradient(step, p):
    """Gradient used by a kernel, read back from one hard step with unit inverse masses:
    dp_i = w_i grad_i C dlam and lam = dlam, so grad = dp / lam."""
    q = p.copy()
    lam = step(q)
    assert lam != 0.0
    return (q - p) / lam


class Cloth:
    """A small perturbed grid with every cloth constraint, coloured."""

    def __init__(self, n, noise=0.0, seed=0, w=None, colored=True, curvature=0.0):
        rng = np.random.default_rng(seed)
        self.x_rest, self.tris = T.grid_mesh(n, n, 1.0, 1.0)
        # a doubly curved rest shape keeps the hard stretch problem regular: a flat
        # inextensible sheet is a singular point (out-of-plane motion changes lengths only to
        # second order) where Gauss-Seidel converges sublinearly
        u, v = self.x_rest[:, 0], self.x_rest[:, 2]
        self.x_rest[:, 1] = curvature * ((u - 0.5) ** 2 + (v - 0.3) ** 2)
        nv = self.x_rest.shape[0]
        self.w = np.ones(nv) if w is None else w
        edges = T.triangle_edges(self.tris)
        trip = T.triangle_corner_triplets(self.tris)
        quads = T.bend_quads(self.tris)
        self.sets = {}
        for name, elems in (("edges", edges), ("trip", trip), ("quads", quads)):
            if colored:
                perm, ptr = T.color_constraints(elems, self.w)
                elems = np.ascontiguousarray(elems[perm])
            else:
                ptr = one_color(elems.shape[0])
            self.sets[name] = (elems, ptr)
        self.edges, self.eptr = self.sets["edges"]
        self.trip, self.tptr = self.sets["trip"]
        self.quads, self.qptr = self.sets["quads"]
        self.L = K.rest_lengths(self.x_rest, self.edges)
        self.gamma = K.rest_angles(self.x_rest, self.trip)
        self.theta = K.rest_dihedrals(self.x_rest, self.quads)
        self.p = self.x_rest + noise / n * rng.normal(size=self.x_rest.shape)


# ----------------------------------------------------------------------------------------------
# constraint values against independent formulas
# ----------------------------------------------------------------------------------------------
def test_angle_value_is_nucleus_acos_formula():
    rng = np.random.default_rng(1)
    p = rng.normal(size=(30, 3))
    trip = rng.permutation(30)[:30].reshape(10, 3).astype(np.int64)
    got = K.rest_angles(p, trip)
    u = p[trip[:, 1]] - p[trip[:, 0]]
    v = p[trip[:, 2]] - p[trip[:, 0]]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    np.testing.assert_allclose(got, np.arccos(np.sum(u * v, axis=1)), atol=1e-12)


def test_dihedral_value_magnitude_and_sign():
    rng = np.random.default_rng(2)
    p = rng.normal(size=(40, 3))
    quads = rng.permutation(40).reshape(10, 4).astype(np.int64)
    th = K.rest_dihedrals(p, quads)
    i, j, k, l = (p[quads[:, c]] for c in range(4))
    na = np.cross(j - i, k - i)
    nb = np.cross(i - j, l - j)  # normal of triangle (j, i, l)
    na /= np.linalg.norm(na, axis=1, keepdims=True)
    nb /= np.linalg.norm(nb, axis=1, keepdims=True)
    np.testing.assert_allclose(np.abs(th), np.arccos(np.clip(np.sum(na * nb, 1), -1, 1)),
                               atol=1e-9)
    # sign: flat hinge in the xy plane, normal +z; folding the wing l towards +z is negative
    for phi in (0.3, -0.7, 2.5):
        x = np.array([[0, 0, 0], [1, 0, 0], [0.3, 1, 0],
                      [0.6, -np.cos(phi), np.sin(phi)]], dtype=float)
        np.testing.assert_allclose(K.rest_dihedrals(x, np.array([[0, 1, 2, 3]])), [-phi],
                                   atol=1e-12)


def test_tet_and_mesh_volume_values():
    rng = np.random.default_rng(3)
    p = rng.normal(size=(8, 3))
    tets = np.array([[0, 1, 2, 3], [4, 5, 6, 7]], dtype=np.int64)
    want = [np.linalg.det(np.stack([p[t[1]] - p[t[0]], p[t[2]] - p[t[0]], p[t[3]] - p[t[0]]]))
            / 6.0 for t in tets]
    np.testing.assert_allclose(K.rest_tet_volumes(p, tets), want, rtol=1e-12)
    x, tris = T.icosphere(2, radius=0.5)
    x = x + rng.normal(scale=0.02, size=x.shape) + np.array([3.0, -2.0, 1.0])
    origin = np.einsum("ij,ij->i", x[tris[:, 0]], np.cross(x[tris[:, 1]], x[tris[:, 2]])).sum() / 6
    assert K.mesh_volume(x, tris) == pytest.approx(origin, rel=1e-11)
    assert 0.9 * 4 / 3 * np.pi * 0.125 < origin < 1.05 * 4 / 3 * np.pi * 0.125


# ----------------------------------------------------------------------------------------------
# gradients: what each kernel moves along equals finite differences of its C
# ----------------------------------------------------------------------------------------------
def _single(kind, rng):
    """(positions, step(q) -> lam, C(q) -> float) for one random constraint of a kind."""
    z = np.zeros(1)
    if kind == "stretch":
        p = rng.normal(size=(2, 3))
        e = np.array([[0, 1]], dtype=np.int64)
        L = K.rest_lengths(p, e) * 0.7
        w = np.ones(2)

        def step(q):
            lam = np.zeros(1)
            K.project_stretch_seq(q, w, e, L, z, z, lam, H, one_color(1))
            return lam[0]
        return p, step, lambda q: K.stretch_values(q, e, L)[0]
    if kind == "angle":
        p = rng.normal(size=(3, 3))
        t = np.array([[0, 1, 2]], dtype=np.int64)
        g = K.rest_angles(p, t) + 0.2
        w = np.ones(3)

        def step(q):
            lam = np.zeros(1)
            K.project_angle_seq(q, w, t, g, z, lam, H, one_color(1))
            return lam[0]
        return p, step, lambda q: K.angle_values(q, t, g)[0]
    if kind == "angle_near_pi":  # an almost straight hair vertex
        d = rng.normal(size=3)
        p = np.stack([-d, np.zeros(3), 1.3 * d]) + 1e-3 * rng.normal(size=(3, 3))
        t = np.array([[1, 0, 2]], dtype=np.int64)
        g = np.array([np.pi - 0.2])
        w = np.ones(3)

        def step(q):
            lam = np.zeros(1)
            K.project_angle_seq(q, w, t, g, z, lam, H, one_color(1))
            return lam[0]
        return p, step, lambda q: K.angle_values(q, t, g)[0]
    if kind == "dihedral_near_flat":
        p = np.array([[0, 0, 0], [1, 0, 0], [0.3, 1, 0], [0.6, -0.8, 0]], dtype=float)
        p += 1e-4 * rng.normal(size=p.shape)
        qd = np.array([[0, 1, 2, 3]], dtype=np.int64)
        th = np.array([0.4])
        w = np.ones(4)

        def step(q):
            lam = np.zeros(1)
            K.project_dihedral_seq(q, w, qd, th, z, z, lam, H, one_color(1))
            return lam[0]
        return p, step, lambda q: K.dihedral_values(q, qd, th)[0]
    if kind == "dihedral":
        p = rng.normal(size=(4, 3))
        qd = np.array([[0, 1, 2, 3]], dtype=np.int64)
        th = K.rest_dihedrals(p, qd) - 0.3
        w = np.ones(4)
        drop = np.array([1.5])

        def step(q):
            lam = np.zeros(1)
            K.project_dihedral_seq(q, w, qd, th, z, drop, lam, H, one_color(1))
            return lam[0]
        return p, step, lambda q: K.dihedral_values(q, qd, th)[0]
    if kind == "tet":
        p = rng.normal(size=(4, 3))
        tt = T.orient_tets(p, np.array([[0, 1, 2, 3]]))
        v0 = K.rest_tet_volumes(p, tt) * 1.3
        w = np.ones(4)

        def step(q):
            lam = np.zeros(1)
            K.project_tet_volume_seq(q, w, tt, v0, z, lam, H, one_color(1))
            return lam[0]
        return p, step, lambda q: K.tet_volume_values(q, tt, v0)[0]
    if kind == "goal":
        p = rng.normal(size=(1, 3))
        idx = np.array([0], dtype=np.int64)
        tgt = rng.normal(size=(1, 3))
        w = np.ones(1)

        def step(q):
            lam = np.zeros(1)
            K.project_goal_seq(q, w, idx, tgt, z, lam, H)
            return lam[0]
        return p, step, lambda q: K.goal_values(q, idx, tgt)[0]
    if kind in ("mesh_volume_closed", "mesh_volume_open"):
        if kind.endswith("closed"):
            x, tris = T.icosphere(1)
        else:
            x, tris = T.grid_mesh(3, 3)
        p = x + rng.normal(scale=0.1, size=x.shape)
        target = K.mesh_volume(p, tris) + 0.5
        w = np.ones(p.shape[0])
        work = np.zeros((p.shape[0], 4))

        def step(q):
            lam = np.zeros(1)
            K.project_mesh_volume(q, w, tris, target, 0.0, lam, H, work)
            return lam[0]
        return p, step, lambda q: K.mesh_volume(q, tris) - target
    raise KeyError(kind)


@pytest.mark.parametrize("kind", ["stretch", "angle", "angle_near_pi", "dihedral",
                                  "dihedral_near_flat", "tet", "goal", "mesh_volume_closed",
                                  "mesh_volume_open"])
def test_kernel_gradient_matches_finite_differences(kind):
    rng = np.random.default_rng(10)
    for _ in range(5):
        p, step, cfun = _single(kind, rng)
        g = kernel_gradient(step, p)
        fd = fd_gradient(cfun, p)
        np.testing.assert_allclose(g, fd, atol=1e-6 * max(1.0, np.abs(fd).max()))


def test_attach_gradient_matches_finite_differences():
    rng = np.random.default_rng(11)
    p = rng.normal(size=(4, 3))
    att = np.array([[0, 1, 2, 3]], dtype=np.int64)
    bary = np.array([[0.2, 0.5, 0.3]])
    w = np.ones(4)
    for row in range(3):  # each row of the vector constraint
        q = p.copy()
        lam = np.zeros((1, 3))
        K.project_attach_seq(q, w, att, bary, np.zeros(1), lam, H, one_color(1))
        g = (q - p)[:, row] / lam[0, row]
        fd = fd_gradient(lambda s: K.attach_values(s, att, bary)[0, row], p)
        np.testing.assert_allclose(g, fd[:, row], atol=1e-7)
        # the step touches only component `row` of the gradient for that row: off-axis fd = 0
        assert np.all(np.abs(np.delete(fd, row, axis=1)) < 1e-9)
    assert np.abs(K.attach_values(q, att, bary)).max() < 1e-12  # linear: one step is exact


# ----------------------------------------------------------------------------------------------
# hard constraints converge on perturbed configurations
# ----------------------------------------------------------------------------------------------
def _iterate(fn, iters):
    for _ in range(iters):
        fn()


def _converge(step, res, iters, tol=1e-9, every=50):
    """Sweep until res() < tol (checked every `every` sweeps) or `iters` sweeps; return res()."""
    for it in range(iters):
        step()
        if it % every == every - 1 and res()[0] < tol:
            break
    return res()


@pytest.mark.parametrize("kind", ["stretch", "angle", "dihedral"])
def test_hard_cloth_constraints_converge(kind):
    # bend alone converges slowly on a curved rest shape (edge lengths are free): flat rest
    c = Cloth(6, noise=0.3, seed=4, curvature=0.0 if kind == "dihedral" else 1.0)
    m = {"stretch": c.L, "angle": c.gamma, "dihedral": c.theta}[kind].shape[0]
    zero = np.zeros(m)
    lam = np.zeros(m)
    if kind == "stretch":
        def res():
            return K.residual_stretch(c.p, c.edges, c.L)

        def step():
            K.project_stretch_seq(c.p, c.w, c.edges, c.L, zero, zero, lam, H, c.eptr)
    elif kind == "angle":
        def res():
            return K.residual_angle(c.p, c.trip, c.gamma)

        def step():
            K.project_angle_seq(c.p, c.w, c.trip, c.gamma, zero, lam, H, c.tptr)
    else:
        def res():
            return K.residual_dihedral(c.p, c.quads, c.theta)

        def step():
            K.project_dihedral_seq(c.p, c.w, c.quads, c.theta, zero, zero, lam, H, c.qptr)
    assert res()[0] > 1e-2  # the perturbation really violates the constraints
    assert _converge(step, res, 4000)[0] < 1e-9
    assert np.all(np.isfinite(c.p))


def test_hard_tets_converge_with_edge_stretch():
    # volume alone is singular on this mesh (the 48 tet volumes of the box have rank 36 at
    # rest), so tets get their edges too, as in the solver
    x, tets = T.tet_box(2, 2, 2, 0.5)
    rng = np.random.default_rng(5)
    p = x + rng.normal(scale=0.05, size=x.shape)
    edges = T.tet_edges(tets)
    perm, ptr = T.color_constraints(tets)
    tets = tets[perm]
    eperm, eptr = T.color_constraints(edges)
    edges = edges[eperm]
    v0 = K.rest_tet_volumes(x, tets)
    L = K.rest_lengths(x, edges)
    w = np.ones(x.shape[0])
    lam, lam_e = np.zeros(len(v0)), np.zeros(len(L))
    assert K.residual_tet_volume(p, tets, v0)[0] > 1e-3
    for _ in range(200):
        K.project_tet_volume(p, w, tets, v0, np.zeros(len(v0)), lam, H, ptr)
        K.project_stretch(p, w, edges, L, np.zeros(len(L)), np.zeros(len(L)), lam_e, H, eptr)
    assert K.residual_tet_volume(p, tets, v0)[0] < 1e-12
    assert K.residual_stretch(p, edges, L)[0] < 1e-9


def test_hard_goal_attach_and_mesh_volume_converge():
    rng = np.random.default_rng(6)
    p = rng.normal(size=(8, 3))
    w = rng.uniform(0.5, 2.0, 8)
    idx = np.array([0, 5], dtype=np.int64)
    tgt = rng.normal(size=(2, 3))
    att = np.array([[1, 2, 3, 4], [6, 2, 4, 7]], dtype=np.int64)
    bary = np.array([[0.2, 0.3, 0.5], [0.6, 0.1, 0.3]])
    lam_g = np.zeros(2)
    lam_a = np.zeros((2, 3))
    for _ in range(200):  # attachments share vertices 2 and 4: sequential, coupled
        K.project_goal(p, w, idx, tgt, np.zeros(2), lam_g, H)
        K.project_attach_seq(p, w, att, bary, np.zeros(2), lam_a, H, one_color(2))
    assert K.residual_goal(p, idx, tgt)[0] < 1e-12
    assert K.residual_attach(p, att, bary)[0] < 1e-9

    x, tris = T.icosphere(2)
    q = x + rng.normal(scale=0.05, size=x.shape)
    target = 1.25 * K.mesh_volume(q, tris)
    lam = np.zeros(1)
    work = np.zeros((q.shape[0], 4))
    for _ in range(20):
        K.project_mesh_volume(q, np.ones(len(q)), tris, target, 0.0, lam, H, work)
    assert K.residual_mesh_volume(q, tris, target)[0] < 1e-9 * target
    assert lam[0] > 0.0  # lam / h^2 is the gauge pressure: positive to inflate


def test_shape_matching_goals_rotation_and_stiffness():
    rng = np.random.default_rng(7)
    rest = rng.normal(size=(12, 3))
    idx = np.arange(12, dtype=np.int64)
    ptr = np.array([0, 12], dtype=np.int64)
    ang = 0.8
    rot = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1]])
    moved = rest @ rot.T + np.array([1.0, 2.0, -3.0])
    w = rng.uniform(0.5, 2.0, 12)
    # a rigidly moved cluster is already at its goals
    p = moved.copy()
    K.shape_match(p, w, ptr, idx, rest, np.array([1.0]))
    np.testing.assert_allclose(p, moved, atol=1e-12)
    # a deformed cluster becomes rigid with stiffness 1, momentum kept (all dynamic)
    p0 = moved + rng.normal(scale=0.2, size=moved.shape)
    p = p0.copy()
    K.shape_match(p, w, ptr, idx, rest, np.array([1.0]))
    d = np.linalg.norm(p[:, None] - p[None], axis=-1)
    d0 = np.linalg.norm(rest[:, None] - rest[None], axis=-1)
    np.testing.assert_allclose(d, d0, atol=1e-12)
    np.testing.assert_allclose(((p - p0) / w[:, None]).sum(0), 0.0, atol=1e-12)
    assert K.residual_shape_match(p, w, ptr, idx, rest)[0] < 1e-12
    # stiffness 0.5 moves exactly half way to the same goals
    q = p0.copy()
    K.shape_match(q, w, ptr, idx, rest, np.array([0.5]))
    np.testing.assert_allclose(q, 0.5 * (p0 + p), atol=1e-12)
    # a mirrored cluster is matched by a rotation, never a reflection
    mirror = rest * np.array([1.0, 1.0, -1.0])
    q = mirror.copy()
    K.shape_match(q, w, ptr, idx, rest, np.array([1.0]))
    d = np.linalg.norm(q[:, None] - q[None], axis=-1)
    np.testing.assert_allclose(d, d0, atol=1e-12)
    vol = np.linalg.det(np.stack([q[1] - q[0], q[2] - q[0], q[3] - q[0]]))
    vol0 = np.linalg.det(np.stack([rest[1] - rest[0], rest[2] - rest[0], rest[3] - rest[0]]))
    assert vol == pytest.approx(vol0, rel=1e-9)


# ----------------------------------------------------------------------------------------------
# momentum, pinned vertices, degenerate input
# ----------------------------------------------------------------------------------------------
def _all_sweeps(c, lam, alpha=0.0, seq=False):
    """Run every cloth kernel once on c.p."""
    ne, nt, nq = len(c.L), len(c.gamma), len(c.theta)
    a = np.full(max(ne, nt, nq), alpha)
    suf = "_seq" if seq else ""
    getattr(K, "project_stretch" + suf)(c.p, c.w, c.edges, c.L, a[:ne], a[:ne], lam["e"], H,
                                        c.eptr)
    getattr(K, "project_angle" + suf)(c.p, c.w, c.trip, c.gamma, a[:nt], lam["t"], H, c.tptr)
    getattr(K, "project_dihedral" + suf)(c.p, c.w, c.quads, c.theta, a[:nq], np.full(nq, 0.5),
                                         lam["q"], H, c.qptr)


def _lams(c):
    return {"e": np.zeros(len(c.L)), "t": np.zeros(len(c.gamma)), "q": np.zeros(len(c.theta))}


def test_internal_constraints_conserve_momentum():
    rng = np.random.default_rng(8)
    c = Cloth(5, noise=0.4, seed=8, w=rng.uniform(0.2, 5.0, 36))
    m = 1.0 / c.w
    lam = _lams(c)
    checks = []
    for kernel in ("stretch", "angle", "dihedral"):
        p0 = c.p.copy()
        ne, nt, nq = len(c.L), len(c.gamma), len(c.theta)
        if kernel == "stretch":
            K.project_stretch(c.p, c.w, c.edges, c.L, np.full(ne, 1e-4), np.zeros(ne), lam["e"],
                              H, c.eptr)
        elif kernel == "angle":
            K.project_angle(c.p, c.w, c.trip, c.gamma, np.zeros(nt), lam["t"], H, c.tptr)
        else:
            K.project_dihedral(c.p, c.w, c.quads, c.theta, np.full(nq, 1e-3), np.ones(nq),
                               lam["q"], H, c.qptr)
        dp = c.p - p0
        scale = np.abs(m[:, None] * dp).sum()
        assert scale > 1e-3
        checks.append(np.abs((m[:, None] * dp).sum(0)).max() / scale)
    # tets, attachments, global volume, damped stretch
    x, tets = T.tet_box(1, 1, 2)
    p = x + rng.normal(scale=0.1, size=x.shape)
    w = rng.uniform(0.2, 5.0, len(x))
    for name in ("tet", "attach", "volume", "damped"):
        p0 = p.copy()
        if name == "tet":
            v0 = K.rest_tet_volumes(x, tets) * 1.1
            K.project_tet_volume_seq(p, w, tets, v0, np.zeros(len(tets)), np.zeros(len(tets)),
                                     H, one_color(len(tets)))
        elif name == "attach":
            att = np.array([[0, 3, 5, 9], [2, 4, 7, 11]], dtype=np.int64)
            bary = np.array([[0.2, 0.3, 0.5], [0.1, 0.1, 0.8]])
            K.project_attach_seq(p, w, att, bary, np.zeros(2), np.zeros((2, 3)), H, one_color(2))
        elif name == "volume":
            topo = T.tet_topology(tets)
            K.project_mesh_volume(p, w, topo.boundary_faces, 0.7, 0.0, np.zeros(1), H,
                                  np.zeros((len(p), 4)))
        else:
            e = T.tet_edges(tets)
            L = K.rest_lengths(x, e)
            xprev = p - rng.normal(scale=0.01, size=p.shape)
            a = np.full(len(e), 1e-3)
            K.project_stretch_damped_seq(p, xprev, w, e, L, a, a, np.full(len(e), 50.0),
                                         np.zeros(len(e)), H, one_color(len(e)))
        dp = p - p0
        scale = np.abs(dp / w[:, None]).sum()
        assert scale > 1e-4, name
        checks.append(np.abs((dp / w[:, None]).sum(0)).max() / scale)
    assert max(checks) < 1e-12, checks


def test_pinned_vertices_never_move():
    w = np.ones(49)
    pinned = np.array([0, 6, 24, 42, 48])
    w[pinned] = 0.0
    c = Cloth(6, noise=0.5, seed=9, w=w)
    p_pinned = c.p[pinned].copy()
    lam = _lams(c)
    for _ in range(50):
        _all_sweeps(c, lam)
    assert np.array_equal(c.p[pinned], p_pinned)
    # other kernels
    rng = np.random.default_rng(9)
    x, tets = T.tet_box(1, 1, 1)
    p = x + rng.normal(scale=0.2, size=x.shape)
    w = np.ones(len(x))
    w[[0, 7]] = 0.0
    keep = p[[0, 7]].copy()
    topo = T.tet_topology(tets)
    v0 = K.rest_tet_volumes(x, tets)
    for _ in range(20):
        K.project_tet_volume_seq(p, w, tets, v0, np.zeros(6), np.zeros(6), H, one_color(6))
        K.project_goal_seq(p, w, np.array([0, 1]), np.zeros((2, 3)), np.zeros(2), np.zeros(2), H)
        K.project_attach_seq(p, w, np.array([[7, 1, 2, 3]]), np.array([[0.3, 0.3, 0.4]]),
                             np.zeros(1), np.zeros((1, 3)), H, one_color(1))
        K.project_mesh_volume(p, w, topo.boundary_faces, 2.0, 0.0, np.zeros(1), H,
                              np.zeros((8, 4)))
        K.shape_match(p, w, np.array([0, 8]), np.arange(8), x, np.array([0.7]))
    assert np.array_equal(p[[0, 7]], keep)
    assert np.abs(p - x).max() > 1e-3  # the dynamic vertices did move


def test_degenerate_configurations_produce_no_nan():
    w = np.ones(4)
    z1 = np.zeros(1)
    cp = one_color(1)
    # zero-length edge, rest > 0
    p = np.zeros((2, 3))
    lam = np.zeros(1)
    K.project_stretch(p, w[:2], np.array([[0, 1]]), np.ones(1), z1, z1, lam, H, cp)
    K.project_stretch_damped(p, p.copy(), w[:2], np.array([[0, 1]]), np.ones(1), z1, z1,
                             np.ones(1), lam, H, cp)
    assert np.all(np.isfinite(p)) and np.all(np.isfinite(lam))
    # collinear corners (angle 0 and pi) and a coincident corner
    for pts in ([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 0, 0], [1, 0, 0], [-2, 0, 0]],
                [[0, 0, 0], [0, 0, 0], [1, 0, 0]]):
        p = np.array(pts, dtype=float)
        lam = np.zeros(1)
        K.project_angle(p, w[:3], np.array([[0, 1, 2]]), np.array([1.0]), z1, lam, H, cp)
        assert np.all(np.isfinite(p)) and np.all(np.isfinite(lam))
    # bend quads: all collinear, a zero-height wing, a zero-length hinge, a flat hinge
    for pts in ([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]],
                [[0, 0, 0], [1, 0, 0], [0.5, 0, 0], [0.5, -1, 0]],
                [[0, 0, 0], [0, 0, 0], [0, 1, 0], [1, 0, 0]],
                [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0]]):
        p = np.array(pts, dtype=float)
        lam = np.zeros(1)
        K.project_dihedral(p, w, np.array([[0, 1, 2, 3]]), np.array([0.5]), z1, np.ones(1),
                           lam, H, cp)
        assert np.all(np.isfinite(p)) and np.all(np.isfinite(lam))
    # the flat hinge is regular: it must have moved towards the rest angle
    assert K.rest_dihedrals(p, np.array([[0, 1, 2, 3]]))[0] == pytest.approx(0.5, abs=0.2)
    # tets: all coincident, collinear (on an axis and along a random direction, where rounding
    # leaves tiny nonzero gradients), coplanar (zero volume but a valid direction)
    d = np.array([0.3, -0.7, 0.2])
    for pts in ([[0, 0, 0]] * 4, [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]],
                [0.1 * d, 1.3 * d, 2.9 * d, -0.7 * d],
                [[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]):
        p = np.array(pts, dtype=float)
        p0 = p.copy()
        lam = np.zeros(1)
        K.project_tet_volume(p, w, np.array([[0, 1, 2, 3]]), np.array([0.1]), z1, lam, H, cp)
        assert np.all(np.isfinite(p)) and np.all(np.isfinite(lam))
        assert np.abs(p - p0).max() < 1.0  # no runaway step along a meaningless direction
    assert K.rest_tet_volumes(p, np.array([[0, 1, 2, 3]]))[0] == pytest.approx(0.1)
    # goal at the target; global volume and shape matching on coincident points
    p = np.zeros((4, 3))
    K.project_goal(p, w, np.array([0]), np.zeros((1, 3)), z1, np.zeros(1), H)
    K.project_mesh_volume(p, w, np.array([[0, 1, 2], [0, 2, 3]]), 1.0, 0.0, np.zeros(1), H,
                          np.zeros((4, 4)))
    line = np.outer(np.array([0.0, 1.0, 2.5, 4.0]), d)  # a closed mesh collapsed to a line
    x, tris = T.icosphere(0)
    q = np.concatenate([line, np.zeros((8, 3))])
    K.project_mesh_volume(q, np.ones(12), tris, 1.0, 0.0, np.zeros(1), H, np.zeros((12, 4)))
    assert np.all(np.isfinite(q)) and np.abs(q[:4] - line).max() < 1.0
    K.shape_match(p, w, np.array([0, 4]), np.arange(4), np.eye(4, 3), np.ones(1))
    K.project_attach(p, np.zeros(4), np.array([[0, 1, 2, 3]]), np.full((1, 3), 1 / 3), z1,
                     np.zeros((1, 3)), H, cp)
    assert np.all(np.isfinite(p))


def test_infinite_compliance_disables_a_constraint():
    p = np.array([[0.0, 0, 0], [2.0, 0, 0]])
    e = np.array([[0, 1]])
    lam = np.zeros(1)
    K.project_stretch(p, np.ones(2), e, np.ones(1), np.array([np.inf]), np.zeros(1), lam, H,
                      one_color(1))
    assert p[1, 0] == 2.0 and lam[0] == 0.0
    p[1, 0] = 0.5  # compressed: the compression compliance (0, hard) applies
    K.project_stretch(p, np.ones(2), e, np.ones(1), np.array([np.inf]), np.zeros(1), lam, H,
                      one_color(1))
    assert p[1, 0] - p[0, 0] == pytest.approx(1.0)


# ----------------------------------------------------------------------------------------------
# XPBD compliance meaning
# ----------------------------------------------------------------------------------------------
def _hanging_spring(h, alpha_s, alpha_c, load, duration, beta=0.0, iters=4, start=1.0,
                    slant=0.3):
    """Vertex 0 pinned at the origin, vertex 1 (1 kg) on an edge of rest length 1 m, pulled by
    a constant force of `load` [N] along (slant, -1, 0) (negative: pushed), starting on that
    line at distance `start`. Solver loop as in the Nucleus solver. Returns (final elongation
    [m], elongation after every substep)."""
    d = np.array([slant, -1.0, 0.0]) / np.hypot(slant, 1.0)
    x = np.stack([np.zeros(3), start * d])
    v = np.zeros_like(x)
    w = np.array([0.0, 1.0])
    e = np.array([[0, 1]], dtype=np.int64)
    L = np.ones(1)
    a_s, a_c, b = np.array([alpha_s]), np.array([alpha_c]), np.array([beta])
    f = np.stack([np.zeros(3), load * d])
    hist = []
    for _ in range(int(round(duration / h))):
        v += h * f * w[:, None]
        p = x + h * v
        lam = np.zeros(1)
        for _ in range(iters):
            if beta:
                K.project_stretch_damped_seq(p, x, w, e, L, a_s, a_c, b, lam, h, one_color(1))
            else:
                K.project_stretch_seq(p, w, e, L, a_s, a_c, lam, h, one_color(1))
        v = (p - x) / h
        x = p
        hist.append(np.linalg.norm(x[1] - x[0]) - 1.0)
    return hist[-1], np.array(hist)


def test_compliance_gives_elongation_load_times_alpha_for_any_substep():
    alpha, load = 1e-3, 20.0
    for h in (1.0 / 60.0, 1.0 / 240.0):
        got, hist = _hanging_spring(h, alpha, 0.0, load, duration=12.0)
        assert got == pytest.approx(alpha * load, rel=1e-6), h
        assert abs(hist[0] - alpha * load) > 0.5 * alpha * load  # it started out of equilibrium
    # the compression compliance applies when the load pushes (along the axis: a pushed
    # pendulum is unstable sideways, so no sideways component at all)
    got, _ = _hanging_spring(1.0 / 60.0, 0.0, 4 * alpha, -load, duration=12.0, slant=0.0)
    assert got == pytest.approx(-4 * alpha * load, rel=1e-6)


def test_stretch_damping_damps_and_keeps_equilibrium():
    alpha, load, h = 1e-3, 20.0, 1.0 / 240.0
    want = alpha * load
    _, free = _hanging_spring(h, alpha, alpha, load, duration=0.5, start=1.1)
    _, damped = _hanging_spring(h, alpha, alpha, load, duration=0.5, beta=20.0, start=1.1)
    tail = slice(len(free) // 2, None)
    assert np.abs(damped[tail] - want).max() < 0.1 * np.abs(free[tail] - want).max()
    final, _ = _hanging_spring(h, alpha, alpha, load, duration=12.0, beta=20.0)
    assert final == pytest.approx(want, rel=1e-6)


def test_bend_dropoff_scales_the_compliance():
    rng = np.random.default_rng(12)
    p = rng.normal(size=(4, 3))
    qd = np.array([[0, 1, 2, 3]], dtype=np.int64)
    rest = K.rest_dihedrals(p, qd) - 1.0
    alpha = np.array([5e-5])
    g = fd_gradient(lambda s: K.dihedral_values(s, qd, rest)[0], p)
    den = np.sum(g * g)
    c0 = K.dihedral_values(p, qd, rest)[0]
    steps = []
    for drop in (0.0, 1.0, 4.0):
        lam = np.zeros(1)
        q = p.copy()
        K.project_dihedral_seq(q, np.ones(4), qd, rest, alpha, np.array([drop]), lam, H,
                               one_color(1))
        scale = 1.0 + drop * abs(c0) / np.pi
        assert K.bend_dropoff_scale(c0, drop) == pytest.approx(scale)
        assert lam[0] == pytest.approx(-c0 / (den + alpha[0] / scale / H**2), rel=1e-6)
        steps.append(abs(lam[0]))
    assert steps[0] < steps[1] < steps[2]  # a larger dropoff resists large angles more


# ----------------------------------------------------------------------------------------------
# coloured parallel sweep == sequential sweep
# ----------------------------------------------------------------------------------------------
def test_colored_parallel_sweep_matches_sequential():
    n = 16
    w = np.ones((n + 1) ** 2)
    pins = [0, n]
    w[pins] = 0.0
    a = Cloth(n, noise=0.3, seed=13, w=w, curvature=1.0)
    b = Cloth(n, noise=0.3, seed=13, w=w, curvature=1.0)
    assert len(a.eptr) > 3 and len(a.tptr) > 3 and len(a.qptr) > 3
    la, lb = _lams(a), _lams(b)
    for _ in range(5):  # rows of a colour are independent: same result up to rounding
        _all_sweeps(a, la, seq=False)
        _all_sweeps(b, lb, seq=True)
    assert np.abs(a.p - b.x_rest).max() > 1e-2
    np.testing.assert_allclose(a.p, b.p, atol=1e-12)
    for key in la:
        np.testing.assert_allclose(la[key], lb[key], atol=1e-9)


def test_colored_parallel_stretch_converges_like_sequential():
    n = 6
    w = np.ones((n + 1) ** 2)
    w[[0, n]] = 0.0
    out = []
    for kernel in (K.project_stretch, K.project_stretch_seq):
        c = Cloth(n, noise=0.3, seed=4, w=w, curvature=1.0)
        c.p[[0, n]] = c.x_rest[[0, n]]  # pins at rest: the constraints stay satisfiable
        z = np.zeros(len(c.L))
        lam = np.zeros(len(c.L))
        res = _converge(lambda: kernel(c.p, c.w, c.edges, c.L, z, z, lam, H, c.eptr),
                        lambda: K.residual_stretch(c.p, c.edges, c.L), 4000)
        assert res[0] < 1e-9
        out.append(c.p)
    np.testing.assert_allclose(out[0], out[1], atol=1e-9)


def _helix(n, turns=2.0, radius=0.05, pitch=0.03):
    t = np.linspace(0.0, 2 * np.pi * turns, n)
    return np.stack([radius * np.cos(t), pitch * t, radius * np.sin(t)], axis=1)


def test_hair_strand_recovers_its_curl_with_stretch_bend_and_torsion():
    n = 9
    x = _helix(n)
    e = T.strand_edges([0, n])
    trip = T.curve_bend_triplets(e, apex_first=True)
    quads = T.curve_torsion_quads(e)
    assert (len(e), len(trip), len(quads)) == (n - 1, n - 2, n - 3)
    L = K.rest_lengths(x, e)
    gam = K.rest_angles(x, trip)
    tor = K.rest_dihedrals(x, quads)
    assert np.all(np.abs(tor) > 0.05)  # a helix has torsion
    rng = np.random.default_rng(15)
    p = x + 0.004 * rng.normal(size=x.shape)
    w = np.ones(n)
    w[:3] = 0.0  # root pinned: three vertices fix position, tangent and the roll about it
    p[:3] = x[:3]
    lam = [np.zeros(n - 1), np.zeros(n - 2), np.zeros(n - 3)]
    z = np.zeros(n)
    for _ in range(3000):
        K.project_stretch_seq(p, w, e, L, z, z, lam[0], H, one_color(n - 1))
        K.project_angle_seq(p, w, trip, gam, z, lam[1], H, one_color(n - 2))
        K.project_dihedral_seq(p, w, quads, tor, z, z, lam[2], H, one_color(n - 3))
    assert K.residual_stretch(p, e, L)[0] < 1e-9
    assert K.residual_angle(p, trip, gam)[0] < 1e-9
    assert K.residual_dihedral(p, quads, tor)[0] < 1e-9
    # lengths, angles and torsions fix the curve up to a rigid motion, and the root fixes that
    np.testing.assert_allclose(p, x, atol=1e-9)


def test_straight_hair_bend_by_angle_and_by_skip_one_distance():
    n = 8
    x = np.stack([np.zeros(n), -np.linspace(0, 0.7, n), np.zeros(n)], axis=1)
    e = T.strand_edges([0, n])
    trip = T.curve_bend_triplets(e, apex_first=True)
    skip = T.curve_skip_pairs(e)
    np.testing.assert_allclose(K.rest_angles(x, trip), np.pi)
    w = np.ones(n)
    w[:2] = 0.0  # root position and direction
    bent = {}
    for mode in ("angle", "skip"):
        p = x.copy()
        p[2:, 0] += 0.05 * np.sin(np.linspace(0, 3, n - 2))  # bend it
        for _ in range(5000):
            K.project_stretch_seq(p, w, e, K.rest_lengths(x, e), np.zeros(n - 1),
                                  np.zeros(n - 1), np.zeros(n - 1), H, one_color(n - 1))
            if mode == "angle":
                K.project_angle_seq(p, w, trip, np.full(n - 2, np.pi), np.zeros(n - 2),
                                    np.zeros(n - 2), H, one_color(n - 2))
            else:
                K.project_stretch_seq(p, w, skip, K.rest_lengths(x, skip), np.zeros(n - 2),
                                      np.zeros(n - 2), np.zeros(n - 2), H, one_color(n - 2))
        assert np.all(np.isfinite(p))
        bent[mode] = np.abs(p[:, 0]).max()
    # the angle constraint straightens the strand along the root direction; the skip-one
    # distance only weakly (near straight it changes to second order in the bend angle)
    assert bent["angle"] < 1e-7
    assert 1e-3 < bent["skip"] < 0.045


def test_kernels_accept_zero_constraints():
    p = np.zeros((3, 3))
    w = np.ones(3)
    z = np.zeros(0)
    cp = np.zeros(1, dtype=np.int64)
    i2, i3, i4 = (np.zeros((0, k), dtype=np.int64) for k in (2, 3, 4))
    for f in (K.project_stretch, K.project_stretch_seq):
        f(p, w, i2, z, z, z, z, H, cp)
    for f in (K.project_angle, K.project_angle_seq):
        f(p, w, i3, z, z, z, H, cp)
    for f in (K.project_dihedral, K.project_dihedral_seq):
        f(p, w, i4, z, z, z, z, H, cp)
    for f in (K.project_tet_volume, K.project_tet_volume_seq):
        f(p, w, i4, z, z, z, H, cp)
    K.project_goal(p, w, np.zeros(0, dtype=np.int64), np.zeros((0, 3)), z, z, H)
    K.project_attach(p, w, i4, np.zeros((0, 3)), z, np.zeros((0, 3)), H, cp)
    assert K.project_mesh_volume(p, w, i3, 1.0, 0.0, np.zeros(1), H, np.zeros((3, 4))) == 0.0
    K.shape_match(p, w, np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64),
                  np.zeros((0, 3)), z)
    assert np.all(p == 0.0)


def test_residual_reports_max_and_rms():
    mx, rms = K.residual(np.array([3.0, -4.0, 0.0]))
    assert mx == 4.0 and rms == pytest.approx(np.sqrt(25.0 / 3.0))
    mx, rms = K.residual(np.array([[3.0, 4.0, 0.0], [0.0, 0.0, 0.0]]))
    assert mx == 5.0 and rms == pytest.approx(np.sqrt(12.5))
    assert K.residual(np.zeros(0)) == (0.0, 0.0)


def test_colored_parallel_matches_sequential_at_production_size():
    # Gauss-Seidel needs O(n^2) sweeps to converge a hard n x n sheet, so at this size only the
    # equivalence of the two sweeps and the decrease of the residual are checked
    a = Cloth(128, noise=0.3, seed=14, curvature=1.0)
    b = Cloth(128, noise=0.3, seed=14, curvature=1.0)
    before = K.residual_stretch(a.p, a.edges, a.L)[0]
    la, lb = _lams(a), _lams(b)
    for _ in range(30):
        _all_sweeps(a, la, seq=False)
        _all_sweeps(b, lb, seq=True)
    np.testing.assert_allclose(a.p, b.p, atol=1e-11)
    assert K.residual_stretch(a.p, a.edges, a.L)[0] < 0.2 * before


def test_one_thread_runs_the_sequential_sweep_bitwise_equal():
    """On one numba thread ``xpbd.sequential_sweep`` picks the sequential kernel for every set:
    the coloured sweep's ``prange`` then runs each colour's rows in storage order, the
    sequential kernel's order, so the positions and multipliers are bitwise equal (checked
    here), and only the per-colour launches are saved."""
    import numba

    keep = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        assert xpbd.sequential_sweep(False) and xpbd.sequential_sweep(True)
        a = Cloth(32, noise=0.3, seed=15, curvature=1.0)
        b = Cloth(32, noise=0.3, seed=15, curvature=1.0)
        assert len(a.eptr) > 3 and len(a.qptr) > 3
        la, lb = _lams(a), _lams(b)
        p0 = a.p.copy()
        for _ in range(5):
            _all_sweeps(a, la, seq=False)
            _all_sweeps(b, lb, seq=True)
        assert np.abs(a.p - p0).max() > 1e-3  # the sweeps moved the sheet
        assert np.array_equal(a.p, b.p)
        for key in la:
            assert np.array_equal(la[key], lb[key])
    finally:
        numba.set_num_threads(keep)
    assert xpbd.sequential_sweep(True)
    assert xpbd.sequential_sweep(False) == (keep == 1)
