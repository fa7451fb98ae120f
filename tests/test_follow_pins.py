"""Pins that follow an animated element (Pins.follow), and mesh sequences with hold modes."""

import numpy as np
import pytest

from conftest import EXAMPLES, write_scene
from lokigraph.api import compile_file
from lokigraph.errors import InputError
from lokigraph.geometry import rotation_matrix_xyz
from lokigraph.run import Simulation

# a skirt (open tube along y) whose waist ring (the tube's 'end' group) is pinned to a capsule
# body that translates and turns about two axes; no collisions, so the motion of the waist is
# given by the pins alone
SKIRT = """
lokigraph: 1
frames: {start: 1, end: 12, fps: 24}
substeps: 4
elements:
  - name: skirt
    geometry:
      generator: tube
      params: {radius: 0.105, length: 0.3, segments: [16, 6], axis: y, center: [0, 0.95, 0]}
    components:
      Dynamic: {mass_density: 0.2, damping: 0.5}
      DiscreteShell: {bend_resistance: 1.0e-7}
      Pins: {select: end, follow: body}
  - name: body
    geometry:
      generator: tube
      params: {radius: 0.1, length: 0.4, segments: [20, 4], axis: y, center: [0, 1, 0],
               capped: true}
    components:
      Kinematic:
        keys:
          - {frame: 1, pivot: [0, 1, 0]}
          - {frame: 13, translate: [0.1, 0.05, -0.05], rotate: [20, 90, 0], pivot: [0, 1, 0]}
"""


def _analytic(x0, frame):
    """Rigid motion of the body keys above at ``frame`` (linear keys, as KinematicAnimation)."""
    s = (frame - 1) / 12.0
    R = rotation_matrix_xyz(np.array([20.0, 90.0, 0.0]) * s)
    piv = np.array([0.0, 1.0, 0.0])
    return (x0 - piv) @ R.T + piv + np.array([0.1, 0.05, -0.05]) * s


def test_waist_follows_rotating_body_exactly(tmp_path):
    c = compile_file(write_scene(tmp_path, SKIRT))
    sk = c.scene.element("skirt")
    waist = sk.geometry.groups["end"]
    assert len(waist) == 16 and np.allclose(sk.geometry.points[waist, 1], 1.1)
    sim = Simulation(c)
    m = c.model
    x0 = m.particle_q0[sk.vertex_slice].copy()
    gw = waist + sk.vertex_offset
    assert np.all(m.particle_inv_mass[gw] == 0) and m.particle_kinematic[gw].all()
    rest = np.setdiff1d(np.arange(sk.vertex_count), waist) + sk.vertex_offset
    assert np.all(m.particle_inv_mass[rest] > 0)
    for frame in range(2, 13):
        sim.step_frame()
        q = sim.state.particle_q
        # the waist is carried rigidly with the body: analytic to round-off
        assert np.abs(q[gw] - _analytic(x0[waist], frame)).max() < 1e-9
        # velocity of the waist is the body's (finite difference of the last substep)
        assert np.all(np.isfinite(sim.state.particle_qd))
    # the body itself is exactly on its keys too
    b = c.scene.element("body")
    assert np.abs(sim.state.particle_q[b.vertex_slice] - _analytic(m.particle_q0[b.vertex_slice],
                                                                   12)).max() < 1e-12
    # the rest of the skirt hangs from the waist: finite, below it, within its length
    q = sim.state.particle_q
    assert np.all(np.isfinite(q[rest]))
    up = rotation_matrix_xyz(np.array([20.0, 90.0, 0.0]) * 11 / 12) @ [0.0, 1.0, 0.0]
    assert np.all((q[rest] - q[gw].mean(0)) @ up < 1e-3)  # below the (tilted) waist ring
    hem = sk.geometry.groups["start"] + sk.vertex_offset
    assert q[hem, 1].mean() < q[gw, 1].mean() - 0.2  # hangs down under gravity
    d = np.linalg.norm(q[hem] - q[gw].mean(0), axis=1)
    assert d.max() < 0.3 * 1.1 + 0.11  # no stretch beyond the material's length


def test_follow_errors_are_located(tmp_path):
    bad = SKIRT.replace("follow: body", "follow: bdy").replace("select: end", "select: waist")
    with pytest.raises(InputError) as ei:
        compile_file(write_scene(tmp_path, bad))
    text = str(ei.value)
    assert "no vertex group named 'waist'" in text and ":12:14:" in text  # the Pins.select value
    # a misspelt follow target is reported too once the selection is fixed
    bad = SKIRT.replace("follow: body", "follow: bdy")
    with pytest.raises(InputError) as ei:
        compile_file(write_scene(tmp_path, bad))
    assert "no element named 'bdy'; did you mean 'body'?" in str(ei.value)
    assert 'element "skirt", Pins.follow' in str(ei.value)
    bad = SKIRT.replace("follow: body", "follow: skirt")
    with pytest.raises(InputError, match="must be another element with Kinematic"):
        compile_file(write_scene(tmp_path, bad))
    # a body without Kinematic (so no KinematicAnimation is scheduled at all)
    static = SKIRT[:SKIRT.index("      Kinematic:")] + "      Collider: {}\n"
    with pytest.raises(InputError) as ei:
        compile_file(write_scene(tmp_path, static))
    assert len(ei.value.diagnostics) == 1
    assert "Pins.follow: 'body' must be another element with Kinematic" in str(ei.value)


def test_follow_static_body_is_a_plain_pin(tmp_path):
    static = SKIRT[:SKIRT.index("        keys:")].replace("Kinematic:", "Kinematic: {}")
    c = compile_file(write_scene(tmp_path, static))
    sim = Simulation(c)
    sk = c.scene.element("skirt")
    gw = sk.geometry.groups["end"] + sk.vertex_offset
    q0 = c.model.particle_q0[gw].copy()
    sim.step_frame()
    assert np.abs(sim.state.particle_q[gw] - q0).max() < 1e-12


# ------------------------------------------------------------------------ mesh sequence hold

SEQ = """
lokigraph: 1
frames: {start: 1, end: 6, fps: 24}
substeps: 2
elements:
  - name: body
    geometry: {sequence: "anim/body.{frame:04d}.obj"HOLD}
    components: {Kinematic: {}}
"""


def _write_sequence(tmp_path, frames):
    from lokigraph.generators import box
    from lokigraph.meshfile import write_mesh

    seq = tmp_path / "anim"
    seq.mkdir(exist_ok=True)
    b = box()
    for f in frames:
        write_mesh(seq / f"body.{f:04d}.obj", b.points + [0, 0.1 * f, 0], b, "obj")
    return b.points


def test_short_sequence_is_an_error_naming_frame_and_file(tmp_path):
    _write_sequence(tmp_path, [1, 2, 3])
    p = write_scene(tmp_path, SEQ.replace("HOLD", ""))
    with pytest.raises(InputError) as ei:
        compile_file(p)
    text = str(ei.value)
    assert "frame 4 of the sequence is missing" in text
    assert "body.0004.obj" in text and "frames 1..3" in text and "hold" in text
    assert f"{p}:6:" in text and "geometry.sequence" in text


@pytest.mark.parametrize("hold, expect", [
    ("last", {4: 3, 5: 3, 6: 3}),
    ("first", {4: 1, 5: 1, 6: 1}),
    ("loop", {4: 1, 5: 2, 6: 3}),
])
def test_sequence_hold_modes(tmp_path, hold, expect):
    pts = _write_sequence(tmp_path, [1, 2, 3])
    c = compile_file(write_scene(tmp_path, SEQ.replace("HOLD", f", hold: {hold}")))
    sim = Simulation(c)
    for frame in range(2, 7):
        sim.step_frame()
        shown = expect.get(frame, frame)
        assert np.allclose(sim.state.particle_q, pts + [0, 0.1 * shown, 0], atol=1e-12), frame


def test_sequence_hold_covers_a_late_start(tmp_path):
    # the files start at frame 3; the run starts at 1: 'last' shows the first file before it
    pts = _write_sequence(tmp_path, [3, 4])
    c = compile_file(write_scene(tmp_path, SEQ.replace("HOLD", ", hold: last")))
    assert np.allclose(c.model.particle_q0, pts + [0, 0.3, 0])
    with pytest.raises(InputError, match="frame 1 of the sequence"):
        compile_file(write_scene(tmp_path, SEQ.replace("HOLD", "")))


def test_example_skirt_follows_body():
    """The shipped example: the waist ring stays on the turning body, the rest hangs below."""
    c = compile_file(EXAMPLES / "skirt_follow.yaml")
    sim = Simulation(c)
    sk = c.scene.element("skirt")
    waist = sk.geometry.groups["end"] + sk.vertex_offset
    body = c.scene.element("body")
    for _ in range(4):
        sim.step_frame()
    q = sim.state.particle_q
    d = c.model.data
    anim = next(v for k, v in d.items() if getattr(v, "follow", None) is not None)
    carried = q[anim.follow.idx]
    # every carried vertex sits exactly at its bound point of the body's current triangles
    from lokigraph.behaviors.attachments.pins import follow_positions as fp

    assert np.abs(carried - fp(q, anim.follow)).max() < 1e-9
    assert set(anim.follow.idx) == set(waist)
    # the body's own vertices are at their animation
    assert np.all(np.isfinite(q[sk.vertex_slice])) and np.all(np.isfinite(q[body.vertex_slice]))
    rest = np.setdiff1d(np.arange(sk.vertex_slice.start, sk.vertex_slice.stop), waist)
    assert np.all(q[rest, 1] < q[waist, 1].max() + 1e-3)
