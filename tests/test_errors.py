"""Bad input: exit code 2, file:line:column, element and field, no traceback, no output."""

import re

import numpy as np
import pytest

from conftest import run_cli
from lokigraph.api import compile_file
from lokigraph.errors import GraphError, InputError

GOOD = """\
lokigraph: 1
frames: {start: 1, end: 3, fps: 24}
elements:
  - name: shirt
    geometry: {generator: grid, params: {resolution: [4, 4]}}
    components:
      Dynamic: {mass_density: 0.15}
      Pins: {vertices: [0]}
output: {dir: OUT}
"""


def _check_cli(tmp_path, scene, pattern):
    out = tmp_path / "out"
    r = run_cli("run", scene, "--out", out, "--quiet")
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr
    assert re.search(pattern, r.stderr), r.stderr
    assert not out.exists()  # nothing written for invalid input
    v = run_cli("validate", scene)
    assert v.returncode == 2 and re.search(pattern, v.stderr)
    return r.stderr


def test_good_scene_validates(scene_file):
    p = scene_file(GOOD)
    r = run_cli("validate", p)
    assert r.returncode == 0, r.stderr


def test_malformed_yaml(scene_file, tmp_path):
    p = scene_file(GOOD.replace("frames: {start: 1, end: 3, fps: 24}",
                                "frames: {start: 1, end: 3, fps: 24"))
    _check_cli(tmp_path, p, r"scene\.yaml:\d+:\d+: malformed YAML")


def test_unknown_key_with_suggestion(scene_file, tmp_path):
    p = scene_file(GOOD.replace("mass_density: 0.15", "mass_densty: 0.15"))
    err = _check_cli(tmp_path, p, r'scene\.yaml:7:17: element "shirt", '
                                  r"Dynamic\.mass_densty: unknown key 'mass_densty'; "
                                  r"did you mean 'mass_density'\?")
    assert err.count("\n") <= 2


def test_negative_value(scene_file, tmp_path):
    p = scene_file(GOOD.replace("mass_density: 0.15", "mass_density: -3"))
    _check_cli(tmp_path, p, r'scene\.yaml:7:\d+: element "shirt", Dynamic\.mass_density: '
                            r"must be > 0 \(got -3\)")


def test_all_errors_reported_together(scene_file, tmp_path):
    p = scene_file(GOOD.replace("mass_density: 0.15", "mass_density: -3, point_mass: -1")
                   .replace("Pins: {vertices: [0]}", "Pinz: {vertices: [0]}"))
    with pytest.raises(InputError) as ei:
        compile_file(p)
    msg = str(ei.value)
    assert msg.startswith("3 errors:")
    assert "unknown component type 'Pinz'; did you mean 'Pins'?" in msg
    assert "point_mass: must be > 0 (got -1)" in msg
    # sorted by line
    lines = [int(m) for m in re.findall(r"scene\.yaml:(\d+):", msg)]
    assert lines == sorted(lines)


def test_unknown_behavior_type(scene_file, tmp_path):
    (tmp_path / "g.yaml").write_text("lokigraph_graph: 1\nname: g\ndomains:\n  forces:\n"
                                     "    - type: Gravty\n  solver:\n    - type: NucleusSolver\n")
    p = scene_file(GOOD.replace("lokigraph: 1", "lokigraph: 1\ngraph: g.yaml"))
    _check_cli(tmp_path, p, r"g\.yaml:5:7: unknown behavior type 'Gravty'; did you mean "
                            r"'Gravity'\?")


def test_missing_mesh_file(scene_file, tmp_path):
    p = scene_file(GOOD.replace("{generator: grid, params: {resolution: [4, 4]}}",
                                "{file: meshes/nope.obj}"))
    _check_cli(tmp_path, p, r'scene\.yaml:5:\d+: element "shirt", geometry\.file: mesh file not '
                            r"found")


def test_mesh_with_nan(scene_file, tmp_path):
    (tmp_path / "bad.obj").write_text("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    p = scene_file(GOOD.replace("{generator: grid, params: {resolution: [4, 4]}}",
                                "{file: bad.obj}").replace("[0]", "[0]"))
    _check_cli(tmp_path, p, r'scene\.yaml:5:\d+: element "shirt", geometry: 1 vertices with '
                            r"non-finite coordinates \(first at vertex 1\)")


def test_mesh_with_out_of_range_index(scene_file, tmp_path):
    (tmp_path / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n")
    p = scene_file(GOOD.replace("{generator: grid, params: {resolution: [4, 4]}}",
                                "{file: bad.obj}"))
    _check_cli(tmp_path, p, r'scene\.yaml:5:\d+: element "shirt", geometry\.file: \S*bad\.obj:5: '
                            r"vertex index 9 out of range \(the file has 3 vertices\)")


def test_cycle(scene_file, tmp_path):
    (tmp_path / "g.yaml").write_text(
        "lokigraph_graph: 1\nname: g\ndomains:\n  forces:\n"
        "    - {type: Gravity, name: a, after: [b]}\n"
        "    - {type: RestSpringForce, name: b, after: [a]}\n"
        "  solver:\n    - type: NucleusSolver\n")
    p = scene_file(GOOD.replace("lokigraph: 1", "lokigraph: 1\ngraph: g.yaml")
                   .replace("Pins: {vertices: [0]}", "RestSpring: {stiffness: 1}"))
    _check_cli(tmp_path, p, r"g\.yaml:5:\d+: cycle in the behavior graph: .*\(members: a, b\)")


def test_two_writers(scene_file, tmp_path):
    (tmp_path / "g.yaml").write_text(
        "lokigraph_graph: 1\nname: g\ndomains:\n  solver:\n"
        "    - {type: NucleusSolver, name: s1}\n    - {type: NucleusSolver, name: s2}\n")
    p = scene_file(GOOD.replace("lokigraph: 1", "lokigraph: 1\ngraph: g.yaml"))
    with pytest.raises(GraphError, match=r"two writers of field 'particle_q': s1 and s2"):
        compile_file(p)


def test_missing_required_component(scene_file, tmp_path):
    p = scene_file(GOOD.replace("      Dynamic: {mass_density: 0.15}\n", ""))
    _check_cli(tmp_path, p, r'element "shirt", Pins: Pins requires component Dynamic')


def test_bad_paint_channel(scene_file, tmp_path):
    p = scene_file(GOOD.replace("Pins: {vertices: [0]}", "Pins: {map: pin_weigths}")
                   .replace("components:", "channels: {pin_weights: {vertices: [0, 4]}}\n"
                                           "    components:"))
    _check_cli(tmp_path, p, r"no channel named 'pin_weigths'; did you mean 'pin_weights'\?")


def test_unknown_graph_and_solver(scene_file, tmp_path):
    p = scene_file(GOOD.replace("lokigraph: 1", "lokigraph: 1\ngraph: defualt"))
    _check_cli(tmp_path, p, r"graph 'defualt' not found; did you mean 'default'\?")
    p = scene_file(GOOD.replace("lokigraph: 1", "lokigraph: 1\nsolver: nucleos"), "s2.yaml")
    _check_cli(tmp_path, p, r"unknown solver 'nucleos'; did you mean 'nucleus'\?")


def test_bad_frames_argument(scene_file, tmp_path):
    p = scene_file(GOOD)
    r = run_cli("run", p, "--frames", "5:2", "--out", tmp_path / "o")
    assert r.returncode == 2 and "Traceback" not in r.stderr


def test_generator_bad_params(scene_file, tmp_path):
    p = scene_file(GOOD.replace("params: {resolution: [4, 4]}", "params: {resolutoin: [4, 4]}"))
    err = _check_cli(tmp_path, p, r"scene\.yaml:5:\d+: .*unknown .*'resolutoin'")
    assert "unexpected keyword argument" not in err and "grid()" not in err  # no raw Python


def test_every_error_in_one_pass_at_user_lines(scene_file, tmp_path):
    """Scene-level, component, compile (bind) and graph-override errors together, exit 2, each
    at a line of the user's scene (never of the installed graphs/default.yaml)."""
    p = scene_file(GOOD.replace("fps: 24", "fps: .nan")
                   .replace("mass_density: 0.15", "mass_densty: 0.15")
                   .replace("output: {dir: OUT}",
                            "  - name: group\n    components: {CollisionGroup: {members: "
                            "[shirt, nobody]}}\ngraph_overrides: {stretch: {importanc: 1}}\n"
                            "output: {dir: OUT}"))
    err = _check_cli(tmp_path, p, r"^4 errors:")
    lines = re.findall(r"scene\.yaml:(\d+):\d+: ", err)
    assert len(lines) == 4 and "default.yaml" not in err, err
    assert "finite" in err and "'nobody'" in err and "'importanc'" in err and "mass_densty" in err
