"""JSON schema of every registered component and behavior parameter model, plus the scene."""

from __future__ import annotations

from .registry import get_registry
from .scene import SceneSpec


def export_schema() -> dict:
    reg = get_registry()
    comps = {name: cls.model_json_schema() for name, cls in sorted(reg.components.items())}
    behs = {name: {"stage": cls.stage, "requires": [t.type_id() for t in cls.requires],
                   "params": cls.ParamsModel.model_json_schema()}
            for name, cls in sorted(reg.behaviors.items())}
    scene = SceneSpec.model_json_schema()
    # let editors autocomplete component names and their fields inside elements[].components
    el = scene.get("$defs", {}).get("ElementSpec")
    if el is not None:
        el["properties"]["components"] = {
            "type": "object", "additionalProperties": False,
            "properties": {n: {"$ref": f"#/$defs/component_{n}"} for n in comps}}
    for n, s in comps.items():
        defs = s.pop("$defs", {})
        scene.setdefault("$defs", {}).update(defs)
        scene["$defs"][f"component_{n}"] = s
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": "lokigraph scene",
            **scene, "x-behaviors": behs}
