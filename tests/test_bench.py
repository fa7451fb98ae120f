"""``lokigraph bench``: the reference cases are true, the errors converge, the command writes its
files. (Timings are reported by the command, never asserted here.)"""

import json
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT
from lokigraph.bench.sweep import bench_setting, pareto, run_bench
from lokigraph.bench.references import elastica_curve

BENCH = ROOT / "graphs" / "bench"


def test_spring_reproduces_the_exact_discrete_solution():
    for n in (1, 2, 4):
        row, _ = bench_setting(BENCH / "spring.yaml", {"substeps": n})
        assert row["discrete_error"] < 1e-12
    # against the continuous cos(t) the error falls with h: first order (the staggered
    # velocity offsets the positions by O(h)); measured 0.069, 0.032, 0.015
    e = [bench_setting(BENCH / "spring.yaml", {"substeps": n})[0]["position_error"]
         for n in (4, 8, 16)]
    assert e[0] > e[1] > e[2] and e[1] / e[2] > 1.8


def test_projectile_error_is_first_order():
    """Symplectic Euler drops g h^2 n(n+1)/2 instead of g t^2/2: the error is g h t / 2."""
    for n in (1, 2, 4):
        row, _ = bench_setting(BENCH / "projectile.yaml", {"substeps": n})
        h = 1.0 / (24 * n)
        assert row["position_error"] == pytest.approx(9.81 * h * 1.0 / 2, rel=1e-9)


def test_catenary_reference_and_convergence():
    e = [bench_setting(BENCH / "catenary.yaml", {"substeps": n})[0]["position_error"]
         for n in (1, 4)]
    assert e[1] < 0.3 * e[0] and e[1] < 0.02  # measured 0.049 -> 0.0088 m


def test_catenary_reference_matches_the_continuous_catenary():
    """The discrete reference of a fine chain approaches the continuous catenary
    y = a cosh(x / a) + c through the pins with the chain's length (independent check of the
    reference itself): a 400-link chain, 1.5 m long, ends 1 m apart."""
    from scipy.optimize import brentq

    from lokigraph.bench.references import catenary

    n = 400
    t = np.abs(np.linspace(-1, 1, n + 1))  # a V of equal links
    drop = np.sqrt(0.75 ** 2 - 0.5 ** 2)
    pts = np.c_[np.linspace(-0.5, 0.5, n + 1), -drop * (1 - t), np.zeros(n + 1)]
    c = _chain_scene(pts)

    class Spec:
        element = "chain"

    idx, x = catenary(c, Spec, 0.0)
    a = brentq(lambda a: 2 * a * np.sinh(0.5 / a) - 1.5, 0.05, 10)
    y = a * np.cosh(x[:, 0] / a) - a * np.cosh(0.5 / a)
    assert np.abs(x[:, 1] - y).max() < 1e-3
    assert np.abs(x[:, 1] - y).max() > 0  # a real comparison


def _chain_scene(pts):
    import tempfile
    from pathlib import Path

    from lokigraph.api import compile_file

    d = Path(tempfile.mkdtemp())
    lines = [f"v {p[0]:.17g} {p[1]:.17g} {p[2]:.17g}" for p in pts]
    lines += [f"l {k + 1} {k + 2}" for k in range(len(pts) - 1)]
    (d / "c.obj").write_text("\n".join(lines) + "\n")
    (d / "s.yaml").write_text(f"""lokigraph: 1
elements:
  - name: chain
    geometry: {{file: c.obj}}
    components: {{Dynamic: {{mass_density: 0.1}}, Rod: {{bend_resistance: 0.0}},
                  Pins: {{vertices: [0, {len(pts) - 1}]}}}}
""")
    return compile_file(d / "s.yaml")


def test_elastica_reference_small_load_matches_linear_beam_theory():
    """Independent check of the BVP: a light load gives the Euler-Bernoulli tip deflection
    q L^4 / (8 EI); the heavy load of the bench case is clearly non-linear (shorter reach)."""
    L, EI = 0.2, 2.616e-5
    q = 1e-3 * EI / L ** 3  # load parameter 1e-3
    x, y = elastica_curve(L, q, EI, np.array([L]))
    assert -y[0] == pytest.approx(q * L ** 4 / (8 * EI), rel=1e-3)
    q = 3 * EI / L ** 3
    x, y = elastica_curve(L, q, EI, np.array([L]))
    assert x[0] < 0.97 * L and -y[0] < q * L ** 4 / (8 * EI)


def test_elastica_converges_with_substeps():
    """With the direct per-strand Rod solve (the default) the error is the 20-segment
    discretisation's at any substep count (measured 7.1e-4 and 7.4e-4 m at 8 and 32 substeps,
    within 2 % of L = 0.2 m); Gauss-Seidel measured 0.17 -> 0.053 m."""
    e = [bench_setting(BENCH / "elastica.yaml", {"substeps": n, "iterations": 15})[0]
         ["position_error"] for n in (8, 32)]
    assert max(e) < 0.02 * 0.2 and abs(e[1] - e[0]) < 5e-4, e


def test_terminal_velocity_error_falls_with_substeps():
    e = [bench_setting(BENCH / "terminal_velocity.yaml", {"substeps": n})[0]["position_error"]
         for n in (1, 4)]
    assert e[0] < 1e-4 and e[1] < 0.5 * e[0]


def test_pareto_front():
    rows = [{"ms_per_frame": 1, "e": 3}, {"ms_per_frame": 2, "e": 1}, {"ms_per_frame": 3, "e": 2}]
    assert pareto(rows, "e") == rows[:2]


def test_bench_writes_table_and_files(tmp_path):
    rows = run_bench(BENCH / "projectile.yaml", {"substeps": ["1", "2"]}, None, tmp_path)
    assert [r["pareto"] for r in rows] == [True, True]
    assert (tmp_path / "bench.csv").read_text().startswith("substeps,")
    assert len(json.loads((tmp_path / "bench.json").read_text())) == 2


def test_stored_reference_roundtrip(tmp_path):
    """--make-reference stores the tight run; a coarse run is then measured against it."""
    scene = tmp_path / "drape.yaml"
    text = (BENCH / "drape_ref.yaml").read_text()
    text = text.replace("resolution: [32, 32]", "resolution: [6, 6]").replace(
        "vertices: [0, 32]", "vertices: [0, 6]").replace("end: 31", "end: 7")
    text = re.sub(r"settings: \{[^}]*\}", "settings: {substeps: 16, iterations: 40}", text)
    assert "settings: {substeps: 16, iterations: 40}" in text
    scene.write_text(text)
    r = subprocess.run([sys.executable, "-m", "lokigraph", "bench", str(scene),
                        "--make-reference"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    ref = np.load(tmp_path / "drape_ref.npy")
    assert ref.shape == (49, 3)
    row, q = bench_setting(scene, {"substeps": 16, "iterations": 40})
    assert row["position_error"] < 1e-12  # the same settings reproduce it
    row, q = bench_setting(scene, {"substeps": 1, "iterations": 5})
    assert row["position_error"] > 1e-4
    with pytest.raises(ValueError, match="stored reference"):
        bench_setting(scene, {}, frames=3)


def test_bench_cli_errors_exit_2(tmp_path):
    r = subprocess.run([sys.executable, "-m", "lokigraph", "bench", str(BENCH / "spring.yaml"),
                        "--sweep", "bogus=1", "--out", str(tmp_path)], capture_output=True,
                       text=True)
    assert r.returncode == 2 and "unknown sweep key" in r.stderr
    assert "Traceback" not in r.stderr


def test_scaling_reports_exponent(tmp_path):
    from lokigraph.bench.sweep import run_scaling

    res = run_scaling(tmp_path, sizes=(8, 16), frames=3)
    assert len(res["rows"]) == 2 and np.isfinite(res["exponent"])
    assert all(r["bytes_per_vertex"] > 0 for r in res["rows"])


def test_pruning_graph_gives_the_same_answer():
    """The minimal graph and the full default graph run the same cloth to the same result."""
    a = bench_setting(BENCH / "drape_64.yaml", {"graph": "default"}, frames=3)[1]
    b = bench_setting(BENCH / "drape_64.yaml", {"graph": "minimal_cloth.yaml"}, frames=3)[1]
    assert np.array_equal(a, b)


@pytest.mark.skipif(shutil.which("lokigraph") is None, reason="console script not installed")
def test_bench_help_runs():
    assert subprocess.run(["lokigraph", "bench", "--help"], capture_output=True).returncode == 0


def test_bench_fluid_pressure_table(tmp_path):
    """`lokigraph bench --fluid N` times the pressure solve of an N^3 grid with three solvers
    and writes fluid.json; every solver reaches the tolerance and a divergence-free field."""
    r = subprocess.run([sys.executable, "-m", "lokigraph", "bench", "--fluid", "8", "--out",
                        str(tmp_path)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    import json

    rows = json.loads((tmp_path / "fluid.json").read_text())
    assert [x["solver"] for x in rows] == ["amg", "jacobi", "cg"]
    assert all(x["residual"] <= 1e-8 and x["cells"] == 512 for x in rows)
    bad = subprocess.run([sys.executable, "-m", "lokigraph", "bench", "--fluid", "1000"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr


def test_sweep_values_keep_their_type():
    """Sweep values from the command line are text; from Python they may be numbers, which are
    kept as given (a float 0.97 once became int 0)."""
    from lokigraph.bench.sweep import _num

    assert _num("3") == 3 and isinstance(_num("3"), int)
    assert _num("0.97") == 0.97 and _num(0.97) == 0.97 and _num(4) == 4
    assert _num("true") is True and _num(False) is False and _num("pcg") == "pcg"
