"""Vertex selections (groups, attributes, regions, combinations) and painted maps from them."""

import numpy as np
import pytest

from conftest import write_scene
from lokigraph.api import compile_file
from lokigraph.errors import InputError
from lokigraph.generators import make_geometry
from lokigraph.scene import load_scene
from lokigraph.selection import Selection, SelectionError, select_indices


@pytest.fixture
def g():
    # 5 x 4 vertices in the xy plane, x and y in [-0.5, 0.5]; u, v channels; a colour attribute
    geo = make_geometry("grid", {"resolution": [4, 3], "plane": "xy"})
    geo.channels["color"] = np.stack([geo.channels["u"], geo.channels["v"],
                                      np.zeros(geo.vertex_count)], 1)
    return geo


def test_every_kind(g):
    top = [15, 16, 17, 18, 19]
    assert select_indices("top", g).tolist() == top
    assert select_indices({"group": "top"}, g).tolist() == top
    assert select_indices({"vertices": [3, 1, 1]}, g).tolist() == [1, 3]
    assert select_indices({"channel": "u", "above": 0.6}, g).tolist() == [
        i for i in range(20) if i % 5 >= 3]
    assert select_indices({"channel": "color", "component": 1, "below": 0.1}, g).tolist() == [
        0, 1, 2, 3, 4]
    assert select_indices({"channel": "u", "above": 0.2, "below": 0.3}, g).tolist() == [
        1, 6, 11, 16]
    assert select_indices({"box": {"min": [-1, 0.4, -1], "max": [1, 1, 1]}}, g).tolist() == top
    assert select_indices({"sphere": {"center": [-0.5, -0.5, 0], "radius": 0.01}},
                          g).tolist() == [0]
    assert select_indices({"plane": {"point": [0, 0.4, 0], "normal": [0, 2, 0]}},
                          g).tolist() == top
    assert select_indices({"union": ["left", "right"]}, g).tolist() == [
        0, 4, 5, 9, 10, 14, 15, 19]
    assert select_indices({"intersection": ["top", "left"]}, g).tolist() == [15]
    assert select_indices({"difference": ["border", "corners", {"vertices": [1]}]},
                          g).tolist() == [2, 3, 5, 9, 10, 14, 16, 17, 18]


def test_region_boundaries_are_inclusive(g):
    # a box and a plane through the top row include it (>=, <=)
    assert select_indices({"box": {"min": [-0.5, 0.5, 0], "max": [0.5, 0.5, 0]}},
                          g).tolist() == [15, 16, 17, 18, 19]
    assert len(select_indices({"plane": {"point": [0, 0.5, 0], "normal": [0, 1, 0]}}, g)) == 5


@pytest.mark.parametrize("sel, msg", [
    ("topp", "no vertex group named 'topp'; did you mean 'top'?"),
    ({"channel": "colour", "above": 0}, "no channel named 'colour'; did you mean 'color'?"),
    ({"channel": "color", "above": 0}, "has 3 components per vertex; give 'component' (0..2)"),
    ({"channel": "color", "component": 3, "above": 0}, "component 3 does not exist"),
    ({"vertices": [20]}, "vertex index 20 out of range (element has 20 vertices)"),
    ({"sphere": {"center": [3, 3, 3], "radius": 0.1}},
     "selects no vertices; the element's bounding box is [-0.5, -0.5, 0] .. [0.5, 0.5, 0] m"),
    ({"intersection": ["top", "bottom"]}, "selects no vertices"),
])
def test_resolution_errors(g, sel, msg):
    with pytest.raises(SelectionError) as ei:
        select_indices(sel, g)
    assert msg in str(ei.value)


@pytest.mark.parametrize("data, msg", [
    ({}, "needs exactly one of group, vertices"),
    ({"group": "a", "box": {"min": [0, 0, 0], "max": [1, 1, 1]}}, "(got group, box)"),
    ({"channel": "u"}, "needs 'above' and/or 'below'"),
    ({"group": "a", "above": 1}, "above only go with 'channel'"),
    ({"box": {"min": [1, 0, 0], "max": [0, 1, 1]}}, "must be <= max"),
    ({"plane": {"normal": [0, 0, 0]}}, "must not be zero"),
    ({"sphere": {"center": [0, 0, 0], "radius": float("nan")}}, "finite"),
    ({"difference": ["a"]}, "at least 2"),
    ({"vertices": [2**40]}, "less than or equal"),
])
def test_validation_messages(data, msg):
    from pydantic import ValidationError

    from lokigraph.component import pydantic_messages

    with pytest.raises(ValidationError) as ei:
        Selection.model_validate(data)
    text = "; ".join(m for _, m in pydantic_messages(ei.value))
    assert msg in text or msg.replace("less than or equal", "<=") in text, text


OBJ = """\
v -0.5 1.0 0 1 0 0
v  0.5 1.0 0 1 0 0
v -0.5 0.5 0 0 0 1
v  0.5 0.5 0 0 0 1
v -0.5 0.0 0 0 0 0.5
v  0.5 0.0 0 0 0 0.5
g waist
f 1 2 4
f 1 4 3
g skirt
f 3 4 6
f 3 6 5
"""

SCENE = """
lokigraph: 1
frames: {start: 1, end: 2, fps: 24}
elements:
  - name: cloth
    geometry: {file: cloth.obj}
    channels:
      stiff: {attribute: color, component: 2, remap: {from: [0, 1], to: [10, 20]}}
      top: {select: {group: waist}, value: 2, default: -1}
      listed: {vertices: [5]}
    components:
      Dynamic:
        mass_density: {attribute: color, component: 0, remap: {from: [0, 1], to: [0.1, 0.3]}}
      Pins: {select: {difference: [waist, skirt]}}
      RestSpring: {stiffness: {select: {box: {min: [0, -1, -1], max: [1, 2, 1]}}, value: 5}}
"""


def test_scene_channels_pins_and_maps_from_groups_and_attributes(tmp_path):
    (tmp_path / "cloth.obj").write_text(OBJ)
    c = compile_file(write_scene(tmp_path, SCENE))
    el = c.scene.element("cloth")
    ch = el.geometry.channels
    assert np.allclose(ch["stiff"], [10, 10, 20, 20, 15, 15])
    assert ch["top"].tolist() == [2, 2, 2, 2, -1, -1]
    assert ch["listed"].tolist() == [0, 0, 0, 0, 0, 1]
    # pinned: the waist group minus the skirt group = vertices 0, 1
    assert np.flatnonzero(c.model.particle_inv_mass == 0).tolist() == [0, 1]
    # the mass density painted from the red channel: 0.3 kg/m^2 on the top row, 0.1 below
    from lokigraph.components.core import RestSpring

    k = c.scene.element("cloth").get(RestSpring)
    from lokigraph.component import resolve_paintable

    assert resolve_paintable(k.stiffness, el).tolist() == [0, 5, 0, 5, 0, 5]


def test_scene_selection_errors_all_at_once_with_lines(tmp_path):
    (tmp_path / "cloth.obj").write_text(OBJ)
    bad = (SCENE.replace("{group: waist}, value", "{group: wiast}, value")
           .replace("component: 2, remap", "component: 7, remap")
           .replace("{difference: [waist, skirt]}",
                    "{intersection: [waist, {box: {min: [5, 5, 5], max: [6, 6, 6]}}]}")
           .replace("{attribute: color, component: 0", "{attribute: colr, component: 0"))
    p = write_scene(tmp_path, bad)
    with pytest.raises(InputError) as ei:
        load_scene(p)
    text = str(ei.value)
    assert len(ei.value.diagnostics) == 4, text
    assert (f"{p}:7:15: element \"cloth\", channels.stiff: attribute 'color' has 3 components "
            f"per vertex; component 7 does not exist") in text
    assert (f"{p}:8:13: element \"cloth\", channels.top: no vertex group named 'wiast'; did you "
            f"mean 'waist'?") in text
    assert (f"{p}:12:9: element \"cloth\", Dynamic.mass_density: no attribute named 'colr'; "
            f"did you mean 'color'?") in text
    assert f"{p}:13:" in text and "Pins.select: the selection (intersection) selects no " in text


def test_generator_named_sets_drive_pins(tmp_path):
    text = """
    lokigraph: 1
    frames: {start: 1, end: 2, fps: 24}
    elements:
      - name: cloth
        geometry: {generator: grid, params: {resolution: [4, 4], plane: xy}}
        components:
          Dynamic: {}
          Pins: {select: top, vertices: [0]}
    """
    c = compile_file(write_scene(tmp_path, text))
    assert np.flatnonzero(c.model.particle_inv_mass == 0).tolist() == [0, 20, 21, 22, 23, 24]


def test_attachment_vertices_take_a_selection(tmp_path):
    text = """
    lokigraph: 1
    frames: {start: 1, end: 2, fps: 24}
    elements:
      - name: patch
        geometry:
          generator: grid
          params: {size: [0.1, 0.1], resolution: [2, 2], center: [0, 0.5, 0]}
        components: {Dynamic: {}}
      - name: body
        geometry: {generator: box, params: {size: [1, 1, 1]}}
        components: {Kinematic: {}}
      - name: glue
        components: {Attachment: {source: patch, target: body, vertices: {group: corners}}}
    """
    c = compile_file(write_scene(tmp_path, text))
    d = c.model.data["attachment"]
    assert sorted(d.attach[:, 0].tolist()) == [0, 2, 6, 8]
    bad = text.replace("{group: corners}", "{group: corner}")
    with pytest.raises(InputError) as ei:
        compile_file(write_scene(tmp_path, bad))
    assert ("glue\", Attachment.vertices: on 'patch': no vertex group named 'corner'; did you "
            "mean 'corners'?") in str(ei.value)
    # index lists keep working, and are range-checked
    ok = text.replace("{group: corners}", "[0, 8]")
    c = compile_file(write_scene(tmp_path, ok))
    assert sorted(c.model.data["attachment"].attach[:, 0].tolist()) == [0, 8]
    with pytest.raises(InputError, match="vertex index 99 out of range"):
        compile_file(write_scene(tmp_path, text.replace("{group: corners}", "[99]")))


def test_paintable_forms_and_messages():
    from pydantic import TypeAdapter, ValidationError

    from lokigraph.component import MapAttribute, MapSelection, Paintable, pydantic_messages

    ta = TypeAdapter(Paintable)
    assert ta.validate_python(2) == 2.0 and ta.validate_python("pin") == "pin"
    assert isinstance(ta.validate_python({"select": "top"}), MapSelection)
    assert isinstance(ta.validate_python({"attribute": "color", "component": 0}), MapAttribute)
    for bad, msg in [({"colour": 1}, "expected a number, a channel name"),
                     (float("inf"), "finite"),
                     ({"attribute": "c", "remap": {"from": [1, 1]}}, "two different values"),
                     ({"select": {"boxx": {}}}, "unknown key 'boxx'")]:
        with pytest.raises(ValidationError) as ei:
            ta.validate_python(bad)
        text = "; ".join(m for _, m in pydantic_messages(ei.value))
        assert msg in text, text
