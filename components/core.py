"""Core components: what makes an element dynamic or kinematic, pins, simple springs."""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from lokigraph.component import (Component, Paintable, VertexIndex, keyable_paintable,
                                 resolve_paintable)
from lokigraph.keys import keyable
from lokigraph.selection import SelectionLike, resolve_selection
from lokigraph.geometry import vertex_measure

Vec3 = tuple[float, float, float]


class Dynamic(Component):
    """The element is simulated: its vertices have mass and integrate in time.

    Mass is lumped from ``mass_density`` over the element's highest-dimensional simplices:
    kg/m^3 for tetrahedra, kg/m^2 for triangles, kg/m for curves; ``point_mass`` [kg] sets the
    mass of every vertex directly instead (required for elements made of points only).
    """

    particle_role: ClassVar[str] = "dynamic"
    needs_geometry: ClassVar[bool] = True

    mass_density: Paintable = Field(0.1, description="Mass density: kg/m^3 (volumes), kg/m^2 "
                                                     "(cloth), kg/m (hair). Paintable.")
    point_mass: float | None = Field(None, gt=0, description="Mass of each vertex [kg]; "
                                                              "overrides mass_density.")
    velocity: Vec3 = Field((0.0, 0.0, 0.0), description="Initial velocity [m/s].")
    damping: keyable(ge=0) = Field(0.0, description="Velocity damping rate [1/s] (Nucleus "
                                   "'damp'): v *= exp(-damping h) per substep. Keyable.")

    @field_validator("mass_density")
    @classmethod
    def _positive(cls, v):
        if isinstance(v, (int, float)) and v <= 0:
            raise ValueError(f"must be > 0 (got {v:g})")
        return v

    def vertex_mass(self, element) -> np.ndarray:
        """Lumped vertex masses [kg], shape (vertex_count,)."""
        if self.point_mass is not None:
            return np.full(element.vertex_count, float(self.point_mass))
        rho = resolve_paintable(self.mass_density, element, "Dynamic.mass_density")
        return rho * vertex_measure(element.geometry)

    def initial_velocity(self, element) -> np.ndarray:
        return np.tile(np.asarray(self.velocity, dtype=np.float64), (element.vertex_count, 1))


class Key(BaseModel):
    """A rigid keyframe of a kinematic element (interpolated as ``Kinematic.interpolation``
    says: linear by default)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    frame: float = Field(ge=-1e7, le=1e7, description="Frame number of the key.")
    translate: Vec3 = Field((0.0, 0.0, 0.0), description="Translation [m].")
    rotate: Vec3 = Field((0.0, 0.0, 0.0), description="Rotation about x, y, z [degrees], about "
                                                       "the pivot.")
    pivot: Vec3 = Field((0.0, 0.0, 0.0), description="Rotation pivot [m] (rest space).")


class Kinematic(Component):
    """The element follows animation: rigid ``keys``, or the mesh ``sequence`` of its geometry.

    Without either it stays at its rest pose (a static collider). A sequence must have a file
    for every frame of the run unless its ``geometry.hold`` is ``first``, ``last`` or ``loop``
    (checked by validate). Dynamic vertices can ride on a kinematic element with
    ``Pins: {select: ..., follow: NAME}``.
    """

    particle_role: ClassVar[str] = "kinematic"
    needs_geometry: ClassVar[bool] = True

    def compliant_stiffness(self, element) -> np.ndarray:
        """Per-vertex spring stiffness [N/m] of compliant vertices (0 = not compliant)."""
        k = resolve_paintable(self.stiffness, element, "Kinematic.stiffness")
        if not np.all(np.isfinite(k)) or np.any(k < 0):
            from lokigraph.errors import Diagnostic, InputError

            i = int(np.argmax(~np.isfinite(k) | (k < 0)))
            raise InputError(Diagnostic(file=element.source_file, line=element.line,
                                        element=element.name, field="Kinematic.stiffness",
                                        message=f"must be finite and >= 0 on every vertex (got "
                                                f"{k[i]:g} at vertex {i})"))
        if not np.any(k):
            return np.zeros(element.vertex_count)
        meas = vertex_measure(element.geometry)
        if not np.any(meas):
            meas = np.ones(element.vertex_count)
        return k * meas

    keys: list[Key] = Field(default_factory=list, description="Rigid keyframes, sorted by frame.")
    interpolation: Literal["linear", "smooth"] = Field(
        "linear", description="How rigid keys are interpolated, per channel (translate x y z, "
        "rotate x y z as XYZ Euler angles, pivot x y z); before the first key and after the last "
        "the pose holds. linear (default): straight lines, so the velocity jumps at every key. "
        "smooth: a C1 monotone cubic Hermite curve through the keys (Fritsch-Carlson tangents, "
        "scipy's PCHIP interior slopes): the tangent at a key is the weighted harmonic mean of "
        "its two neighbouring slopes, zero where the curve turns (a local extreme or a flat "
        "neighbour, like Maya's auto tangents: no overshoot) and zero at the first and last key, "
        "so the velocity is continuous everywhere, holds included. Unlike a keyed field's "
        "'interp: smooth' (zero tangent at every key), a channel keyed at a constant rate keeps "
        "it through its interior keys. The peak speed of a segment can exceed its key-to-key "
        "rate: 1.5x between two zero tangents. Needs strictly increasing key frames.")
    stiffness: Paintable = Field(0.0, description="Compliant kinematics (Loki): stiffness per "
                                 "unit area [N/m^3] pulling a vertex to its animated position "
                                 "(rho / h^2 with the 1/h^2 folded in, so it does not change "
                                 "with substeps). Vertices with stiffness > 0 become momentum-free "
                                 "unknowns that only contacts can push; 0 = follows the "
                                 "animation exactly. Paintable.")

    @field_validator("stiffness")
    @classmethod
    def _nonnegative(cls, v):
        if isinstance(v, (int, float)) and v < 0:
            raise ValueError(f"must be >= 0 (got {v:g})")
        return v

    @field_validator("keys")
    @classmethod
    def _sorted(cls, v):
        frames = [k.frame for k in v]
        if frames != sorted(frames):
            raise ValueError("keys must be sorted by frame")
        return v

    @model_validator(mode="after")
    def _smooth_distinct(self):
        if self.interpolation == "smooth":
            frames = [k.frame for k in self.keys]
            dup = next((a for a, b in zip(frames, frames[1:]) if b <= a), None)
            if dup is not None:
                raise ValueError(f"interpolation: smooth needs strictly increasing key frames "
                                 f"(two keys at frame {dup:g}: a jump cannot be smooth; use "
                                 f"linear or move one key)")
        return self


class Pins(Component):
    """Hard pins: pinned vertices get inverse mass 0, so no force or constraint moves them.

    The pinned vertices are the union of ``select`` (a selection: a group name such as
    ``waist`` or a grid's ``top``, a region, a channel threshold, a combination; see
    :mod:`lokigraph.selection`), ``vertices`` (0-based indices) and a painted ``map`` (pinned
    where map > ``threshold``).

    Without ``follow`` they keep their initial position exactly. With ``follow: BODY`` (a
    ``Kinematic`` element) they are carried by BODY's animation: at bind time each pinned vertex
    x is bound to the nearest triangle (a, b, c) of BODY at its initial pose: the barycentric
    coordinates w of the closest point s = w_a a + w_b b + w_c c, and the offset d = x - s
    expressed in the triangle's frame (e1 = unit(b - a), n = unit((b - a) x (c - a)),
    e2 = n x e1), all fixed. Every substep the vertex is placed at s(t) + [e1 e2 n](t) d from
    the triangle's animated vertices: exact under rigid motion of the body (translation and
    rotation), and it follows the body's deformation otherwise. A body without triangles
    carries each vertex by its nearest vertex (the offset kept in world axes: translation only).
    """

    needs: ClassVar[tuple[str, ...]] = ("Dynamic",)
    selection_fields: ClassVar[tuple[str, ...]] = ("select",)
    select: SelectionLike | None = Field(None, description="Pinned vertices by selection: a "
                                         "group name, or {group: ...}, {box: ...}, {sphere: ...},"
                                         " {plane: ...}, {channel: ..., above: ...}, {union: "
                                         "[...]}, ... (see lokigraph.selection).")
    vertices: list[VertexIndex] = Field(default_factory=list, description="Pinned vertex "
                                        "indices (0-based).")
    map: Paintable | None = Field(None, description="Painted pin weights; pinned where > "
                                                    "threshold.")
    threshold: float = Field(0.5, description="Map value above which a vertex is pinned.")
    follow: str | None = Field(None, description="A Kinematic element whose animation carries "
                               "the pinned vertices (nearest triangle, barycentric coordinates "
                               "and an offset in the triangle's frame fixed at bind); null = "
                               "pinned in place.")

    def pinned(self, element) -> np.ndarray:
        """Boolean mask (vertex_count,) of the pinned vertices; InputError if out of range."""
        from lokigraph.errors import Diagnostic, InputError

        mask = np.zeros(element.vertex_count, dtype=bool)
        idx = np.asarray(self.vertices, dtype=np.int64)
        if idx.size:
            if idx.max() >= element.vertex_count:
                raise InputError(Diagnostic(file=element.source_file, line=element.line,
                                            column=element.column, element=element.name,
                                            field="Pins.vertices",
                                            message=f"vertex index {int(idx.max())} out of "
                                                    f"range (element has "
                                                    f"{element.vertex_count} vertices)"))
            mask[idx] = True
        if self.select is not None:
            mask[resolve_selection(self.select, element, "Pins.select")] = True
        if self.map is not None:
            mask |= resolve_paintable(self.map, element, "Pins.map") > self.threshold
        return mask


class RestSpring(Component):
    """A linear spring pulling every vertex to its rest position: f = -k (x - x_rest).

    The simplest force there is; used for the spring of Nucleus section 4.2.
    """

    needs: ClassVar[tuple[str, ...]] = ("Dynamic",)
    stiffness: keyable_paintable(ge=0) = Field(
        1.0, description="Spring stiffness per vertex [N/m], >= 0. Paintable. Keyable (scalar "
                         "keys, the same on every vertex).")
    anchor: Vec3 | None = Field(None, description="Fixed anchor point [m] for every vertex "
                                                  "instead of its rest position.")

    @field_validator("stiffness")
    @classmethod
    def _nonnegative(cls, v):
        if isinstance(v, (int, float)) and v < 0:
            raise ValueError(f"must be >= 0 (got {v:g})")
        return v
