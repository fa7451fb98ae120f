"""A fluid domain element: an Eulerian velocity field on a regular grid (one-way coupling)."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from lokigraph.component import Component

Vec3 = tuple[float, float, float]
_Pos = Annotated[float, Field(gt=0)]


class FluidDomain(Component):
    """A fluid (air or water) velocity field on a regular grid, e.g. a cached fluid simulation.

    ``file``: an ``.npz`` with ``velocity`` of shape (nx, ny, nz, 3) [m/s] (optionally a time
    series (nt, nx, ny, nz, 3) with ``times`` [s]), sampled trilinearly at cloth and hair
    vertices and fed to their drag. Without a file the field is ``uniform`` [m/s]. Outside the
    box the fluid is at rest. The coupling is one way (fluid -> solids); the two-way Newton
    coupling of the Avatar supplement (Figure 2) is not implemented.
    """

    origin: Vec3 = Field((0.0, 0.0, 0.0), description="Lower corner of the grid box [m].")
    size: tuple[_Pos, _Pos, _Pos] = Field((1.0, 1.0, 1.0), description="Size of the grid box "
                                                                       "[m], > 0 on each axis.")
    file: str | None = Field(None, description="Velocity grid .npz, relative to the scene file.")
    uniform: Vec3 = Field((0.0, 0.0, 0.0), description="Velocity when no file is given [m/s].")
    density: float = Field(1.204, gt=0, description="Fluid density [kg/m^3] (informative).")
