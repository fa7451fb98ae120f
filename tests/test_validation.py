"""Validation: every error of a file in one pass at the user's file:line, NaN/inf rejected, value
bounds, hostile YAML bounded, the JSON schema's bounds and coverage."""

import io
import json
import math
import re
from contextlib import redirect_stderr, redirect_stdout

import pytest

from conftest import ROOT as ROOT_DIR
from lokigraph.api import compile_file
from lokigraph.cli import main
from lokigraph.errors import InputError
from lokigraph.scene import check_sequence_pattern, load_scene
from lokigraph.yamlio import MAX_ALIAS_NODES, MAX_DEPTH, load_yaml_text

GOOD = """\
lokigraph: 1
frames: {start: 1, end: 3, fps: 24}
output: {dir: OUT}
elements:
  - name: cloth
    geometry: {generator: grid, params: {resolution: [4, 4]}}
    components:
      Dynamic: {mass_density: 0.15}
      Collider: {}
      Pins: {vertices: [0]}
"""


def _errors(path) -> InputError:
    with pytest.raises(InputError) as ei:
        compile_file(path)
    return ei.value


def _validate(path) -> tuple[int, str]:
    err = io.StringIO()
    with redirect_stderr(err), redirect_stdout(io.StringIO()):
        rc = main(["validate", str(path)])
    return rc, err.getvalue()


def test_good_scene(scene_file):
    assert _validate(scene_file(GOOD))[0] == 0


# ---- every error in one pass ---------------------------------------------------------------

FOUR = """\
lokigraph: 1
frames: {start: 1, end: 3, fps: -24}
output: {dir: OUT}
elements:
  - name: cloth
    geometry: {generator: grid, params: {resolution: [4, 4]}}
    components:
      Dynamic: {mass_densty: 0.15}
      Collider: {}
  - name: group
    components:
      CollisionGroup:
        members: [cloth, nobody]
graph_overrides:
  stretch: {importanc: 1}
"""


def test_four_mistakes_in_one_pass(scene_file):
    """A scene-level error, a component error, a bind error (unknown group member, found by
    compile) and a bad graph override: all four at once, each at the user's line."""
    e = _errors(scene_file(FOUR))
    got = [(d.line, d.message) for d in e.diagnostics]
    assert len(got) == 4, e
    assert str(e).startswith("4 errors:")
    assert got[0] == (2, "must be > 0 (got -24)")
    assert got[1][0] == 8 and "unknown key 'mass_densty'; did you mean 'mass_density'?" in got[1][1]
    assert got[2] == (13, "no element named 'nobody'")
    assert e.diagnostics[2].column == 26  # at the list item, not at the element
    assert got[3][0] == 15 and "unknown key 'importanc'" in got[3][1]
    assert all(d.file.endswith("scene.yaml") for d in e.diagnostics)


def test_four_mistakes_cli(scene_file):
    rc, err = _validate(scene_file(FOUR))
    assert rc == 2 and "Traceback" not in err
    assert len(re.findall(r"scene\.yaml:\d+:\d+: ", err)) == 4, err


def test_no_spurious_errors_about_elements_that_failed(scene_file):
    """An element whose geometry is in error is left out of compile; what refers to it (a group
    member, a stitch) and what needs its failed component (Pins needs Dynamic) is not reported
    a second time."""
    text = """\
    lokigraph: 1
    substeps: 0
    elements:
      - name: cloth
        geometry: {generator: grid, params: {resolution: [4, 4], plane: xq}}
        components: {Dynamic: {mass_density: 0.2}, Collider: {}}
      - name: body
        geometry: {generator: sphere}
        components:
          Dynamic: {mass_density: -1}
          Collider: {}
          Pins: {vertices: [0]}
      - name: group
        components: {CollisionGroup: {members: [cloth, body, ghost]}}
      - name: st
        components: {Stitch: {a: cloth, b: body, pairs: [[0, 1]]}}
    """
    e = _errors(scene_file(text))
    msgs = [d.message for d in e.diagnostics]
    assert len(msgs) == 4, e
    assert any("substeps" in d.field for d in e.diagnostics)
    assert any("plane" in d.field for d in e.diagnostics)
    assert any(d.field == "Dynamic.mass_density" and d.element == "body" for d in e.diagnostics)
    assert "no element named 'ghost'" in msgs
    assert not any("'cloth'" in m or "requires component Dynamic" in m for m in msgs)


def test_component_selection_error_keeps_the_element(scene_file):
    """A selection of one component in error leaves only that component out: the element's
    other components are still bound (and their problems found)."""
    text = """\
    lokigraph: 1
    elements:
      - name: cloth
        geometry: {generator: grid, params: {resolution: [4, 4]}}
        components:
          Dynamic: {mass_density: 0.2}
          Collider: {nocollide_sets: {a: [999]}}
          Pins: {select: nosuchgroup}
      - name: group
        components: {CollisionGroup: {members: [cloth, ghost]}}
    """
    e = _errors(scene_file(text))
    got = [(d.line, d.field) for d in e.diagnostics]
    assert got == [(7, "Collider.nocollide_sets.a"), (8, "Pins.select"),
                   (10, "CollisionGroup.members")], e


def test_element_errors_and_component_errors_together(scene_file):
    """A bad element name does not hide the problems of its components."""
    text = GOOD.replace("name: cloth", "name: 'my cloth'").replace("mass_density: 0.15",
                                                                   "mass_density: -1")
    e = _errors(scene_file(text))
    fields = sorted(d.field for d in e.diagnostics)
    assert fields == ["Dynamic.mass_density", "name"], e


def test_top_level_errors_do_not_hide_elements(scene_file):
    text = GOOD.replace("lokigraph: 1", "lokigraph: 2\nunknown_key: 1\ngravity: [0, 0]") \
        .replace("Pins: {vertices: [0]}", "Pins: {vertices: [999]}")
    e = _errors(scene_file(text))
    msgs = str(e)
    assert "scene.lokigraph" in msgs and "unknown_key" in msgs and "gravity" in msgs
    assert "Pins.vertices" in msgs and "999" not in msgs or "out of range" in msgs, msgs


def test_load_scene_still_raises(scene_file):
    with pytest.raises(InputError):
        load_scene(scene_file(FOUR))
    s = load_scene(scene_file(FOUR), partial=True)
    assert len(s.diagnostics) == 2 and s.failed == {"cloth": {"Dynamic"}}


# ---- graph_overrides at the user's line ----------------------------------------------------

@pytest.mark.parametrize("override, line, pattern", [
    ("stretch: {importanc: 0.5}", 12, r"graph_overrides\.stretch\.importanc: unknown key"),
    ("stretch: {importance: 2}", 12, r"graph_overrides\.stretch\.importance: must be <= 1"),
    ("nucleus_solver: {iterations: .nan}", 12, r"iterations: must be a finite number"),
    ("no_such: {x: 1}", 12, r"no graph node named 'no_such'"),
    ("stretch: 3", 12, r"graph_overrides\.stretch: must be a mapping"),
])
def test_bad_override_at_scene_line(scene_file, override, line, pattern):
    p = scene_file(GOOD + f"graph_overrides:\n  {override}\n")
    e = _errors(p)
    assert len(e.diagnostics) == 1, e
    d = e.diagnostics[0]
    assert d.file == str(p) and d.line == line, e
    assert re.search(pattern, d.format()), d.format()
    assert "default.yaml" not in str(e)


def test_override_of_graph_in_error_not_checked(scene_file):
    e = _errors(scene_file(GOOD + "graph: 5\ngraph_overrides: {my_node: {x: 1}}\n"))
    assert len(e.diagnostics) == 1 and e.diagnostics[0].field == "scene.graph", e


# ---- NaN and infinities --------------------------------------------------------------------

@pytest.mark.parametrize("extra, field", [
    ("gravity: [.nan, 0, 0]\n", "scene.gravity.0"),
    ("gravity: [0, -.inf, 0]\n", "scene.gravity.1"),
    ("gravity: [0, -1e999, 0]\n", "scene.gravity.1"),
    ("  - name: w\n    components: {Wind: {speed: .nan}}\n", "Wind.speed"),
    ("  - name: w\n    components: {Wind: {keys: [{frame: 1, speed: .inf}]}}\n",
     "Wind.keys.0.speed"),
    ("  - name: w\n    components: {Wind: {keys: [{frame: .nan}]}}\n", "Wind.keys.0.frame"),
    ("  - name: k\n    geometry: {generator: sphere}\n    components: {Kinematic: {keys: "
     "[{frame: 1, translate: [.nan, 0, 0]}]}}\n", "Kinematic.keys.0.translate.0"),
    ("  - name: s\n    components: {ShapeCollider: {radius: .inf}}\n", "ShapeCollider.radius"),
])
def test_nan_and_inf_rejected(scene_file, extra, field):
    text = GOOD + extra if extra.startswith("  -") else GOOD.replace("output:", extra + "output:")
    e = _errors(scene_file(text))
    assert [d.field for d in e.diagnostics] == [field], e
    assert "finite" in e.diagnostics[0].message


def test_nan_in_component_fields_and_params(scene_file):
    text = GOOD.replace("mass_density: 0.15", "mass_density: 0.15, damping: .nan") \
        .replace("Collider: {}", "Collider: {thickness: .inf}")
    e = _errors(scene_file(text))
    assert sorted(d.field for d in e.diagnostics) == ["Collider.thickness", "Dynamic.damping"]


# ---- bounds ----------------------------------------------------------------------------------

@pytest.mark.parametrize("frames, pattern", [
    ("{start: -9223372036854775808, end: 2}", r"frames\.start: must be >= -10000000"),
    ("{start: 1, end: 2000000}", r"at most 1000000 frames"),
    ("{start: 1, end: 3, fps: 1e308}", r"frames\.fps: must be <= 100000"),
    ("{start: 1, end: 3, fps: 0}", r"frames\.fps: must be > 0"),
])
def test_frame_bounds(scene_file, frames, pattern):
    e = _errors(scene_file(GOOD.replace("{start: 1, end: 3, fps: 24}", frames)))
    assert re.search(pattern, str(e)), e
    assert e.diagnostics[0].line == 2


def test_step_rate_bound(scene_file):
    e = _errors(scene_file(GOOD.replace("fps: 24", "fps: 100000") + "substeps: 1000\n"))
    assert "fps * substeps = 1e+08" in str(e) and e.diagnostics[0].line == 11, e


@pytest.mark.parametrize("replace, field", [
    ("Pins: {vertices: [0]}", "Pins.vertices.0"),
    ("Collider: {}", "Collider.nocollide_sets.a.0"),
])
def test_huge_vertex_indices(scene_file, replace, field):
    value = "Pins: {vertices: [99999999999999999999999]}" if "Pins" in replace else \
        "Collider: {nocollide_sets: {a: [18446744073709551616]}}"
    e = _errors(scene_file(GOOD.replace(replace, value)))
    assert [d.field for d in e.diagnostics] == [field], e
    assert "must be <= 2147483647" in str(e)


def test_huge_stitch_and_channel_indices(scene_file):
    text = GOOD.replace("    components:", "    channels: {p: {vertices: [2147483648]}}\n"
                        "    components:") + \
        "  - name: st\n    components: {Stitch: {a: cloth, b: cloth, pairs: [[0, 2**70]]}}\n"
    text = text.replace("2**70", str(2**70))
    e = _errors(scene_file(text))
    assert sorted(d.field for d in e.diagnostics) == ["Stitch.pairs.0.1", "channels.p.vertices.0"]


@pytest.mark.parametrize("pattern, ok", [
    ("anim/body.{frame:04d}.obj", True), ("{frame}.obj", True), ("a{{b}}{frame:3}.ply", True),
    ("{frame:zz}.obj", False), ("{frame[0]}.obj", False), ("{frame.real}.obj", False),
    ("{frame!r}.obj", False), ("{0}.obj", False), ("{}.obj", False), ("{frame", False),
    ("frame}.obj", False), ("{frame:999999999d}.obj", False), ("body.obj", False),
])
def test_sequence_pattern(pattern, ok):
    if ok:
        assert check_sequence_pattern(pattern) == pattern
    else:
        with pytest.raises(ValueError, match="sequence pattern"):
            check_sequence_pattern(pattern)


def test_bad_sequence_pattern_in_scene(scene_file):
    p = scene_file(GOOD.replace("{generator: grid, params: {resolution: [4, 4]}}",
                                "{sequence: '{frame:zz}.obj'}"))
    rc, err = _validate(p)
    assert rc == 2 and "Traceback" not in err
    assert re.search(r"scene\.yaml:6:\d+: element \"cloth\", geometry\.sequence: bad sequence "
                     r"pattern", err), err


# ---- hostile YAML ----------------------------------------------------------------------------

def _yaml_error(text) -> str:
    with pytest.raises(InputError) as ei:
        load_yaml_text(text, "s.yaml")
    return str(ei.value)


def test_deep_nesting():
    assert f"nesting deeper than {MAX_DEPTH} levels" in _yaml_error("a: " + "[" * 10**5 + "\n")
    assert "nesting deeper" in _yaml_error("a: " + "[" * 5000 + "]" * 5000 + "\n")
    block = "a:\n" + "".join(" " * (i + 1) + f"k{i}:\n" for i in range(500))
    assert "nesting deeper" in _yaml_error(block)
    load_yaml_text("a: " + "[" * (MAX_DEPTH - 2) + "]" * (MAX_DEPTH - 2) + "\n")  # fine


def test_alias_bomb():
    text = "a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"b{i}: &b{i} [{', '.join(['*a' if i == 0 else f'*b{i - 1}'] * 10)}]\n"
        for i in range(9))
    assert f"past {MAX_ALIAS_NODES} extra values" in _yaml_error(text)
    data, _ = load_yaml_text("a: &a [1, 2]\nb: *a\nc: {<<: {x: 1}}\n")  # aliases still work
    assert data["b"] == [1, 2]


def test_recursive_alias():
    assert "recursive alias" in _yaml_error("a: &a [1, *a]\n")
    assert "recursive alias" in _yaml_error("a: &a {b: *a}\n")


def test_huge_integers():
    assert "s.yaml:1:4: integer with 5000 digits is too large" in _yaml_error("a: " + "9" * 5000)
    assert "integer with" in _yaml_error("a: [1, -" + "9" * 4400 + "]")
    assert "too large" in _yaml_error("? " + "9" * 5000 + "\n: 1\n")  # as a key
    data, _ = load_yaml_text("a: " + "9" * 4000)  # under Python's limit: read, bounded later
    assert data["a"] == int("9" * 4000)


@pytest.mark.parametrize("text, pattern", [
    ("a: !!float abc\n", r"s\.yaml:1:4: cannot read value 'abc'"),
    ("a: !!python/object:os.system x\n", r"malformed YAML: could not determine a constructor"),
    ("a: 2001-13-45\n", r"cannot read value '2001-13-45'"),
    ('a: "x\\0y"\n', r"s\.yaml:1:4: NUL character"),
    ("a: 1\nb: \x07\n", r"s\.yaml:2:4: malformed YAML: control character U\+0007"),
    ("a: 1\n---\nb: 2\n", r"expected a single document in the stream, but found another"),
    ("? [a, b]\n: 1\n", r"mapping keys must be scalars"),
    ("a: 1\na: 2\n", r"s\.yaml:2:1: duplicate key 'a'"),
])
def test_bad_yaml_scalars(text, pattern):
    assert re.search(pattern, _yaml_error(text)), _yaml_error(text)


def test_unreadable_files(tmp_path):
    (tmp_path / "bin.yaml").write_bytes(bytes(range(256)))
    (tmp_path / "dir.yaml").mkdir()
    for name, pattern in [("bin.yaml", r"not UTF-8 text"), ("dir.yaml", r"is a folder"),
                          ("none.yaml", r"file not found")]:
        rc, err = _validate(tmp_path / name)
        assert rc == 2 and re.search(pattern, err) and "Traceback" not in err, err


# ---- JSON schema -----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def schema():
    from lokigraph.schema import export_schema

    s = export_schema()
    json.dumps(s, allow_nan=False)  # plain JSON: no NaN or infinity anywhere
    return s


def _has_bound(prop: dict) -> bool:
    keys = {"minimum", "exclusiveMinimum", "maximum", "exclusiveMaximum"}
    if keys & set(prop):
        return True
    subs = prop.get("anyOf", []) + prop.get("oneOf", []) + prop.get("prefixItems", []) + (
        [prop["items"]] if isinstance(prop.get("items"), dict) else [])
    return any(_has_bound(p) for p in subs if isinstance(p, dict))


@pytest.mark.parametrize("model, fields", [
    ("Frames", ["start", "end", "fps"]),
    ("component_Dynamic", ["point_mass", "damping"]),
    ("component_DiscreteShell", ["youngs_modulus", "poisson_ratio", "thickness",
                                 "bend_resistance", "max_tether_anchors"]),
    ("component_Rod", ["youngs_modulus", "radius"]),
    ("component_Volume", ["youngs_modulus", "poisson_ratio"]),
    ("component_Collider", ["thickness", "friction"]),
    ("component_Drag", ["fluid_density", "fluid_viscosity", "thickness"]),
    ("component_Pressure", ["volume_scale", "compliance"]),
    ("component_FluidDomain", ["size", "density"]),
    ("component_Stitch", ["pairs"]),
    ("component_Wind", ["noise", "seed"]),
    ("Key", ["frame"]),
    ("WindKey", ["frame"]),
    ("MapVertices", ["vertices"]),
    ("Transform", ["scale"]),
])
def test_schema_bounds(schema, model, fields):
    props = schema["$defs"][model]["properties"]
    for f in fields:
        assert _has_bound(props[f]), (model, f, props[f])


def test_schema_scene_bounds(schema):
    props = schema["properties"]
    assert props["substeps"]["minimum"] == 1 and props["substeps"]["maximum"] == 10000
    assert _has_bound(props["seed"])
    assert schema["$defs"]["Frames"]["properties"]["fps"]["exclusiveMinimum"] == 0
    assert schema["$defs"]["component_Dynamic"]["properties"]["point_mass"]["anyOf"][0][
        "exclusiveMinimum"] == 0


def test_schema_covers_generators(schema):
    from lokigraph.generators import GENERATOR_MODELS

    rules = schema["$defs"]["GeometrySpec"]["allOf"]
    named = {r["if"]["properties"]["generator"]["const"]: r["then"]["properties"]["params"]
             for r in rules}
    assert set(named) == set(GENERATOR_MODELS)
    for name, ref in named.items():
        target = schema["$defs"][ref["$ref"].split("/")[-1]]
        assert target["properties"], name
    grid = schema["$defs"]["generator_grid"]["properties"]
    assert "resolution" in grid and "size" in grid


def test_schema_covers_graph_overrides(schema):
    from lokigraph.compile import load_graph

    go = schema["properties"]["graph_overrides"]["properties"]
    names = {n.name for n in load_graph("default").nodes}
    assert set(go) == names
    ref = go["stretch"]["$ref"].split("/")[-1]
    imp = schema["$defs"][ref]["properties"]["importance"]
    assert imp["exclusiveMinimum"] == 0 and imp["maximum"] == 1
    ref = go["nucleus_solver"]["$ref"].split("/")[-1]
    assert schema["$defs"][ref]["properties"]["iterations"]["minimum"] == 1


def test_schema_refs_resolve(schema):
    text = json.dumps(schema)
    for ref in set(re.findall(r'"\$ref": "#/\$defs/([^"]+)"', text)):
        assert ref in schema["$defs"], ref


def test_shipped_params_and_defaults_are_finite():
    """No default relies on infinity (allow_inf_nan=False would reject it on assignment)."""
    from lokigraph.registry import get_registry

    reg = get_registry()
    for cls in list(reg.components.values()) + [b.ParamsModel for b in reg.behaviors.values()]:
        for name, f in cls.model_fields.items():
            d = f.default
            if isinstance(d, float):
                assert math.isfinite(d), (cls.__name__, name)


def test_graph_file_given_as_scene(tmp_path):
    from lokigraph.cli import main as cli_main

    r = cli_main(["validate", str(ROOT_DIR / "graphs" / "bench" / "minimal_cloth.yaml")])
    assert r == 2


def test_map_file_that_is_not_a_regular_file_or_too_big(scene_file, tmp_path, capsys):
    """/dev/zero as a map used to hang validate (np.loadtxt reads forever)."""
    from lokigraph.cli import main as cli_main

    big = tmp_path / "big.txt"
    big.write_text("1.0\n" * 100000)
    for target in ("/dev/zero", str(big)):
        p = scene_file(f"""\
            lokigraph: 1
            frames: {{start: 1, end: 2, fps: 24}}
            elements:
              - name: cloth
                geometry: {{generator: grid, params: {{resolution: [4, 4]}}}}
                channels: {{weight: {{file: {target}}}}}
                components:
                  Dynamic: {{mass_density: 0.1}}
            """)
        assert cli_main(["validate", str(p)]) == 2
        err = capsys.readouterr().err
        assert "Traceback" not in err and "channels.weight" in err, err
