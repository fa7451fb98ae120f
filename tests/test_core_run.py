"""End-to-end runs of the core path: symplectic Euler, pins, output files, run.json."""

import json

import numpy as np
import pytest

from conftest import EXAMPLES, run_cli
from lokigraph.api import compile_file, run_file
from lokigraph.run import Simulation


def test_example_pinned_cloth_free_fall(tmp_path):
    """Pinned corners stay exactly put; a free corner falls as symplectic Euler predicts."""
    scene = EXAMPLES / "pinned_particles.yaml"
    c = compile_file(scene)
    sim = Simulation(c)
    m = c.model
    q0 = m.particle_q0.copy()
    h = m.dt
    g = 9.81
    n = 0
    for _ in range(6):
        sim.step_frame()
        n += m.substeps
    q = sim.state.particle_q
    # pins 0 and 16 are bit-identical to the start
    assert np.array_equal(q[[0, 16]], q0[[0, 16]])
    # the free far corner (no material in this scene): y_n = y0 - g h^2 n (n+1) / 2
    far = 16 * 17 + 16
    expected = q0[far, 1] - g * h * h * n * (n + 1) / 2
    assert q[far, 1] == pytest.approx(expected, rel=1e-12, abs=1e-12)
    assert np.allclose(q[far, [0, 2]], q0[far, [0, 2]])
    # and it is *not* the explicit-Euler or exact answer (the test can tell them apart)
    assert abs(q[far, 1] - (q0[far, 1] - g * h * h * n * (n - 1) / 2)) > 1e-4


def test_run_writes_frames_and_runjson(tmp_path):
    out = tmp_path / "out"
    r = run_cli("run", EXAMPLES / "pinned_particles.yaml", "--out", out, "--frames", "3:6",
                "--format", "ply", "--quiet")
    assert r.returncode == 0, r.stderr
    files = sorted(p.name for p in (out / "cloth").iterdir())
    assert files == ["0003.ply", "0004.ply", "0005.ply", "0006.ply"]
    info = json.loads((out / "run.json").read_text())
    assert info["status"] == "ok"
    assert info["frames"]["written"] == [3, 4, 5, 6]
    assert len(info["per_frame"]) == 5  # frames 2..6 simulated
    assert all(f["seconds"] >= 0 for f in info["per_frame"])
    assert "numpy" in info["versions"] and info["scene"]["lokigraph"] == 1
    import meshio

    mesh = meshio.read(out / "cloth" / "0006.ply")
    assert mesh.points.shape == (289, 3)
    assert not list(out.rglob(".*tmp*"))  # no temporary files left behind
    # the output settings are recorded; velocities reach the writer
    assert info["output"]["format"] == "ply" and info["output"]["elements"] == ["cloth"]
    assert info["output"]["overwrite"] is False and info["output"]["kinematic"] is False
    assert info["output"]["velocities"] and mesh.point_data  # PLY holds velocities
    assert info["frames"]["requested"] == [3, 6] and info["error"] is None
    assert r.stdout.startswith("wrote frames 3..6 of cloth in ") and "status ok" in r.stdout


@pytest.mark.parametrize("fmt", ["obj", "vtu"])
def test_formats_roundtrip(tmp_path, fmt):
    res = run_file(EXAMPLES / "pinned_particles.yaml", out_dir=tmp_path, fmt=fmt, frames=(1, 2),
                   progress=False)
    from lokigraph.meshfile import read_mesh

    g = read_mesh(tmp_path / "cloth" / f"0002.{fmt}")
    assert np.allclose(g.points, res.state.particle_q, atol=1e-6)
    assert len(g.triangles) == 512


def _spring_scene(tmp_path, h, x0=1.0, frames=40):
    p = tmp_path / f"spring_{h:.4f}.yaml"
    p.write_text(f"""
lokigraph: 1
frames: {{start: 0, end: {frames}, fps: {float(1.0 / h)!r}}}
substeps: 1
gravity: [0, 0, 0]
elements:
  - name: mass
    geometry: {{generator: points, params: {{positions: [[{x0}, 0, 0]]}}}}
    components:
      Dynamic: {{point_mass: 1.0}}
      RestSpring: {{stiffness: 1.0, anchor: [0, 0, 0]}}
""")
    return p


def _phase(tmp_path, h, steps):
    c = compile_file(_spring_scene(tmp_path, h, frames=steps))
    sim = Simulation(c)
    xs = [(sim.state.particle_q[0, 0], sim.state.particle_qd[0, 0])]
    for _ in range(steps):
        sim.step_frame()
        xs.append((sim.state.particle_q[0, 0], sim.state.particle_qd[0, 0]))
    return np.array(xs)


def test_spring_phase_portraits(tmp_path):
    """Nucleus section 4.2: symplectic Euler on x'' = -x: hexagon at h=1, square at h=sqrt 2,
    unbounded growth for h > 2."""
    ph = _phase(tmp_path, 1.0, 12)
    assert np.allclose(ph[6], ph[0], atol=1e-12) and np.allclose(ph[12], ph[0], atol=1e-12)
    assert not any(np.allclose(ph[k], ph[0], atol=1e-6) for k in range(1, 6))  # period exactly 6
    ph = _phase(tmp_path, np.sqrt(2.0), 8)
    assert np.allclose(ph[4], ph[0], atol=1e-12) and np.allclose(ph[8], ph[0], atol=1e-12)
    assert not any(np.allclose(ph[k], ph[0], atol=1e-6) for k in range(1, 4))
    # bounded (closed orbit) for h = 0.5: the discrete energy x^2 + v^2 - h x v is conserved
    ph = _phase(tmp_path, 0.5, 200)
    e = ph[:, 0] ** 2 + ph[:, 1] ** 2 - 0.5 * ph[:, 0] * ph[:, 1]
    # symplectic Euler's modified energy for v_{n+1}=v_n - h x_n, x_{n+1}=x_n+h v_{n+1}
    assert np.ptp(ph[:, 0]) < 2.5 and np.ptp(e) < 0.6
    ph = _phase(tmp_path, 2.05, 60)
    r = np.hypot(ph[:, 0], ph[:, 1])
    assert r[-1] > 10 * r[0]  # unstable beyond h = 2


def test_determinism():
    c1 = compile_file(EXAMPLES / "pinned_particles.yaml")
    c2 = compile_file(EXAMPLES / "pinned_particles.yaml")
    s1, s2 = Simulation(c1), Simulation(c2)
    for _ in range(3):
        s1.step_frame()
        s2.step_frame()
    assert np.array_equal(s1.state.particle_q, s2.state.particle_q)
    assert np.array_equal(s1.state.particle_qd, s2.state.particle_qd)


def test_nonfinite_guard_keeps_frames(scene_file, tmp_path):
    # explicit spring with h*sqrt(k/m) = 3 > 2: blows up; the guard stops with exit code 3
    p = scene_file("""
    lokigraph: 1
    frames: {start: 1, end: 400, fps: 1}
    substeps: 1
    gravity: [0, 0, 0]
    elements:
      - name: bomb
        geometry: {generator: points, params: {positions: [[1, 0, 0], [0, 1, 0]]}}
        components:
          Dynamic: {point_mass: 1.0}
          RestSpring: {stiffness: 9.0, anchor: [0, 0, 0]}
    """)
    out = tmp_path / "o"
    r = run_cli("run", p, "--out", out, "--format", "ply", "--quiet")
    assert r.returncode == 3, r.stderr
    assert "Traceback" not in r.stderr
    assert 'element "bomb"' in r.stderr and "non-finite" in r.stderr and "vertex 0" in r.stderr
    info = json.loads((out / "run.json").read_text())
    assert info["status"] == "failed" and "non-finite" in info["error"]
    written = sorted((out / "bomb").iterdir())
    assert len(written) == len(info["frames"]["written"]) > 10
    import meshio

    for f in written:  # every kept frame is complete and finite
        assert np.isfinite(meshio.read(f).points).all()


def test_kinematic_keys_follow_animation(scene_file):
    p = scene_file("""
    lokigraph: 1
    frames: {start: 1, end: 11, fps: 10}
    substeps: 2
    elements:
      - name: ball
        geometry: {generator: sphere, params: {radius: 0.1, subdivisions: 1}}
        components:
          Kinematic:
            keys:
              - {frame: 1, translate: [0, 0, 0]}
              - {frame: 11, translate: [1, 0, 0], rotate: [0, 90, 0]}
    """)
    c = compile_file(p)
    sim = Simulation(c)
    q0 = c.model.particle_q0.copy()
    for _ in range(5):
        sim.step_frame()
    # halfway: translated by 0.5 m, rotated by 45 degrees about y
    from lokigraph.geometry import rotation_matrix_xyz

    expect = q0 @ rotation_matrix_xyz([0, 45, 0]).T + [0.5, 0, 0]
    assert np.allclose(sim.state.particle_q, expect, atol=1e-12)
    v_expected = np.zeros(3)
    assert np.all(np.isfinite(sim.state.particle_qd))
    assert not np.allclose(sim.state.particle_qd, v_expected)


def test_kinematic_sequence(tmp_path):
    from lokigraph.generators import box
    from lokigraph.meshfile import write_mesh

    seq = tmp_path / "anim"
    seq.mkdir()
    b = box()
    for f in range(1, 4):
        write_mesh(seq / f"body.{f:04d}.obj", b.points + [0, 0.1 * f, 0], b, "obj")
    p = tmp_path / "s.yaml"
    p.write_text("""
lokigraph: 1
frames: {start: 1, end: 3, fps: 24}
substeps: 2
elements:
  - name: body
    geometry: {sequence: "anim/body.{frame:04d}.obj"}
    components: {Kinematic: {}}
""")
    c = compile_file(p)
    sim = Simulation(c)
    assert np.allclose(sim.state.particle_q, b.points + [0, 0.1, 0])
    sim.step_substep()  # half a frame
    assert np.allclose(sim.state.particle_q, b.points + [0, 0.15, 0])
    sim.step_substep()
    sim.step_frame()
    assert np.allclose(sim.state.particle_q, b.points + [0, 0.3, 0])
