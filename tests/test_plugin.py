"""A plugin package from tests/ is installed and used by a scene (entry points)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import run_cli

PKG = Path(__file__).resolve().parent / "plugin_pkg"

GRAPH = """
lokigraph_graph: 1
name: with_plugin
domains:
  forces:
    - type: Gravity
    - type: ThrusterForce
  constraints:
    - type: FloorConstraint
      params: {importance: 0.5, order: 50}
  solver:
    - type: NucleusSolver
      params: {iterations: 4}
"""

SCENE = """
lokigraph: 1
graph: graph.yaml
frames: {start: 1, end: 24, fps: 24}
substeps: 2
elements:
  - name: dots
    geometry: {generator: points, params: {positions: [[0, 0.5, 0], [1, 0.5, 0]]}}
    components:
      Dynamic: {point_mass: 1.0}
      Thruster: {force: [2.0, 0, 0], floor: 0.2}
"""


@pytest.fixture(scope="module")
def plugin_site(tmp_path_factory):
    target = tmp_path_factory.mktemp("site")
    r = subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps",
                        "--no-build-isolation", "--no-index", "--target", str(target), str(PKG)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return target


def test_plugin_behaviors_listed_and_used(plugin_site, tmp_path):
    env = {"PYTHONPATH": str(plugin_site)}
    r = run_cli("behaviors", env=env)
    assert r.returncode == 0
    line = [ln for ln in r.stdout.splitlines() if "FloorConstraint" in ln][0]
    assert "from=lokigraph-example-plugin" in line and "constraint" in line
    (tmp_path / "graph.yaml").write_text(GRAPH)
    (tmp_path / "scene.yaml").write_text(SCENE)
    out = tmp_path / "out"
    r = run_cli("run", tmp_path / "scene.yaml", "--out", out, "--quiet", env=env)
    assert r.returncode == 0, r.stderr
    info = json.loads((out / "run.json").read_text())
    # the custom constraint ran in the interleaved loop: importance 0.5 of 4 iterations = 2 per
    # substep, 2 substeps per frame
    assert all(f["stats"]["floor_projections"] == 4 for f in info["per_frame"])
    last = (out / "dots" / "0024.obj").read_text().split("\n")
    ys = [float(ln.split()[2]) for ln in last if ln.startswith("v ")]
    xs = [float(ln.split()[1]) for ln in last if ln.startswith("v ")]
    assert min(ys) >= 0.2 - 1e-12  # the floor held
    t = 23 / 24
    assert xs[0] == pytest.approx(0.5 * 2.0 * t * t, rel=0.05)  # thrust pushed along x


def test_without_plugin_the_type_is_unknown(tmp_path):
    (tmp_path / "graph.yaml").write_text(GRAPH)
    (tmp_path / "scene.yaml").write_text(SCENE)
    r = run_cli("validate", tmp_path / "scene.yaml")
    assert r.returncode == 2
    assert "unknown component type 'Thruster'" in r.stderr
