"""The README's two commands, run as a new user runs them: in a fresh venv, from a clean copy of
the repository, command 1 then command 2, in the same shell environment.

The commands are read from the README itself (the ``bash`` block under "Two commands"), so the
README cannot drift from what is tested. Command 2 ends in ``python -m pytest -q``; the default
test narrows that pytest to the tests that a stale install broke before (the packaging test and
the ``lokigraph`` console script) to keep the suite short; the ``slow`` variant runs command 2
verbatim (the whole suite, minus this module, which would recurse).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
NESTED = "LOKIGRAPH_README_TEST_NESTED"

pytestmark = pytest.mark.skipif(os.environ.get(NESTED) == "1",
                                reason="already inside the README-commands test")


def readme_commands() -> list[str]:
    """The shell commands of the README's "Two commands" block, in order."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    sec = text.split("## Two commands", 1)[1]
    block = re.search(r"```bash\n(.*?)```", sec, re.S).group(1)
    cmds = [ln.strip() for ln in block.splitlines() if ln.strip() and not ln.strip().startswith("#")]
    return cmds


def clean_copy(dest: Path) -> Path:
    """What a fresh clone holds: tracked files plus untracked ones git does not ignore."""
    r = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT,
                       capture_output=True, check=True)
    for rel in filter(None, r.stdout.decode().split("\0")):
        src = ROOT / rel
        if not src.is_file():
            continue
        dst = dest / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dst)
    return dest


def base_env(tmp_path: Path) -> dict:
    """The environment of a new shell: no active venv, the base python3 first on PATH."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("VIRTUAL_ENV", "PYTHONPATH", "PYTHONHOME", "NUMBA_CACHE_DIR",
                        "LOKIGRAPH_CACHE_DIR") and not k.startswith("PYTEST")}
    venv_bin = str(Path(sys.executable).parent)
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep)
                                  if p != venv_bin)
    env["XDG_CACHE_HOME"] = str(tmp_path / "user-cache")  # this user's cache, not the tester's
    env[NESTED] = "1"
    return env


def _run(cmd: str, cwd: Path, env: dict, timeout: float) -> subprocess.CompletedProcess:
    # both commands run in one shell session, as a user pastes them one after the other
    return subprocess.run(["bash", "-c", cmd], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout)


def _both(tmp_path: Path, second: str) -> tuple[subprocess.CompletedProcess, Path]:
    first, _ = readme_commands()
    repo = clean_copy(tmp_path / "lokigraph")
    env = base_env(tmp_path)
    r1 = _run(first, repo, env, 1200)
    assert r1.returncode == 0, f"command 1 failed:\n{r1.stdout[-3000:]}\n{r1.stderr[-3000:]}"
    assert (repo / "out" / "flag_wind" / "run.json").exists()
    site = next((repo / ".venv" / "lib").glob("python3*/site-packages"))
    stray = [p for p in (site / "lokigraph").rglob("*") if p.suffix in (".nbi", ".nbc")]
    assert not stray, f"numba cache files inside the installed package: {stray[:3]}"
    assert any((tmp_path / "user-cache" / "lokigraph" / "numba").rglob("*.nbi"))
    # the same shell: the venv of command 1 is still active
    r2 = _run(f". .venv/bin/activate && {second}", repo, env, 1800)
    return r2, repo


def test_readme_commands_one_then_two(tmp_path):
    first, second = readme_commands()
    assert second.endswith("python -m pytest -q"), second
    narrowed = second + " tests/test_packaging.py tests/test_bench.py::test_bench_help_runs"
    r2, repo = _both(tmp_path, narrowed)
    tail = r2.stdout[-3000:] + r2.stderr[-3000:]
    assert r2.returncode == 0, f"command 2 failed:\n{tail}"
    assert re.search(r"\b2 passed\b", r2.stdout), tail
    # the editable install is the one imported, and the CLI works from it
    r = subprocess.run([str(repo / ".venv" / "bin" / "lokigraph"), "--version"],
                       capture_output=True, text=True)
    assert r.returncode == 0 and "lokigraph" in r.stdout, r.stderr


@pytest.mark.slow
def test_readme_commands_verbatim(tmp_path):
    _, second = readme_commands()
    r2, _ = _both(tmp_path, second)
    assert r2.returncode == 0, r2.stdout[-4000:] + r2.stderr[-2000:]
    assert re.search(r"\d+ passed", r2.stdout)
