"""The implicit solver (Loki supplement eq. 1): ``solver`` (backward Euler by Newton with a line
search, block-sparse Hessians, PCG), ``energy`` (the energy protocol every material and
attachment implements, and the assembly it shares) and ``linear`` (PCG and preconditioners)."""

from .solver import PROJECTED_TYPES, ImplicitParams, ImplicitSolver

__all__ = ["PROJECTED_TYPES", "ImplicitParams", "ImplicitSolver"]
