"""Analytic collider shapes (a ground plane, spheres, capsules) for data-less elements."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from lokigraph.component import Component

Vec3 = tuple[float, float, float]


class ShapeCollider(Component):
    """A static analytic collider: dynamic vertices are kept outside it (unilateral).

    ``plane``: the half-space above ``center`` along ``normal``; ``sphere``: radius about
    ``center``; ``capsule``: a segment of ``length`` along ``axis`` through ``center`` swept by
    ``radius``. ``thickness`` is added to the surface. Friction is Coulomb (position-based).
    """

    shape: Literal["plane", "sphere", "capsule"] = "plane"
    center: Vec3 = Field((0.0, 0.0, 0.0), description="Centre / point on the plane [m].")
    normal: Vec3 = Field((0.0, 1.0, 0.0), description="Plane normal (unit after normalising).")
    axis: Vec3 = Field((0.0, 0.0, 1.0), description="Capsule axis direction.")
    radius: float = Field(0.1, ge=0, description="Sphere / capsule radius [m].")
    length: float = Field(1.0, ge=0, description="Capsule segment length [m].")
    thickness: float = Field(0.0, ge=0, description="Collision thickness added to the surface [m].")
    friction: float = Field(0.0, ge=0, description="Coulomb friction coefficient [-].")
