"""A fluid domain element: a prescribed velocity grid (one-way coupling) or a simulated Eulerian
MAC grid of air or water coupled two ways with cloth and hair (Avatar supplement section 2)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from lokigraph.component import Component
from lokigraph.keys import keyable

Vec3 = tuple[float, float, float]
_Pos = Annotated[float, Field(gt=0)]


class FluidBoundary(BaseModel):
    """Boundary condition of one face of a simulated fluid box."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    type: Literal["wall", "open", "inflow"] = Field(
        "wall", description="wall: no flow through the face (free slip); open: pressure 0 "
                            "outside, fluid leaves or enters freely; inflow: a prescribed "
                            "velocity into the box along the face's inward normal.")
    velocity: keyable(ge=0, le=1e3) = Field(
        0.0, description="Inflow speed into the box [m/s] (type inflow). Keyable.")


class FluidDomain(Component):
    """A fluid (air or water) in a box.

    **Prescribed** (``simulate: false``, the default): ``file`` is an ``.npz`` with
    ``velocity`` of shape (nx, ny, nz, 3) [m/s] (optionally a time series (nt, nx, ny, nz, 3)
    with ``times`` [s]), sampled trilinearly at cloth and hair vertices and fed to their drag.
    Without a file the field is ``uniform`` [m/s]. Outside the box the fluid is at rest. One
    way: fluid -> solids.

    **Simulated** (``simulate: true``): an incompressible fluid on a staggered MAC grid of
    ``cell_size`` over the box, two-way coupled with every element carrying ``Drag`` (Avatar
    supplement section 2, Figure 2, as one weak-coupling pass per substep with Nucleus): the
    fluid velocity at the vertices drives their drag; the opposite of the drag impulses the
    solids received goes into the fluid; a pressure projection and a semi-Lagrangian
    (or MacCormack) advection follow. ``uniform`` is the initial velocity. Solids in the box
    feel buoyancy ``-V grad p`` (V: the Drag element volume) when ``buoyancy`` is on. Static
    ``ShapeCollider`` elements (plane, sphere, capsule) are obstacles the fluid flows around;
    so are moving kinematic meshes (a character): every closed triangle mesh of a
    ``Kinematic`` element (or those named in ``obstacles``) is rasterized into solid face
    fractions every substep and pushes the fluid with its own velocity.
    """

    origin: Vec3 = Field((0.0, 0.0, 0.0), description="Lower corner of the grid box [m].")
    size: tuple[_Pos, _Pos, _Pos] = Field((1.0, 1.0, 1.0), description="Size of the grid box "
                                                                       "[m], > 0 on each axis.")
    file: str | None = Field(None, description="Velocity grid .npz, relative to the scene file "
                                               "(prescribed mode only).")
    uniform: Vec3 = Field((0.0, 0.0, 0.0), description="Prescribed: velocity when no file is "
                                                       "given [m/s]; simulated: the initial "
                                                       "velocity [m/s].")
    density: float = Field(1.204, gt=0, le=1e5, description="Fluid density [kg/m^3] (air "
                                                            "1.204, water 998).")
    simulate: bool = Field(False, description="Simulate the fluid on a MAC grid, coupled two "
                                              "ways with the solids (see above).")
    cell_size: float = Field(0.05, gt=0, description="Simulated: grid cell size [m]; the cell "
                                                     "count per axis is size / cell_size "
                                                     "rounded (at least 2).")
    viscosity: float = Field(0.0, ge=0, le=1e3, description="Simulated: dynamic viscosity "
                             "[Pa s] (explicit diffusion; air 1.81e-5, water 1.0e-3; 0 = "
                             "inviscid, numerical diffusion only).")
    gravity: bool = Field(False, description="Simulated: apply the scene's gravity to the fluid "
                                             "(hydrostatic pressure: what makes buoyancy).")
    buoyancy: bool = Field(True, description="Simulated: solids with Drag feel -V grad p "
                                             "(V: Drag element volume) [N].")
    advection: Literal["semi_lagrangian", "maccormack"] = Field(
        "maccormack", description="Simulated: velocity advection scheme (MacCormack: "
                                  "second order, limited to local extrema).")
    pressure_solver: Literal["amg", "jacobi", "cg"] = Field(
        "amg", description="Simulated: preconditioner of the pressure CG (amg: pyamg smoothed "
                           "aggregation V-cycle; jacobi; cg: none).")
    pressure_tolerance: float = Field(1e-8, gt=0, lt=1, description="Simulated: relative "
                                      "residual of the pressure solve [-].")
    x_min: FluidBoundary = Field(default_factory=FluidBoundary,
                                 description="Boundary at the box face x = origin.x.")
    x_max: FluidBoundary = Field(default_factory=FluidBoundary,
                                 description="Boundary at the box face x = origin.x + size.x.")
    y_min: FluidBoundary = Field(default_factory=FluidBoundary,
                                 description="Boundary at the box face y = origin.y.")
    y_max: FluidBoundary = Field(default_factory=FluidBoundary,
                                 description="Boundary at the box face y = origin.y + size.y.")
    z_min: FluidBoundary = Field(default_factory=FluidBoundary,
                                 description="Boundary at the box face z = origin.z.")
    z_max: FluidBoundary = Field(default_factory=FluidBoundary,
                                 description="Boundary at the box face z = origin.z + size.z.")
    obstacles: list[str] | None = Field(
        None, description="Simulated: kinematic elements that displace the fluid, moving with "
        "their animation (closed triangle meshes, rasterized as solid face fractions every "
        "substep); null = every Kinematic element with a closed triangle mesh; [] = none.")
    write_fields: bool = Field(False, description="Simulated: write velocity [m/s] and pressure "
                               "[Pa] per frame as VTK image data to fields_dir/NNNN.vti.")
    fields_dir: str | None = Field(None, description="Folder of the .vti files, relative to "
                                   "the scene file (default: <run output folder>/<element "
                                   "name>, i.e. output.dir or --out).")

    @model_validator(mode="after")
    def _consistent(self):
        if self.simulate and self.file is not None:
            raise ValueError("a simulated FluidDomain takes no velocity file (file is for "
                             "prescribed grids); drop 'file' or set simulate: false")
        faces = (self.x_min, self.x_max, self.y_min, self.y_max, self.z_min, self.z_max)
        if self.simulate and any(f.type == "inflow" for f in faces) and not any(
                f.type == "open" for f in faces):
            raise ValueError("an inflow face needs an open face for the fluid to leave "
                             "(incompressible: nothing else can take the volume)")
        return self
