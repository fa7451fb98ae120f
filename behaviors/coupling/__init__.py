"""Coupling to fluids: ``fluid`` (one-way sampling of prescribed velocity grids; two-way weak
coupling with a simulated MAC grid, Avatar supplement Figure 2)."""

from .fluid import FluidCoupling, FluidTwoWay

__all__ = ["FluidCoupling", "FluidTwoWay"]
