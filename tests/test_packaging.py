"""Install from a built wheel into a fresh virtual environment and run a shipped scene."""

import json
import os
import subprocess
import sys
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def make_venv_sharing_deps(env_dir: Path) -> Path:
    """A fresh venv whose dependencies (numpy, numba ...) come from the interpreter running the
    tests, whatever that is (a venv or not), and nothing else: no network is needed and the
    package under test is only what gets installed into the new venv.

    ``system_site_packages`` would give the *base* Python's packages, which lack numba when the
    tests run from a venv; a ``.pth`` file naming this interpreter's site-packages gives exactly
    the packages the test run itself imports. Its own site-packages comes first on sys.path, so a
    lokigraph installed there wins over any in the shared folders (and an editable install's
    finder, activated by a .pth file of its own, is not run for a folder added this way).
    """
    import site
    import sysconfig

    venv.EnvBuilder(system_site_packages=False, with_pip=False).create(env_dir)
    py = env_dir / "bin" / "python"
    purelib = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_path("
                              "'purelib'))"], capture_output=True, text=True, check=True)
    dirs = dict.fromkeys([*site.getsitepackages(), sysconfig.get_path("purelib"),
                          sysconfig.get_path("platlib"),
                          # folders that .pth files of this interpreter added (shared deps)
                          *(p for p in sys.path if p.endswith(("site-packages", "dist-packages")))])
    (Path(purelib.stdout.strip()) / "_lokigraph_test_deps.pth").write_text(
        "\n".join(d for d in dirs if Path(d).is_dir()) + "\n")
    return py


def test_wheel_installs_and_runs(tmp_path):
    dist = tmp_path / "dist"
    r = subprocess.run([sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir",
                        str(dist), str(ROOT)], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    wheel = next(dist.glob("lokigraph-*.whl"))
    import zipfile

    names = zipfile.ZipFile(wheel).namelist()
    for must in ("lokigraph/cli.py", "lokigraph/behaviors/solvers/nucleus/solver.py",
                 "lokigraph/behaviors/solvers/nucleus/xpbd.py",
                 "lokigraph/behaviors/materials/stretch.py",
                 "lokigraph/behaviors/attachments/pins.py", "lokigraph/behaviors/air/kernels.py",
                 "lokigraph/behaviors/coupling/fluid.py", "lokigraph/behaviors/collision/shapes.py",
                 "lokigraph/bench/sweep.py", "lokigraph/bench/stress.py",
                 "lokigraph/bench/references.py",
                 "lokigraph/components/core.py", "lokigraph/graphs/default.yaml",
                 "lokigraph/graphs/examples/pinned_particles.yaml",
                 "lokigraph/graphs/examples/lid_soft.npy",
                 "lokigraph/behaviors/collision/contacts.py",
                 "lokigraph/graphs/bench/catenary.yaml", "lokigraph/graphs/bench/chain.obj",
                 "lokigraph/graphs/bench/drape_ref.npy"):
        assert must in names, must
    # every source module installs (a subpackage missing from pyproject's ``packages`` would not)
    for top, dest in (("lokigraph", "lokigraph"), ("behaviors", "lokigraph/behaviors"),
                      ("components", "lokigraph/components")):
        for f in (ROOT / top).rglob("*.py"):
            if "__pycache__" in f.parts:
                continue
            rel = f"{dest}/{f.relative_to(ROOT / top).as_posix()}"
            assert rel in names, f"{rel} missing from the wheel"
    assert not any(n.startswith(("behaviors/", "components/", "graphs/")) for n in names)
    env_dir = tmp_path / "venv"
    py = make_venv_sharing_deps(env_dir)
    r = subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "--quiet",
                        "--no-deps", "--no-index", str(wheel)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH",)}
    code = ("import lokigraph, lokigraph.graphs, pathlib, sys; "
            "print(lokigraph.__file__); "
            "print(pathlib.Path(lokigraph.graphs.__file__).parent / 'examples' / "
            "'pinned_particles.yaml')")
    r = subprocess.run([str(py), "-I", "-c", code], capture_output=True, text=True, env=env,
                       cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    mod, scene = r.stdout.split()
    assert str(env_dir) in mod, f"lokigraph imported from {mod}, not from the wheel"
    lg = env_dir / "bin" / "lokigraph"
    out = tmp_path / "out"
    r = subprocess.run([str(lg), "run", scene, "--out", str(out), "--quiet"], capture_output=True,
                       text=True, env=env, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    info = json.loads((out / "run.json").read_text())
    assert info["status"] == "ok" and len(info["frames"]["written"]) > 1
    r = subprocess.run([str(lg), "behaviors"], capture_output=True, text=True, env=env)
    assert "NucleusSolver" in r.stdout
    # bench and stress run from the installed package
    cat = Path(scene).parent.parent / "bench" / "catenary.yaml"
    r = subprocess.run([str(lg), "bench", str(cat), "--sweep", "substeps=1", "--out",
                        str(tmp_path / "b")], capture_output=True, text=True, env=env,
                       cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "b" / "bench.json").read_text())[0]["position_error"] < 0.1
    r = subprocess.run([str(lg), "stress", "--quick", "--only", "sliver"], capture_output=True,
                       text=True, env=env, cwd=tmp_path)
    assert r.returncode == 0 and "1/1 cases passed" in r.stdout, r.stdout + r.stderr
