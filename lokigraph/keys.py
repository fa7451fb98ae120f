"""Keyed parameters: a float field of a component given as values at frames.

Syntax (any field documented "Keyable.")::

    Wind: {speed: {keys: {1: 0.0, 24: 8.0}, interp: linear}}
    RestSpring: {stiffness: {keys: {1: 10.0, 10: 40.0}, interp: step}}

``keys`` maps a frame number (finite, at least one key) to a value (finite, within the bounds
of the field: a key of ``RestSpring.stiffness`` must be >= 0 like the plain value). ``interp``:

* ``linear`` (default): straight lines between keys;
* ``step``: the value of the last key at or before the frame (it changes exactly at a key);
* ``smooth``: a C1 cubic Hermite segment with zero tangents at every key (``smoothstep``,
  v_i + (v_{i+1} - v_i) s^2 (3 - 2 s)). It eases in and out of each key and never overshoots:
  every value lies between its two neighbouring keys, so the bounds checked on the keys hold at
  every time (Catmull-Rom would overshoot, e.g. a stiffness keyed 0 -> 10 -> 10 dips below 0).

Before the first key the first value holds, after the last key the last value holds.

When: behaviors evaluate a keyed field once per substep at the *start* of the substep, at the
frame ``f + j / substeps`` for substep ``j`` (0-based) of the step from frame ``f`` to ``f + 1``
(:func:`step_frame`): the time at which the explicit forces of the symplectic Euler step are
evaluated. A ``step`` key at frame K therefore affects the substeps that start at K or later:
the states written for frames <= K equal those of a run with the value before the key, bit for
bit, and frame K + 1 is the first to differ.

A plain number takes exactly the code path it took before keys existed (a float stays a float);
only :class:`Keyed` values are re-evaluated per substep.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Annotated, Literal, Union

import numpy as np
from pydantic import (BaseModel, ConfigDict, Discriminator, Field, PrivateAttr, Tag,
                      field_validator)
from pydantic.types import FiniteFloat

__all__ = ["INTERPOLATIONS", "Keyed", "KeyedFloat", "evaluate_many", "is_keyed", "keyable",
           "step_frame", "value_at"]

INTERPOLATIONS = ("linear", "smooth", "step")
MAX_KEYS = 100_000
"""Most keys of one keyed value."""


class Keyed(BaseModel):
    """A scalar keyed over frames: ``{keys: {FRAME: VALUE, ...}, interp: linear|smooth|step}``."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    keys: dict[Annotated[FiniteFloat, Field(ge=-1e7, le=1e7)], FiniteFloat] = Field(
        description="Frame -> value (frames and values finite; at least one key).")
    interp: Literal["linear", "smooth", "step"] = Field(
        "linear", description="Interpolation between keys: linear, smooth (C1 cubic Hermite "
                              "with zero tangents at the keys: no overshoot) or step (holds "
                              "the last key's value).")
    _frames: np.ndarray = PrivateAttr()
    _values: np.ndarray = PrivateAttr()

    @field_validator("keys")
    @classmethod
    def _count(cls, v):
        if not v:
            raise ValueError("needs at least one key ({FRAME: VALUE})")
        if len(v) > MAX_KEYS:
            raise ValueError(f"at most {MAX_KEYS} keys (got {len(v)})")
        return v

    def model_post_init(self, __context) -> None:
        items = sorted(self.keys.items())
        self._frames = np.array([f for f, _ in items], dtype=np.float64)
        self._values = np.array([v for _, v in items], dtype=np.float64)

    def evaluate(self, frame: float) -> float:
        """The value at ``frame`` (a float, exact at a key)."""
        fr, va = self._frames, self._values
        if frame <= fr[0]:
            return float(va[0])
        if frame >= fr[-1]:
            return float(va[-1])
        i = int(np.searchsorted(fr, frame, side="right")) - 1  # fr[i] <= frame < fr[i + 1]
        a = float(va[i])
        if self.interp == "step":
            return a
        s = (frame - float(fr[i])) / (float(fr[i + 1]) - float(fr[i]))
        if self.interp == "smooth":
            s = s * s * (3.0 - 2.0 * s)
        return a + (float(va[i + 1]) - a) * s


def is_keyed(value) -> bool:
    return isinstance(value, Keyed)


def value_at(value, frame: float):
    """``value`` itself when it is not keyed (unchanged, same object), else its value at
    ``frame``."""
    return value.evaluate(frame) if isinstance(value, Keyed) else value


def evaluate_many(values, frame: float) -> np.ndarray:
    """float64 array of :func:`value_at` of every item of ``values`` at ``frame``."""
    return np.array([float(value_at(v, frame)) for v in values], dtype=np.float64)


def step_frame(ctx) -> float:
    """The frame at which keyed values are evaluated in the substep of ``ctx`` (a
    :class:`~lokigraph.behavior.StepContext`): the start of the substep, ``ctx.frame + j /
    substeps`` for substep ``j`` of the current frame (exact at every whole frame)."""
    s = int(ctx.model.substeps)
    return float(ctx.frame) + (int(ctx.substep) % s) / s


def _kind(v):
    if isinstance(v, Keyed) or (isinstance(v, dict) and "keys" in v):
        return "Keyed"
    return "float"


@lru_cache(maxsize=None)
def _bounded_keyed(ge=None, gt=None, le=None, lt=None) -> type[Keyed]:
    if ge is None and gt is None and le is None and lt is None:
        return Keyed
    value = Annotated[FiniteFloat, Field(ge=ge, gt=gt, le=le, lt=lt)]
    name = "Keyed"  # the same name in messages and JSON schema titles

    return type(name, (Keyed,), {
        "__annotations__": {"keys": dict[Annotated[FiniteFloat, Field(ge=-1e7, le=1e7)], value]},
        "keys": Field(description="Frame -> value (frames finite, values finite and within "
                                  "the field's bounds; at least one key)."),
        "__module__": __name__,
        "__qualname__": "Keyed_" + "_".join(f"{n}{v:g}".replace("-", "m").replace(".", "p")
                                            for n, v in (("ge", ge), ("gt", gt), ("le", le),
                                                         ("lt", lt)) if v is not None)})


def keyable(ge=None, gt=None, le=None, lt=None):
    """The type of a keyable float field: a finite float or :class:`Keyed`, with the bounds
    applied to the plain value and to every key's value."""
    return Annotated[
        Union[Annotated[FiniteFloat, Field(ge=ge, gt=gt, le=le, lt=lt), Tag("float")],
              Annotated[_bounded_keyed(ge, gt, le, lt), Tag("Keyed")]],
        Discriminator(_kind)]


KeyedFloat = keyable()
"""A keyable float field without bounds: a finite number or ``{keys: {...}, interp: ...}``."""
