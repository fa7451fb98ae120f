"""The Nucleus solver (Stam 2009): symplectic Euler + interleaved Gauss-Seidel constraints.

Per substep of size h:

1. v += h M^-1 f (forces accumulated by the force stage), implicit drag if present,
   velocity damping;
2. predicted positions p = x + h v; kinematic vertices take their animated pose;
3. every constraint type projects p, interleaved: type k runs ceil(importance_k * iterations)
   times, spread evenly over the iterations, ordered by ``order`` inside an iteration, and every
   type runs in the final iteration (Nucleus section 6, Figure 11);
4. v = (p - x) / h, x = p.

With no constraints this is exactly symplectic Euler (Nucleus section 4.2).

References: J. Stam, "Nucleus: Towards a Unified Dynamics Solver for Computer Graphics",
IEEE CAD/Graphics 2009. Compliance (XPBD) for resolution- and substep-independent stiffness:
Macklin, Mueller, Chentanez, "XPBD", MIG 2016.

Limitations: Gauss-Seidel converges slowly for long chains at few iterations (use more
iterations or substeps; ``lokigraph bench`` measures the trade-off).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pydantic import Field

from lokigraph.behavior import Behavior, Params
from lokigraph.components.core import Dynamic

from ...air.kernels import implicit_drag_update_inv_mass
from ..damping import apply_damping, bind_damping


#: plain iterations before the Chebyshev acceleration starts (Wang 2015 uses a short delay)
_CHEB_DELAY = 3


class NucleusParams(Params):
    iterations: int = Field(15, ge=1, le=10000, description="Constraint iterations per substep "
                            "(default 15: a 64x64 cloth hanging from two corners holds 1 % "
                            "strain at rest; measured 0.74 %).")
    interleave: bool = Field(True, description="Interleave constraint types across iterations "
                             "(Nucleus Figure 11); false runs each type's passes back to back "
                             "in order (Figure 9), for comparison.")
    chebyshev_rho: float = Field(0.0, ge=0.0, lt=1.0, description="Chebyshev semi-iterative "
                                 "acceleration of the constraint iterations (Wang 2015): an "
                                 "estimate of the iteration's spectral radius [-]; 0 = off "
                                 "(default). Measured at 0.9, worst-frame edge strain over 24 "
                                 "frames, off -> on, same cost: cloth_pinned 10.2 -> 5.2 %, "
                                 "flag_wind 17.1 -> 11.7 %, skirt_follow 3.7 -> 1.4 %, "
                                 "sleeve_pinch 13.7 -> 6.0 %, cloth_on_sphere 184 -> 100 %. Off "
                                 "by default: with it on, a 20 m/s ball shot into a pinned "
                                 "cloth at one substep slides the cloth off itself (cause not "
                                 "found). Too high a value oscillates.")


def interleave_plan(types: list[tuple[str, float, int]], iterations: int,
                    interleave: bool = True) -> list[list[int]]:
    """Which constraint types run in each iteration.

    ``types``: (name, importance in (0, 1], order). Type k runs ceil(importance * iterations)
    times, spread evenly; all types run in the last iteration; inside an iteration types are
    sorted by (order, name). Returns, per iteration, the list of type indices.
    """
    n = int(iterations)
    ranked = sorted(range(len(types)), key=lambda i: (types[i][2], types[i][0]))
    counts = [max(1, min(n, math.ceil(types[i][1] * n - 1e-9))) for i in range(len(types))]
    if not interleave:  # Figure 9: all passes of a type, then the next type
        return [[i] for i in ranked for _ in range(counts[i])]
    plan = []
    for s in range(1, n + 1):
        slot = [i for i in ranked if (s * counts[i]) // n > ((s - 1) * counts[i]) // n]
        plan.append(slot)
    return plan


@dataclass
class _NucleusData:
    damp_rate: np.ndarray  # per vertex [1/s]
    dynamic: np.ndarray  # global indices of dynamic vertices
    kinematic: np.ndarray  # global indices of kinematic vertices
    p: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # scratch, allocated once
    #: Chebyshev acceleration scratch (iterate before the last and before this iteration)
    cheb_prev: np.ndarray | None = None
    cheb_before: np.ndarray | None = None
    plan: list | None = None
    #: keyed Dynamic.damping: (vertex slice, Keyed), written into damp_rate every substep
    keyed_damping: list = field(default_factory=list)


class NucleusSolver(Behavior):
    """Symplectic Euler with interleaved constraint projection (see module docstring)."""

    stage = "solve"
    solver = "nucleus"
    requires = (Dynamic,)
    reads_optional = ("particle_f", "constraints", "kinematic_q", "drag")
    writes = ("particle_q", "particle_qd")
    ParamsModel = NucleusParams

    def bind(self, ctx, elements):
        m = ctx.model
        damp, keyed = bind_damping(m, elements)
        data = _NucleusData(damp, np.flatnonzero(~m.particle_kinematic),
                            np.flatnonzero(m.particle_kinematic),
                            np.zeros((m.particle_count, 3)), keyed_damping=keyed)
        if self.params.chebyshev_rho > 0:
            data.cheb_prev = np.zeros((m.particle_count, 3))
            data.cheb_before = np.zeros((m.particle_count, 3))
        return data

    def step(self, ctx, data):
        m, st, ctl = ctx.model, ctx.state, ctx.control
        h = ctx.dt
        x, v = st.particle_q, st.particle_qd
        apply_damping(ctx, v, data.damp_rate, data.keyed_damping)
        v += (h * m.particle_inv_mass)[:, None] * st.particle_f
        D = st.fields.get("drag_D")
        if D is not None:  # implicit drag: (M + h D) v' = M v + h D u   (per vertex, 3x3)
            implicit_drag_update_inv_mass(v, m.particle_inv_mass, D, st.fields["drag_u"], h)
        p = data.p
        np.multiply(v, h, out=p)
        p += x
        kin = data.kinematic
        if len(kin):
            p[kin] = ctl.kinematic_q[kin]
        cons = ctx.constraints
        if cons:
            if data.plan is None:
                data.plan = interleave_plan([(b.name, b.params.importance, b.params.order)
                                             for b, _ in cons], self.params.iterations,
                                            self.params.interleave)
            for b, d in cons:
                b.begin_substep(ctx, d)
            if data.cheb_prev is None:
                for slot in data.plan:
                    for i in slot:
                        b, d = cons[i]
                        b.project(ctx, d, p)
            else:
                self._iterate_chebyshev(ctx, data, p, cons)
            for b, d in cons:
                b.finalize(ctx, d, p)
            for b, d in cons:
                if hasattr(b, "after_finalize"):
                    b.after_finalize(ctx, d, p)
        np.subtract(p, x, out=v)
        v *= 1.0 / h
        x[:] = p

    def _iterate_chebyshev(self, ctx, data, p, cons):
        """The interleaved iterations with Chebyshev semi-iterative acceleration (Wang 2015,
        "A Chebyshev Semi-Iterative Approach for Accelerating Projective and Position-based
        Dynamics"): after iteration k the iterate is over-relaxed against the one before the
        last, p = w_k (p - p_{k-2}) + p_{k-2}, with w from the spectral radius estimate rho,
        starting after a few plain iterations and skipping the final pass (every type runs
        there, and collisions must have the last word). Pinned/kinematic vertices are restored
        by the projections themselves (w = 0 vertices are never written)."""
        rho2 = self.params.chebyshev_rho ** 2
        prev, before = data.cheb_prev, data.cheb_before
        dyn = ctx.model.particle_inv_mass > 0.0
        prev[:] = p
        omega = 1.0
        last = len(data.plan) - 1
        for k, slot in enumerate(data.plan):
            before[:] = p
            for i in slot:
                b, d = cons[i]
                b.project(ctx, d, p)
            if k >= _CHEB_DELAY and k < last:
                omega = (2.0 / (2.0 - rho2) if k == _CHEB_DELAY
                         else 4.0 / (4.0 - rho2 * omega))
                p[dyn] = omega * (p[dyn] - prev[dyn]) + prev[dyn]
            prev, before = before, prev
        data.cheb_prev, data.cheb_before = prev, before

    def describe(self, data):
        return (f"iterations {self.params.iterations}, {len(data.dynamic)} dynamic / "
                f"{len(data.kinematic)} kinematic vertices")
