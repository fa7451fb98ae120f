"""Eulerian fluid (air, water) on a staggered MAC grid: advection, pressure projection with
algebraic-multigrid-preconditioned CG, VTK image output. Used by the two-way coupling in
:mod:`lokigraph.behaviors.coupling.fluid`."""

from .grid import FACES, KINDS, PRESSURE_SOLVERS, MacGrid, pressure_poisson, sample_mac, splat_mac
from .vti import read_vti, write_vti

__all__ = ["FACES", "KINDS", "MacGrid", "PRESSURE_SOLVERS", "pressure_poisson", "read_vti",
           "sample_mac", "splat_mac", "write_vti"]
