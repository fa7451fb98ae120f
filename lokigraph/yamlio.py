"""YAML reading that remembers where every value came from (file, line, column).

``load_yaml`` returns plain Python data plus a :class:`Locations` table keyed by the path of
each value (a tuple of mapping keys and list indices), so that a validation error deep inside a
component can be reported as ``scene.yaml:14:7``.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from .errors import Diagnostic, InputError


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

    def diag(self, path: tuple, message: str, element: str = "", field: str = "") -> Diagnostic:
        line, col = self.get(path)
        return Diagnostic(file=self.file, line=line, column=col, element=element, field=field,
                          message=message)


def _construct(node, path: tuple, locs: Locations, errors: list[Diagnostic]):
    if isinstance(node, yaml.MappingNode):
        out = {}
        locs.set(path, node.start_mark)
        for key_node, value_node in node.value:
            key = yaml.safe_load(yaml.serialize(key_node)) if not isinstance(
                key_node, yaml.ScalarNode) else _scalar(key_node)
            if isinstance(key, (list, dict)):
                errors.append(Diagnostic(file=locs.file, line=key_node.start_mark.line + 1,
                                         column=key_node.start_mark.column + 1,
                                         message="mapping keys must be scalars"))
                continue
            if key in out:
                errors.append(Diagnostic(file=locs.file, line=key_node.start_mark.line + 1,
                                         column=key_node.start_mark.column + 1,
                                         message=f"duplicate key {key!r}"))
            sub = path + (key,)
            out[key] = _construct(value_node, sub, locs, errors)
            # the key's own position is where a user looks for "field: value"
            locs.set(sub, key_node.start_mark)
        return out
    if isinstance(node, yaml.SequenceNode):
        locs.set(path, node.start_mark)
        out = []
        for i, item in enumerate(node.value):
            out.append(_construct(item, path + (i,), locs, errors))
            locs.set(path + (i,), item.start_mark)
        return out
    locs.set(path, node.start_mark)
    return _scalar(node)


class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads ``1e6`` / ``1.0e6`` as floats (YAML 1.2 style); PyYAML's
    YAML 1.1 resolver reads them as strings, which would silently become channel names."""


_Loader.yaml_implicit_resolvers = {k: list(v) for k, v in
                                   yaml.SafeLoader.yaml_implicit_resolvers.items()}
_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    __import__("re").compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                    |\.[0-9_]+(?:[eE][-+][0-9]+)?
                    |[-+]?\.(?:inf|Inf|INF)
                    |\.(?:nan|NaN|NAN))$""", __import__("re").X),
    list("-+0123456789."))

_resolver_loader = _Loader("")


def _scalar(node):
    # Resolve the scalar's tag the way SafeLoader would (ints, floats, bools, null, strings).
    return _resolver_loader.construct_object(node, deep=True)


def load_yaml_text(text: str, file: str = "<string>") -> tuple[object, Locations]:
    locs = Locations(file)
    try:
        node = yaml.compose(text, Loader=_Loader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc)
        raise InputError(Diagnostic(file=file, line=(mark.line + 1) if mark else 0,
                                    column=(mark.column + 1) if mark else 0,
                                    message=f"malformed YAML: {problem}")) from None
    if node is None:
        raise InputError(Diagnostic(file=file, message="the file is empty"))
    errors: list[Diagnostic] = []
    try:
        data = _construct(node, (), locs, errors)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise InputError(Diagnostic(file=file, line=(mark.line + 1) if mark else 0,
                                    column=(mark.column + 1) if mark else 0,
                                    message=f"malformed YAML: {exc}")) from None
    if errors:
        raise InputError(errors)
    return data, locs


def load_yaml(path: str | Path) -> tuple[object, Locations]:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(Diagnostic(file=str(path), message="file not found")) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(Diagnostic(file=str(path), message=f"cannot read file: {exc}")) from None
    return load_yaml_text(text, str(path))
