"""Stitches and welds between two elements: zero-length distance constraints, projected by the
edge kernels of :mod:`lokigraph.behaviors.materials.stretch`."""

from __future__ import annotations

import numpy as np

from lokigraph.behavior import ConstraintBehavior
from lokigraph.components.materials import Stitch

from ..materials.common import Packed, _concat
from ..materials.stretch import _project_edges, residual_stretch


class StitchConstraint(ConstraintBehavior):
    """Stitches and welds between two elements: zero-length distance constraints."""

    requires = (Stitch,)
    default_importance = 1.0
    default_order = 31

    def bind(self, ctx, elements):
        parts = []
        for e in elements:
            c = e.get(Stitch)
            try:
                a, b = ctx.scene.element(c.a), ctx.scene.element(c.b)
            except KeyError as exc:
                ctx.error(e, "Stitch", f"no element named {exc.args[0]!r}")
                continue
            pairs = np.asarray(c.pairs, dtype=np.int64).reshape(-1, 2)
            if c.weld_distance is not None:
                from scipy.spatial import cKDTree

                qa = a.geometry.points
                qb = b.geometry.points
                res = cKDTree(qb).query(qa, distance_upper_bound=c.weld_distance)
                ok = np.isfinite(res[0])
                pairs = np.vstack([pairs, np.column_stack([np.flatnonzero(ok), res[1][ok]])])
            if len(pairs) and (pairs[:, 0].max() >= a.vertex_count
                               or pairs[:, 1].max() >= b.vertex_count or pairs.min() < 0):
                ctx.error(e, "Stitch.pairs", "vertex index out of range")
                continue
            g = np.column_stack([pairs[:, 0] + a.vertex_offset, pairs[:, 1] + b.vertex_offset])
            al = np.full(len(g), 0.0 if c.stiffness is None else 1.0 / c.stiffness)
            parts.append((g, np.zeros(len(g)), al, al))
        cat = _concat(parts)
        return None if cat is None else Packed.build(*cat)

    def project(self, ctx, d, p):
        _project_edges(ctx, d, p)

    def residual(self, ctx, d, p):
        return float(residual_stretch(p, d.idx, d.rest)[0])

    def describe(self, d):
        return f"{len(d)} stitches" if d is not None else ""


# ==============================================================================================
# Implicit energy: a stitch is a zero-rest spring (a weld a hard penalty), the stretch module's
# spring energy (lokigraph.behaviors.materials.stretch.spring_energy)
# ==============================================================================================
from ..materials.stretch import (edge_energy, edge_energy_stencils,  # noqa: E402
                                 edge_load_state_arrays, edge_multipliers, edge_state_arrays,
                                 edge_update_multipliers)

StitchConstraint.energy_stencils = edge_energy_stencils
StitchConstraint.energy = edge_energy
StitchConstraint.energy_update_multipliers = edge_update_multipliers
StitchConstraint.energy_multipliers = edge_multipliers
StitchConstraint.state_arrays = edge_state_arrays
StitchConstraint.load_state_arrays = edge_load_state_arrays
