"""Generators: documented vertex order, named vertex sets, strict parameters, size limits."""

import time
import typing

import numpy as np
import pytest

from conftest import run_cli, write_scene
from lokigraph.errors import InputError
from lokigraph.generators import (GENERATOR_MODELS, GENERATORS, MAX_GENERATED_VERTICES,
                                  GeneratorParamsError, make_geometry)
from lokigraph.scene import GeometrySpec, load_scene


def test_models_cover_every_generator_and_document_it():
    assert set(GENERATOR_MODELS) == set(GENERATORS)
    literal = typing.get_args(typing.get_args(GeometrySpec.model_fields["generator"].annotation)[0])
    assert set(literal) == set(GENERATORS)
    for name, model in GENERATOR_MODELS.items():
        schema = model.model_json_schema()
        assert schema["additionalProperties"] is False
        assert "Vertex order" in schema["description"], name
        assert "Named sets" in schema["description"], name
        for fname, prop in schema["properties"].items():
            assert prop.get("description"), (name, fname)
        make_geometry(name, {})  # defaults build


def test_grid_order_and_sets():
    g = make_geometry("grid", {"resolution": [3, 2], "plane": "xy", "size": [3, 2]})
    rx, ry = 3, 2
    i, j = 2, 1
    assert np.allclose(g.points[j * (rx + 1) + i], [0.5, 0.0, 0.0])  # (i - rx/2, j - ry/2)
    assert g.groups["left"].tolist() == [0, 4, 8]
    assert g.groups["right"].tolist() == [3, 7, 11]
    assert g.groups["bottom"].tolist() == [0, 1, 2, 3]
    assert g.groups["top"].tolist() == [8, 9, 10, 11]
    assert g.groups["corners"].tolist() == [0, 3, 8, 11]
    assert g.groups["border"].tolist() == [0, 1, 2, 3, 4, 7, 8, 9, 10, 11]
    assert np.all(g.points[g.groups["top"], 1] == g.points[:, 1].max())  # xy: top is largest y
    assert np.allclose(g.channels["u"][g.groups["right"]], 1)


def test_strands_tube_box_tet_box_sets():
    s = make_geometry("strands", {"count": [2, 3], "segments": 4, "length": 0.2})
    assert s.groups["root"].tolist() == [0, 5, 10, 15, 20, 25]
    assert s.groups["tip"].tolist() == [4, 9, 14, 19, 24, 29]
    assert np.allclose(s.points[s.groups["tip"], 1] - s.points[s.groups["root"], 1], -0.2)
    t = make_geometry("tube", {"segments": [8, 3], "axis": "y", "length": 0.4,
                               "center": [0, 1, 0], "capped": True})
    assert t.groups["start"].tolist() == list(range(8))
    assert t.groups["end"].tolist() == list(range(24, 32))
    assert np.allclose(t.points[t.groups["end"], 1], 1.2)
    assert np.allclose(t.points[t.groups["start"], 1], 0.8)
    assert t.groups["caps"].tolist() == [32, 33]
    assert np.allclose(t.points[0], [0.1, 0.8, 0.0])  # angle 0: (x, z) = r (1, 0) for axis y
    b = make_geometry("box", {"size": [2, 2, 2]})
    for k, (face, ax, val) in enumerate([("xmin", 0, -1), ("xmax", 0, 1), ("ymin", 1, -1),
                                         ("ymax", 1, 1), ("zmin", 2, -1), ("zmax", 2, 1)]):
        assert len(b.groups[face]) == 4 and np.all(b.points[b.groups[face], ax] == val)
    assert np.allclose(b.points[4 * 1 + 2 * 0 + 1], [1, -1, 1])
    tb = make_geometry("tet_box", {"resolution": [2, 3, 1], "size": [0.2, 0.3, 0.1]})
    assert len(tb.groups["ymax"]) == 3 * 2 and len(tb.groups["surface"]) == 3 * 4 * 2
    i, j, k = 1, 2, 1
    assert np.allclose(tb.points[(i * 4 + j) * 2 + k], [0.0, 0.05, 0.05])


@pytest.mark.parametrize("name, params", [
    ("grid", {"resolution": [10**7, 10**7]}),
    ("grid", {"resolution": [3000, 3000]}),
    ("grid", {"resolution": [10**7, 1]}),
    ("sphere", {"subdivisions": 12}),
    ("sphere", {"subdivisions": 10**9}),
    ("tet_box", {"resolution": [1000, 1000, 1000]}),
    ("tet_box", {"resolution": [150, 150, 100]}),  # 3.4e6 vertices but 13.5e6 tetrahedra
    ("strands", {"count": [1000, 1000], "segments": 10}),
    ("tube", {"segments": [10**6, 10]}),
])
def test_size_limits_before_allocation(name, params):
    t = time.perf_counter()
    with pytest.raises(GeneratorParamsError) as ei:
        make_geometry(name, params)
    assert time.perf_counter() - t < 0.5
    msg = str(ei.value)
    assert f"{MAX_GENERATED_VERTICES:,}" in msg or "8,000,000" in msg
    assert "vertices" in msg and "would have" in msg


@pytest.mark.parametrize("name, params, msg", [
    ("grid", {"resolutoin": [4, 4]}, "resolutoin: unknown key 'resolutoin'; did you mean "
                                     "'resolution'?"),
    ("grid", {"size": [float("nan"), 1]}, "size.0: must be a finite number"),
    ("grid", {"resolution": [0, 4]}, "resolution.0: must be >= 1 (got 0)"),
    ("grid", {"plane": "xw"}, "plane:"),
    ("sphere", {"radius": -1}, "radius: must be > 0 (got -1)"),
    ("strands", {"direction": [0, 0, 0]}, "direction: must not be zero"),
    ("tube", {"segments": [2, 4]}, "segments.0: must be >= 3 (got 2)"),
    ("points", {"positions": []}, "positions:"),
    ("box", {"size": [1, 1]}, "size"),
])
def test_clean_parameter_messages(name, params, msg):
    with pytest.raises(GeneratorParamsError) as ei:
        make_geometry(name, params)
    text = str(ei.value)
    assert msg in text, text
    assert "unexpected keyword" not in text and "()" not in text


def test_scene_reports_generator_errors_at_their_lines(tmp_path):
    p = write_scene(tmp_path, """
    lokigraph: 1
    elements:
      - name: a
        geometry:
          generator: grid
          params:
            resolution: [10000000, 10000000]
      - name: b
        geometry: {generator: tube, params: {radius: .nan, segmnts: [8, 2]}}
    """)
    t = time.perf_counter()
    with pytest.raises(InputError) as ei:
        load_scene(p)
    assert time.perf_counter() - t < 2
    text = str(ei.value)
    assert f'{p}:6:' in text and 'element "a", geometry.params: grid 10000000 x 10000000 would ' \
                                 'have 1e+14 vertices' in text
    assert f'element "b", geometry.params.radius: must be a finite number' in text
    assert f"element \"b\", geometry.params.segmnts: unknown key 'segmnts'; did you mean " \
           f"'segments'?" in text


def test_cli_validate_rejects_huge_sphere_quickly(tmp_path):
    p = write_scene(tmp_path, """
    lokigraph: 1
    elements:
      - name: ball
        geometry: {generator: sphere, params: {subdivisions: 12}}
    """)
    t = time.perf_counter()
    r = run_cli("validate", p)
    assert time.perf_counter() - t < 30
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "would have 1.678e+08 vertices, more than the limit of 4,000,000" in r.stderr
