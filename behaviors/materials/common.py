"""Packing shared by the constraint behaviors: an element's rest positions (``_rest``), coloured
constraint rows with their parameters (:class:`Packed`) and the concatenation of per-element row
sets (``_concat``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import topology as T
from ..solvers.nucleus.xpbd import PARALLEL_MIN_CONSTRAINTS


def _rest(ctx, e, comp) -> np.ndarray:
    """Rest positions of an element (local), from the component's rest channel if any."""
    ch = getattr(comp, "rest_channel", None)
    if ch:
        if ch not in e.channels:
            ctx.error(e, f"{type(comp).__name__}.rest_channel", f"no channel named {ch!r}")
            return e.geometry.points
        r = np.asarray(e.channels[ch], dtype=np.float64)
        if r.shape != (e.vertex_count, 3):
            ctx.error(e, f"{type(comp).__name__}.rest_channel",
                      f"channel {ch!r} has shape {r.shape}, expected ({e.vertex_count}, 3)")
            return e.geometry.points
        return r
    return ctx.model.particle_rest[e.vertex_slice]


@dataclass
class Packed:
    """Coloured constraint rows (global vertex indices) and their parameters."""

    idx: np.ndarray  # (m, k) int64
    rest: np.ndarray  # (m,)
    alpha: np.ndarray  # (m,) compliance
    alpha2: np.ndarray  # (m,) second compliance (compression) or dropoff
    lam: np.ndarray  # (m,)
    color_ptr: np.ndarray
    sequential: bool = False
    beta: np.ndarray | None = None  # stretch damping
    perm: np.ndarray | None = None  # row i is row perm[i] of the rows given to ``build``

    @classmethod
    def build(cls, idx, rest, alpha, alpha2=None, beta=None, sequential=None):
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        if sequential is None:
            sequential = len(idx) < PARALLEL_MIN_CONSTRAINTS
        perm, ptr = T.color_constraints(idx, vertex_count=int(idx.max()) + 1 if len(idx) else 0)
        a2 = alpha2 if alpha2 is not None else np.zeros(len(idx))
        return cls(np.ascontiguousarray(idx[perm]), np.ascontiguousarray(rest[perm]),
                   np.ascontiguousarray(alpha[perm]), np.ascontiguousarray(a2[perm]),
                   np.zeros(len(idx)), ptr, sequential,
                   None if beta is None else np.ascontiguousarray(beta[perm]), perm)

    def __len__(self):
        return len(self.idx)


def _concat(parts):
    parts = [p for p in parts if p is not None and len(p[0])]
    if not parts:
        return None
    return [np.concatenate([p[k] for p in parts]) for k in range(len(parts[0]))]
