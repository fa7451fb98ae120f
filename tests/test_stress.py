"""The stress harness: it runs, reports every case with figures, and catches a blow-up."""

from pathlib import Path

from lokigraph.stress import Case, cases, format_rows, run_case


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
    assert len(cases(True)) == 6
