"""Material and constraint components: cloth, hair, volumes, goals, attachments, pressure."""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from lokigraph.component import Component, Paintable, VertexIndex
from lokigraph.keys import KeyedFloat
from lokigraph.selection import IndicesOrSelection, resolve_selection


class DiscreteShell(Component):
    """Cloth material on 2-simplices (Nucleus stretch, shear and bend constraints).

    Stiffnesses are physical and mapped to per-constraint compliances that do not change
    meaning with resolution or substeps: an edge of rest length L carrying area A_e gets a spring
    stiffness E t A_e / L^2; a hinge gets D * 3 L^2 / (A_1 + A_2) (discrete shells).
    """

    needs: ClassVar[tuple[str, ...]] = ("Dynamic",)
    youngs_modulus: float | None = Field(None, gt=0, description="Young's modulus E [Pa]; null "
                                         "= inextensible (hard stretch constraints).")
    poisson_ratio: float = Field(0.3, ge=0.0, lt=0.5, description="Poisson ratio [-].")
    thickness: float = Field(5e-4, gt=0, description="Material thickness t [m] (not the "
                                                     "collision thickness).")
    compression_ratio: float = Field(1.0, ge=0, description="Compression resistance relative to "
                                     "stretch resistance [-] (0: buckles freely).")
    shear_stiffness: float | None = Field(None, ge=0, description="Membrane shear stiffness "
                                          "G t [N/m]; null = from E and nu (off if inextensible).")
    bend_resistance: float = Field(1e-6, ge=0, description="Bending stiffness D [N m]; 0 = off.")
    bend_angle_dropoff: float = Field(0.0, ge=0, description="Bend stiffness grows by "
                                      "(1 + dropoff |angle - rest| / pi) [-] (Maya's dropoff).")
    stretch_damping: float = Field(0.0, ge=0, description="Stretch damping (XPBD beta) [s].")
    rest_length_scale: float = Field(1.0, gt=0, description="Scales every rest length [-] "
                                     "(Maya's restLengthScale).")
    rest_channel: str | None = Field(None, description="Channel with rest positions (n, 3); "
                                                       "default: the initial shape.")
    tethers: bool = Field(True, description="Long-range tethers to pinned vertices (inextensible "
                                            "materials only): no sag beyond rest distance.")
    max_strain: Paintable | None = Field(None, description="Strain limit eps_e [-]: no edge "
                                         "longer than (1 + eps_e) L0 (Loki constitutive strain "
                                         "limiting, solved with the contacts). Paintable.")
    max_tether_anchors: int = Field(4, ge=1, le=1000, description="Tethers per vertex (nearest "
                                                                   "pins).")


class Rod(Component):
    """Hair material on 1-simplices: stretch, bend and twist.

    Stretch: axial spring E pi r^2 / L; bend at an interior vertex: EI / l_avg with
    I = pi r^4 / 4 unless ``bend_resistance`` gives EI directly. Solved per strand directly
    (``solve: direct``, :mod:`lokigraph.behaviors.materials.rod`) or by Gauss-Seidel curve
    type-2 angle constraints. Twist (``solve: direct`` only): every segment carries a material
    frame, a reference direction parallel-transported in time plus a twist angle with its own
    rotational inertia (m r^2 / 2 per segment, a solid circular fibre), twist stiffness GJ
    between adjacent segments; the twist follows the centre line but does not push back on it.
    """

    needs: ClassVar[tuple[str, ...]] = ("Dynamic",)
    youngs_modulus: float | None = Field(None, gt=0, description="Young's modulus [Pa]; null = "
                                         "inextensible.")
    radius: float = Field(4e-5, gt=0, description="Fibre radius [m].")
    bend_resistance: float | None = Field(None, ge=0, description="Bending stiffness EI [N m^2]; "
                                          "null = E pi r^4 / 4 (1e-9 if inextensible).")
    compression_ratio: float = Field(1.0, ge=0, description="Compression/stretch resistance.")
    rest_length_scale: float = Field(1.0, gt=0, description="Scales every rest length [-] "
                                     "(Maya's restLengthScale).")
    rest_channel: str | None = Field(None, description="Channel with rest positions (n, 3).")
    tethers: bool | None = Field(None, description="Long-range tethers to pinned vertices "
                                 "(inextensible only); null = on with solve 'gauss_seidel', off "
                                 "with 'direct' (redundant there: the direct solve holds every "
                                 "strand's length, and they cost a parallel pass per iteration; "
                                 "set true for a branched curve, which falls back to "
                                 "Gauss-Seidel).")
    max_tether_anchors: int = Field(2, ge=1, le=1000, description="Tethers per vertex (nearest "
                                                                   "pins).")
    max_strain: Paintable | None = Field(None, description="Strain limit eps_e [-] of every "
                                         "segment (constitutive, solved with contacts).")
    solve: Literal["direct", "gauss_seidel"] = Field(
        "direct", description="How Nucleus solves stretch and bend [-]: 'direct' solves each "
        "strand's constraints together, one Newton step of the whole strand per iteration "
        "(banded LDL^T, RodConstraint; open polylines only, others fall back); 'gauss_seidel' "
        "projects them one by one (StretchConstraint + BendConstraint). Measured at the default "
        "4 substeps x 15 iterations: elastica bench (q L^3/EI = 3) error 0.36 % of L direct, "
        "101 % Gauss-Seidel; hair_strands max segment strain 0.000 % direct, 10 % Gauss-Seidel "
        "(graphs/bench/rod_direct.py).")
    twist_resistance: float | None = Field(
        None, ge=0, description="Twist stiffness GJ [N m^2] of the material frame (solve "
        "'direct' only); null = EI / (1 + poisson_ratio), i.e. G J with G = E / (2 (1 + nu)), "
        "J = pi r^4 / 2 (from bend_resistance when given, else from E and r; 1e-9 / (1 + nu) "
        "if inextensible without bend_resistance); 0 = no twist (no material frame). The twist "
        "does not act on the positions (one-way: the frame follows the centre line), so it "
        "never changes them.")
    poisson_ratio: float = Field(0.3, ge=0.0, lt=0.5, description="Poisson ratio nu [-] of the "
                                 "fibre, for the default twist_resistance (G = E / (2 (1 + "
                                 "nu))).")
    root_twist: KeyedFloat = Field(0.0, description="Twist angle [rad] of the material frame at "
                                   "a pinned root vertex, about the root segment, relative to "
                                   "its reference frame (the rest frame carried by parallel "
                                   "transport): the follicle holds the strand's twist there; a "
                                   "root carried by a body (Pins.follow) also turns with the "
                                   "body's spin about the root segment. Keyable (evaluated at "
                                   "the end of each substep, like the pose of a kinematic "
                                   "vertex).")

    @model_validator(mode="after")
    def _auto_tethers(self):
        if self.tethers is None:
            self.tethers = self.solve == "gauss_seidel"
        return self


class Volume(Component):
    """Soft-body material on 3-simplices: tet edge stretch and tet volume preservation."""

    needs: ClassVar[tuple[str, ...]] = ("Dynamic",)
    youngs_modulus: float = Field(1e5, gt=0, description="Young's modulus [Pa].")
    poisson_ratio: float = Field(0.3, ge=0.0, lt=0.5, description="Poisson ratio [-].")
    rest_channel: str | None = Field(None, description="Channel with rest positions (n, 3).")


class Goal(Component):
    """Goal attraction (Nucleus input-mesh attract) and soft pins.

    Each vertex is pulled toward the same vertex of the ``target`` element (animated, same vertex
    count) or, with no target, toward its own initial position (a soft pin).
    """

    needs: ClassVar[tuple[str, ...]] = ("Dynamic",)
    target: str | None = Field(None, description="Element whose vertices are the goals; null = "
                                                 "own initial positions (soft pins).")
    stiffness: Paintable = Field(1.0, description="Goal stiffness per vertex [N/m]; 0 = free. "
                                                  "Paintable.")


class Attachment(Component):
    """Point-to-surface attachment (a data-less element): vertices of ``source`` are attached to
    the closest triangles of ``target``, at fixed barycentric coordinates (``fixed``) or free to
    slide along the surface (``sliding``).

    ``fixed`` keeps no offset: each vertex is drawn onto the closest point of the surface found
    at bind (x = sum of barycentrics times the triangle's vertices), so a vertex that starts off
    the surface moves onto it. To carry vertices *with* their offset on an animated body, use
    ``Pins: {select: ..., follow: BODY}``. ``vertices`` takes indices, a group name or any
    selection (lokigraph.selection) on the source element."""

    #: fields selecting vertices of another element (resolved at bind, not on this element)
    foreign_selections: ClassVar[tuple[str, ...]] = ("vertices",)
    source: str = Field(description="Element whose vertices are attached.")
    target: str = Field(description="Element providing the surface (triangles).")
    vertices: IndicesOrSelection | None = Field(
        None, description="Source vertices: a list of 0-based indices, a group name or a "
        "selection ({group: ...}, {box: ...}, ...) on the source element (default: all).")
    mode: Literal["fixed", "sliding"] = "fixed"
    stiffness: float | None = Field(None, gt=0, description="Stiffness [N/m]; null = hard.")

    def source_vertices(self, source) -> np.ndarray:
        """Local indices of the attached vertices of ``source`` (InputError if invalid)."""
        if self.vertices is None:
            return np.arange(source.vertex_count, dtype=np.int64)
        return resolve_selection(self.vertices, source, "Attachment.vertices")


class Stitch(Component):
    """Component-to-component stitches and welds (a data-less element).

    ``pairs`` lists [vertex of a, vertex of b]; ``weld_distance`` adds every pair of vertices of a
    and b closer than it [m]. Hard (weld) when stiffness is null.
    """

    a: str = Field(description="First element.")
    b: str = Field(description="Second element.")
    pairs: list[tuple[VertexIndex, VertexIndex]] = Field(
        default_factory=list, description="[vertex of a, vertex of b] pairs (0-based indices).")
    weld_distance: float | None = Field(None, gt=0, description="Auto-pair distance [m].")
    stiffness: float | None = Field(None, gt=0, description="Stiffness [N/m]; null = weld.")


class Pressure(Component):
    """Air pressure in a (closed or open) triangle mesh: hold a target volume, or apply a
    pressure. Open meshes measure volume against the mean of their vertices."""

    needs: ClassVar[tuple[str, ...]] = ("Dynamic",)
    mode: Literal["volume", "pressure"] = "volume"
    volume_scale: float = Field(1.0, gt=0, description="Target volume / rest volume [-].")
    compliance: float = Field(0.0, ge=0, description="Volume compliance [m^3/Pa] (0 = hard).")
    pressure: float = Field(0.0, description="Gauge pressure [Pa] in 'pressure' mode.")


class Rigid(Component):
    """Rigid / shape-matching constraint on the whole element (Mueller et al. 2005)."""

    needs: ClassVar[tuple[str, ...]] = ("Dynamic",)
    stiffness: float = Field(1.0, gt=0, le=1.0, description="Fraction of the way to the matched "
                                                            "shape per projection [-].")

    @model_validator(mode="after")
    def _ok(self):
        return self
