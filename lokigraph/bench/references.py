"""Independent truth for ``lokigraph bench``: closed forms, exact discrete solutions, BVP solves.

A bench scene names its reference in a top-level ``reference:`` block (``run`` ignores it)::

    reference: {kind: catenary, element: chain}

Every reference takes its parameters from the scene itself (gravity, masses, pins, stiffness,
drag), so a wrong parameter mapping in the simulator shows up as an error instead of being copied
into the truth. Each function returns ``(indices, positions)``: the vertices compared and where
they should be at time ``t``. None of them runs the simulator.

=================== ====================================================================
kind                truth
=================== ====================================================================
free_fall           x0 + v0 t + g t^2 / 2 (every free dynamic vertex; a projectile when
                    the element has an initial velocity)
spring              undamped oscillator about the RestSpring anchor, cos/sin in closed form
                    (``exact_discrete_spring`` gives the symplectic Euler recurrence's own
                    closed form, Nucleus section 4.2)
catenary            static equilibrium of an inextensible chain of point masses pinned at
                    both ends (discrete catenary: constant horizontal tension, link slopes
                    grow by m_k g / H), solved to 1e-13
elastica            static heavy cantilever (clamped root, free tip) of a Rod: the elastica
                    EI theta'' = -q (L - s) cos theta by scipy ``solve_bvp`` at tol 1e-10
terminal_velocity   falling patch with isotropic linear drag c: v_t = rho g / c,
                    y = y0 - v_t (t - tau (1 - exp(-t / tau))), tau = rho / c
stored              positions in ``file`` (.npy next to the scene) computed once at the
                    tight ``settings`` (``lokigraph bench SCENE --make-reference``)
=================== ====================================================================
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

KINDS = ("free_fall", "spring", "catenary", "elastica", "terminal_velocity", "stored")


def _element(compiled, name):
    scene = compiled.scene
    if name is None:
        dyn = [e for e in scene.elements if "Dynamic" in e.components]
        if len(dyn) != 1:
            raise ValueError("reference: name the element (the scene has several dynamic ones)")
        return dyn[0]
    return scene.element(name)


def _free(compiled, el):
    sl = el.vertex_slice
    idx = np.arange(sl.start, sl.stop)
    return idx[compiled.model.particle_inv_mass[idx] > 0]


def free_fall(compiled, spec, t):
    m = compiled.model
    if spec.element is None:  # every free vertex of the scene
        idx = np.flatnonzero(m.particle_inv_mass > 0)
    else:
        idx = _free(compiled, _element(compiled, spec.element))
    g = np.asarray(compiled.scene.spec.gravity, dtype=np.float64)
    return idx, m.particle_q0[idx] + m.particle_qd0[idx] * t + 0.5 * g * t * t


def _spring_params(compiled, el):
    rs = el.components["RestSpring"]
    if not isinstance(rs.stiffness, (int, float)):
        raise ValueError("reference spring: RestSpring.stiffness must be a number")
    idx = _free(compiled, el)
    m = compiled.model
    w = np.sqrt(float(rs.stiffness) / m.particle_mass[idx])
    a = m.particle_rest[idx] if rs.anchor is None else np.asarray(rs.anchor, dtype=np.float64)
    return idx, w[:, None], a


def spring(compiled, spec, t):
    el = _element(compiled, spec.element)
    idx, w, a = _spring_params(compiled, el)
    m = compiled.model
    d0, v0 = m.particle_q0[idx] - a, m.particle_qd0[idx]
    return idx, a + d0 * np.cos(w * t) + v0 / w * np.sin(w * t)


def exact_discrete_spring(compiled, spec, h, n):
    """The closed form of symplectic Euler on the spring after n steps of size h (h w < 2).

    v_{k+1} = v_k - h w^2 (x_k - a), x_{k+1} = x_k + h v_{k+1} has x_k - a = A cos(k th) +
    B sin(k th) with cos th = 1 - (h w)^2 / 2.
    """
    el = _element(compiled, spec.element)
    idx, w, a = _spring_params(compiled, el)
    m = compiled.model
    d0, v0 = m.particle_q0[idx] - a, m.particle_qd0[idx]
    th = np.arccos(1.0 - 0.5 * (h * w) ** 2)
    d1 = d0 + h * (v0 - h * w * w * d0)
    B = (d1 - d0 * np.cos(th)) / np.sin(th)
    return idx, a + d0 * np.cos(n * th) + B * np.sin(n * th)


def _chain_order(el):
    """Vertex order along a single open polyline element."""
    e = el.geometry.edges
    n = el.vertex_count
    deg = np.bincount(e.ravel(), minlength=n)
    if len(e) != n - 1 or deg.max() > 2:
        raise ValueError("reference catenary: the element must be one open polyline")
    nbr = [[] for _ in range(n)]
    for a, b in e.tolist():  # compile-time topology walk, not a hot path
        nbr[a].append(b)
        nbr[b].append(a)
    order = [int(np.flatnonzero(deg == 1)[0])]
    prev = -1
    while len(order) < n:
        nxt = [v for v in nbr[order[-1]] if v != prev][0]
        prev = order[-1]
        order.append(nxt)
    return np.array(order)


def catenary(compiled, spec, t):
    from scipy.optimize import least_squares

    el = _element(compiled, spec.element)
    order = _chain_order(el) + el.vertex_offset
    m = compiled.model
    inv = m.particle_inv_mass[order]
    if inv[0] != 0 or inv[-1] != 0 or (inv[1:-1] == 0).any():
        raise ValueError("reference catenary: pin both ends and nothing else")
    rest = m.particle_rest[order]
    lengths = np.linalg.norm(np.diff(rest, axis=0), axis=1)
    g = np.asarray(compiled.scene.spec.gravity, dtype=np.float64)
    gn = np.linalg.norm(g)
    down = g / gn
    p0, p1 = m.particle_q0[order[0]], m.particle_q0[order[-1]]
    span = p1 - p0
    horiz = span - down * (span @ down)
    dh = np.linalg.norm(horiz)
    ex = horiz / dh
    dv = -(span @ down)  # rise of the far end
    w = m.particle_mass[order[1:-1]] * gn  # interior node weights

    def slopes(s0, H):
        return s0 + np.concatenate([[0.0], np.cumsum(w)]) / H  # s_{k+1} = s_k + w_k / H

    def resid(p):
        s = slopes(p[0], np.exp(p[1]))
        c = 1.0 / np.sqrt(1.0 + s * s)
        return [np.sum(lengths * c) - dh, np.sum(lengths * s * c) - dv]

    total_w = w.sum()
    sol = least_squares(resid, [-0.5, np.log(total_w)], xtol=1e-15,
                        ftol=1e-15, gtol=1e-15)
    s = slopes(sol.x[0], np.exp(sol.x[1]))
    c = 1.0 / np.sqrt(1.0 + s * s)
    steps = lengths[:, None] * (c[:, None] * ex - (s * c)[:, None] * down)
    pos = p0 + np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])
    return order[1:-1], pos[1:-1]


def elastica_curve(L, q, EI, s_eval, tol=1e-10):
    """Heavy cantilever: (x(s), y(s)) in the plane (x along the clamp, y up) at arclengths s.

    EI theta'' = -q (L - s) cos theta, theta(0) = 0 (clamped), theta'(L) = 0 (free tip), theta
    the angle below the clamp direction; solved with scipy's collocation BVP solver.
    """
    from scipy.integrate import solve_bvp

    def f(s, y):
        th, k, x, z = y
        return np.vstack([k, -q * (L - s) * np.cos(th) / EI, np.cos(th), -np.sin(th)])

    def bc(ya, yb):
        return np.array([ya[0], yb[1], ya[2], ya[3]])

    s = np.linspace(0.0, L, 201)
    guess = np.vstack([np.zeros_like(s), np.zeros_like(s), s, np.zeros_like(s)])
    sol = solve_bvp(f, bc, s, guess, tol=tol, max_nodes=200000)
    if not sol.success:
        raise RuntimeError(f"elastica BVP did not converge: {sol.message}")
    y = sol.sol(s_eval)
    return y[2], y[3]


def elastica(compiled, spec, t):
    el = _element(compiled, spec.element)
    rod = el.components["Rod"]
    order = _chain_order(el)
    if order[0] != 0:
        order = order[::-1]
    gidx = order + el.vertex_offset
    m = compiled.model
    inv = m.particle_inv_mass[gidx]
    if inv[0] != 0 or inv[1] != 0 or (inv[2:] == 0).any():
        raise ValueError("reference elastica: pin the first two vertices (the clamp) only")
    rest = m.particle_rest[gidx]
    seg = np.linalg.norm(np.diff(rest, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    L = s[-1]
    EI = rod.bend_resistance
    if EI is None:
        EI = rod.youngs_modulus * np.pi * rod.radius ** 4 / 4.0
    gn = np.linalg.norm(compiled.scene.spec.gravity)
    q = m.particle_mass[gidx].sum() * gn / L  # weight per length
    x, y = elastica_curve(L, q, EI, s)
    q0 = m.particle_q0[gidx]
    ex = (q0[1] - q0[0]) / np.linalg.norm(q0[1] - q0[0])
    up = -np.asarray(compiled.scene.spec.gravity, dtype=np.float64) / gn
    pos = q0[0] + x[:, None] * ex + y[:, None] * up
    return gidx[2:], pos[2:]


def terminal_velocity(compiled, spec, t):
    el = _element(compiled, spec.element)
    drag = el.components["Drag"]
    dyn = el.components["Dynamic"]
    if drag.model != "linear" or not isinstance(drag.coefficient, (int, float)) \
            or not isinstance(dyn.mass_density, (int, float)) or dyn.point_mass is not None:
        raise ValueError("reference terminal_velocity: linear Drag and Dynamic.mass_density "
                         "must be numbers")
    tau = float(dyn.mass_density) / float(drag.coefficient)
    g = np.asarray(compiled.scene.spec.gravity, dtype=np.float64)
    idx = _free(compiled, el)
    m = compiled.model
    v0 = m.particle_qd0[idx]
    # dv/dt = g - v / tau: v = g tau + (v0 - g tau) e^{-t/tau}
    disp = g * tau * t + (v0 - g * tau) * tau * (1.0 - np.exp(-t / tau))
    return idx, m.particle_q0[idx] + disp


def stored(compiled, spec, t):
    path = Path(compiled.scene.base_dir) / spec.file
    if not path.exists():
        raise FileNotFoundError(f"{path}: no stored reference; make it with `lokigraph bench "
                                f"{compiled.scene.file} --make-reference`")
    arr = np.load(path)
    if arr.shape != compiled.model.particle_q0.shape:
        raise ValueError(f"{path}: shape {arr.shape} does not match the scene "
                         f"{compiled.model.particle_q0.shape}")
    idx = np.flatnonzero(compiled.model.particle_inv_mass > 0)
    return idx, arr[idx]


FUNCTIONS = {"free_fall": free_fall, "spring": spring, "catenary": catenary,
             "elastica": elastica, "terminal_velocity": terminal_velocity, "stored": stored}


def capstan_limit(P, m, a0, a1, mu, g=9.81):
    """Largest tension ratio T1 / T2 a discrete rope on a drum holds: ``P`` (n, 3) vertex
    positions with the drum's axis along z through the origin, ``m`` vertex masses [kg],
    vertices ``a0 .. a1`` on the drum, the part beyond ``a1`` hanging free (T2 = its weight).
    Marches over the arc vertices from a1 to a0, each at its friction limit mu N against a
    slip toward index 0, with its own weight (the discrete form of exp(mu theta))."""
    T2 = g * float(np.sum(m[a1 + 1:]))
    t = T2
    for i in range(a1, a0 - 1, -1):
        t_out = (P[i + 1] - P[i])[:2] / np.linalg.norm(P[i + 1] - P[i])
        t_in = (P[i - 1] - P[i])[:2] / np.linalg.norm(P[i - 1] - P[i])
        nrm = P[i, :2] / np.linalg.norm(P[i, :2])
        tan = np.array([-nrm[1], nrm[0]])
        if tan @ t_out < 0:
            tan = -tan
        A = np.stack([t_in, nrm + mu * tan], 1)
        t, _n = np.linalg.solve(A, -(t * t_out + np.array([0.0, -m[i] * g])))
    return t / T2


def evaluate(compiled, spec, t):
    """(indices, positions) of the reference named by ``spec`` (the scene's ``reference``)."""
    return FUNCTIONS[spec.kind](compiled, spec, t)
