"""Registry of behaviors and components, discovered through entry points.

Groups: ``lokigraph.behaviors`` and ``lokigraph.components``. An entry point may load a class
or a list of classes. The built-ins register the same way a plugin does. A plugin that fails to
import is reported with its distribution name; using one of its types raises an error chained to
the import error (never a silent skip).
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, field
from importlib.metadata import entry_points

from .behavior import Behavior
from .component import Component

GROUPS = ("lokigraph.behaviors", "lokigraph.components")


@dataclass
class Registry:
    behaviors: dict[str, type[Behavior]] = field(default_factory=dict)
    components: dict[str, type[Component]] = field(default_factory=dict)
    source: dict[str, str] = field(default_factory=dict)  # type id -> distribution name
    broken: dict[str, tuple[str, BaseException]] = field(default_factory=dict)  # ep -> (dist, exc)

    def add(self, cls, dist: str = "") -> None:
        if isinstance(cls, type) and issubclass(cls, Behavior):
            self.behaviors[cls.type_id()] = cls
        elif isinstance(cls, type) and issubclass(cls, Component):
            self.components[cls.type_id()] = cls
        else:
            raise TypeError(f"{cls!r} is neither a Behavior nor a Component subclass")
        self.source[cls.type_id()] = dist

    def suggest(self, name: str, kind: str) -> str:
        pool = self.behaviors if kind == "behavior" else self.components
        near = difflib.get_close_matches(name, list(pool), n=1, cutoff=0.6)
        broken = ""
        if self.broken:
            broken = "; note: plugins failed to load: " + ", ".join(
                f"{ep} (from {dist}: {type(e).__name__}: {e})" for ep, (dist, e) in
                sorted(self.broken.items()))
        return (f"; did you mean {near[0]!r}?" if near else "") + broken

    def broken_error(self):
        """The first import error of a broken plugin, to chain lookup errors to."""
        for _, (_, exc) in sorted(self.broken.items()):
            return exc
        return None


_REGISTRY: Registry | None = None


def get_registry(refresh: bool = False) -> Registry:
    global _REGISTRY
    if _REGISTRY is not None and not refresh:
        return _REGISTRY
    reg = Registry()
    # built-ins first, directly (works from a source tree without installed metadata too)
    from lokigraph.behaviors import BUILTIN_BEHAVIORS
    from lokigraph.components import BUILTIN_COMPONENTS

    for cls in BUILTIN_COMPONENTS + BUILTIN_BEHAVIORS:
        reg.add(cls, "lokigraph")
    for group in GROUPS:
        for ep in sorted(entry_points(group=group), key=lambda e: e.name):
            dist = ep.dist.name if ep.dist is not None else "?"
            if dist == "lokigraph":
                continue
            try:
                obj = ep.load()
                items = obj if isinstance(obj, (list, tuple)) else [obj]
                for cls in items:
                    reg.add(cls, dist)
            except Exception as exc:  # noqa: BLE001 - remembered and reported with the dist name
                reg.broken[f"{group}:{ep.name}"] = (dist, exc)
    _REGISTRY = reg
    return reg
