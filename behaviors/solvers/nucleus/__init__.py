"""The Nucleus solver: ``solver`` (time stepping and the interleaved constraint schedule) and
``xpbd`` (the XPBD primitives and conventions every constraint kernel shares)."""

from .solver import NucleusParams, NucleusSolver, interleave_plan

__all__ = ["NucleusParams", "NucleusSolver", "interleave_plan"]
