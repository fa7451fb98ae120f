"""Wind: the sum of all Wind elements sampled at every vertex into ``air_velocity`` [m/s]
(uniform, keyed, with smooth noise; kernel :func:`lokigraph.behaviors.air.kernels.wind_velocity`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lokigraph.behavior import Behavior
from lokigraph.components.air import Wind

from . import kernels as A


@dataclass
class _Wind:
    winds: list  # Wind components


class WindField(Behavior):
    """Samples the sum of all Wind elements at every vertex into ``air_velocity`` [m/s]."""

    stage = "forces"
    requires = (Wind,)
    accumulates = ("air_velocity",)

    def bind(self, ctx, elements):
        return _Wind([e.get(Wind) for e in elements])

    def init_state(self, model, state, data):
        state.accumulator("air_velocity", (model.particle_count, 3))
        state.fields["_wind_tmp"] = np.zeros((model.particle_count, 3))

    def step(self, ctx, data):
        u = ctx.state.fields["air_velocity"]
        tmp = ctx.state.fields["_wind_tmp"]
        t = ctx.time
        frame = ctx.model.fps * t + ctx.frame  # approximate key time (frames)
        for w in data.winds:  # loop over wind elements, not vertices
            speed, direction = w.speed, np.asarray(w.direction, dtype=np.float64)
            if w.keys:
                fr = [k.frame for k in w.keys]
                sp = [k.speed if k.speed is not None else w.speed for k in w.keys]
                speed = float(np.interp(frame, fr, sp))
                dirs = np.array([k.direction if k.direction is not None else w.direction
                                 for k in w.keys], dtype=np.float64)
                direction = np.array([np.interp(frame, fr, dirs[:, i]) for i in range(3)])
            A.wind_velocity(ctx.state.particle_q, t, direction, speed, w.noise, w.noise_scale,
                            w.seed, tmp)
            u += tmp
