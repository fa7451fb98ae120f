"""The z-buffer rasteriser of :mod:`lokigraph.preview` (numba; compiled once, cached on disk).

Imported only when a preview is drawn."""

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def raster_triangles(xy, iz, tris, ccol, img, zb):
    """Fill triangles with a depth test. xy: (n, 2) pixel coordinates (x right, y down);
    iz: (n,) inverse depth (larger is nearer); ccol: (T, 3, 3) corner colours,
    interpolated perspective-correctly."""
    H, W = zb.shape
    for t in range(tris.shape[0]):
        i0, i1, i2 = tris[t, 0], tris[t, 1], tris[t, 2]
        x0, y0, x1, y1, x2, y2 = xy[i0, 0], xy[i0, 1], xy[i1, 0], xy[i1, 1], xy[i2, 0], \
            xy[i2, 1]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if abs(area) < 1e-12:
            continue
        inv = 1.0 / area
        xmin = max(int(np.floor(min(x0, x1, x2))), 0)
        xmax = min(int(np.ceil(max(x0, x1, x2))), W - 1)
        ymin = max(int(np.floor(min(y0, y1, y2))), 0)
        ymax = min(int(np.ceil(max(y0, y1, y2))), H - 1)
        z0, z1, z2 = iz[i0], iz[i1], iz[i2]
        for py in range(ymin, ymax + 1):
            sy = py + 0.5
            for px in range(xmin, xmax + 1):
                sx = px + 0.5
                w0 = ((x1 - sx) * (y2 - sy) - (x2 - sx) * (y1 - sy)) * inv
                w1 = ((x2 - sx) * (y0 - sy) - (x0 - sx) * (y2 - sy)) * inv
                w2 = 1.0 - w0 - w1
                if w0 < -1e-9 or w1 < -1e-9 or w2 < -1e-9:
                    continue
                z = w0 * z0 + w1 * z1 + w2 * z2
                if z <= zb[py, px]:
                    continue
                zb[py, px] = z
                a0, a1, a2 = w0 * z0 / z, w1 * z1 / z, w2 * z2 / z
                for c in range(3):
                    img[py, px, c] = a0 * ccol[t, 0, c] + a1 * ccol[t, 1, c] + \
                        a2 * ccol[t, 2, c]

@numba.njit(cache=True, nogil=True)
def raster_segments(xy, iz, segs, scol, rad, img, zb):
    """Draw segments as round-capped strokes of radius ``rad`` pixels with a depth test."""
    H, W = zb.shape
    r2 = rad * rad
    for s in range(segs.shape[0]):
        a, b = segs[s, 0], segs[s, 1]
        xa, ya, xb, yb = xy[a, 0], xy[a, 1], xy[b, 0], xy[b, 1]
        dx, dy = xb - xa, yb - ya
        n = int(np.sqrt(dx * dx + dy * dy) * 2.0) + 1
        for k in range(n + 1):
            f = k / n
            x, y = xa + f * dx, ya + f * dy
            z = iz[a] + f * (iz[b] - iz[a])
            for py in range(max(int(y - rad), 0), min(int(y + rad) + 1, H)):
                for px in range(max(int(x - rad), 0), min(int(x + rad) + 1, W)):
                    ex, ey = px + 0.5 - x, py + 0.5 - y
                    if ex * ex + ey * ey > r2 or z <= zb[py, px]:
                        continue
                    zb[py, px] = z
                    for c in range(3):
                        img[py, px, c] = scol[s, c]
