"""The stress harness: it runs, reports every case with figures, and catches a blow-up."""

from pathlib import Path

from lokigraph.bench.stress import Case, cases, format_rows, run_case


def test_stress_harness_reports_and_catches_failures(tmp_path):
    bomb = Case("explicit spring beyond h*omega = 2", """
lokigraph: 1
frames: {start: 1, end: 400, fps: 1}
substeps: 1
gravity: [0, 0, 0]
elements:
  - name: bomb
    geometry: {generator: points, params: {positions: [[1, 0, 0]]}}
    components: {Dynamic: {point_mass: 1.0}, RestSpring: {stiffness: 9.0, anchor: [0, 0, 0]}}
""", 399)
    r = run_case(bomb, tmp_path / "bomb")
    assert not r["passed"] and r["why"].startswith("non-finite")
    calm = Case("free fall", """
lokigraph: 1
frames: {start: 1, end: 10, fps: 24}
elements:
  - name: p
    geometry: {generator: points, params: {positions: [[0, 0, 0]]}}
    components: {Dynamic: {point_mass: 1.0}}
""", 9)
    r = run_case(calm, tmp_path / "calm")
    assert r["passed"] and abs(r["energy_excess_J"]) < 1e-9
    text = format_rows([r])
    assert text.startswith("PASS  free fall")
    assert len(cases(True)) == 8


def test_quick_stress_suite_passes():
    """`lokigraph stress --quick` in CI: every case must pass (a failing case fails the build,
    with its figures in the message)."""
    from lokigraph.bench.stress import run_stress

    rows = run_stress(quick=True)
    failed = [r for r in rows if not r["passed"]]
    assert not failed, format_rows(failed)


def test_stress_cli_exit_code(tmp_path):
    """The command returns 0 when its cases pass, 3 when one fails, 2 on a bad selection, and
    writes stress.json."""
    import json
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "lokigraph", "stress", "--quick", "--only",
                        "mass ratio", "--out", str(tmp_path)], capture_output=True, text=True)
    rows = json.loads((tmp_path / "stress.json").read_text())
    assert len(rows) == 1 and r.returncode == (0 if rows[0]["passed"] else 3)
    assert "1/1 cases passed" in r.stdout or "0/1 cases passed" in r.stdout
    r = subprocess.run([sys.executable, "-m", "lokigraph", "stress", "--only", "no such case"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "no stress case matches" in r.stderr


def test_tangle_counts_of_the_interpenetrated_case(tmp_path):
    """The two tangle measures of the case that starts interpenetrated (``no_worse``), after
    its first frame: the cloth's own intersecting pairs (two sheets cut through each other)
    and the cloth vertices inside the closed kinematic ball, by winding number: the same
    vertices as |x| < r for the sphere of radius 0.3 at the origin (vertices within 1 % of r
    left out: the mesh is faceted), and more of them when the cloth moves into the ball (the
    measure can fail)."""
    import numpy as np

    from lokigraph.api import compile_file
    from lokigraph.bench.stress import _crossed, tangle_counts
    from lokigraph.run import Simulation

    case = [c for c in cases(True) if "interpenetrated" in c.name][0]
    assert case.no_worse
    _crossed(tmp_path / "crossed.obj")
    (tmp_path / "scene.yaml").write_text(case.scene)
    c = compile_file(tmp_path / "scene.yaml")
    sim = Simulation(c)
    sim.step_frame()  # the sheets start crossed along a line of shared positions (touching)
    q = sim.state.particle_q.copy()
    pairs, inside = tangle_counts(c, q)
    assert pairs > 0  # and cut through each other after the first frame
    cl = c.scene.element("cloth").vertex_slice
    r = np.linalg.norm(q[cl], axis=1)
    sure = np.abs(r - 0.3) > 0.003
    q_in = np.zeros(len(q), dtype=bool)
    q_in[cl] = r < 0.3
    assert inside >= (q_in[cl] & sure).sum() and inside <= (r < 0.3).sum() + (~sure).sum()
    assert (r < 0.297).sum() > 0
    q2 = q.copy()
    q2[cl, 0] *= 0.5  # the sheets squeezed toward the ball's axis: more of them inside
    assert tangle_counts(c, q2)[1] > inside
    q3 = q.copy()
    q3[cl, 1] += 10.0  # far above the ball: nothing inside, the sheets still cross
    assert tangle_counts(c, q3) == (pairs, 0)
