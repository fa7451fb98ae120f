"""Progress and logs of `lokigraph run`: a bar on a terminal, plain lines otherwise, --quiet, -v."""

import fcntl
import io
import os
import pty
import select
import struct
import subprocess
import sys
import termios

from conftest import EXAMPLES, run_cli

from lokigraph.progress import RunProgress, substep_line

PINNED = EXAMPLES / "pinned_particles.yaml"

# a small cloth on a sphere: collisions report contact statistics per substep
CONTACT_SCENE = """
lokigraph: 1
graph: default
frames: {start: 1, end: 3, fps: 24}
substeps: 2
elements:
  - name: cloth
    geometry:
      generator: grid
      params: {size: [1.0, 1.0], resolution: [8, 8], plane: xz, center: [0, 0.35, 0]}
    components:
      Dynamic: {mass_density: 0.15, damping: 0.2}
      Collider: {thickness: 0.002, friction: 0.3}
  - name: ball
    geometry: {generator: sphere, params: {radius: 0.3, subdivisions: 2}}
    components:
      Kinematic: {}
      Collider: {thickness: 0.002, friction: 0.5, one_sided: true}
  - name: contact
    components:
      CollisionGroup: {members: [cloth, ball], methods: [vertex_face, edge_edge, self]}
      CollisionResponse: {strength: 1.0, damping: 0.0}
"""


def test_not_a_tty_gives_plain_lines(tmp_path):
    r = run_cli("run", PINNED, "--out", tmp_path / "out")
    assert r.returncode == 0, r.stderr
    assert "\r" not in r.stderr and "\x1b" not in r.stderr
    lines = r.stderr.splitlines()
    # a short run: a line per frame, each with the frame, ms/frame and ETA
    assert len(lines) == 23, r.stderr
    assert lines[0].startswith("frame 2 (1/23") and lines[-1].startswith("frame 24 (23/23, 100%)")
    assert all("ms/frame" in ln and "ETA" in ln for ln in lines)


def test_quiet_prints_nothing_on_stderr(tmp_path):
    r = run_cli("run", PINNED, "--out", tmp_path / "out", "--quiet")
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""
    assert r.stdout.startswith("wrote frames 1..24")


def test_verbose_prints_a_line_per_substep_with_stats(tmp_path, scene_file):
    p = scene_file(CONTACT_SCENE)
    r = run_cli("run", p, "--out", tmp_path / "out", "--quiet", "-v")
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 2 * 2, r.stderr  # frames 2, 3 x 2 substeps; no progress with --quiet
    assert [ln.split(" t=")[0] for ln in lines] == [
        "frame 2 substep 1/2", "frame 2 substep 2/2", "frame 3 substep 1/2",
        "frame 3 substep 2/2"]
    for ln in lines:
        for key in ("contacts_vf=", "contacts_ee=", "max_active_contacts=", " ms"):
            assert key in ln, ln


def test_verbose_lines_come_with_progress_lines(tmp_path):
    r = run_cli("run", PINNED, "--out", tmp_path / "out", "-v")
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    assert sum(" substep " in ln for ln in lines) == 23 * 4
    assert sum("ms/frame" in ln for ln in lines) == 23


def test_tty_shows_a_bar_with_eta(tmp_path):
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 110, 0, 0))
    env = dict(os.environ, COLUMNS="100", TERM="xterm")
    proc = subprocess.Popen([sys.executable, "-m", "lokigraph.cli", "run", str(PINNED), "--out",
                             str(tmp_path / "out")], stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=slave, env=env)
    os.close(slave)
    chunks = []
    while True:
        ready, _, _ = select.select([master], [], [], 60)
        if not ready:
            break
        try:
            data = os.read(master, 4096)
        except OSError:  # the child closed the terminal (EIO on Linux)
            break
        if not data:
            break
        chunks.append(data)
    out, _ = proc.communicate(timeout=120)
    os.close(master)
    assert proc.returncode == 0
    text = b"".join(chunks).decode("utf-8", "replace")
    assert "\r" in text  # redrawn in place
    final = text.replace("\r\n", "\n").split("\r")[-1]
    assert "frame 24" in final and "100%" in final and "23/23" in final, final
    assert "ETA" in final and "ms/frame" in final, final
    assert b"wrote frames 1..24" in out


def test_plain_lines_every_few_seconds_for_long_runs():
    buf = io.StringIO()
    p = RunProgress(0, 100, buf, tty=False, every=3600.0, short=10)
    for f in range(1, 101):
        p.update(f, 0.01)
    p.close()
    lines = buf.getvalue().splitlines()
    assert [ln.split(" (")[0] for ln in lines] == ["frame 1", "frame 100"]


def test_substep_line_is_compact():
    line = substep_line(3, 2, 4, 0.125, 0.0021, {"contacts_vf": 12.0, "max_residual": 1.5e-6})
    assert line == "frame 3 substep 2/4 t=0.1250 2.1 ms contacts_vf=12 max_residual=1.5e-06"
