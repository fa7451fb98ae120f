"""Coupling to other simulations: ``fluid`` (one-way coupling to a fluid velocity grid)."""

from .fluid import FluidCoupling

__all__ = ["FluidCoupling"]
