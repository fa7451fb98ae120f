"""narrowphase's distance kernels decide "clamped" and "outside" from the numerators where
those alone decide, and divide elsewhere (``_outside_unit``): bitwise the results of the
division-first kernels (copied here as the reference) on random, degenerate, lattice (exact
parallels and ties), tiny, huge, signed-zero and non-finite inputs."""

import numpy as np
from numba import njit

from lokigraph.behaviors.collision import narrowphase as N


@njit(cache=True, inline="always")
def _ref_pt_seg_sq(px, py, pz, ax, ay, az, bx, by, bz):
    dx, dy, dz = bx - ax, by - ay, bz - az
    wx, wy, wz = px - ax, py - ay, pz - az
    dd = dx * dx + dy * dy + dz * dz
    t = 0.0
    if dd > 0.0:
        t = (wx * dx + wy * dy + wz * dz) / dd
        if t < 0.0:
            t = 0.0
        elif t > 1.0:
            t = 1.0
    qx, qy, qz = wx - t * dx, wy - t * dy, wz - t * dz
    return qx * qx + qy * qy + qz * qz, t


@njit(cache=True)
def _ref_pt_tri_sq(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    e1x, e1y, e1z = bx - ax, by - ay, bz - az
    e2x, e2y, e2z = cx - ax, cy - ay, cz - az
    wx, wy, wz = px - ax, py - ay, pz - az
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    nn = nx * nx + ny * ny + nz * nz
    l1 = e1x * e1x + e1y * e1y + e1z * e1z
    l2 = e2x * e2x + e2y * e2y + e2z * e2z
    best, b0, b1, b2 = np.inf, 1.0, 0.0, 0.0
    well_conditioned = nn > 1e-10 * l1 * l2
    if nn > 0.0:
        ux = wy * e2z - wz * e2y
        uy = wz * e2x - wx * e2z
        uz = wx * e2y - wy * e2x
        vx = e1y * wz - e1z * wy
        vy = e1z * wx - e1x * wz
        vz = e1x * wy - e1y * wx
        s = (ux * nx + uy * ny + uz * nz) / nn
        t = (vx * nx + vy * ny + vz * nz) / nn
        if s >= 0.0 and t >= 0.0 and s + t <= 1.0:
            qx = wx - s * e1x - t * e2x
            qy = wy - s * e1y - t * e2y
            qz = wz - s * e1z - t * e2z
            best = qx * qx + qy * qy + qz * qz
            b0, b1, b2 = 1.0 - s - t, s, t
            if well_conditioned:
                return best, b0, b1, b2
    d2, tt = _ref_pt_seg_sq(px, py, pz, ax, ay, az, bx, by, bz)
    if d2 < best:
        best, b0, b1, b2 = d2, 1.0 - tt, tt, 0.0
    d2, tt = _ref_pt_seg_sq(px, py, pz, bx, by, bz, cx, cy, cz)
    if d2 < best:
        best, b0, b1, b2 = d2, 0.0, 1.0 - tt, tt
    d2, tt = _ref_pt_seg_sq(px, py, pz, cx, cy, cz, ax, ay, az)
    if d2 < best:
        best, b0, b1, b2 = d2, tt, 0.0, 1.0 - tt
    return best, b0, b1, b2


@njit(cache=True)
def _ref_seg_seg_sq(p0x, p0y, p0z, p1x, p1y, p1z, q0x, q0y, q0z, q1x, q1y, q1z):
    d1x, d1y, d1z = p1x - p0x, p1y - p0y, p1z - p0z
    d2x, d2y, d2z = q1x - q0x, q1y - q0y, q1z - q0z
    rx, ry, rz = p0x - q0x, p0y - q0y, p0z - q0z
    nx = d1y * d2z - d1z * d2y
    ny = d1z * d2x - d1x * d2z
    nz = d1x * d2y - d1y * d2x
    nn = nx * nx + ny * ny + nz * nz
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    best, bs, bt = np.inf, 0.0, 0.0
    if nn > 0.0:
        ax_ = d2y * rz - d2z * ry
        ay_ = d2z * rx - d2x * rz
        az_ = d2x * ry - d2y * rx
        cx_ = d1y * rz - d1z * ry
        cy_ = d1z * rx - d1x * rz
        cz_ = d1x * ry - d1y * rx
        s = (nx * ax_ + ny * ay_ + nz * az_) / nn
        t = (nx * cx_ + ny * cy_ + nz * cz_) / nn
        if s >= 0.0 and s <= 1.0 and t >= 0.0 and t <= 1.0:
            qx = rx + s * d1x - t * d2x
            qy = ry + s * d1y - t * d2y
            qz = rz + s * d1z - t * d2z
            best, bs, bt = qx * qx + qy * qy + qz * qz, s, t
            if nn > 1e-10 * a * e:
                return best, bs, bt
    d2, tt = _ref_pt_seg_sq(p0x, p0y, p0z, q0x, q0y, q0z, q1x, q1y, q1z)
    if d2 < best:
        best, bs, bt = d2, 0.0, tt
    d2, tt = _ref_pt_seg_sq(p1x, p1y, p1z, q0x, q0y, q0z, q1x, q1y, q1z)
    if d2 < best:
        best, bs, bt = d2, 1.0, tt
    d2, tt = _ref_pt_seg_sq(q0x, q0y, q0z, p0x, p0y, p0z, p1x, p1y, p1z)
    if d2 < best:
        best, bs, bt = d2, tt, 0.0
    d2, tt = _ref_pt_seg_sq(q1x, q1y, q1z, p0x, p0y, p0z, p1x, p1y, p1z)
    if d2 < best:
        best, bs, bt = d2, tt, 1.0
    return best, bs, bt


@njit(cache=True)
def _all_ee(X, out_new, out_ref):
    for i in range(X.shape[0] // 4):
        a, b, c, d = X[4 * i], X[4 * i + 1], X[4 * i + 2], X[4 * i + 3]
        r = N._seg_seg_sq(a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2], d[0], d[1], d[2])
        q = _ref_seg_seg_sq(a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2], d[0], d[1],
                            d[2])
        for k in range(3):
            out_new[i, k] = r[k]
            out_ref[i, k] = q[k]


@njit(cache=True)
def _all_vf(X, out_new, out_ref):
    for i in range(X.shape[0] // 4):
        a, b, c, d = X[4 * i], X[4 * i + 1], X[4 * i + 2], X[4 * i + 3]
        r = N._pt_tri_sq(a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2], d[0], d[1], d[2])
        q = _ref_pt_tri_sq(a[0], a[1], a[2], b[0], b[1], b[2], c[0], c[1], c[2], d[0], d[1],
                           d[2])
        for k in range(4):
            out_new[i, k] = r[k]
            out_ref[i, k] = q[k]


def _inputs(seed, n=200_000):
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((4 * n, 3))
    k = 4 * (n // 11)
    blocks = [X[j * k:(j + 1) * k] for j in range(11)]
    blocks[0][0::4] = blocks[0][1::4]  # a zero-length first segment / a point on a corner
    blocks[1][2::4] = blocks[1][3::4]  # a zero-length second segment / a degenerate triangle
    blocks[2][0::4] = 0.5 * (blocks[2][1::4] + blocks[2][2::4])  # a point on a segment
    blocks[3][:] = np.round(blocks[3], 1)  # a lattice: exact parallels, coplanar ties
    blocks[4] *= 1e-160  # tiny (products underflow)
    blocks[5] *= 1e150  # huge (products overflow)
    blocks[6][rng.random(blocks[6].shape) < 0.3] = -0.0  # signed zeros
    blocks[7][0::4] = blocks[7][2::4] + 1e-17  # near coincidence
    blocks[8][:, 2] = 0.0  # coplanar
    blocks[9][::37] = np.inf  # non-finite
    blocks[9][5::41, 1] = -np.inf
    blocks[9][11::43, 0] = np.nan
    # near the clamps: a point near the end of the other segment's line, scaled by 1 +- ulps
    m = blocks[10]
    m[0::4] = m[2::4] + (m[3::4] - m[2::4]) * (1.0 + rng.integers(-4, 5, (len(m) // 4, 1))
                                              * 2.0 ** -52)
    return X


def _bits_equal(a, b):
    return a.tobytes() == b.tobytes()


def test_edge_edge_distance_is_bitwise_the_division_first_kernel():
    for seed in (0, 1):
        X = _inputs(seed)
        n = len(X) // 4
        new, ref = np.empty((n, 3)), np.empty((n, 3))
        _all_ee(X, new, ref)
        assert _bits_equal(new, ref)
        # the cases the shortcut decides are common: most pairs of random segments
        assert np.count_nonzero((ref[:, 1] == 0.0) | (ref[:, 1] == 1.0)) > n // 2


def test_point_triangle_distance_is_bitwise_the_division_first_kernel():
    for seed in (2, 3):
        X = _inputs(seed)
        n = len(X) // 4
        new, ref = np.empty((n, 4)), np.empty((n, 4))
        _all_vf(X, new, ref)
        assert _bits_equal(new, ref)
        assert np.count_nonzero(np.min(ref[:, 1:], axis=1) == 0.0) > n // 2
