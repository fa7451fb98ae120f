"""lokigraph wedge: variants, the local cluster, failures, resume after a kill, an external
scheduler with two workers (all on 127.0.0.1, tiny scenes)."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lokigraph.cli import main
from lokigraph.wedge import Wedge, _is_complete, parse_vary, run_wedge, variant_name

pytest.importorskip("distributed", reason="the wedge extra (dask[distributed]) is not installed")

TINY = """\
lokigraph: 1
graph: default
frames: {start: 1, end: 3, fps: 24}
substeps: 1
elements:
  - name: cloth
    geometry:
      generator: grid
      params: {size: [1.0, 1.0], resolution: [5, 5], plane: xz, center: [0, 1, 0]}
    components:
      Dynamic: {mass_density: 0.2, damping: 0.1}
      DiscreteShell: {bend_resistance: 1.0e-6}
      Pins: {vertices: [0, 5]}
output: {dir: out, format: obj}
"""

#: the last gravity makes every position non-finite in the first substep: exit 3 at run time
GRAVITIES = "gravity=[0,-9.81,0],[0,-5,0],[0,-1e300,0],[-2,-9.81,0]"
BAD = "gravity=0,-1e+300,0"
TIMEOUT = 60


@pytest.fixture
def tiny(tmp_path):
    p = tmp_path / "scene" / "tiny.yaml"
    p.parent.mkdir()
    p.write_text(TINY)
    return p


def _env():
    e = dict(os.environ, NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1")
    e["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).resolve().parents[1]),
                                       e.get("PYTHONPATH", "")])
    return e


def _ok_runs(out: Path) -> dict:
    found = {}
    for rj in out.glob("*/run.json"):
        try:
            if json.loads(rj.read_text())["status"] == "ok":
                found[rj.parent.name] = rj.stat().st_mtime_ns
        except (OSError, ValueError, KeyError):
            pass
    return found


def test_vary_values_names_and_keys(tiny, tmp_path):
    pairs = parse_vary(["substeps=1,2", "cloth.DiscreteShell.bend_resistance=1e-6,1.0e-5",
                        "gravity=[0,-9.81,0],[0,-1e3,0]", "seed=true"])
    assert pairs[0] == ("substeps", [1, 2])
    assert pairs[1][1] == [1e-6, 1e-5] and all(isinstance(v, float) for v in pairs[1][1])
    assert pairs[2][1] == [[0, -9.81, 0], [0, -1000.0, 0]]
    assert variant_name([("substeps", 2), ("cloth.DiscreteShell.bend_resistance", 1e-5)]) == \
        "substeps=2__cloth.DiscreteShell.bend_resistance=1e-05"
    odd = variant_name([("cloth.Pins.vertices", [0, 5]), ("solver", "a b/c")])
    assert "/" not in odd and " " not in odd and len(odd.split("__")[-1]) == 8
    assert len(variant_name([("x", "y" * 500)])) <= 120
    w = Wedge(tiny, ["substeps=1,2", "cloth.DiscreteShell.bend_resistance=1e-6,1e-5",
                     "graph_overrides.nucleus_solver.iterations=5", "frames.fps=30"],
              out=tmp_path / "w")
    assert len(w.variants) == 4
    assert w.variants[0]["name"] == ("substeps=1__cloth.DiscreteShell.bend_resistance=1e-06__"
                                     "graph_overrides.nucleus_solver.iterations=5__frames.fps=30")
    assert "bend_resistance: 1.0e-05" in w.variants[3]["text"]
    assert not (tmp_path / "w").exists()  # planning writes nothing


@pytest.mark.parametrize("vary, words", [
    ("substepz=1,2", "did you mean 'substeps'"),
    ("cloth.DiscreteShel.bend_resistance=1", "has no component 'DiscreteShel'"),
    ("cloth.DiscreteShell.bend=1", "has no field 'bend'"),
    ("nocloth.Dynamic.damping=1", "unknown key 'nocloth'"),
    ("cloth.Dynamic.damping=-1,0.1", "must be >= 0"),
    ("graph_overrides.nucleus_solver.iterationz=5", "iterationz"),
    ("substeps", "expected KEY=V1,V2"),
])
def test_bad_keys_and_values_are_input_errors(tiny, tmp_path, capsys, vary, words):
    out = tmp_path / "w"
    assert main(["wedge", str(tiny), "--vary", vary, "--out", str(out)]) == 2
    assert words in capsys.readouterr().err
    assert not out.exists()  # nothing ran, nothing written


def test_local_cluster_failure_table_sheet_and_resume(tiny, tmp_path, capsys):
    out = tmp_path / "w"
    args = ["wedge", str(tiny), "--vary", GRAVITIES, "--out", str(out), "--workers", "2"]
    assert main(args) == 3  # one variant failed, the others ran
    text = capsys.readouterr().out
    assert text.count("] gravity=") == 4 and "3/4 variants ok" in text
    folders = sorted(p.name for p in out.iterdir() if p.is_dir())
    assert folders == sorted(["gravity=0,-9.81,0", "gravity=0,-5,0", BAD, "gravity=-2,-9.81,0"])
    res = json.loads((out / "wedge.json").read_text())
    by = {r["name"]: r for r in res["rows"]}
    assert by[BAD]["status"] == "failed" and by[BAD]["exit_code"] == 3
    assert "non-finite" in by[BAD]["error"]
    for name, r in by.items():
        assert (out / name / "variant.yaml").exists()
        assert json.loads((out / name / "run.json").read_text())["status"] == r["status"]
        if name != BAD:
            assert r["status"] == "ok" and r["frames_written"] == 3
            assert r["wall_s"] > 0 and r["cpu_s"] > 0 and r["ms_per_frame"] > 0
            assert r["numba_threads"] == 1  # the local cluster's workers are single-threaded
    rows = list(csv.DictReader((out / "wedge.csv").open()))
    assert [r["name"] for r in rows] == [r["name"] for r in res["rows"]]
    assert {"gravity", "status", "wall_s", "cpu_s", "ms_per_frame"} <= set(rows[0])
    assert rows[0]["gravity"] == "0,-9.81,0"
    png = (out / "contact_sheet.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5000
    # resume: the ok variants are complete, the failed one is not
    w = Wedge(tiny, [GRAVITIES], out=out)
    assert [_is_complete(v["dir"], v["text"], None, None) is not None for v in w.variants] == \
        [True, True, False, True]
    # an unchanged rerun with every variant ok starts no cluster and touches nothing
    good = ["gravity=[0,-9.81,0],[0,-5,0]"]
    before = _ok_runs(out)
    res2 = run_wedge(tiny, good, out=out, workers=2)
    assert (res2["skipped"], res2["ran"], res2["failed"]) == (2, 0, 0)
    assert _ok_runs(out) == before


def test_killed_wedge_resumes_without_rerunning_finished(tiny, tmp_path):
    out = tmp_path / "w"
    # one worker runs them in order: a quick variant, then three of ~1 s each
    vary = "substeps=1,400,401,402"
    proc = subprocess.Popen([sys.executable, "-m", "lokigraph.cli", "wedge", str(tiny),
                             "--vary", vary, "--out", str(out), "--workers", "1"],
                            env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            start_new_session=True)
    try:
        t0 = time.monotonic()
        while not _ok_runs(out) and proc.poll() is None and time.monotonic() - t0 < TIMEOUT:
            time.sleep(0.05)
    finally:
        with_pg = proc.poll() is None
        if with_pg:
            os.killpg(proc.pid, signal.SIGKILL)  # the wedge and its cluster's processes
        proc.wait(10)
    assert with_pg, proc.stdout.read().decode()
    time.sleep(0.2)
    finished = _ok_runs(out)
    assert 1 <= len(finished) < 4, finished
    res = run_wedge(tiny, [vary], out=out, workers=1)
    assert res["ok"] == 4 and res["failed"] == 0
    assert res["skipped"] == len(finished) and res["ran"] == 4 - len(finished)
    after = _ok_runs(out)
    assert all(after[n] == t for n, t in finished.items())  # not rerun
    assert len(after) == 4


def test_external_scheduler_and_two_workers(tiny, tmp_path):
    sched_file = tmp_path / "scheduler.json"
    env = _env()
    procs = []
    try:
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
             "--port", "0", "--no-dashboard", "--scheduler-file", str(sched_file)],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True))
        t0 = time.monotonic()
        while not sched_file.exists() and time.monotonic() - t0 < TIMEOUT:
            time.sleep(0.05)
        address = json.loads(sched_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        for i in range(2):
            procs.append(subprocess.Popen(
                [sys.executable, "-m", "distributed.cli.dask_worker", address, "--host",
                 "127.0.0.1", "--nthreads", "1", "--no-nanny", "--no-dashboard", "--name",
                 f"w{i}"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                start_new_session=True))
        out = tmp_path / "w"
        assert main(["wedge", str(tiny), "--vary", "substeps=1,2",
                     "--vary", "cloth.DiscreteShell.bend_resistance=1e-6,1e-5",
                     "--out", str(out), "--scheduler", address, "--quiet"]) == 0
        res = json.loads((out / "wedge.json").read_text())
        assert res["cluster"] == address and res["ok"] == 4
        assert len({r["pid"] for r in res["rows"]}) >= 1
        assert all(os.getpid() != r["pid"] for r in res["rows"])  # ran in the workers
        assert (out / "contact_sheet.png").exists()
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.terminate()
        for p in reversed(procs):
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5)


def test_missing_dask_names_the_extra(tiny, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    assert main(["wedge", str(tiny), "--vary", "substeps=1", "--out", str(tmp_path / "w")]) == 2
    assert "lokigraph[wedge]" in capsys.readouterr().err


def test_usd_format_variants_and_contact_sheet(tiny, tmp_path):
    pytest.importorskip("pxr")
    from lokigraph.wedge import _last_frame_meshes

    out = tmp_path / "w"
    assert main(["wedge", str(tiny), "--vary", "substeps=1,2", "--format", "usd", "--out",
                 str(out), "--workers", "1", "--quiet"]) == 0
    for name in ("substeps=1", "substeps=2"):
        info = json.loads((out / name / "run.json").read_text())
        assert info["status"] == "ok" and info["format"] == "usd"
        assert (out / name / "run.usd").is_file()
        meshes = _last_frame_meshes(out / name)  # the contact sheet reads the stage
        assert meshes and len(meshes[0][0]) > 0
    assert (out / "contact_sheet.png").is_file()
