"""YAML reading that remembers where every value came from (file, line, column).

``load_yaml`` returns plain Python data plus a :class:`Locations` table keyed by the path of
each value (a tuple of mapping keys and list indices), so that a validation error deep inside a
component can be reported as ``scene.yaml:14:7``.

Hostile input is bounded before it can hurt: nesting deeper than :data:`MAX_DEPTH`, aliases that
would expand a file past :data:`MAX_ALIAS_NODES` extra values ("billion laughs"), recursive
aliases, integers too long to convert, NUL characters in strings and undecodable scalars are all
reported as located diagnostics, never as a crash or a hang.
"""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from .errors import Diagnostic, InputError

MAX_DEPTH = 100
"""Deepest nesting of mappings and lists accepted (a scene needs fewer than 10 levels)."""

MAX_NODES = 2_000_000
"""Most YAML nodes in one file (a scene with a 10^6-entry vertex list still fits)."""

MAX_ALIAS_NODES = 100_000
"""Most values that aliases (``*name``) may add by expansion, over the whole file."""

_MAX_INT_BITS = 14_000  # at most 4215 decimal digits: under Python's int <-> str limit (4300)


class Locations:
    """Path -> (line, column), both 1-based. Unknown paths fall back to their nearest parent."""

    def __init__(self, file: str):
        self.file = file
        self._pos: dict[tuple, tuple[int, int]] = {}

    def set(self, path: tuple, mark) -> None:
        self._pos[path] = (mark.line + 1, mark.column + 1)

    def get(self, path: tuple) -> tuple[int, int]:
        path = tuple(path)
        while path:
            if path in self._pos:
                return self._pos[path]
            path = path[:-1]
        return self._pos.get((), (0, 0))

    def has(self, path: tuple) -> bool:
        return tuple(path) in self._pos

    def diag(self, path: tuple, message: str, element: str = "", field: str = "") -> Diagnostic:
        line, col = self.get(path)
        return Diagnostic(file=self.file, line=line, column=col, element=element, field=field,
                          message=message)


class _Abort(Exception):
    """Stop reading the file: one diagnostic that makes the rest meaningless."""

    def __init__(self, diag: Diagnostic):
        self.diag = diag


def _at(file: str, mark, message: str) -> Diagnostic:
    return Diagnostic(file=file, line=(mark.line + 1) if mark else 0,
                      column=(mark.column + 1) if mark else 0, message=message)


class _Builder:
    """Turns a composed node tree into plain data, bounded in depth and in alias expansion."""

    def __init__(self, locs: Locations, distinct_nodes: int):
        self.locs = locs
        self.errors: list[Diagnostic] = []
        self.budget = distinct_nodes + MAX_ALIAS_NODES
        self.visits = 0
        self.active: set[int] = set()  # ids of the nodes on the current path (recursive aliases)

    def build(self, node, path: tuple):
        self.visits += 1
        if self.visits > self.budget:
            raise _Abort(_at(self.locs.file, node.start_mark,
                             f"aliases expand this file past {MAX_ALIAS_NODES} extra values "
                             f"(an alias bomb?); write the values out or use fewer aliases"))
        if len(path) > MAX_DEPTH:
            raise _Abort(_at(self.locs.file, node.start_mark,
                             f"nesting deeper than {MAX_DEPTH} levels"))
        if isinstance(node, (yaml.MappingNode, yaml.SequenceNode)):
            if id(node) in self.active:
                raise _Abort(_at(self.locs.file, node.start_mark,
                                 "an alias refers to a value that contains it (recursive alias)"))
            self.active.add(id(node))
            try:
                if isinstance(node, yaml.MappingNode):
                    return self._mapping(node, path)
                return self._sequence(node, path)
            finally:
                self.active.discard(id(node))
        self.locs.set(path, node.start_mark)
        return self._scalar(node)

    def _mapping(self, node, path):
        out = {}
        # merge keys (<<: *defaults) first: the mapping's own keys override what they bring
        for key_node, value_node in node.value:
            if key_node.tag != "tag:yaml.org,2002:merge":
                continue
            sources = value_node.value if isinstance(value_node, yaml.SequenceNode) else [
                value_node]
            for src in sources:
                if not isinstance(src, yaml.MappingNode):
                    self.errors.append(_at(self.locs.file, src.start_mark, "a merge key (<<) "
                                           "takes a mapping or a list of mappings"))
                    continue
                for k, v in self.build(src, path).items():
                    out.setdefault(k, v)
        self.locs.set(path, node.start_mark)
        own: set = set()
        for key_node, value_node in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            if not isinstance(key_node, yaml.ScalarNode):
                self.errors.append(_at(self.locs.file, key_node.start_mark,
                                       "mapping keys must be scalars"))
                continue
            n_errors = len(self.errors)
            key = self._scalar(key_node)
            if len(self.errors) > n_errors:  # the key itself could not be read (reported)
                continue
            try:
                hash(key)
            except TypeError:
                self.errors.append(_at(self.locs.file, key_node.start_mark,
                                       "mapping keys must be scalars"))
                continue
            if key in own:
                self.errors.append(_at(self.locs.file, key_node.start_mark,
                                       f"duplicate key {_short(key)}"))
            own.add(key)
            sub = path + (key,)
            out[key] = self.build(value_node, sub)
            # the key's own position is where a user looks for "field: value"
            self.locs.set(sub, key_node.start_mark)
        return out

    def _sequence(self, node, path):
        self.locs.set(path, node.start_mark)
        out = []
        for i, item in enumerate(node.value):
            out.append(self.build(item, path + (i,)))
            self.locs.set(path + (i,), item.start_mark)
        return out

    def _scalar(self, node):
        # Resolve the scalar's tag the way SafeLoader would (ints, floats, bools, null, strings).
        try:
            value = _resolver_loader.construct_object(node, deep=True)
        except yaml.YAMLError as exc:
            self.errors.append(_at(self.locs.file, node.start_mark,
                                   f"malformed YAML: {getattr(exc, 'problem', None) or exc}"))
            return None
        except ValueError as exc:
            text = str(node.value)
            kind = str(node.tag).rsplit(":", 1)[-1]
            if "integer string conversion" in str(exc) or (
                    len(text) > 50 and text.lstrip("+-").replace("_", "").isdigit()):
                msg = f"integer with {len(text)} digits is too large"
            elif kind == "timestamp":
                msg = f"cannot read value {_short(text)} as a date: {exc}"
            else:
                msg = f"cannot read value {_short(text)} as {kind}"
            self.errors.append(_at(self.locs.file, node.start_mark, msg))
            return None
        except (TypeError, OverflowError, ArithmeticError):
            kind = str(node.tag).rsplit(":", 1)[-1]
            self.errors.append(_at(self.locs.file, node.start_mark,
                                   f"cannot read value {_short(str(node.value))} as {kind}"))
            return None
        finally:
            _resolver_loader.constructed_objects.pop(node, None)
        if isinstance(value, int) and value.bit_length() > _MAX_INT_BITS:
            # hex and sexagesimal integers escape Python's 4300-digit limit on reading, but
            # not on printing: refuse them here so that no message can fail to show them
            self.errors.append(_at(self.locs.file, node.start_mark,
                                   f"integer with about {int(value.bit_length() * 0.30103)} "
                                   f"digits is too large"))
            return None
        if isinstance(value, str) and "\x00" in value:
            self.errors.append(_at(self.locs.file, node.start_mark,
                                   "NUL character (\\0) in a string"))
            return value.replace("\x00", "")
        return value


def _short(value, n: int = 60) -> str:
    s = repr(value)
    return s if len(s) <= n else s[:n - 5] + "...'"


class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads ``1e6`` / ``1.0e6`` as floats (YAML 1.2 style); PyYAML's
    YAML 1.1 resolver reads them as strings, which would silently become channel names.

    Composing is bounded: nesting deeper than :data:`MAX_DEPTH` and more than :data:`MAX_NODES`
    nodes stop the reader with a located error (PyYAML's composer recurses per level).
    """

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0
        self.node_count = 0

    def compose_node(self, parent, index):
        self.node_count += 1
        if self.node_count > MAX_NODES:
            raise _Abort(_at(self.name, self.peek_event().start_mark,
                             f"more than {MAX_NODES} values in one file"))
        if self._depth >= MAX_DEPTH:
            raise _Abort(_at(self.name, self.peek_event().start_mark,
                             f"nesting deeper than {MAX_DEPTH} levels"))
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


_Loader.yaml_implicit_resolvers = {k: list(v) for k, v in
                                   yaml.SafeLoader.yaml_implicit_resolvers.items()}
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                    |\.[0-9_]+(?:[eE][-+][0-9]+)?
                    |[-+]?\.(?:inf|Inf|INF)
                    |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."))

_resolver_loader = _Loader("")


def _yaml_error(file: str, exc: yaml.YAMLError, text: str = "") -> Diagnostic:
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None)
    if isinstance(exc, yaml.reader.ReaderError):
        ch = exc.character
        what = f"U+{ch:04X}" if isinstance(ch, int) else repr(ch)
        before = text[:exc.position] if isinstance(exc.position, int) else ""
        line = before.count("\n") + 1 if text else 0
        col = len(before) - (before.rfind("\n") + 1) + 1 if text else 0
        return Diagnostic(file=file, line=line, column=col,
                          message=f"malformed YAML: control character {what} is not allowed")
    if problem is None:
        problem = str(exc)
    context = getattr(exc, "context", None)
    if context and problem.startswith("but "):  # "expected a single document ..., but found"
        problem = f"{context}, {problem}"
    return _at(file, mark, f"malformed YAML: {problem}")


def load_yaml_text(text: str, file: str = "<string>") -> tuple[object, Locations]:
    locs = Locations(file)
    try:
        loader = _Loader(text)
    except yaml.YAMLError as exc:  # a character YAML does not allow, found before parsing
        raise InputError(_yaml_error(file, exc, text)) from None
    loader.name = file
    try:
        try:
            node = loader.get_single_node()
        except yaml.YAMLError as exc:
            raise InputError(_yaml_error(file, exc, text)) from None
        except RecursionError:  # pragma: no cover - MAX_DEPTH stops it first
            raise InputError(Diagnostic(file=file, message="malformed YAML: nested too "
                                                           "deeply")) from None
        finally:
            loader.dispose()
        if node is None:
            raise InputError(Diagnostic(file=file, message="the file is empty"))
        builder = _Builder(locs, loader.node_count)
        try:
            data = builder.build(node, ())
        except yaml.YAMLError as exc:
            raise InputError(_yaml_error(file, exc)) from None
    except _Abort as stop:
        raise InputError(stop.diag) from None
    if builder.errors:
        raise InputError(builder.errors)
    return data, locs


def load_yaml(path: str | Path) -> tuple[object, Locations]:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(Diagnostic(file=str(path), message="file not found")) from None
    except IsADirectoryError:
        raise InputError(Diagnostic(file=str(path), message="is a folder, not a file")) from None
    except UnicodeDecodeError as exc:
        raise InputError(Diagnostic(file=str(path), message=f"not UTF-8 text (byte "
                                                            f"{exc.start}): is this a YAML "
                                                            f"file?")) from None
    except (OSError, ValueError) as exc:
        raise InputError(Diagnostic(file=str(path), message=f"cannot read file: {exc}")) from None
    return load_yaml_text(text, str(path))
