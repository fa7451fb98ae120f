"""Checkpoints, ``run --resume`` and ``initial_state``/``preroll`` (issue 14).

A run killed with SIGKILL at a (seeded) random frame and resumed writes frames bit-identical
(binary PLY, doubles) to an uninterrupted run, with self-collision (cloth_on_sphere, reduced)
and with crossing memory and compliant kinematics active (pinch, reduced so that the plates
touch the cloth inside the frame range).
"""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "graphs" / "examples"
# one numba thread: the same results as more threads (checked when developing), and ~10x faster
# on a shared 2-core machine (the parallel kernels' start-up dominates these small scenes)
ENV = dict(os.environ, NUMBA_NUM_THREADS="1")


def _edit(src: Path, dst: Path, replacements: list[tuple[str, str]]) -> Path:
    text = src.read_text()
    for old, new in replacements:
        assert old in text, old
        text = text.replace(old, new)
    dst.write_text(text)
    return dst


def _sphere_scene(tmp: Path) -> Path:
    return _edit(EXAMPLES / "cloth_on_sphere.yaml", tmp / "cos.yaml", [
        ("resolution: [64, 64]", "resolution: [14, 14]"),
        ("subdivisions: 4", "subdivisions: 2"),
        ("center: [0, 0.6, 0]", "center: [0, 0.33, 0]"),
        ("end: 48", "end: 10"),
        ("format: obj}", "format: ply, checkpoint_every: 3}")])


def _pinch_scene(tmp: Path) -> Path:
    shutil.copy(EXAMPLES / "lid_soft.npy", tmp / "lid_soft.npy")
    return _edit(EXAMPLES / "pinch.yaml", tmp / "pinch.yaml", [
        ("end: 61", "end: 12"),
        ("{frame: 25, translate: [0, -0.06, 0]}, {frame: 49, translate: [0, 0, 0]}",
         "{frame: 7, translate: [0, -0.06, 0]}, {frame: 13, translate: [0, 0, 0]}"),
        ("format: obj}", "format: ply, checkpoint_every: 3}")])


def _cli(*args, check=True):
    p = subprocess.run([sys.executable, "-m", "lokigraph", "run", *map(str, args), "--quiet"],
                       env=ENV, capture_output=True, text=True, timeout=240)
    if check:
        assert p.returncode == 0, p.stdout + p.stderr
    return p


def _kill_at(scene: Path, out: Path, element: str, frame: int) -> None:
    """Run ``scene`` into ``out`` and SIGKILL it as soon as ``frame`` is written."""
    proc = subprocess.Popen([sys.executable, "-m", "lokigraph", "run", str(scene), "--out",
                             str(out), "--quiet"], env=ENV, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    target = out / element / f"{frame:04d}.ply"
    deadline = time.monotonic() + 240
    try:
        while not target.exists():
            assert proc.poll() is None, "the run ended before it could be killed"
            assert time.monotonic() < deadline
            time.sleep(0.005)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    assert not (out / "run.json").exists()


def _frames(out: Path) -> dict[str, bytes]:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.glob("*/*.ply"))}


def _check_resume(scene: Path, tmp: Path, element: str, seed: int, last: int) -> dict:
    ref = tmp / "ref"
    _cli(scene, "--out", ref)
    k = random.Random(seed).randint(3, last - 2)
    killed = tmp / "killed"
    _kill_at(scene, killed, element, k)
    p = _cli(scene, "--resume", killed)
    assert "status ok" in p.stdout
    a, b = _frames(ref), _frames(killed)
    assert a.keys() == b.keys() and len(a) >= last
    bad = [name for name in a if a[name] != b[name]]
    assert not bad, f"killed at frame {k}: frames differ after --resume: {bad}"
    info = json.loads((killed / "run.json").read_text())
    assert info["status"] == "ok"
    assert 1 <= info["resumed_from"] <= k + 1
    assert info["frames"]["written"] == list(range(1, last + 1))
    assert [r["frame"] for r in info["per_frame"]] == list(range(2, last + 1))
    # the last checkpoints hold the same state, bit for bit
    for name in ("0010.npz",) if (ref / "checkpoints" / "0010.npz").exists() else ():
        za, zb = np.load(ref / "checkpoints" / name), np.load(killed / "checkpoints" / name)
        for key in za.files:
            if key != "meta":
                assert np.array_equal(za[key], zb[key]), key
    return info


def test_resume_after_kill_is_bit_identical(tmp_path):
    info = _check_resume(_sphere_scene(tmp_path), tmp_path, "cloth", seed=14, last=10)
    assert max(r["stats"].get("contacts_vf", 0) for r in info["per_frame"]) > 0


def test_resume_with_crossing_memory_and_compliant_kinematics(tmp_path):
    info = _check_resume(_pinch_scene(tmp_path), tmp_path, "cloth", seed=3, last=12)
    # the plates press the cloth inside the range: contacts active in the final rounds
    assert max(r["stats"].get("max_final_active", 0) for r in info["per_frame"]) > 0
    assert info["output"]["elements"] == ["cloth", "lid"]  # the compliant lid is written
    z = np.load(tmp_path / "killed" / "checkpoints" / "0012.npz")
    assert np.count_nonzero(z["behavior/collision_detect/0.side_mem"]) > 0  # crossing memory
    ref_lid = tmp_path / "ref" / "lid" / "0008.ply"
    assert ref_lid.read_bytes() == (tmp_path / "killed" / "lid" / "0008.ply").read_bytes()


def test_resume_refuses_another_scene(tmp_path):
    scene = _sphere_scene(tmp_path)
    out = tmp_path / "run"
    _cli(scene, "--out", out, "--frames", "1:2")
    other = _edit(scene, tmp_path / "other.yaml", [("damping: 0.2", "damping: 0.3")])
    p = _cli(other, "--resume", out, check=False)
    assert p.returncode == 2
    assert "different scene" in p.stderr
    p = _cli(scene, "--resume", tmp_path / "nothing", check=False)
    assert p.returncode == 2 and "no checkpoint" in p.stderr


def _pinned(tmp: Path, extra: str = "", start: int = 1, output: str = "format: ply}") -> Path:
    return _edit(EXAMPLES / "cloth_pinned.yaml", tmp / f"pinned{start}{len(extra)}.yaml", [
        ("resolution: [32, 32]", "resolution: [8, 8]"),
        ("Pins: {vertices: [0, 32]}", "Pins: {vertices: [0, 8]}"),
        ("frames: {start: 1, end: 48, fps: 24}", f"frames: {{start: {start}, end: 12, fps: 24}}"),
        ("format: obj}", output + "\n" + extra)])


def _q(path: Path) -> np.ndarray:
    from lokigraph.meshfile import read_mesh

    return read_mesh(path).points


def test_initial_state_equals_continuing_the_run(tmp_path, monkeypatch):
    from lokigraph.api import compile_file
    from lokigraph.run import run

    monkeypatch.chdir(tmp_path)
    first = run(compile_file(_pinned(tmp_path, output="format: ply, checkpoint_every: 5, "
                                              "checkpoint_keep: 9}")), out_dir="a",
                progress=False)
    assert sorted(p.name for p in (tmp_path / "a/checkpoints").iterdir()) == [
        "0001.npz", "0006.npz", "0011.npz", "0012.npz"]
    assert first.status == "ok"
    # from the checkpoint at frame 6: positions and velocities exact -> frames equal bit for bit
    scene = _pinned(tmp_path, "initial_state: {from: a, frame: 6}\n", start=6)
    run(compile_file(scene), out_dir="b", progress=False)
    for f in range(6, 13):
        assert (tmp_path / "a/cloth" / f"{f:04d}.ply").read_bytes() == \
            (tmp_path / "b/cloth" / f"{f:04d}.ply").read_bytes(), f
    # from the frame files when there is no checkpoint (PLY holds velocities)
    scene = _pinned(tmp_path, "initial_state: {from: a, frame: 5}\n", start=5)
    r = run(compile_file(scene), out_dir="c", progress=False)
    assert np.array_equal(r.state.particle_q, first.state.particle_q)
    info = json.loads((tmp_path / "c/run.json").read_text())
    assert info["initial_state"]["frame"] == 5 and info["warnings"] == []


def test_initial_state_errors_name_the_line(tmp_path, monkeypatch):
    from lokigraph.api import compile_file
    from lokigraph.errors import InputError
    from lokigraph.run import run

    monkeypatch.chdir(tmp_path)
    run(compile_file(_pinned(tmp_path)), out_dir="a", progress=False, frames=(1, 3))
    for extra, text in [("initial_state: {from: nowhere, frame: 2}\n", "not a folder"),
                        ("initial_state: {from: a, frame: 9}\n", "was not written")]:
        scene = _pinned(tmp_path, extra)
        with pytest.raises(InputError) as exc:
            run(compile_file(scene), out_dir="x", progress=False)
        line = scene.read_text().splitlines().index(extra.strip()) + 1
        assert f"{scene}:{line}" in str(exc.value) and text in str(exc.value)


def test_preroll_changes_the_first_written_frame(tmp_path, monkeypatch):
    from lokigraph.api import compile_file
    from lokigraph.run import run

    monkeypatch.chdir(tmp_path)
    plain = run(compile_file(_pinned(tmp_path, start=4)), out_dir="plain", progress=False)
    pre = run(compile_file(_pinned(tmp_path, "preroll: 3\n", start=7)), out_dir="pre",
              progress=False)
    assert pre.frames_written[0] == 7 and not (tmp_path / "pre/cloth/0006.ply").exists()
    assert not np.array_equal(_q(tmp_path / "pre/cloth/0007.ply"),
                              _q(tmp_path / "plain/cloth/0004.ply"))
    # 3 frames of preroll from frame 4 end where a run started at frame 4 is at frame 7
    assert np.array_equal(_q(tmp_path / "pre/cloth/0007.ply"), _q(tmp_path / "plain/cloth/0007.ply"))
    assert np.array_equal(pre.state.particle_q, plain.state.particle_q)
