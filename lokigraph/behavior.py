"""Behaviors: the nodes of the graph.

A behavior declares the component types it requires (an element carrying all of them is bound),
optional ones, what it reads and writes in the state, and its stage. At compile time ``bind``
packs the data of every bound element into flat arrays (its *data*); per substep ``step`` runs
vectorised over all of them. A behavior keeps no simulation state on ``self``: ``self`` holds
only its validated graph parameters.

Constraint behaviors (for the ``nucleus`` solver) do not step on their own: they contribute a
constraint *type* with an importance and an order, and the solver calls ``project`` in its
interleaved loop (Nucleus section 6).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

if TYPE_CHECKING:  # pragma: no cover
    from .model import Control, Model, State
    from .scene import Element

#: stages in execution order within one substep
STAGES = ("control", "forces", "collision", "solve", "coupling", "diagnostics")


class Params(BaseModel):
    """Graph-level parameters of a behavior (strict; NaN and infinities rejected)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class ConstraintParams(Params):
    importance: float = Field(1.0, gt=0, le=1.0,
                              description="Fraction of the solver iterations in which this "
                                          "constraint type is projected (1 = every iteration); "
                                          "it always runs in the final pass.")
    order: int = Field(0, description="Place in the sequence inside one iteration (lower first).")


class Behavior:
    """Base class of every behavior. Subclass, declare, implement ``bind`` and ``step``."""

    stage: ClassVar[str] = "forces"
    requires: ClassVar[tuple[type, ...]] = ()
    #: an element must also carry at least one of these (if any are given)
    requires_any: ClassVar[tuple[type, ...]] = ()
    optional: ClassVar[tuple[type, ...]] = ()
    #: elements carrying any of these are not bound
    excludes: ClassVar[tuple[type, ...]] = ()
    #: a behavior that always runs once the scene has elements (no component needed)
    always: ClassVar[bool] = False
    #: state fields read (must be written by someone, else this behavior is pruned)
    reads: ClassVar[tuple[str, ...]] = ()
    #: state fields read if present
    reads_optional: ClassVar[tuple[str, ...]] = ()
    #: state fields this behavior owns (a second writer is a compile error)
    writes: ClassVar[tuple[str, ...]] = ()
    #: state fields this behavior adds into (any number of accumulators; run before readers)
    accumulates: ClassVar[tuple[str, ...]] = ()
    #: solver behaviors name the solver they implement; the scene picks one
    solver: ClassVar[str | None] = None
    ParamsModel: ClassVar[type[Params]] = Params

    def __init__(self, name: str, params: Params | None = None):
        self.name = name
        self.params = params if params is not None else self.ParamsModel()

    @classmethod
    def type_id(cls) -> str:
        return cls.__name__

    # -- compile time -------------------------------------------------------------------
    def bind(self, ctx: "BindContext", elements: list["Element"]):
        """Pack the data of ``elements`` into arrays; return it (or None if nothing to do)."""
        return None

    def init_state(self, model: "Model", state: "State", data) -> None:
        """Allocate this behavior's fields in ``state`` (called once after bind)."""

    # -- run time -----------------------------------------------------------------------
    def step(self, ctx: "StepContext", data) -> None:
        """Run one substep over all bound elements."""

    def frame_end(self, ctx: "StepContext", data) -> None:
        """Called once at the end of every frame (diagnostics, per-frame statistics)."""

    def describe(self, data) -> str:
        """One line for ``lokigraph plan`` (e.g. counts of packed items)."""
        return ""

    # -- checkpoints (lokigraph.checkpoint) ----------------------------------------------
    def state_arrays(self, data) -> dict[str, np.ndarray]:
        """The per-run memory this behavior keeps in ``data`` between substeps (anything
        besides State and Control that a later step reads and an earlier step wrote: contact
        side history, warm starts, counters, RNG state as arrays). A checkpoint stores it under
        the node's name; scratch buffers, per-substep values rebuilt before use, and memos of
        input files are not state. Default: nothing."""
        return {}

    def load_state_arrays(self, data, arrays: dict[str, np.ndarray]) -> None:
        """Restore what :meth:`state_arrays` returned (same keys, same shapes), in place."""


class ConstraintBehavior(Behavior):
    """A constraint type for the ``nucleus`` solver (Nucleus section 6).

    ``project(ctx, data, p)`` performs one Gauss-Seidel pass over all constraints of this type,
    moving predicted positions ``p`` in place; ``begin_substep`` resets per-substep multipliers.
    """

    stage = "solve"
    accumulates = ("constraints",)
    ParamsModel = ConstraintParams
    default_importance: ClassVar[float] = 1.0
    default_order: ClassVar[int] = 0

    def __init__(self, name: str, params: Params | None = None):
        if params is None:
            params = self.ParamsModel(importance=self.default_importance, order=self.default_order)
        super().__init__(name, params)

    def begin_substep(self, ctx: "StepContext", data) -> None:
        if data is not None and getattr(data, "lam", None) is not None:
            data.lam[:] = 0.0

    def project(self, ctx: "StepContext", data, p: np.ndarray) -> None:  # pragma: no cover
        raise NotImplementedError

    def finalize(self, ctx: "StepContext", data, p: np.ndarray) -> None:
        """Called once after the last iteration (e.g. a final collision pass)."""

    def residual(self, ctx: "StepContext", data, p: np.ndarray) -> float:
        """Max |C| over this type's constraints (for diagnostics); NaN if not implemented."""
        return float("nan")


def vertex_indices(elements) -> np.ndarray:
    """Global vertex indices of ``elements``, concatenated in order, int64."""
    parts = [np.arange(e.vertex_slice.start, e.vertex_slice.stop) for e in elements]
    return np.concatenate(parts).astype(np.int64) if parts else np.zeros(0, np.int64)


_BIND_CACHES: list = []


def register_bind_cache(clear) -> None:
    """Register ``clear()``, which drops a memo that behaviors keep while they bind (e.g. the
    topology of a large mesh shared by several behaviors); compile calls every registered one
    once all behaviors are bound, so the memo does not outlive the compile."""
    if clear not in _BIND_CACHES:
        _BIND_CACHES.append(clear)


def clear_bind_caches() -> None:
    for clear in _BIND_CACHES:
        clear()


class SolverCoupling:
    """A coupling that runs inside an implicit solver's nonlinear loop (the Avatar supplement's
    Figure 2). A behavior whose bound data carries one as ``data.solver_coupling`` is found by
    the implicit solver (through ``model.data``), which, per substep, calls ``begin`` once, then
    after every solid solve ``iterate`` with the start positions ``x0``, the new iterate ``x``
    and the inertial target ``xt`` (which a coupling force may move: ``xt += h^2 M^-1 df``),
    and stops when ``iterate`` returns a change below its tolerance or after its most
    iterations. ``iterate`` updates the solid's inputs in place (e.g. the air velocity that
    drag pulls toward) and returns the largest change of them [m/s]."""

    def begin(self, ctx) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def iterate(self, ctx, x0, x, xt) -> float:  # pragma: no cover - interface
        raise NotImplementedError


@dataclass
class BindContext:
    """What ``bind`` sees: the model under construction and the scene."""

    model: "Model"
    scene: object
    diagnostics: list = field(default_factory=list)

    def error(self, element, field_name: str, message: str) -> None:
        from .errors import Diagnostic

        self.diagnostics.append(Diagnostic(file=element.source_file, line=element.line,
                                           column=element.column, element=element.name,
                                           field=field_name, message=message))


@dataclass
class StepContext:
    """What ``step`` sees: model (static), state (dynamic), control (inputs), time and step."""

    model: "Model"
    state: "State"
    control: "Control"
    dt: float
    time: float
    substep: int
    frame: int
    constraints: list = field(default_factory=list)  # [(behavior, data)] sorted by order
    stats: dict = field(default_factory=dict)
    #: the run's output folder when it writes frames (``lokigraph run --out``), else None; for
    #: behaviors that write per-frame files of their own (e.g. fluid fields) in ``frame_end``
    out_dir: "Path | None" = None
