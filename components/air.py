"""Air: a wind field (data-less element) and per-object drag and lift parameters."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from lokigraph.component import Component, keyable_paintable
from lokigraph.keys import Keyed, KeyedFloat, keyable

Vec3 = tuple[float, float, float]
KeyedVec3 = tuple[KeyedFloat, KeyedFloat, KeyedFloat]


class WindKey(BaseModel):
    """A key of the wind: speed and/or direction at a frame (linear in between)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    frame: float = Field(ge=-1e7, le=1e7, description="Frame number of the key.")
    speed: float | None = Field(None, description="Wind speed at this key [m/s].")
    direction: Vec3 | None = Field(None, description="Wind direction at this key.")


class Wind(Component):
    """A uniform wind with optional smooth deterministic gusts (noise), keyable.

    u(x, t) = speed * direction + gusts, gusts of RMS noise * speed with wavelengths up to
    ``noise_scale`` (see :func:`lokigraph.behaviors.air.kernels.wind_velocity`). ``speed`` and
    each component of ``direction`` may be keyed (``speed: {keys: {1: 0, 24: 8}, interp:
    smooth}``, see :mod:`lokigraph.keys`); the older ``keys: [{frame, speed, direction}]`` list
    (linear) still works but not together with keyed fields.
    """

    direction: KeyedVec3 = Field((1.0, 0.0, 0.0), description="Wind direction (normalised). "
                                 "Keyable (each component).")
    speed: keyable() = Field(0.0, description="Wind speed [m/s]. Keyable.")
    noise: float = Field(0.0, ge=0, description="Gust amplitude relative to speed [-].")
    noise_scale: float = Field(1.0, gt=0, description="Largest gust wavelength [m].")
    seed: int = Field(0, ge=0, le=2**63 - 1, description="Seed of the gust pattern.")
    keys: list[WindKey] = Field(default_factory=list, description="Keyed speed / direction "
                                "(linear; the older form of keyed speed and direction).")

    @model_validator(mode="after")
    def _one_kind_of_keys(self):
        if self.keys and (isinstance(self.speed, Keyed)
                          or any(isinstance(c, Keyed) for c in self.direction)):
            raise ValueError("give keyed speed/direction either as 'keys: [...]' or as keyed "
                             "fields ({keys: {FRAME: VALUE}}), not both")
        return self


class Drag(Component):
    """Air drag and lift of a dynamic element, solved implicitly per vertex (stable at any h).

    model ``linear``: isotropic, ``coefficient`` per unit area (cloth) / length (hair) / vertex
    (points) [kg/(s m^2), kg/(s m), kg/s]; ``anisotropic``: ``normal``/``tangent`` coefficients per
    unit area (faces) or cross-flow/along (rods); ``ergun``: the Ergun anisotropic drag of the
    Avatar supplement eq. 1-3 with the user scales xi_D, xi_perp, xi_par, xi_N and degree c.
    Lift (eq. 4) scales with ``lift`` (xi_L); it needs faces or rods.
    """

    needs: ClassVar[tuple[str, ...]] = ("Dynamic",)
    model: Literal["linear", "anisotropic", "ergun"] = "linear"
    coefficient: keyable_paintable(ge=0) = Field(
        0.0, description="Isotropic linear drag (see model). Paintable. Keyable (scalar keys "
                         ">= 0, the same on every vertex).")
    normal: float = Field(0.0, ge=0, description="Anisotropic: coefficient along the face normal "
                                                 "(rods: across the rod).")
    tangent: float = Field(0.0, ge=0, description="Anisotropic: coefficient in the face plane "
                                                  "(rods: along the rod).")
    xi_D: float = Field(1.0, ge=0, description="Ergun global drag scale [-] (eq. 2).")
    xi_perp: float = Field(1.0, ge=0, description="Ergun normal drag scale [-].")
    xi_par: float = Field(1.0, ge=0, description="Ergun tangential drag scale [-].")
    xi_N: float = Field(1.0, ge=0, description="Ergun non-linear term scale [-].")
    degree: float = Field(1.0, ge=0, description="Ergun drag degree c [-].")
    fiber_diameter: float = Field(1e-4, gt=0, description="Fibre diameter D [m].")
    material_fraction: float = Field(0.3, gt=0, lt=1, description="Solid fraction gamma [-].")
    thickness: float = Field(5e-4, gt=0, description="Material thickness for element volume [m].")
    fluid_density: float = Field(1.204, gt=0, description="Air density [kg/m^3].")
    fluid_viscosity: float = Field(1.81e-5, gt=0, description="Dynamic viscosity [Pa s].")
    lift: float = Field(0.0, ge=0, description="Lift scale xi_L [-] (eq. 4).")
