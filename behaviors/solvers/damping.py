"""Velocity damping shared by the solvers: ``Dynamic.damping`` [1/s] per vertex, constant or
keyed (:mod:`lokigraph.keys`, evaluated every substep), applied to the old velocity as
``v *= exp(-damping * h)`` before forces (damping the force increment instead would bias static
equilibria)."""

from __future__ import annotations

import numpy as np

from lokigraph.components.core import Dynamic
from lokigraph.keys import Keyed, step_frame


def bind_damping(model, elements) -> tuple[np.ndarray, list]:
    """Per-vertex damping rates [1/s] (n,) and the keyed ones as (vertex slice, Keyed)."""
    rate = np.zeros(model.particle_count)
    keyed = []
    for e in elements:
        d = e.get(Dynamic).damping
        if isinstance(d, Keyed):
            keyed.append((e.vertex_slice, d))
        else:
            rate[e.vertex_slice] = d
    return rate, keyed


def apply_damping(ctx, v: np.ndarray, rate: np.ndarray, keyed: list) -> None:
    """Write this substep's keyed rates into ``rate`` and damp ``v`` in place."""
    if keyed:
        f = step_frame(ctx)
        for sl, key in keyed:
            rate[sl] = key.evaluate(f)
    if rate.any():
        v *= np.exp(-rate * ctx.dt)[:, None]
