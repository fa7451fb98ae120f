"""JSON schema of a scene file: every registered component, every generator's parameters, and
``graph_overrides`` for the nodes of the shipped default graph, with value bounds
(``minimum``/``exclusiveMinimum``/``maximum``) wherever a field has a physical range.

Editors that read JSON schema (VS Code's YAML extension, for instance) then complete component
names, fields and generator parameters and flag a negative mass while typing;
``lokigraph validate`` performs the same checks and more (vertex counts, references).
"""

from __future__ import annotations

from .registry import get_registry
from .scene import SceneSpec


def _merge(defs: dict, schema: dict, name: str) -> dict:
    """Move ``schema``'s own ``$defs`` into ``defs`` and store it there as ``name``."""
    for k, v in schema.pop("$defs", {}).items():
        defs.setdefault(k, v)
    defs[name] = schema
    return {"$ref": f"#/$defs/{name}"}


def _generator_models() -> dict:
    try:
        from .generators import GENERATOR_MODELS
    except ImportError:  # pragma: no cover - older generators module
        return {}
    return dict(GENERATOR_MODELS)


def _default_graph_nodes():
    """(node name, behavior class) of the shipped default graph, in graph order."""
    from .compile import load_graph

    reg = get_registry()
    try:
        graph = load_graph("default")
    except Exception:  # noqa: BLE001 - the schema still serves everything else  # pragma: no cover
        return []
    return [(n.name, reg.behaviors[n.type]) for n in graph.nodes if n.type in reg.behaviors]


def export_schema() -> dict:
    reg = get_registry()
    comps = {name: cls.model_json_schema() for name, cls in sorted(reg.components.items())}
    behs = {name: {"stage": cls.stage, "requires": [t.type_id() for t in cls.requires],
                   "params": cls.ParamsModel.model_json_schema()}
            for name, cls in sorted(reg.behaviors.items())}
    scene = SceneSpec.model_json_schema()
    defs = scene.setdefault("$defs", {})

    # elements[].components: component names and their fields
    comp_refs = {n: _merge(defs, s, f"component_{n}") for n, s in comps.items()}
    el = defs.get("ElementSpec")
    if el is not None:
        el["properties"]["components"] = {
            "type": "object", "additionalProperties": False,
            "description": "Components by type name (see `lokigraph behaviors`).",
            "properties": comp_refs}

    # geometry.params: the parameters of the generator named in 'generator'
    gens = _generator_models()
    geo = defs.get("GeometrySpec")
    if gens and geo is not None:
        rules = []
        for name, model in sorted(gens.items()):
            ref = _merge(defs, model.model_json_schema(), f"generator_{name}")
            rules.append({"if": {"properties": {"generator": {"const": name}},
                                 "required": ["generator"]},
                          "then": {"properties": {"params": ref}}})
        geo.setdefault("allOf", []).extend(rules)
        gen_prop = geo.get("properties", {}).get("generator")
        if isinstance(gen_prop, dict):
            gen_prop.setdefault("description", "Built-in generator; its parameters go in "
                                               "'params': " + ", ".join(sorted(gens)) + ".")

    # graph_overrides: node name of the default graph -> that behavior's parameters
    nodes = _default_graph_nodes()
    if nodes:
        props = {}
        for node, cls in nodes:
            key = f"params_{cls.type_id()}"
            if key not in defs:
                _merge(defs, cls.ParamsModel.model_json_schema(), key)
            props[node] = {"$ref": f"#/$defs/{key}",
                           "description": f"Parameters of node {node!r} ({cls.type_id()}, stage "
                                          f"{cls.stage})."}
        go = scene["properties"].get("graph_overrides", {})
        scene["properties"]["graph_overrides"] = {
            "type": "object", "description": (go.get("description", "") + " Node names of the "
                                              "shipped default graph are listed; another graph "
                                              "may have other nodes.").strip(),
            "properties": props,
            "additionalProperties": {"type": "object"}}
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": "lokigraph scene",
            **scene, "x-behaviors": behs}
