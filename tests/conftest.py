import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "graphs" / "examples"
DATA = Path(__file__).resolve().parent / "data"


def write_scene(tmp_path: Path, text: str, name: str = "scene.yaml") -> Path:
    p = tmp_path / name
    p.write_text(textwrap.dedent(text).lstrip())
    return p


def resumed_ends(make_sim, saved, key, frames=4):
    """Final positions of two runs restored from the checkpoint arrays ``saved`` and stepped
    ``frames`` frames: as saved, and with the array ``key`` zeroed (a test that a run state
    carries over: the first must continue bitwise, the second must not)."""
    import numpy as np

    from lokigraph import checkpoint

    ends = []
    for drop in (False, True):
        b = make_sim()
        arrays = dict(saved)
        if drop:
            arrays[key] = np.zeros_like(arrays[key])
        checkpoint.restore(b, arrays)
        for _ in range(frames):
            b.step_frame()
        ends.append(b.state.particle_q.copy())
    return ends


def run_cli(*args, cwd=None, env=None):
    """Run the CLI in a subprocess (checks exit codes and that no traceback leaks)."""
    e = dict(os.environ)
    if env:
        e.update(env)
    return subprocess.run([sys.executable, "-m", "lokigraph.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, env=e)


@pytest.fixture
def scene_file(tmp_path):
    def make(text, name="scene.yaml"):
        return write_scene(tmp_path, text, name)
    return make
