"""Air drag and lift (Nucleus section 5; Avatar supplement section 2).

Drag is never an explicit force: this behavior accumulates per-vertex 3x3 drag matrices D and the
solver applies ``(M + h D) v' = M v + h D u`` after the explicit force update (unconditionally
stable; in still air it never adds kinetic energy). Lift is an explicit force orthogonal to the
relative velocity.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lokigraph.behavior import Behavior
from lokigraph.component import resolve_paintable
from lokigraph.components.air import Drag
from lokigraph.components.core import Dynamic
from lokigraph.geometry import vertex_measure
from lokigraph.keys import Keyed, step_frame

from . import kernels as A


@dataclass
class _Drag:
    iso: np.ndarray  # (n,) isotropic coefficient per vertex [kg/s]
    faces: np.ndarray
    face_cn: np.ndarray
    face_ct: np.ndarray
    face_ergun: np.ndarray  # (F, 9) or empty
    face_thick: np.ndarray
    face_lift: np.ndarray
    edges: np.ndarray
    edge_cn: np.ndarray
    edge_ct: np.ndarray
    edge_ergun: np.ndarray
    edge_radius: np.ndarray
    edge_lift: np.ndarray
    De_f: np.ndarray
    De_e: np.ndarray
    zero_u: np.ndarray
    #: keyed isotropic coefficients: (vertex slice, vertex measure, Keyed), per substep
    keyed: list = field(default_factory=list)


class AirDrag(Behavior):
    """Drag matrices (isotropic, anisotropic, Ergun) and lift of every element with Drag."""

    stage = "forces"
    requires = (Dynamic, Drag)
    reads_optional = ("air_velocity",)
    accumulates = ("drag", "particle_f")

    def bind(self, ctx, elements):
        n = ctx.model.particle_count
        iso = np.zeros(n)
        keyed = []
        F = {k: [] for k in ("tri", "cn", "ct", "erg", "th", "lift", "kind")}
        E = {k: [] for k in ("edge", "cn", "ct", "erg", "r", "lift", "kind")}
        for e in elements:
            c = e.get(Drag)
            g = e.geometry
            meas = vertex_measure(g) if (len(g.triangles) or len(g.edges)) else np.ones(
                e.vertex_count)
            if c.model == "linear" and isinstance(c.coefficient, Keyed):
                keyed.append((e.vertex_slice, meas, c.coefficient))  # lokigraph.keys
            elif c.model == "linear":
                iso[e.vertex_slice] += resolve_paintable(c.coefficient, e, "Drag.coefficient") \
                    * meas
            if len(g.triangles) and (c.model != "linear" or c.lift > 0):
                m = len(g.triangles)
                F["tri"].append(g.triangles + e.vertex_offset)
                F["cn"].append(np.full(m, c.normal if c.model == "anisotropic" else 0.0))
                F["ct"].append(np.full(m, c.tangent if c.model == "anisotropic" else 0.0))
                F["erg"].append(_ergun(c, m))
                F["th"].append(np.full(m, c.thickness))
                F["lift"].append(np.full(m, c.lift))
            elif len(g.edges) and (c.model != "linear" or c.lift > 0):
                m = len(g.edges)
                E["edge"].append(g.edges + e.vertex_offset)
                E["cn"].append(np.full(m, c.normal if c.model == "anisotropic" else 0.0))
                E["ct"].append(np.full(m, c.tangent if c.model == "anisotropic" else 0.0))
                E["erg"].append(_ergun(c, m))
                E["r"].append(np.full(m, c.fiber_diameter / 2))
                E["lift"].append(np.full(m, c.lift))
        cat = lambda lst, shape: np.concatenate(lst) if lst else np.zeros(shape)  # noqa: E731
        faces = cat(F["tri"], (0, 3)).astype(np.int64)
        edges = cat(E["edge"], (0, 2)).astype(np.int64)
        return _Drag(iso, faces, cat(F["cn"], 0), cat(F["ct"], 0), cat(F["erg"], (0, 10)),
                     cat(F["th"], 0), cat(F["lift"], 0), edges, cat(E["cn"], 0),
                     cat(E["ct"], 0), cat(E["erg"], (0, 10)), cat(E["r"], 0), cat(E["lift"], 0),
                     np.zeros((len(faces), 3, 3)), np.zeros((len(edges), 3, 3)),
                     np.zeros((n, 3)), keyed)

    def init_state(self, model, state, data):
        state.accumulator("drag_D", (model.particle_count, 3, 3))

    def step(self, ctx, d):
        st = ctx.state
        D = st.fields["drag_D"]
        x, v = st.particle_q, st.particle_qd
        u = st.fields.get("air_velocity", d.zero_u)
        st.fields["drag_u"] = u
        if d.keyed:
            f = step_frame(ctx)
            for sl, meas, key in d.keyed:
                d.iso[sl] = key.evaluate(f) * meas
        A.accumulate_isotropic_drag(d.iso, D)
        if len(d.faces):
            _face_matrices(x, v, u, d)
            A.scatter_element_matrices(d.faces, d.De_f, D)
            if d.face_lift.any():
                A.accumulate_lift(x, v, u, d.faces, d.De_f, d.face_lift, st.particle_f)
        if len(d.edges):
            _edge_matrices(x, v, u, d)
            A.scatter_element_matrices(d.edges, d.De_e, D)
            if d.edge_lift.any():
                A.accumulate_lift(x, v, u, d.edges, d.De_e, d.edge_lift, st.particle_f)

    def describe(self, d):
        return (f"{int((d.iso > 0).sum())} vertices isotropic, {len(d.faces)} faces, "
                f"{len(d.edges)} rod segments")


def _ergun(c, m):
    """Per-element packed Ergun parameters plus a flag column (1 = use Ergun)."""
    p = A.pack_ergun_parameters(m, diameter=c.fiber_diameter, gamma=c.material_fraction,
                                mu=c.fluid_viscosity, rho=c.fluid_density, xi_D=c.xi_D,
                                xi_perp=c.xi_perp, xi_par=c.xi_par, xi_N=c.xi_N, c=c.degree)
    flag = np.full((m, 1), 1.0 if c.model == "ergun" else 0.0)
    return np.hstack([p, flag])


def _face_matrices(x, v, u, d):
    erg = d.face_ergun[:, 9] > 0
    if erg.all():
        A.face_drag_matrices_ergun(x, v, u, d.faces, d.face_thick,
                                   np.ascontiguousarray(d.face_ergun[:, :9]), d.De_f)
    elif not erg.any():
        A.face_drag_matrices_linear(x, d.faces, d.face_cn, d.face_ct, d.De_f)
    else:  # mixed models across elements
        A.face_drag_matrices_linear(x, d.faces, d.face_cn, d.face_ct, d.De_f)
        tmp = np.zeros_like(d.De_f)
        A.face_drag_matrices_ergun(x, v, u, d.faces, d.face_thick,
                                   np.ascontiguousarray(d.face_ergun[:, :9]), tmp)
        d.De_f[erg] = tmp[erg]


def _edge_matrices(x, v, u, d):
    erg = d.edge_ergun[:, 9] > 0
    A.edge_drag_matrices_linear(x, d.edges, d.edge_cn, d.edge_ct, d.De_e)
    if erg.any():
        tmp = np.zeros_like(d.De_e)
        A.edge_drag_matrices_ergun(x, v, u, d.edges, d.edge_radius,
                                   np.ascontiguousarray(d.edge_ergun[:, :9]), tmp)
        d.De_e[erg] = tmp[erg]
