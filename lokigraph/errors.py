"""One exception family for everything a user can get wrong, each mapped to a CLI exit code.

``InputError`` (exit 2) carries a list of :class:`Diagnostic` so that every problem of a file is
reported at once, sorted by position. ``SimulationError`` (exit 3) names the element, vertex and
step where a run went wrong. Anything else escaping the CLI is a bug (exit 1).
"""

from __future__ import annotations

from dataclasses import dataclass, field

EXIT_OK = 0
EXIT_UNEXPECTED = 1
EXIT_INPUT = 2
EXIT_SIMULATION = 3


@dataclass(frozen=True, order=True)
class Diagnostic:
    """One problem found in user input.

    ``file``/``line``/``column`` are 1-based where known; ``element`` and ``field`` name the scene
    element and the ``Component.field`` (or graph node) concerned.
    """

    file: str = ""
    line: int = 0
    column: int = 0
    element: str = ""
    field: str = ""
    message: str = ""

    def format(self) -> str:
        where = ""
        if self.file:
            where = self.file
            if self.line:
                where += f":{self.line}"
                if self.column:
                    where += f":{self.column}"
            where += ": "
        what = []
        if self.element:
            what.append(f'element "{self.element}"')
        if self.field:
            what.append(self.field)
        head = ", ".join(what)
        return f"{where}{head + ': ' if head else ''}{self.message}"


class LokigraphError(Exception):
    """Base of every error lokigraph raises on purpose."""

    exit_code = EXIT_UNEXPECTED


class InputError(LokigraphError):
    """Invalid input: YAML, components, geometry or graph. Carries every diagnostic found."""

    exit_code = EXIT_INPUT

    def __init__(self, diagnostics: list[Diagnostic] | Diagnostic | str):
        if isinstance(diagnostics, str):
            diagnostics = [Diagnostic(message=diagnostics)]
        elif isinstance(diagnostics, Diagnostic):
            diagnostics = [diagnostics]
        self.diagnostics = sorted(set(diagnostics))
        super().__init__(self._text())

    def _text(self) -> str:
        lines = [d.format() for d in self.diagnostics]
        if len(lines) == 1:
            return lines[0]
        return f"{len(lines)} errors:\n" + "\n".join("  " + s for s in lines)


class GraphError(InputError):
    """The behavior graph is invalid (unknown type, cycle, two writers, missing component)."""


class SimulationError(LokigraphError):
    """A run failed (non-finite value, solver failure). Frames written before it are kept."""

    exit_code = EXIT_SIMULATION

    def __init__(self, message: str, *, element: str = "", vertex: int = -1, step: int = -1,
                 frame: int = -1):
        self.element = element
        self.vertex = vertex
        self.step = step
        self.frame = frame
        parts = []
        if element:
            parts.append(f'element "{element}"')
        if vertex >= 0:
            parts.append(f"vertex {vertex}")
        if frame >= 0:
            parts.append(f"frame {frame}")
        if step >= 0:
            parts.append(f"substep {step}")
        super().__init__((", ".join(parts) + ": " if parts else "") + message)


class OutputError(LokigraphError):
    """The output location is unusable: exit 2 when known before running (``--out`` is a file, a
    folder that cannot be created or written, another run's frames in the way), exit 3 when a
    write fails during the run (disk full, permission lost). Frames written before it are kept."""

    def __init__(self, message: str, exit_code: int = EXIT_INPUT):
        self.exit_code = exit_code
        super().__init__(message)


@dataclass
class DiagnosticList:
    """Collects diagnostics during validation; ``raise_if_any`` raises once with all of them."""

    items: list[Diagnostic] = field(default_factory=list)
    error_type: type = InputError

    def add(self, **kw) -> None:
        self.items.append(Diagnostic(**kw))

    def extend(self, diags) -> None:
        self.items.extend(diags)

    def __bool__(self) -> bool:
        return bool(self.items)

    def raise_if_any(self) -> None:
        if self.items:
            raise self.error_type(self.items)
