"""Model (static, packed once), State (dynamic), Control (time-varying inputs).

Struct of arrays with one global vertex numbering: every element with geometry owns the slice
``element.vertex_slice`` of every per-vertex array.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Model:
    """Static data built at compile time."""

    particle_count: int
    #: initial positions [m], shape (particle_count, 3)
    particle_q0: np.ndarray
    #: rest positions [m] (rest channel where given, else initial), shape (particle_count, 3)
    particle_rest: np.ndarray
    #: initial velocities [m/s], shape (particle_count, 3)
    particle_qd0: np.ndarray
    #: lumped masses [kg], shape (particle_count,); 0 for kinematic vertices
    particle_mass: np.ndarray
    #: inverse masses [1/kg], shape (particle_count,); 0 = kinematic or pinned
    particle_inv_mass: np.ndarray
    #: True for vertices driven by animation (kinematic elements), shape (particle_count,)
    particle_kinematic: np.ndarray
    #: compliant kinematic vertices (animated, but pushed by contacts), shape (particle_count,)
    particle_compliant: np.ndarray
    #: per-vertex element index, shape (particle_count,)
    particle_element: np.ndarray
    elements: list
    gravity: np.ndarray
    fps: float
    substeps: int
    seed: int = 0
    data: dict = field(default_factory=dict)  # behavior name -> packed data

    @property
    def dt(self) -> float:
        """Substep size h [s]."""
        return 1.0 / (self.fps * self.substeps)

    def locate(self, vertex: int) -> tuple[str, int]:
        """Global vertex index -> (element name, local vertex index)."""
        e = self.elements[int(self.particle_element[vertex])]
        return e.name, int(vertex - e.vertex_offset)


@dataclass
class State:
    """Dynamic arrays of one substep."""

    #: positions [m], shape (particle_count, 3)
    particle_q: np.ndarray
    #: velocities [m/s], shape (particle_count, 3)
    particle_qd: np.ndarray
    #: force accumulator [N], shape (particle_count, 3); cleared before the force stage
    particle_f: np.ndarray
    #: positions at the start of the current substep [m], shape (particle_count, 3)
    particle_q_prev: np.ndarray
    #: extra fields declared by behaviors (name -> array)
    fields: dict = field(default_factory=dict)
    #: names in ``fields`` that are zeroed at the start of every substep (accumulators)
    accumulators: set = field(default_factory=set)
    time: float = 0.0

    def accumulator(self, name: str, shape) -> np.ndarray:
        """Get (allocating once) a per-substep accumulator field."""
        arr = self.fields.get(name)
        if arr is None:
            arr = np.zeros(shape)
            self.fields[name] = arr
            self.accumulators.add(name)
        return arr

    @classmethod
    def from_model(cls, model: Model) -> "State":
        q = model.particle_q0.copy()
        return cls(q, model.particle_qd0.copy(), np.zeros_like(q), q.copy())

    def copy(self) -> "State":
        return State(self.particle_q.copy(), self.particle_qd.copy(), self.particle_f.copy(),
                     self.particle_q_prev.copy(),
                     {k: (v.copy() if isinstance(v, np.ndarray) else v)
                      for k, v in self.fields.items()}, set(self.accumulators), self.time)


@dataclass
class Control:
    """Time-varying inputs for the substep being computed."""

    #: animated positions of kinematic vertices at the end of the substep [m]
    kinematic_q: np.ndarray
    #: animated positions at the start of the substep [m]
    kinematic_q_prev: np.ndarray
    time: float = 0.0
