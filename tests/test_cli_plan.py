"""plan / behaviors / schema commands, pruning reasons, one-way fluid coupling."""

import json

import numpy as np
import pytest

from conftest import EXAMPLES, run_cli
from lokigraph.api import compile_file
from lokigraph.run import Simulation


def test_plan_prunes_collision_drag_coupling_with_reasons():
    r = run_cli("plan", EXAMPLES / "cloth_pinned.yaml", "--json")
    assert r.returncode == 0, r.stderr
    plan = json.loads(r.stdout)
    pruned = {p["type"]: p["reason"] for p in plan["pruned"]}
    assert pruned["CollisionDetect"] == "no element carries CollisionGroup"
    assert pruned["CollisionConstraint"] == "no element carries CollisionGroup"
    assert pruned["AirDrag"] == "no element carries Dynamic + Drag"
    assert pruned["WindField"] == "no element carries Wind"
    assert pruned["FluidCoupling"] == "no element carries FluidDomain"
    kept = [b["type"] for st in plan["stages"].values() for b in st]
    assert {"Gravity", "StretchConstraint", "NucleusSolver"} <= set(kept)
    solver = [b for b in plan["stages"]["solve"] if b["type"] == "NucleusSolver"][0]
    assert solver["elements"] == ["cloth"]
    text = run_cli("plan", EXAMPLES / "cloth_pinned.yaml").stdout
    assert "pruned:" in text and "air_drag (AirDrag): no element carries Dynamic + Drag" in text


def test_read_of_pruned_writer_is_pruned_with_chain(scene_file):
    # a graph whose collision response is present but whose detector is not bound
    p = scene_file("""
    lokigraph: 1
    frames: {start: 1, end: 2, fps: 24}
    elements:
      - name: c
        geometry: {generator: grid, params: {resolution: [2, 2]}}
        components: {Dynamic: {}}
    """)
    c = compile_file(p)
    reasons = {n: r for n, t, r in c.schedule.pruned}
    assert reasons["collisions"] == "no element carries CollisionGroup"


def test_behaviors_and_schema_commands(tmp_path):
    r = run_cli("behaviors")
    assert r.returncode == 0
    assert "NucleusSolver" in r.stdout and "from=lokigraph" in r.stdout
    out = tmp_path / "schema.json"
    r = run_cli("schema", "--out", out)
    assert r.returncode == 0, r.stderr
    schema = json.loads(out.read_text())
    comps = schema["$defs"]["ElementSpec"]["properties"]["components"]["properties"]
    assert "DiscreteShell" in comps and "CollisionGroup" in comps
    shell = schema["$defs"]["component_DiscreteShell"]
    assert "[Pa]" in shell["properties"]["youngs_modulus"]["description"]
    assert schema["additionalProperties"] is False
    assert "NucleusSolver" in schema["x-behaviors"]


def test_fluid_domain_drives_drag(scene_file, tmp_path):
    """A patch inside a fluid box moving at U reaches v = U + (terminal fall) under linear drag;
    a second patch outside the box only falls."""
    grid = np.zeros((3, 3, 3, 3))
    grid[..., 0] = 2.0  # 2 m/s along x inside the box
    np.savez(tmp_path / "flow.npz", velocity=grid)
    p = scene_file("""
    lokigraph: 1
    frames: {start: 1, end: 49, fps: 24}
    gravity: [0, 0, 0]
    elements:
      - name: inside
        geometry: {generator: grid, params: {size: [0.1, 0.1], resolution: [2, 2], center: [0, 0, 0]}}
        components: {Dynamic: {mass_density: 1.0}, Drag: {model: linear, coefficient: 5.0}}
      - name: outside
        geometry: {generator: grid, params: {size: [0.1, 0.1], resolution: [2, 2], center: [0, 0, 5]}}
        components: {Dynamic: {mass_density: 1.0}, Drag: {model: linear, coefficient: 5.0}}
      - name: river
        components: {FluidDomain: {origin: [-100, -1, -1], size: [200, 2, 2], file: flow.npz}}
    """)
    c = compile_file(p)
    sim = Simulation(c)
    for _ in range(48):
        sim.step_frame()
    v = sim.state.particle_qd
    ins, out = c.scene.element("inside"), c.scene.element("outside")
    assert v[ins.vertex_slice, 0].mean() == pytest.approx(2.0, rel=1e-3)
    assert np.abs(v[out.vertex_slice]).max() < 1e-12


def test_fluid_domain_bad_file(scene_file, tmp_path):
    p = scene_file("""
    lokigraph: 1
    elements:
      - name: c
        geometry: {generator: grid, params: {resolution: [2, 2]}}
        components: {Dynamic: {}, Drag: {coefficient: 1.0}}
      - name: river
        components: {FluidDomain: {file: nope.npz}}
    """)
    r = run_cli("validate", p)
    assert r.returncode == 2 and 'element "river", FluidDomain.file: cannot read' in r.stderr
