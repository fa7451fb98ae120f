"""lokigraph preview: headless renders of a run's frames (PNG, GIF, MP4), per-vertex colouring,
the run.json statistics plot, ``run --preview``, and one-line errors."""

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("matplotlib")
pytest.importorskip("imageio")

from PIL import Image  # noqa: E402  (matplotlib's dependency)

from conftest import write_scene  # noqa: E402
from lokigraph import preview  # noqa: E402
from lokigraph.cli import main  # noqa: E402
from lokigraph.errors import InputError  # noqa: E402

CLOTH = """\
lokigraph: 1
frames: {start: 1, end: 5, fps: 24}
substeps: 2
elements:
  - name: cloth
    geometry: {generator: grid, params: {size: [1, 1], resolution: [8, 8], plane: xz,
               center: [0, 1, 0]}}
    components:
      Dynamic: {mass_density: 0.2}
      Pins: {vertices: [0, 8]}
  - name: ball
    geometry: {generator: sphere, params: {radius: 0.15, subdivisions: 2, center: [0, 0.6, 0]}}
    components:
      Kinematic: {}
output: {dir: OUT, kinematic: true}
"""

HAIR = """\
lokigraph: 1
frames: {start: 1, end: 4, fps: 24}
substeps: 2
elements:
  - name: hair
    geometry:
      generator: strands
      params: {count: [3, 3], spacing: 0.02, length: 0.2, segments: 8, direction: [1, 0, 0],
               center: [0, 1, 0]}
    components:
      Dynamic: {mass_density: 2.0e-4, damping: 0.5}
      Rod: {radius: 4.0e-5, bend_resistance: 5.0e-8}
      Pins: {map: root}
output: {dir: OUT}
"""


def _cli(capsys, *args):
    capsys.readouterr()
    rc = main([str(a) for a in args])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _one_line_error(rc, err, code=2):
    assert rc == code, err
    assert "Traceback" not in err
    assert len(err.strip().splitlines()) == 1, err


@pytest.fixture(scope="module")
def cloth_run(tmp_path_factory):
    """An 8x8 cloth over 5 frames with a kinematic sphere, run with --preview."""
    d = tmp_path_factory.mktemp("cloth")
    scene = write_scene(d, CLOTH)
    out = d / "out"
    rc = main(["run", str(scene), "--out", str(out), "--quiet", "--preview"])
    assert rc == 0
    return out


@pytest.fixture(scope="module")
def hair_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("hair")
    scene = write_scene(d, HAIR)
    out = d / "out"
    assert main(["run", str(scene), "--out", str(out), "--quiet"]) == 0
    return out


def _img(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB")).astype(float) / 255.0


def _foreground(img) -> np.ndarray:
    return np.abs(img - 1.0).max(axis=2) > 0.02


def test_run_preview_writes_gif_and_stats(cloth_run):
    gif = cloth_run / "preview.gif"
    info = json.loads((cloth_run / "run.json").read_text())
    with Image.open(gif) as im:
        assert im.size == preview.DEFAULT_SIZE
        assert im.n_frames == len(info["frames"]["written"]) == 5
    stats = cloth_run / "run_stats.png"
    with Image.open(stats) as im:
        assert im.format == "PNG" and im.size[0] > 300 and im.size[1] > 200


def test_png_frames_show_shaded_cloth_and_grey_collider(cloth_run, tmp_path, capsys):
    dest = tmp_path / "png"
    rc, out, err = _cli(capsys, "preview", cloth_run, "--png", "--size", "320x240", "-o", dest)
    assert rc == 0, err
    files = sorted(p.name for p in dest.iterdir())
    assert files == [f"{f:04d}.png" for f in range(1, 6)]
    img = _img(dest / "0003.png")
    assert img.shape == (240, 320, 3)
    fg = _foreground(img)
    assert 0.03 < fg.mean() < 0.8        # the objects cover a plausible part of the frame
    px = img[fg]
    blue = px[(px[:, 2] - px[:, 0] > 0.15)]
    grey = px[(np.ptp(px, axis=1) < 0.03) & (px.mean(1) < 0.9) & (px.mean(1) > 0.2)]
    assert len(blue) > 200                # cloth (the first dynamic element's colour)
    assert len(grey) > 100                # the kinematic sphere
    assert blue.mean(1).std() > 0.01      # shading: the cloth's brightness varies
    assert grey.mean(1).std() > 0.01


def test_strain_and_speed_colouring_differ_from_plain(cloth_run, tmp_path, capsys):
    imgs = {}
    for color in ("none", "strain", "speed"):
        dest = tmp_path / color
        rc, _, err = _cli(capsys, "preview", cloth_run, "--png", "--frames", "4:4", "--color",
                          color, "-o", dest, "--quiet")
        assert rc == 0, err
        assert [p.name for p in dest.iterdir()] == ["0004.png"]
        imgs[color] = _img(dest / "0004.png")
    assert np.abs(imgs["strain"] - imgs["none"]).mean() > 0.005
    assert np.abs(imgs["speed"] - imgs["none"]).mean() > 0.005
    assert np.abs(imgs["speed"] - imgs["strain"]).mean() > 0.005


def test_vertex_strain_values():
    rest = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    pts = rest * [1.1, 1.0, 1.0]
    edges = np.array([[0, 1], [0, 2]])
    s = preview.vertex_strain(pts, rest, edges)
    assert np.allclose(s, [0.05, 0.1, 0.0])


def test_hair_curves(hair_run, tmp_path, capsys):
    dest = tmp_path / "hair.gif"
    rc, out, err = _cli(capsys, "preview", hair_run, "--gif", "-o", dest, "--size", "200x160")
    assert rc == 0, err
    with Image.open(dest) as im:
        assert im.n_frames == 4 and im.size == (200, 160)
        im.seek(3)
        img = np.asarray(im.convert("RGB")).astype(float) / 255
    fg = _foreground(img)
    assert 0.005 < fg.mean() < 0.5
    px = img[fg]
    assert (px[:, 0] - px[:, 2] > 0.1).mean() > 0.5   # brown strands


def test_mp4_or_gif_fallback(cloth_run, tmp_path, monkeypatch):
    if preview.has_ffmpeg():
        path = preview.render(cloth_run, "mp4", size=(160, 120), dest=tmp_path / "a.mp4")
        assert path.suffix == ".mp4" and path.stat().st_size > 1000
    msgs = []
    monkeypatch.setattr(preview, "has_ffmpeg", lambda: False)
    path = preview.render(cloth_run, "mp4", size=(160, 120), dest=tmp_path / "b.mp4",
                          log=msgs.append)
    assert path.suffix == ".gif" and path.is_file()
    assert "imageio-ffmpeg" in msgs[0]


def test_stats_alone(cloth_run, tmp_path, capsys):
    d = tmp_path / "copy"
    shutil.copytree(cloth_run, d)
    (d / "run_stats.png").unlink()
    (d / "preview.gif").unlink()
    rc, out, err = _cli(capsys, "preview", d, "--stats")
    assert rc == 0, err
    assert (d / "run_stats.png").is_file() and not (d / "preview.gif").exists()


def test_errors_are_one_line(cloth_run, tmp_path, capsys):
    rc, _, err = _cli(capsys, "preview", tmp_path)
    _one_line_error(rc, err)
    assert "no run.json" in err
    for bad in (["--frames", "7:9"], ["--frames", "x"], ["--frames", "3:2"],
                ["--camera", "1"], ["--size", "10x10"], ["--fps", "0"]):
        rc, _, err = _cli(capsys, "preview", cloth_run, "--png", "-o", tmp_path / "p", *bad)
        _one_line_error(rc, err)
    d = tmp_path / "noframes"
    shutil.copytree(cloth_run, d)
    shutil.rmtree(d / "cloth")
    rc, _, err = _cli(capsys, "preview", d)
    _one_line_error(rc, err)
    assert "not found" in err
    info = json.loads((d / "run.json").read_text())
    info["frames"]["written"] = []
    (d / "run.json").write_text(json.dumps(info))
    rc, _, err = _cli(capsys, "preview", d)
    _one_line_error(rc, err)
    assert "no written frames" in err


def test_missing_extra_names_it(cloth_run, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio", None)
    monkeypatch.setitem(sys.modules, "imageio.v2", None)
    with pytest.raises(InputError, match=r"lokigraph\[preview\]"):
        preview.render(cloth_run, "gif")


def test_run_preview_without_extra_fails_before_simulating(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "imageio", None)
    monkeypatch.setitem(sys.modules, "imageio.v2", None)
    scene = write_scene(tmp_path, CLOTH)
    rc, _, err = _cli(capsys, "run", scene, "--out", tmp_path / "out", "--quiet", "--preview")
    _one_line_error(rc, err)
    assert "lokigraph[preview]" in err
    assert not (tmp_path / "out").exists()


def test_preview_reads_a_usd_run(tmp_path):
    pytest.importorskip("pxr")
    from conftest import EXAMPLES

    scene = EXAMPLES / "pinned_particles.yaml"
    runs = {}
    for fmt in ("obj", "usd"):
        out = tmp_path / fmt
        assert main(["run", str(scene), "--out", str(out), "--quiet", "--frames", "1:6",
                     "--format", fmt]) == 0
        runs[fmt] = preview.load_run(out, need_rest=True)
    a, b = runs["obj"], runs["usd"]
    assert a.frames == b.frames == [1, 2, 3, 4, 5, 6]
    for pa, pb in zip(a.parts, b.parts):
        assert pa.name == pb.name and np.array_equal(pa.triangles, pb.triangles)
        for qa, qb in zip(pa.points, pb.points):
            assert np.allclose(qa, qb, atol=1e-6)
        assert pb.velocities[-1] is not None  # the stage's velocities
    assert preview.render(tmp_path / "usd", "png", frames=(6, 6))
    assert (tmp_path / "usd" / "preview" / "0006.png").is_file()


def test_fluid_slices(tmp_path):
    """`lokigraph preview OUT --fluid-slices z`: one PNG per written .vti, the speed on the
    middle plane; the image's brightest pixels lie where the field is fastest."""
    from lokigraph.behaviors.fluid.vti import write_vti
    from lokigraph.preview import fluid_slice_image

    n = (6, 5, 4)
    vel = np.zeros(n + (3,))
    vel[4, 3, :, 0] = 2.0  # a fast jet through cell (4, 3) of every z slice
    for f in (1, 2):
        write_vti(tmp_path / "air" / f"{f:04d}.vti", np.zeros(3), np.full(3, 0.1), vel,
                  np.zeros(n))
    (tmp_path / "cloth").mkdir()  # a mesh folder without fields is skipped
    img = fluid_slice_image(vel, "z", scale=1)
    assert img.shape == (5, 6, 3)  # rows: y from top to bottom, columns: x
    bright = img.sum(-1)
    assert np.unravel_index(bright.argmax(), bright.shape) == (5 - 1 - 3, 4)
    r = subprocess.run([sys.executable, "-m", "lokigraph", "preview", str(tmp_path),
                        "--fluid-slices", "z", "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "air" / "slice_z").iterdir()) == ["0001.png",
                                                                                "0002.png"]
    empty = tmp_path / "nothing"
    empty.mkdir()
    r = subprocess.run([sys.executable, "-m", "lokigraph", "preview", str(empty),
                        "--fluid-slices", "z"], capture_output=True, text=True)
    assert r.returncode == 2 and "no fluid fields" in r.stderr and "Traceback" not in r.stderr
