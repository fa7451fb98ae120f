"""One-way fluid coupling: samples FluidDomain velocity grids at every vertex into
``air_velocity`` (read by drag and lift)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit, prange

from lokigraph.behavior import Behavior
from lokigraph.components.fluid import FluidDomain


@njit(cache=True, parallel=True)
def sample_grid(x, origin, size, grid, out):
    """Add the trilinear sample of ``grid`` (nx, ny, nz, 3) over the box to ``out`` (n, 3);
    points outside the box get nothing."""
    nx, ny, nz = grid.shape[0], grid.shape[1], grid.shape[2]
    for i in prange(x.shape[0]):
        u = (x[i, 0] - origin[0]) / size[0] * (nx - 1)
        v = (x[i, 1] - origin[1]) / size[1] * (ny - 1)
        w = (x[i, 2] - origin[2]) / size[2] * (nz - 1)
        if u < 0 or v < 0 or w < 0 or u > nx - 1 or v > ny - 1 or w > nz - 1:
            continue
        i0 = min(int(u), nx - 2) if nx > 1 else 0
        j0 = min(int(v), ny - 2) if ny > 1 else 0
        k0 = min(int(w), nz - 2) if nz > 1 else 0
        fu, fv, fw = u - i0, v - j0, w - k0
        for c in range(3):
            acc = 0.0
            for a in range(2):
                for b in range(2):
                    for d in range(2):
                        ii = min(i0 + a, nx - 1)
                        jj = min(j0 + b, ny - 1)
                        kk = min(k0 + d, nz - 1)
                        wt = ((fu if a else 1 - fu) * (fv if b else 1 - fv)
                              * (fw if d else 1 - fw))
                        acc += wt * grid[ii, jj, kk, c]
            out[i, c] += acc


@dataclass
class _Domains:
    items: list  # (origin, size, grids (nt, nx, ny, nz, 3), times)


class FluidCoupling(Behavior):
    """Samples every FluidDomain at the vertices into ``air_velocity`` (accumulated)."""

    stage = "forces"  # sampled before drag reads it (graph domain: coupling)
    requires = (FluidDomain,)
    accumulates = ("air_velocity",)

    def bind(self, ctx, elements):
        items = []
        for e in elements:
            c = e.get(FluidDomain)
            if c.file is None:
                g = np.tile(np.asarray(c.uniform, np.float64), (2, 2, 2, 1))[None]
                t = np.zeros(1)
            else:
                path = Path(e.base_dir) / c.file
                try:
                    data = np.load(path)
                    g = np.asarray(data["velocity"], np.float64)
                    t = np.asarray(data["times"], np.float64) if "times" in data else np.zeros(1)
                except (OSError, KeyError, ValueError) as exc:
                    ctx.error(e, "FluidDomain.file", f"cannot read velocity grid {path}: {exc}")
                    continue
                if g.ndim == 4:
                    g = g[None]
                if g.ndim != 5 or g.shape[-1] != 3 or len(t) != g.shape[0]:
                    ctx.error(e, "FluidDomain.file", f"velocity must be (nx, ny, nz, 3) or "
                              f"(nt, nx, ny, nz, 3) with matching times; got {g.shape}")
                    continue
                if not np.isfinite(g).all():
                    ctx.error(e, "FluidDomain.file", "velocity grid has non-finite values")
                    continue
            items.append((np.asarray(c.origin, np.float64), np.asarray(c.size, np.float64), g,
                          t))
        return _Domains(items)

    def init_state(self, model, state, data):
        state.accumulator("air_velocity", (model.particle_count, 3))

    def step(self, ctx, d):
        u = ctx.state.fields["air_velocity"]
        for origin, size, g, t in d.items:  # loop over domains, not vertices
            k = int(np.clip(np.searchsorted(t, ctx.time, side="right") - 1, 0, len(t) - 1))
            sample_grid(ctx.state.particle_q, origin, size, g[k], u)

    def describe(self, d):
        return f"{len(d.items)} fluid domains (one-way)"
