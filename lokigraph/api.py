"""Python entry points: load, compile and run scenes without the CLI."""

from __future__ import annotations

from pathlib import Path

from .compile import Compiled, compile_scene
from .run import RunResult, Simulation, run
from .scene import load_scene


def compile_file(path: str | Path) -> Compiled:
    """Load, validate and compile a scene file (raises InputError with every problem found).

    The scene is loaded with ``partial=True`` so that compile checks what is valid even when
    other parts are not: the problems of the scene file and those compile finds (unknown
    collision-group members, bad graph overrides, out-of-range vertices ...) come in one error.
    """
    return compile_scene(load_scene(path, partial=True))


def run_file(path: str | Path, **kw) -> RunResult:
    """Compile and run a scene file; keyword arguments go to :func:`lokigraph.run.run`."""
    return run(compile_file(path), **kw)


__all__ = ["compile_file", "run_file", "compile_scene", "load_scene", "run", "Simulation"]
