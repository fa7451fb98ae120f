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

import re
from dataclasses import dataclass, field
from pathlib import Path

import networkx as nx
import numpy as np
from pydantic import ValidationError

from .behavior import STAGES, BindContext, Behavior, ConstraintBehavior
from .component import pydantic_diagnostics
from .errors import Diagnostic, GraphError, InputError
from .model import Model
from .registry import get_registry
from .scene import Scene
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
        return cand if cand.exists() else p
    return shipped_graph_dir() / f"{graph}.yaml"


def load_graph(graph: str, base_dir: str = ".", scene_locs: Locations | None = None) -> GraphSpec:
    path = resolve_graph_path(graph, base_dir)
    if not path.exists():
        shipped = sorted(x.stem for x in shipped_graph_dir().glob("*.yaml"))
        import difflib

        near = difflib.get_close_matches(graph, shipped, n=1)
        msg = (f"graph {graph!r} not found" + (f"; did you mean {near[0]!r}?" if near else "")
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
            nodes.append(GraphNode(name, t, str(domain), dict(item.get("params") or {}),
                                   list(after), npath))
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
    reg = get_registry()
    out = []
    overrides = scene.spec.graph_overrides
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
        params.update(overrides.get(node.name, {}))
        try:
            p = cls.ParamsModel.model_validate(params)
        except ValidationError as exc:
            for d in pydantic_diagnostics(exc, graph.locations, node.path + ("params",), "",
                                          f"{node.name}.params",
                                          known_fields=cls.ParamsModel.model_fields):
                diags.append(d)
            continue
        out.append((cls(node.name, p), node))
    return out


def compile_scene(scene: Scene) -> Compiled:
    """Compile a loaded scene into a Schedule and a Model (raises InputError/GraphError)."""
    diags: list[Diagnostic] = []
    graph = load_graph(scene.spec.graph, scene.base_dir, scene.locations)
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
    if diags:
        raise GraphError(diags)

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
    except nx.NetworkXNoCycle:
        pass
    if diags:
        raise GraphError(diags)

    stages: dict[str, list[Bound]] = {}
    for s in STAGES:
        names = [n for n in G.nodes if stage_of[n] == s]
        sub = G.subgraph(names)
        order = list(nx.lexicographical_topological_sort(sub))
        stages[s] = [byname[n] for n in order]

    # ---- model and binding
    model = build_model(scene)
    ctx = BindContext(model, scene)
    for b in [x for s in STAGES for x in stages[s]]:
        try:
            b.data = b.behavior.bind(ctx, b.elements)
        except InputError as exc:
            ctx.diagnostics.extend(exc.diagnostics)
        model.data[b.behavior.name] = b.data
    if ctx.diagnostics:
        raise InputError(ctx.diagnostics)
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


def build_model(scene: Scene) -> Model:
    """Global vertex numbering, masses (from components with a ``particle_role``)."""
    offset = 0
    qs, rest, qd, mass, kin, elem, comp_k = [], [], [], [], [], [], []
    diags = []
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
        r = el.geometry.channels.get(_rest_channel(el))
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
    if diags:
        raise InputError(diags)
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
    inv[compliant] = 1.0 / (kc[compliant] * h * h)
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
