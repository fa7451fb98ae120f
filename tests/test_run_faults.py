"""Run loop faults: output locations (exit 2 before simulating), write failures during the run
(exit 3), Ctrl-C and SIGTERM (130/143), run.json on every end, temp files, a second run into a
folder, --frames outside the scene, and what is written (kinematic colliders, velocities)."""

import errno
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, run_cli
from lokigraph import run as run_mod
from lokigraph.api import compile_file, run_file
from lokigraph.cli import main
from lokigraph.errors import InputError, OutputError
from lokigraph.meshfile import read_mesh

SCENE = """\
lokigraph: 1
frames: {start: 1, end: 6, fps: 24}
substeps: 2
elements:
  - name: cloth
    geometry: {generator: grid, params: {size: [1, 1], resolution: [6, 6], plane: xz,
               center: [0, 1, 0]}}
    components:
      Dynamic: {mass_density: 0.2}
      Pins: {vertices: [0, 6]}
output: {dir: OUT}
"""


class _Result:
    def __init__(self, returncode, out, err):
        self.returncode, self.stdout, self.stderr = returncode, out, err


@pytest.fixture
def cli(capsys):
    """The CLI in-process (faster than run_cli; main() catches and formats the same way)."""
    def call(*args):
        capsys.readouterr()
        rc = main([str(a) for a in args])
        cap = capsys.readouterr()
        return _Result(rc, cap.out, cap.err)
    return call


def _one_line_error(r, code):
    assert r.returncode == code, (r.returncode, r.stdout, r.stderr)
    assert "Traceback" not in r.stderr
    err = r.stderr.strip()
    assert err and "\n" not in err, err
    return err


def _frames(folder: Path, ext="obj"):
    return sorted(int(p.stem) for p in folder.glob(f"*.{ext}"))


def _assert_complete(out: Path, names, nverts, ext="obj"):
    """Every frame present parses with all its vertices; frames are contiguous and the same for
    every element, and match run.json; no temporaries are left."""
    info = json.loads((out / "run.json").read_text())
    written = info["frames"]["written"]
    for name in names:
        got = _frames(out / name, ext)
        assert got == written, (name, got, written)
        for f in got:
            g = read_mesh(out / name / f"{f:04d}.{ext}")
            assert g.points.shape == (nverts, 3) and np.isfinite(g.points).all()
    if written:
        assert written == list(range(written[0], written[0] + len(written)))
    assert not [p for p in out.rglob("*") if ".tmp" in p.name]
    return info


# -- output locations known bad before running: exit 2, one line, nothing simulated ------------

def test_out_is_a_file(scene_file, tmp_path):
    p = scene_file(SCENE)
    f = tmp_path / "afile"
    f.write_text("keep me")
    err = _one_line_error(run_cli("run", p, "--out", f, "--quiet"), 2)
    assert "afile" in err and "is a file" in err
    assert f.read_text() == "keep me"


def test_out_cannot_be_created(scene_file, tmp_path, cli):
    p = scene_file(SCENE)
    (tmp_path / "afile").write_text("")
    err = _one_line_error(cli("run", p, "--out", tmp_path / "afile" / "sub", "--quiet"), 2)
    assert "cannot create output folder" in err and "afile" in err


def test_element_folder_is_a_file(scene_file, tmp_path, cli):
    p = scene_file(SCENE)
    out = tmp_path / "o"
    out.mkdir()
    (out / "cloth").write_text("")
    err = _one_line_error(cli("run", p, "--out", out, "--quiet"), 2)
    assert "element folder" in err and "cloth" in err and "is a file" in err
    assert not (out / "run.json").exists()


def test_read_only_folder(scene_file, tmp_path, cli):
    p = scene_file(SCENE)
    out = tmp_path / "ro"
    out.mkdir()
    out.chmod(0o555)
    try:
        try:
            (out / "probe").write_text("")
        except PermissionError:
            pass
        else:
            pytest.skip("running as root (or similar): chmod does not stop writes here; "
                        "test_unwritable_folder_simulated covers the write probe")
        err = _one_line_error(cli("run", p, "--out", out, "--quiet"), 2)
        assert "ro" in err and "Permission denied" in err
    finally:
        out.chmod(0o755)


def test_unwritable_folder_simulated(scene_file, tmp_path, cli, monkeypatch):
    """The write probe, with the folder's writes refused (works as root too)."""
    import builtins

    def refuse(path, *a, **kw):
        if ".write-probe.tmp-" in str(path):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))
        return builtins.open(path, *a, **kw)

    monkeypatch.setattr(run_mod, "open", refuse, raising=False)
    out = tmp_path / "o"
    err = _one_line_error(cli("run", scene_file(SCENE), "--out", out, "--quiet"), 2)
    assert f"cannot write in output folder {out}: Permission denied" in err
    assert not list((out / "cloth").iterdir()) and not (out / "run.json").exists()


def test_frames_outside_scene_range(scene_file, tmp_path, cli):
    p = scene_file(SCENE)
    out = tmp_path / "o"
    for fr in ("1:30", "0:3", "4:2"):
        err = _one_line_error(cli("run", p, "--frames", fr, "--out", out, "--quiet"), 2)
        assert "frame range 1:6" in err and f"--frames {fr}" in err
    assert not out.exists()
    with pytest.raises(InputError, match="outside the scene's frame range"):
        run_file(p, frames=(2, 7), out_dir=out)


# -- write failures during the run: exit 3, run.json "failed" --------------------------------

@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EACCES])
def test_write_failure_during_run(scene_file, tmp_path, monkeypatch, capsys, code):
    p = scene_file(SCENE)
    out = tmp_path / "o"
    real = run_mod.write_mesh
    calls = []

    def failing(path, *a, **kw):
        calls.append(path)
        if len(calls) == 4:
            raise OSError(code, os.strerror(code), str(path))
        return real(path, *a, **kw)

    monkeypatch.setattr(run_mod, "write_mesh", failing)
    rc = main(["run", str(p), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 3 and "\n" not in err and "Traceback" not in err, err
    assert os.strerror(code) in err and "0004.obj" in err
    assert "frames 1..3 of cloth" in err and "run.json status failed" in err
    info = _assert_complete(out, ["cloth"], 49)
    assert info["status"] == "failed" and os.strerror(code) in info["error"]
    assert info["frames"]["written"] == [1, 2, 3]


def test_runjson_write_failure(scene_file, tmp_path, monkeypatch, capsys):
    p = scene_file(SCENE)

    def no_space(*a, **kw):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(run_mod, "_write_run_json", no_space)
    rc = main(["run", str(p), "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert rc == 3 and "\n" not in err, err
    assert "run.json" in err and "No space left on device" in err
    assert _frames(tmp_path / "o" / "cloth") == [1, 2, 3, 4, 5, 6]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_FSIZE semantics")
def test_real_write_failure_file_size_limit(scene_file, tmp_path):
    """A real OS write failure (EFBIG from RLIMIT_FSIZE, as a full disk would give ENOSPC)."""
    p = scene_file(SCENE.replace("resolution: [6, 6]", "resolution: [40, 40]")
                   .replace("Pins: {vertices: [0, 6]}", "Pins: {vertices: [0, 40]}"))
    out = tmp_path / "o"
    # warm the JIT in-process first (numba may write its cache), then limit file sizes
    code = textwrap.dedent(f"""
        import resource, sys
        from lokigraph.cli import main
        assert main(["run", {str(p)!r}, "--out", {str(tmp_path / 'warm')!r}, "--frames", "1:2",
                     "--quiet"]) == 0
        resource.setrlimit(resource.RLIMIT_FSIZE, (30000, resource.RLIM_INFINITY))
        sys.exit(main(["run", {str(p)!r}, "--out", {str(out)!r}, "--quiet"]))
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    err = _one_line_error(r, 3)
    assert "File too large" in err and "0001.obj" in err
    info = json.loads((out / "run.json").read_text())
    assert info["status"] == "failed" and info["frames"]["written"] == []
    assert not list((out / "cloth").iterdir())  # the partial temp was removed


# -- Ctrl-C and SIGTERM: a real process, stopped after its first frames -------------------------

LONG = """\
lokigraph: 1
frames: {start: 1, end: 100000, fps: 24}
substeps: 4
elements:
  - name: a
    geometry: {generator: grid, params: {size: [1, 1], resolution: [30, 30], plane: xz,
               center: [0, 1, 0]}}
    components: {Dynamic: {mass_density: 0.2}, Pins: {vertices: [0, 30]}}
  - name: b
    geometry: {generator: grid, params: {size: [1, 1], resolution: [30, 30], plane: xz,
               center: [0, 3, 0]}}
    components: {Dynamic: {mass_density: 0.2}, Pins: {vertices: [0, 30]}}
output: {dir: OUT}
"""


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize("sig,code,fmt", [(signal.SIGINT, 130, "obj"),
                                          (signal.SIGTERM, 143, "ply")])
def test_signal_writes_runjson_and_complete_frames(scene_file, tmp_path, sig, code, fmt):
    p = scene_file(LONG)
    out = tmp_path / "o"

    def default_sigint():  # a child of a background job may start with SIGINT ignored
        signal.signal(signal.SIGINT, signal.SIG_DFL)

    proc = subprocess.Popen([sys.executable, "-m", "lokigraph.cli", "run", str(p), "--out",
                             str(out), "--format", fmt, "--quiet"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=default_sigint)
    try:
        deadline = time.monotonic() + 120
        while not (out / "b" / f"0003.{fmt}").exists():
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no frame written in 120 s"
            time.sleep(0.01)
        proc.send_signal(sig)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == code, stderr
    assert "Traceback" not in stderr and stderr.strip().count("\n") == 0, stderr
    assert ("interrupted" if sig == signal.SIGINT else "terminated (SIGTERM)") in stderr
    assert "run.json status interrupted" in stderr
    info = _assert_complete(out, ["a", "b"], 31 * 31, fmt)
    assert info["status"] == "interrupted"
    assert info["interrupted_by"] == signal.Signals(sig).name
    assert len(info["frames"]["written"]) >= 3 and info["frames"]["written"][0] == 1


def test_signal_deferred_during_frame_write():
    """A signal inside a frame write waits for the write to finish, then interrupts."""
    sigs = run_mod._Signals()
    done = []
    with sigs, pytest.raises(run_mod.RunInterrupted) as info:
        with sigs.deferred():
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.05)
            done.append(1)
    assert done == [1] and info.value.signum == signal.SIGTERM
    assert signal.getsignal(signal.SIGTERM) is not sigs._handle  # restored


def test_cli_restores_sigterm_handler(scene_file, tmp_path, capsys):
    before = signal.getsignal(signal.SIGTERM)
    assert main(["validate", str(scene_file(SCENE))]) == 0
    assert signal.getsignal(signal.SIGTERM) is before


# -- temporaries cannot be mistaken for frames ---------------------------------------------

def test_temp_names_and_stale_cleanup(scene_file, tmp_path):
    tmp = run_mod.temp_path(tmp_path / "0007.obj")
    assert tmp.name.startswith(".") and not tmp.name.endswith(".obj")
    assert run_mod.TEMP_RE.match(tmp.name)

    def boom(path):  # a writer dying half-way leaves nothing behind
        Path(path).write_text("v 0 0")
        raise OSError(errno.ENOSPC, "full")

    with pytest.raises(OSError):
        run_mod.atomic_write(tmp_path / "0007.obj", boom)
    assert list(tmp_path.iterdir()) == []
    # stale temps of a killed run (dead pid; also the older .tmpPID.obj naming) are removed
    out = tmp_path / "o"
    (out / "cloth").mkdir(parents=True)
    dead = 2 ** 22 + 12345  # above any Linux pid_max
    stale = [out / "cloth" / f".0003.obj.tmp-{dead}", out / "cloth" / f".0004.obj.tmp{dead}.obj",
             out / f".run.json.tmp-{dead}"]
    for s in stale:
        s.write_text("partial")
    keep = out / "cloth" / "notes.txt"
    keep.write_text("mine")
    p = scene_file(SCENE)
    r = run_cli("run", p, "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr
    assert not any(s.exists() for s in stale) and keep.exists()


# -- a second run into the same folder ---------------------------------------------------

def test_second_run_refuses_then_overwrites(scene_file, tmp_path, cli):
    p = scene_file(SCENE)
    out = tmp_path / "o"
    assert cli("run", p, "--out", out, "--quiet").returncode == 0
    # another scene's element folder from an older run
    (out / "shirt").mkdir()
    (out / "shirt" / "0001.obj").write_text("v 0 0 0\n")
    before = {f: f.stat().st_mtime_ns for f in out.rglob("*") if f.is_file()}
    err = _one_line_error(cli("run", p, "--out", out, "--frames", "1:3", "--quiet"), 2)
    assert str(out) in err and "another run" in err and "--overwrite" in err
    assert {f: f.stat().st_mtime_ns for f in out.rglob("*") if f.is_file()} == before
    # --overwrite: the folder then holds exactly the new run
    r = cli("run", p, "--out", out, "--frames", "2:3", "--quiet", "--overwrite")
    assert r.returncode == 0, r.stderr
    assert _frames(out / "cloth") == [2, 3] and not (out / "shirt").exists()
    info = json.loads((out / "run.json").read_text())
    assert info["frames"]["written"] == [2, 3] and info["output"]["overwrite"] is True
    assert info["output"]["replaced"] == {"run_json": True, "frame_files": 7}
    # the scene's output.overwrite does the same
    p2 = scene_file(SCENE.replace("output: {dir: OUT}", "output: {dir: OUT, overwrite: true}"),
                    "s2.yaml")
    assert cli("run", p2, "--out", out, "--quiet").returncode == 0
    assert _frames(out / "cloth") == [1, 2, 3, 4, 5, 6]


def test_run_into_empty_or_unrelated_folder(scene_file, tmp_path, cli):
    p = scene_file(SCENE)
    out = tmp_path / "o"
    out.mkdir()
    (out / "notes").mkdir()
    (out / "notes" / "todo.txt").write_text("x")
    (out / "readme.txt").write_text("x")
    assert cli("run", p, "--out", out, "--quiet").returncode == 0
    assert (out / "notes" / "todo.txt").exists() and (out / "readme.txt").exists()


def test_overwrite_never_clears_input_meshes(tmp_path):
    from lokigraph.generators import box
    from lokigraph.meshfile import write_mesh

    anim = tmp_path / "o" / "body"
    anim.mkdir(parents=True)
    b = box()
    for f in range(1, 4):
        write_mesh(anim / f"{f:04d}.obj", b.points + [0, 0.1 * f, 0], b, "obj")
    p = tmp_path / "s.yaml"
    p.write_text("""
lokigraph: 1
frames: {start: 1, end: 3, fps: 24}
elements:
  - name: body
    geometry: {sequence: "o/body/{frame:04d}.obj"}
    components: {Kinematic: {}}
output: {dir: o, kinematic: true, overwrite: true}
""")
    with pytest.raises(OutputError, match="input meshes"):
        run_file(p, out_dir=tmp_path / "o")
    assert _frames(anim) == [1, 2, 3]


# -- what is written -------------------------------------------------------------------------

KIN = """\
lokigraph: 1
frames: {start: 1, end: 5, fps: 4}
substeps: 2
elements:
  - name: cloth
    geometry: {generator: grid, params: {size: [1, 1], resolution: [4, 4], plane: xz,
               center: [0, 2, 0]}}
    components: {Dynamic: {mass_density: 0.2}}
  - name: ball
    geometry: {generator: sphere, params: {radius: 0.2, subdivisions: 1}}
    components:
      Kinematic:
        keys: [{frame: 1, translate: [0, 0, 0]}, {frame: 5, translate: [1, 0, 0]}]
  - name: ground
    components: {ShapeCollider: {shape: plane, normal: [0, 1, 0]}}
output: OUTPUT
"""


def test_kinematic_colliders_written_when_asked(scene_file, tmp_path):
    p = scene_file(KIN.replace("OUTPUT", "{dir: OUT}"))
    run_file(p, out_dir=tmp_path / "a", progress=False)
    assert sorted(d.name for d in (tmp_path / "a").iterdir()
                  if d.is_dir() and d.name != "checkpoints") == ["cloth"]

    p = scene_file(KIN.replace("OUTPUT", "{dir: OUT, kinematic: true}"), "k.yaml")
    res = run_file(p, out_dir=tmp_path / "b", progress=False)
    assert res.elements == ["cloth", "ball"]
    q0 = compile_file(p).scene.element("ball").geometry.points
    for f in range(1, 6):  # the ball's animated positions, frame by frame
        g = read_mesh(tmp_path / "b" / "ball" / f"{f:04d}.obj")
        assert np.allclose(g.points, q0 + [(f - 1) / 4, 0, 0], atol=1e-6)
    info = json.loads((tmp_path / "b" / "run.json").read_text())
    assert info["output"]["elements"] == ["cloth", "ball"] and info["output"]["kinematic"]
    assert info["output"]["format"] == "obj" and info["status"] == "ok"

    p = scene_file(KIN.replace("OUTPUT", "{dir: OUT, elements: [ball]}"), "e.yaml")
    res = run_file(p, out_dir=tmp_path / "c", progress=False)
    assert res.elements == ["ball"] and not (tmp_path / "c" / "cloth").exists()


def test_output_elements_checked(scene_file, tmp_path, cli):
    p = scene_file(KIN.replace("OUTPUT", "{dir: OUT, elements: [bal, ground]}"))
    r = cli("validate", p)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "scene.yaml:16:31: output.elements" in r.stderr
    assert "unknown element 'bal'; did you mean 'ball'?" in r.stderr
    assert 'element "ground", output.elements: element has no geometry' in r.stderr
    r = cli("run", p, "--out", tmp_path / "o", "--quiet")
    assert r.returncode == 2 and not (tmp_path / "o").exists()


def test_writer_gets_velocities_and_unchanged_geometry(scene_file, tmp_path, monkeypatch):
    calls = []

    def writer(path, points, geo, fmt, *, velocities=None):
        calls.append((Path(path), points.copy(), geo, None if velocities is None
                      else velocities.copy()))
        Path(path).write_text("v 0 0 0\n")

    monkeypatch.setattr(run_mod, "write_mesh", writer)
    p = scene_file(KIN.replace("OUTPUT", "{dir: OUT, kinematic: true}"))
    c = compile_file(p)
    res = run_mod.run(c, out_dir=tmp_path / "o", progress=False)
    last = {c_[0].parent.name: c_ for c_ in calls}
    for name in ("cloth", "ball"):
        el = c.scene.element(name)
        path, pts, geo, vel = last[name]
        assert path.name.startswith(".0005.obj.tmp") and geo is el.geometry
        assert np.array_equal(pts, res.state.particle_q[el.vertex_slice])
        assert np.array_equal(vel, res.state.particle_qd[el.vertex_slice])
    assert np.allclose(last["ball"][3], [1.0, 0, 0])  # 1 m/s along x
    assert json.loads((tmp_path / "o" / "run.json").read_text())["output"]["velocities"]


def test_cli_summary_line(scene_file, tmp_path, cli):
    r = cli("run", scene_file(SCENE), "--out", tmp_path / "o", "--quiet")
    assert r.returncode == 0 and r.stderr == ""
    lines = r.stdout.strip().splitlines()
    assert len(lines) == 1 and "frames 1..6 of cloth" in lines[0] and "status ok" in lines[0]


def test_bench_and_stress_out_is_a_file(tmp_path):
    """bench and stress write result files too: an unusable --out is one line, exit 2."""
    blocker = tmp_path / "results"
    blocker.write_text("not a folder")
    scene = ROOT / "graphs" / "bench" / "catenary.yaml"
    for args in (("bench", scene, "--sweep", "substeps=1", "--frames", "2", "--out", blocker),
                 ("stress", "--quick", "--only", "sliver", "--out", blocker / "sub")):
        r = run_cli(*args)
        assert r.returncode in (2, 3), (args[0], r.returncode, r.stderr[-2000:])
        assert "Traceback" not in r.stderr and "cannot write results" in r.stderr, r.stderr
