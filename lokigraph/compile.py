"""Compile: scene + graph YAML -> validated behaviors -> networkx DAG -> pruned Schedule + Model.

* Edges come from declarations: within a stage, a writer of a field runs before accumulators of
  it, which run before its readers; ``after:`` adds explicit edges.
* Every behavior that no element needs is pruned, with the reason kept; a behavior that reads a
  field nobody writes any more is pruned too (with the chain of reasons).
* Two writers of one field, a cycle, an unknown type ("did you mean"), bad parameters and a
  missing required component are compile errors, all collected and raised once.
* Inside a stage the order is the lexicographic topological order of node names: runs are
  deterministic.
"""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass, field
from pathlib import Path

import networkx as nx
import numpy as np
from pydantic import ValidationError

from .behavior import STAGES, BindContext, Behavior, ConstraintBehavior, clear_bind_caches
from .component import pydantic_messages
from .errors import Diagnostic, GraphError, InputError
from .model import Model
from .registry import get_registry
from .scene import MAX_STEP_RATE, Scene
from .yamlio import Locations, load_yaml

def shipped_graph_dir() -> Path:
    import lokigraph.graphs as g

    return Path(g.__file__).resolve().parent


@dataclass
class GraphNode:
    name: str
    type: str
    domain: str
    params: dict
    after: list[str]
    path: tuple  # location path in the graph YAML


@dataclass
class GraphSpec:
    name: str
    file: str
    nodes: list[GraphNode]
    locations: Locations


def resolve_graph_path(graph: str, base_dir: str) -> Path:
    p = Path(graph)
    if p.suffix in (".yaml", ".yml"):
        cand = Path(base_dir) / p
        return cand if _exists(cand) else p
    return shipped_graph_dir() / f"{graph}.yaml"


def _exists(path: Path) -> bool:
    try:
        return path.exists()
    except (OSError, ValueError):  # a name too long for the file system, a NUL byte
        return False


def load_graph(graph: str, base_dir: str = ".", scene_locs: Locations | None = None) -> GraphSpec:
    path = resolve_graph_path(graph, base_dir)
    if not _exists(path):
        shipped = sorted(x.stem for x in shipped_graph_dir().glob("*.yaml"))
        import difflib

        near = difflib.get_close_matches(graph, shipped, n=1)
        shown = repr(graph) if len(graph) <= 80 else repr(graph[:60]) + f" ({len(graph)} chars)"
        msg = (f"graph {shown} not found" + (f"; did you mean {near[0]!r}?" if near else "")
               + f" (shipped graphs: {', '.join(shipped)})")
        if scene_locs is not None:
            raise GraphError(scene_locs.diag(("graph",), msg))
        raise GraphError(msg)
    data, locs = load_yaml(path)
    diags = []
    if not isinstance(data, dict) or "domains" not in data:
        raise GraphError(locs.diag((), "a graph file is a mapping with 'domains: {domain: "
                                       "[nodes]}'"))
    unknown = set(data) - {"lokigraph_graph", "name", "description", "domains"}
    for k in sorted(unknown):
        diags.append(locs.diag((k,), f"unknown key {k!r}"))
    nodes: list[GraphNode] = []
    names: dict[str, tuple] = {}
    domains = data["domains"] or {}
    if not isinstance(domains, dict):
        raise GraphError(locs.diag(("domains",), "'domains' must map domain names to lists"))
    for domain, items in domains.items():
        if not isinstance(items, list):
            diags.append(locs.diag(("domains", domain), "a domain holds a list of nodes"))
            continue
        for i, item in enumerate(items):
            npath = ("domains", domain, i)
            if isinstance(item, str):
                item = {"type": item}
            if not isinstance(item, dict) or "type" not in item:
                diags.append(locs.diag(npath, "a node needs at least 'type'"))
                continue
            bad = set(item) - {"type", "name", "params", "after"}
            for k in sorted(bad):
                diags.append(locs.diag(npath + (k,), f"unknown node key {k!r} (allowed: type, "
                                                    f"name, params, after)"))
            t = str(item["type"])
            name = str(item.get("name") or _snake(t))
            if name in names:
                diags.append(locs.diag(npath, f"duplicate node name {name!r}; give one a 'name'"))
            names[name] = npath
            after = item.get("after") or []
            if isinstance(after, str):
                after = [after]
            if not isinstance(after, list) or not all(isinstance(a, str) for a in after):
                diags.append(locs.diag(npath + ("after",), "'after' is a node name or a list of "
                                                           "node names"))
                after = []
            params = item.get("params") or {}
            if not isinstance(params, dict):
                diags.append(locs.diag(npath + ("params",), "'params' maps parameter names to "
                                                            "values"))
                params = {}
            nodes.append(GraphNode(name, t, str(domain), dict(params), list(after), npath))
    if diags:
        raise GraphError(diags)
    return GraphSpec(str(data.get("name") or path.stem), str(path), nodes, locs)


def _snake(name: str) -> str:
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower()


@dataclass
class Bound:
    behavior: Behavior
    node: GraphNode
    elements: list
    data: object = None


@dataclass
class Schedule:
    """The compiled per-substep schedule."""

    stages: dict[str, list[Bound]]
    pruned: list[tuple[str, str, str]]  # (name, type, reason)
    graph: GraphSpec
    constraints: list[Bound] = field(default_factory=list)

    def all(self) -> list[Bound]:
        return [b for s in STAGES for b in self.stages.get(s, [])]

    def find(self, type_id: str) -> list[Bound]:
        return [b for b in self.all() if b.behavior.type_id() == type_id]

    def as_dict(self) -> dict:
        out = {"graph": self.graph.name, "graph_file": self.graph.file, "stages": {},
               "pruned": [{"name": n, "type": t, "reason": r} for n, t, r in self.pruned]}
        for s in STAGES:
            out["stages"][s] = [{
                "name": b.behavior.name, "type": b.behavior.type_id(),
                "elements": [e.name for e in b.elements],
                **({"importance": b.behavior.params.importance, "order": b.behavior.params.order}
                   if isinstance(b.behavior, ConstraintBehavior) else {}),
                "detail": b.behavior.describe(b.data)} for b in self.stages.get(s, [])]
        return out

    def format(self) -> str:
        lines = [f"graph: {self.graph.name} ({self.graph.file})"]
        for s in STAGES:
            items = self.stages.get(s, [])
            if not items:
                continue
            lines.append(f"stage {s}:")
            # constraint types in the order the solver interleaves them, then the rest
            items = sorted(items, key=lambda b: (
                0 if isinstance(b.behavior, ConstraintBehavior) else 1,
                b.behavior.params.order if isinstance(b.behavior, ConstraintBehavior) else 0))
            for b in items:
                els = ", ".join(e.name for e in b.elements) or "(all)"
                extra = ""
                if isinstance(b.behavior, ConstraintBehavior):
                    extra = (f" [importance {b.behavior.params.importance:g}, "
                             f"order {b.behavior.params.order}]")
                det = b.behavior.describe(b.data)
                lines.append(f"  {b.behavior.name} ({b.behavior.type_id()}){extra}: {els}"
                             + (f" -- {det}" if det else ""))
        if self.pruned:
            lines.append("pruned:")
            for n, t, r in self.pruned:
                lines.append(f"  {n} ({t}): {r}")
        return "\n".join(lines)


@dataclass
class Compiled:
    scene: Scene
    schedule: Schedule
    model: Model


def _instantiate(graph: GraphSpec, scene: Scene, diags: list) -> list[tuple[Behavior, GraphNode]]:
    """Validate every node's parameters (with the scene's ``graph_overrides`` applied). A problem
    in an override is reported at the scene file's line, one in the graph at the graph's."""
    reg = get_registry()
    out = []
    # a scene whose 'graph' is in error is compiled with the default graph: its overrides name
    # nodes of the graph the user meant, so they are not checked against this one
    overrides = {} if "graph" in scene.failed_fields else scene.spec.graph_overrides
    node_names = {n.name for n in graph.nodes}
    for oname in overrides:
        if oname not in node_names:
            import difflib

            near = difflib.get_close_matches(oname, sorted(node_names), n=1)
            diags.append(scene.locations.diag(("graph_overrides", oname),
                                              f"no graph node named {oname!r}"
                                              + (f"; did you mean {near[0]!r}?" if near else "")))
    for node in graph.nodes:
        cls = reg.behaviors.get(node.type)
        if cls is None:
            d = graph.locations.diag(node.path + ("type",), f"unknown behavior type {node.type!r}"
                                     f"{reg.suggest(node.type, 'behavior')}")
            diags.append(d)
            continue
        params = dict(node.params)
        if issubclass(cls, ConstraintBehavior):
            params.setdefault("importance", cls.default_importance)
            params.setdefault("order", cls.default_order)
        ov = overrides.get(node.name) or {}
        params.update(ov)
        try:
            p = cls.ParamsModel.model_validate(params)
        except ValidationError as exc:
            diags.extend(_param_diagnostics(exc, cls, node, graph, scene, ov))
            continue
        out.append((cls(node.name, p), node))
    return out


def _param_diagnostics(exc: ValidationError, cls, node: GraphNode, graph: GraphSpec,
                       scene: Scene, ov: dict) -> list[Diagnostic]:
    out = []
    for loc, msg in pydantic_messages(exc, cls.ParamsModel.model_fields):
        dotted = ".".join(str(x) for x in loc)
        if (loc and loc[0] in ov) or (not loc and ov):
            path = ("graph_overrides", node.name) + loc
            out.append(scene.locations.diag(path, msg, field=f"graph_overrides.{node.name}"
                                            + (f".{dotted}" if dotted else "")))
        else:
            out.append(graph.locations.diag(node.path + ("params",) + loc, msg,
                                            field=f"{node.name}.params"
                                            + (f".{dotted}" if dotted else "")))
    return out


def compile_scene(scene: Scene) -> Compiled:
    """Compile a loaded scene into a Schedule and a Model (raises InputError/GraphError).

    Every check runs even after a problem is found (the graph's, the components', then binding),
    so that one pass reports every problem; a scene loaded with ``partial=True`` adds its own
    diagnostics, and the problems that only follow from a part of it that failed to load (an
    element left out, a component in error) are dropped. Raises once, with all of them.
    """
    diags: list[Diagnostic] = []
    # a spec changed after validation (bench sweeps use model_copy) is checked again here
    rate = scene.spec.frames.fps * scene.spec.substeps
    if not (0 < rate <= MAX_STEP_RATE) or scene.spec.substeps < 1:
        _raise(scene, [scene.locations.diag(("substeps",), f"fps * substeps = {rate:g} substeps "
                                            f"per second: must be in (0, {MAX_STEP_RATE:g}] "
                                            f"with substeps >= 1", field="scene")])
    try:
        graph = load_graph(scene.spec.graph, scene.base_dir, scene.locations)
    except InputError as exc:
        _raise(scene, exc.diagnostics, graph_error=True)
    behaviors = _instantiate(graph, scene, diags)
    reg = get_registry()

    # component-level requirements (e.g. Pins needs Dynamic on the same element)
    for el in scene.elements:
        for cname, comp in el.components.items():
            for need in getattr(type(comp), "needs", ()):
                if need not in el.components:
                    diags.append(scene.locations.diag(
                        ("elements", el.index, "components", cname),
                        f"{cname} requires component {need} on the same element",
                        element=el.name, field=cname))
            if getattr(type(comp), "needs_geometry", False) and el.geometry is None:
                diags.append(scene.locations.diag(("elements", el.index, "components", cname),
                                                  f"{cname} needs geometry", element=el.name,
                                                  field=cname))

    # ---- decide what each behavior binds to, prune what nobody needs
    kept: list[Bound] = []
    pruned: list[tuple[str, str, str]] = []
    for beh, node in behaviors:
        cls = type(beh)
        if cls.solver is not None and cls.solver != scene.spec.solver:
            pruned.append((beh.name, cls.type_id(), f"scene selects solver "
                                                     f"{scene.spec.solver!r}, not {cls.solver!r}"))
            continue
        if cls.always:
            els = [e for e in scene.elements if e.geometry is not None]
        else:
            els = [e for e in scene.elements
                   if e.has(*cls.requires) and not any(e.has(x) for x in cls.excludes)
                   and (not cls.requires_any or any(e.has(x) for x in cls.requires_any))]
        if not els and not cls.always:
            req = " + ".join(t.type_id() for t in cls.requires) or ""
            if cls.requires_any:
                anyof = " or ".join(t.type_id() for t in cls.requires_any)
                req = f"{req} + ({anyof})" if req else anyof
            pruned.append((beh.name, cls.type_id(), f"no element carries {req}"))
            continue
        kept.append(Bound(beh, node, els))

    known_solvers = sorted({t.solver for t in reg.behaviors.values() if t.solver})
    if scene.spec.solver not in known_solvers:
        import difflib

        near = difflib.get_close_matches(scene.spec.solver, known_solvers, n=1)
        diags.append(scene.locations.diag(("solver",), f"unknown solver {scene.spec.solver!r}"
                                          + (f"; did you mean {near[0]!r}?" if near else "")
                                          + f" (known: {', '.join(known_solvers) or 'none'})"))

    # fixpoint: a behavior that reads a field nobody (kept) writes is pruned, with the chain
    changed = True
    while changed:
        changed = False
        produced: dict[str, list[str]] = {}
        for b in kept:
            for f in type(b.behavior).writes + type(b.behavior).accumulates:
                produced.setdefault(f, []).append(b.behavior.name)
        for b in list(kept):
            missing = [f for f in type(b.behavior).reads if f not in produced]
            if missing:
                f = missing[0]
                writers = [beh.name for beh, _ in behaviors
                           if f in type(beh).writes + type(beh).accumulates]
                why = {n: r for n, _, r in pruned}
                chain = "; ".join(f"{w} was pruned ({why.get(w, 'absent')})" for w in writers)
                pruned.append((b.behavior.name, b.behavior.type_id(),
                               f"reads {f!r}, which no remaining behavior writes"
                               + (f": {chain}" if chain else "")))
                kept.remove(b)
                changed = True

    # ---- DAG
    G = nx.DiGraph()
    byname = {b.behavior.name: b for b in kept}
    stage_of = {b.behavior.name: type(b.behavior).stage for b in kept}
    for b in kept:
        if type(b.behavior).stage not in STAGES:
            diags.append(graph.locations.diag(b.node.path, f"behavior {b.behavior.type_id()} "
                                              f"declares unknown stage {type(b.behavior).stage!r}"))
        G.add_node(b.behavior.name)
    writers: dict[str, list[str]] = {}
    for b in kept:
        for f in type(b.behavior).writes:
            writers.setdefault(f, []).append(b.behavior.name)
    for f, ws in sorted(writers.items()):
        if len(ws) > 1:
            diags.append(graph.locations.diag(byname[ws[1]].node.path,
                                              f"two writers of field {f!r}: "
                                              f"{' and '.join(sorted(ws))}"))
    for a in kept:
        ca = type(a.behavior)
        for b in kept:
            if a is b:
                continue
            cb = type(b.behavior)
            if stage_of[a.behavior.name] != stage_of[b.behavior.name]:
                continue
            rb = set(cb.reads) | set(cb.reads_optional)
            if (set(ca.writes) & (rb | set(cb.accumulates))) or (set(ca.accumulates) & rb):
                G.add_edge(a.behavior.name, b.behavior.name)
    for b in kept:
        for dep in b.node.after:
            if dep not in byname:
                if dep in {n.name for n in graph.nodes}:
                    continue  # pruned dependency: ordering is moot
                diags.append(graph.locations.diag(b.node.path + ("after",),
                                                  f"'after' names unknown node {dep!r}"))
                continue
            if stage_of[dep] != stage_of[b.behavior.name]:
                if STAGES.index(stage_of[dep]) > STAGES.index(stage_of[b.behavior.name]):
                    diags.append(graph.locations.diag(
                        b.node.path + ("after",), f"{b.behavior.name} (stage "
                        f"{stage_of[b.behavior.name]}) cannot run after {dep} (stage "
                        f"{stage_of[dep]})"))
                continue
            G.add_edge(dep, b.behavior.name)
    try:
        cycle = nx.find_cycle(G)
        members = sorted({u for u, _ in cycle})
        diags.append(graph.locations.diag(byname[members[0]].node.path,
                                          f"cycle in the behavior graph: "
                                          f"{' -> '.join([u for u, _ in cycle] + [cycle[0][0]])}"
                                          f" (members: {', '.join(members)})"))
        _raise(scene, diags, graph_error=True)  # no order to bind in
    except nx.NetworkXNoCycle:
        pass
    graph_error = bool(diags)

    stages: dict[str, list[Bound]] = {}
    for s in STAGES:
        names = [n for n in G.nodes if stage_of[n] == s]
        sub = G.subgraph(names)
        order = list(nx.lexicographical_topological_sort(sub))
        stages[s] = [byname[n] for n in order]

    # ---- model and binding
    model = _build_model(scene, diags)
    ctx = BindContext(model, scene)
    # with problems already found, what is bound may be inconsistent (a behavior whose
    # parameters failed is missing): a failure of bind then only follows from those problems
    lenient = bool(diags or scene.diagnostics)
    try:
        for b in [x for s in STAGES for x in stages[s]]:
            try:
                b.data = b.behavior.bind(ctx, b.elements)
            except InputError as exc:
                ctx.diagnostics.extend(exc.diagnostics)
            except Exception:  # noqa: BLE001 - see above; without earlier problems it is a bug
                if not lenient:
                    raise
                b.data = None
            model.data[b.behavior.name] = b.data
    finally:
        clear_bind_caches()
    diags.extend(ctx.diagnostics)
    diags.extend(output_diagnostics(scene))
    if diags or scene.diagnostics:
        _raise(scene, diags, graph_error=graph_error)
    # a constraint type whose elements yield no constraints (e.g. shear with no shear stiffness)
    for s in STAGES:
        for b in list(stages[s]):
            if isinstance(b.behavior, ConstraintBehavior) and b.data is None:
                stages[s].remove(b)
                pruned.append((b.behavior.name, b.behavior.type_id(),
                               "bound elements yield no constraints ("
                               + ", ".join(e.name for e in b.elements) + ")"))
    constraints = sorted([b for b in stages["solve"] if isinstance(b.behavior, ConstraintBehavior)
                          and b.data is not None],
                         key=lambda b: (b.behavior.params.order, b.behavior.name))
    schedule = Schedule(stages, pruned, graph, constraints)
    return Compiled(scene, schedule, model)


def output_diagnostics(scene) -> list:
    """Problems of ``output.elements`` (unknown names, elements without geometry), located at
    the scene's lines; compile and ``lokigraph validate`` report them with everything else."""
    names = scene.spec.output.elements
    if names is None:
        return []
    by_name = {e.name: e for e in scene.elements}
    diags = []
    for i, n in enumerate(names):
        el = by_name.get(n)
        where = ("output", "elements", i)
        if el is None:
            near = difflib.get_close_matches(str(n), list(by_name), n=1, cutoff=0.6)
            diags.append(scene.locations.diag(
                where, f"unknown element {n!r}" + (f"; did you mean {near[0]!r}?" if near
                                                   else ""), field="output.elements"))
        elif el.geometry is None or el.vertex_count == 0:
            diags.append(scene.locations.diag(where, "element has no geometry to write",
                                              element=n, field="output.elements"))
    return diags


def _raise(scene: Scene, found: list[Diagnostic], graph_error: bool = False):
    """Raise once with the scene's own diagnostics and those found by compile, minus the
    spurious ones, each at the most precise place of the user's file."""
    found = [_refine(d, scene) for d in found if not _spurious(d, scene)]
    every = list(scene.diagnostics) + found
    if not every:  # pragma: no cover - only spurious ones: the scene's own explain them
        every = list(found)
    if graph_error and not scene.diagnostics:
        raise GraphError(every)
    raise InputError(every)


def _spurious(d: Diagnostic, scene: Scene) -> bool:
    """True for a compile diagnostic that only follows from a part of the scene that failed to
    load (and was reported): an element left out, a component in error on its element."""
    for name, parts in scene.failed.items():
        if "*" in parts:
            if d.element == name or f"'{name}'" in d.message or f'"{name}"' in d.message:
                return True
        elif d.element == name and any(p and (p in d.message or d.field.split(".")[0] == p)
                                       for p in parts):
            return True
    return False


def _refine(d: Diagnostic, scene: Scene) -> Diagnostic:
    """A diagnostic placed at its element's first line (``ctx.error``) moves to the field it
    names (``CollisionGroup.members`` -> the line of ``members``, or of the list item the
    message quotes)."""
    if not d.field or d.file != scene.file:
        return d
    el = next((e for e in scene.elements if e.name == d.element), None)
    if el is None or (d.line, d.column) not in ((el.line, el.column), (el.line, 0), (0, 0)):
        return d
    parts: list = [int(p) if p.isdigit() else p for p in d.field.split(".")]
    if parts[0] in el.components:
        parts = ["components"] + parts
    path = ("elements", el.index) + tuple(parts)
    value = _lookup(scene.raw, path)
    if isinstance(value, list):  # point at the item the message quotes
        for i, item in enumerate(value):
            if isinstance(item, (str, int)) and not isinstance(item, bool) and (
                    repr(item) in d.message):
                path = path + (i,)
                break
    line, col = scene.locations.get(path)
    if not line:
        return d
    return Diagnostic(file=d.file, line=line, column=col, element=d.element, field=d.field,
                      message=d.message)


def _lookup(data, path: tuple):
    for p in path:
        try:
            data = data[p]
        except (KeyError, IndexError, TypeError):
            return None
    return data


def build_model(scene: Scene) -> Model:
    """Global vertex numbering, masses (from components with a ``particle_role``)."""
    diags: list[Diagnostic] = []
    model = _build_model(scene, diags)
    if diags:
        raise InputError(diags)
    return model


def _build_model(scene: Scene, diags: list) -> Model:
    """:func:`build_model` that reports its problems into ``diags`` and still returns a model."""
    offset = 0
    qs, rest, qd, mass, kin, elem, comp_k = [], [], [], [], [], [], []
    for el in scene.elements:
        if el.geometry is None:
            continue
        el.vertex_offset = offset
        n = el.vertex_count
        offset += n
        role, m, v0 = "kinematic", np.zeros(n), np.zeros((n, 3))
        kc = np.zeros(n)
        for comp in el.components.values():
            if hasattr(comp, "compliant_stiffness"):
                try:
                    kc = comp.compliant_stiffness(el)
                except InputError as exc:
                    diags.extend(exc.diagnostics)
            r = getattr(type(comp), "particle_role", None)
            if r == "dynamic":
                role = "dynamic"
                try:
                    m = comp.vertex_mass(el)
                    v0 = comp.initial_velocity(el)
                except InputError as exc:
                    diags.extend(exc.diagnostics)
                    m = np.ones(n)
        qs.append(el.geometry.points)
        rname = _rest_channel(el)
        r = el.geometry.channels.get(rname)
        if r is not None and np.size(r) != 3 * n:
            diags.append(Diagnostic(file=el.source_file, line=el.line, column=el.column,
                                    element=el.name, field=f"channels.{rname}",
                                    message=f"rest positions channel {rname!r} holds "
                                            f"{np.size(r)} values, not 3 per vertex ({3 * n})"))
            r = None
        rest.append(np.asarray(r, dtype=np.float64).reshape(n, 3) if r is not None
                    else el.geometry.points)
        qd.append(v0)
        mass.append(m)
        kin.append(np.full(n, role == "kinematic"))
        elem.append(np.full(n, el.index, dtype=np.int64))
        comp_k.append(kc if role == "kinematic" else np.zeros(n))
        if role == "dynamic" and n and np.any(m <= 0):
            bad = int(np.argmax(m <= 0))
            diags.append(Diagnostic(file=el.source_file, line=el.line, column=el.column,
                                    element=el.name, field="Dynamic.mass_density",
                                    message=f"{int((m <= 0).sum())} vertices with zero mass "
                                            f"(first at vertex {bad}); isolated vertices need "
                                            f"an edge, triangle or tetrahedron, or point_mass"))
    cat = lambda xs, shape: np.concatenate(xs) if xs else np.zeros(shape)  # noqa: E731
    q0 = cat(qs, (0, 3)).astype(np.float64)
    m = cat(mass, (0,)).astype(np.float64)
    k = cat(kin, (0,)).astype(bool)
    inv = np.where((m > 0) & ~k, 1.0 / np.where(m > 0, m, 1.0), 0.0)
    # compliant kinematics: the energy (K/2)|x_goal - x|^2 is an inertia term with mass K h^2
    # around the animated position (Loki supplement eq. 3-4)
    kc = cat(comp_k, (0,)).astype(np.float64)
    h = 1.0 / (scene.spec.frames.fps * scene.spec.substeps)
    compliant = k & (kc > 0)
    with np.errstate(over="ignore", under="ignore", divide="ignore"):
        inv[compliant] = 1.0 / (kc[compliant] * h * h)
    bad = compliant & ~np.isfinite(inv)
    if bad.any():  # K V h^2 underflows: a stiffness too small to mean anything
        elem_of = cat(elem, (0,)).astype(np.int64)
        el = scene.elements[int(elem_of[int(np.argmax(bad))])]
        diags.append(Diagnostic(file=el.source_file, line=el.line, column=el.column,
                                element=el.name, field="Kinematic.stiffness",
                                message=f"{int(bad.sum())} vertices have a compliant stiffness so "
                                        f"small that K * area * h^2 is 0 at this time step; use "
                                        f"0 (not compliant) or a larger value"))
        inv[bad] = 0.0
    return Model(particle_count=len(q0), particle_q0=q0, particle_rest=cat(rest, (0, 3)).copy(),
                 particle_qd0=cat(qd, (0, 3)).astype(np.float64), particle_mass=m,
                 particle_inv_mass=inv, particle_kinematic=k, particle_compliant=compliant,
                 particle_element=cat(elem, (0,)).astype(np.int64), elements=scene.elements,
                 gravity=np.asarray(scene.spec.gravity, dtype=np.float64),
                 fps=scene.spec.frames.fps, substeps=scene.spec.substeps, seed=scene.spec.seed)


def _rest_channel(el) -> str:
    for comp in el.components.values():
        ch = getattr(comp, "rest_channel", None)
        if ch:
            return ch
    return "rest"
