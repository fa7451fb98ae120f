"""Collision components: per-object Collider, and data-less collision groups with a response."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from lokigraph.component import Component, Paintable, VertexIndex


class Collider(Component):
    """Per-object collision properties. Collision thickness is not material thickness.

    The thickness [m] extrudes every point, edge and triangle of the object into a proximity
    region; ``thickness_outer`` / ``thickness_inner`` scale it (paintable) on the side the
    triangle normal points to and on the other side. ``collide`` = 0 on a vertex makes it, and
    every edge and triangle touching it, invisible to contact.
    """

    needs_geometry: ClassVar[bool] = True
    thickness: float = Field(0.002, ge=0, description="Collision thickness [m].")
    thickness_outer: Paintable = Field(1.0, description="Scale of the thickness on the outer "
                                                        "side (normal side) [-]. Paintable.")
    thickness_inner: Paintable = Field(1.0, description="Scale of the thickness on the inner "
                                                        "side [-]. Paintable.")
    friction: float = Field(0.3, ge=0, description="Coulomb friction coefficient [-].")
    one_sided: bool = Field(False, description="Contacts only push toward the outer side of this "
                                               "mesh's triangles (by their normal).")
    collide: Paintable = Field(1.0, description="Per-vertex collide map: 0 = invisible to "
                                                "contact [-]. Paintable.")
    collide_dynamic: bool = Field(True, description="Collide with other dynamic objects.")
    collide_kinematic: bool = Field(True, description="Collide with kinematic objects.")
    collide_self: bool = Field(True, description="Self collisions (dynamic objects).")
    nocollide_sets: dict[str, list[VertexIndex]] = Field(
        default_factory=dict, description="Named vertex sets: vertices in sets of the same name "
        "(on this or other objects) do not collide with each other, only with everything else.")


Method = Literal["vertex_face", "edge_edge", "self"]


class CollisionGroup(Component):
    """A collision group (on a data-less element): its members collide with each other with the
    listed methods. Several groups may coexist, each with its own methods and response."""

    members: list[str] = Field(description="Names of the colliding elements.")
    methods: list[Method] = Field(default_factory=lambda: ["vertex_face", "edge_edge", "self"])
    exclude_pairs: list[tuple[str, str]] = Field(default_factory=list,
                                                 description="Element pairs that never collide.")
    proximity_tolerant: Literal["auto", "on", "off"] = Field(
        "auto", description="Primitives already inside each other's thickness at the start of a "
        "step only stop approaching instead of being pushed apart (Loki). 'auto': on for "
        "dynamic-kinematic contacts, off for the rest.")
    recover_crossings: bool = Field(True, description="A dynamic vertex remembers which side of a "
        "two-sided kinematic surface it came from; if animation pushes it through (an "
        "impossible pinch) it is pulled back by at most half its thickness per substep once "
        "there is room, instead of staying on the wrong side.")
    margin: float = Field(0.002, ge=0, description="Extra distance [m] beyond the contact "
                                                   "distance for candidate pairs.")


class CollisionResponse(Component):
    """How the contacts of the group on the same element are resolved."""

    needs: ClassVar[tuple[str, ...]] = ("CollisionGroup",)
    strength: float = Field(1.0, gt=0, le=1, description="Fraction of the correction applied "
                                                         "per projection [-].")
    damping: float = Field(0.0, ge=0, le=1, description="Damping of the relative tangential "
                                                        "motion of contacts per substep [-].")
    restitution: float = Field(0.0, ge=0, le=1, description="Blend between inelastic (0) and "
                                                            "elastic (1) normal response [-].")
    friction_scale: float = Field(1.0, ge=0, description="Multiplies the colliders' friction.")
