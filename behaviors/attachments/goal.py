"""Goals: attraction of vertices toward an animated target element, or soft pins to the initial
pose (painted stiffness)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from lokigraph.behavior import ConstraintBehavior
from lokigraph.component import resolve_paintable
from lokigraph.components.core import Dynamic
from lokigraph.components.materials import Goal

from ..solvers.nucleus.xpbd import PARALLEL_MIN_CONSTRAINTS, _INF, _LEN_EPS, _hot, residual


# ==============================================================================================
# XPBD kernels
# ==============================================================================================
@_hot
def _goal_one(j, p, w, index, target, alpha, lam, inv_h2):
    v = index[j]
    wv = w[v]
    if wv <= 0.0:
        return
    dx = p[v, 0] - target[j, 0]
    dy = p[v, 1] - target[j, 1]
    dz = p[v, 2] - target[j, 2]
    d = math.sqrt(dx * dx + dy * dy + dz * dz)
    if d < _LEN_EPS:
        return
    al = alpha[j]
    if not al < _INF:
        return
    at = al * inv_h2
    dl = (-d - at * lam[j]) / (wv + at)
    lam[j] += dl
    f = wv * dl / d
    p[v, 0] += f * dx
    p[v, 1] += f * dy
    p[v, 2] += f * dz


@njit(cache=True, parallel=True)
def project_goal(p, w, index, target, alpha, lam, h):
    """Goal attraction / soft pin ``C = |p_v - g|``, parallel over entries.

    index (m,) int64 vertex of each entry, unique (two entries on one vertex would race);
    target g [m] (m, 3); alpha compliance [m/N] (m,) (0: hard pin to g); lam (m,). A zero-rest
    spring to a moving target: the pull is isotropic. Not momentum conserving (external).
    """
    inv_h2 = 1.0 / (h * h)
    for j in prange(index.shape[0]):
        _goal_one(j, p, w, index, target, alpha, lam, inv_h2)


@njit(cache=True)
def project_goal_seq(p, w, index, target, alpha, lam, h):
    """Sequential variant of ``project_goal`` (repeated indices allowed)."""
    inv_h2 = 1.0 / (h * h)
    for j in range(index.shape[0]):
        _goal_one(j, p, w, index, target, alpha, lam, inv_h2)


@njit(cache=True)
def goal_values(p, index, target):
    """C = |p_v - g| [m] per entry, shape (m,)."""
    out = np.empty(index.shape[0])
    for j in range(index.shape[0]):
        d = 0.0
        for k in range(3):
            t = p[index[j], k] - target[j, k]
            d += t * t
        out[j] = math.sqrt(d)
    return out


def residual_goal(p, index, target):
    """(max |C| [m], RMS [m]) of the goal constraints."""
    return residual(goal_values(p, index, target))


# ------------------------------------------------------------------ Nucleus constraint behavior


@dataclass
class _Goal:
    idx: np.ndarray
    target_idx: np.ndarray  # global index of the goal vertex, or -1 for a fixed target
    target: np.ndarray  # (m, 3) goal positions (updated per substep for animated targets)
    alpha: np.ndarray
    lam: np.ndarray


class GoalConstraint(ConstraintBehavior):
    """Goal attraction toward an animated target element, or soft pins to the initial pose."""

    requires = (Dynamic, Goal)
    default_importance = 1.0
    default_order = 35

    def bind(self, ctx, elements):
        idx, tidx, alpha = [], [], []
        scene = ctx.scene
        for e in elements:
            c = e.get(Goal)
            k = resolve_paintable(c.stiffness, e, "Goal.stiffness")
            if np.any(k < 0):
                ctx.error(e, "Goal.stiffness", "must be >= 0")
                continue
            on = np.flatnonzero(k > 0)
            if c.target is not None:
                try:
                    t = scene.element(c.target)
                except KeyError:
                    ctx.error(e, "Goal.target", f"no element named {c.target!r}")
                    continue
                if t.vertex_count != e.vertex_count:
                    ctx.error(e, "Goal.target", f"target {c.target!r} has {t.vertex_count} "
                              f"vertices, this element has {e.vertex_count}")
                    continue
                tidx.append(on + t.vertex_offset)
            else:
                tidx.append(np.full(len(on), -1))
            idx.append(on + e.vertex_offset)
            alpha.append(1.0 / k[on])
        if not idx or not sum(len(i) for i in idx):
            return None
        idx = np.concatenate(idx).astype(np.int64)
        tidx = np.concatenate(tidx).astype(np.int64)
        target = ctx.model.particle_q0[idx].copy()
        return _Goal(idx, tidx, target, np.concatenate(alpha), np.zeros(len(idx)))

    def begin_substep(self, ctx, d):
        d.lam[:] = 0.0
        anim = d.target_idx >= 0
        if anim.any():
            d.target[anim] = ctx.control.kinematic_q[d.target_idx[anim]]

    def project(self, ctx, d, p):
        fn = project_goal_seq if len(d.idx) < PARALLEL_MIN_CONSTRAINTS else project_goal
        fn(p, ctx.model.particle_inv_mass, d.idx, d.target, d.alpha, d.lam, ctx.dt)

    def residual(self, ctx, d, p):
        return float(residual_goal(p, d.idx, d.target)[0])

    def describe(self, d):
        return f"{len(d.idx)} goal vertices" if d is not None else ""


# ==============================================================================================
# Implicit energy (behaviors/solvers/implicit/energy.py has the protocol)
# ==============================================================================================
from ..solvers.implicit.energy import grad_or_dummy, hess_or_dummy, row_k  # noqa: E402


@njit(cache=True)
def goal_energy(x, index, target, alpha, hard_k, mode, grad, hess):
    """Goal / soft-pin energy ``k |x_v - g|^2 / 2`` (``k = 1 / alpha``; the hard penalty when
    alpha is 0). Gradient and Hessian ``k I`` exact."""
    E = 0.0
    for j in range(index.shape[0]):
        v = index[j]
        k = row_k(alpha[j], hard_k, v, v)
        if k == 0.0:
            continue
        for r in range(3):
            dr = x[v, r] - target[j, r]
            E += 0.5 * k * dr * dr
            if mode >= 1:
                grad[v, r] += k * dr
            if mode >= 2:
                hess[j, 0, 0, r, r] = k
    return E


def _goal_energy_stencils(self, ctx, d):
    return [d.idx.reshape(-1, 1)]


def _goal_energy(self, ctx, d, x, grad, hess, opts):
    # animated targets are refreshed by begin_substep (the solver calls it every substep)
    return goal_energy(x, d.idx, d.target, d.alpha, opts.hard_k, opts.mode,
                       grad_or_dummy(grad, opts), hess_or_dummy(hess, 0, opts))


# the implicit energy protocol on the Nucleus constraint type of this effect
GoalConstraint.energy_stencils = _goal_energy_stencils
GoalConstraint.energy = _goal_energy
