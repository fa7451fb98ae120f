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
