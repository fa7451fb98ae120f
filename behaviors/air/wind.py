"""Wind: the sum of all Wind elements sampled at every vertex into ``air_velocity`` [m/s]
(uniform, keyed, with smooth noise; kernel :func:`lokigraph.behaviors.air.kernels.wind_velocity`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lokigraph.behavior import Behavior
from lokigraph.components.air import Wind
from lokigraph.keys import Keyed, step_frame

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
        for w in data.winds:  # loop over wind elements, not vertices
            speed, direction = w.speed, w.direction
            if isinstance(speed, Keyed) or any(isinstance(c, Keyed) for c in direction):
                f = step_frame(ctx)  # keyed fields (lokigraph.keys): start of the substep
                speed = speed.evaluate(f) if isinstance(speed, Keyed) else speed
                direction = tuple(c.evaluate(f) if isinstance(c, Keyed) else c
                                  for c in direction)
            direction = np.asarray(direction, dtype=np.float64)
            if w.keys:  # the older list of keys (linear)
                frame = step_frame(ctx)  # the frame at the start of this substep
                fr = [k.frame for k in w.keys]
                sp = [k.speed if k.speed is not None else w.speed for k in w.keys]
                speed = float(np.interp(frame, fr, sp))
                dirs = np.array([k.direction if k.direction is not None else w.direction
                                 for k in w.keys], dtype=np.float64)
                direction = np.array([np.interp(frame, fr, dirs[:, i]) for i in range(3)])
            A.wind_velocity(ctx.state.particle_q, t, direction, speed, w.noise, w.noise_scale,
                            w.seed, tmp)
            u += tmp
