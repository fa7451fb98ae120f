"""Kinematic.interpolation: linear (default, unchanged) and smooth (C1 monotone cubic Hermite)
rigid keys."""

import numpy as np
import pytest

from lokigraph.api import compile_file
from lokigraph.behaviors.animation import hermite_at, monotone_slopes
from lokigraph.errors import InputError
from lokigraph.geometry import rotation_matrix_xyz
from lokigraph.run import Simulation

KEYS = """
              - {frame: 1, translate: [0, 0, 0], rotate: [0, 0, 0]}
              - {frame: 4, translate: [0.3, 0.1, 0], rotate: [10, 40, 0]}
              - {frame: 7, translate: [-0.2, 0.3, 0], rotate: [20, 100, -30]}
              - {frame: 12, translate: [0.1, 0.3, 0.4], rotate: [20, 160, 15], pivot: [0, 0.1, 0]}
"""


def _scene(scene_file, interp=None, keys=KEYS, substeps=3):
    line = "" if interp is None else f"\n            interpolation: {interp}"
    return scene_file(f"""
    lokigraph: 1
    frames: {{start: 1, end: 13, fps: 24}}
    substeps: {substeps}
    elements:
      - name: ball
        geometry: {{generator: sphere, params: {{radius: 0.1, subdivisions: 1}}}}
        components:
          Kinematic:{line}
            keys:{keys}
    """)


def _trajectory(path, frames=12):
    sim = Simulation(compile_file(path))
    out = [sim.state.particle_q.copy()]
    vel = []
    for _ in range(frames):
        for _ in range(sim.model.substeps):
            sim.step_substep()
            out.append(sim.state.particle_q.copy())
            vel.append(sim.state.particle_qd.copy())
        sim.frame += 1
    return np.array(out), np.array(vel)


def _curve(fr, y):
    y = np.asarray(y, dtype=np.float64).reshape(len(fr), -1)
    return y, monotone_slopes(np.asarray(fr, dtype=np.float64), y)


def test_smooth_passes_through_keys_and_is_c1():
    fr = np.array([1.0, 4.0, 7.0, 12.0, 13.5])
    y, m = _curve(fr, [[0, 0], [0.3, 40], [-0.2, 100], [0.1, 160], [0.1, 200]])
    for f, v in zip(fr, y):
        assert np.array_equal(hermite_at(f, fr, y, m), v)
    # one-sided derivatives agree at every key (C1), and equal the tangents
    eps = 1e-6
    for i, f in enumerate(fr):
        left = (hermite_at(f, fr, y, m) - hermite_at(f - eps, fr, y, m)) / eps
        right = (hermite_at(f + eps, fr, y, m) - hermite_at(f, fr, y, m)) / eps
        assert np.allclose(left, right, atol=1e-4), (i, left, right)
        assert np.allclose(right, m[i], atol=1e-4)
    # zero tangents at the ends (the pose holds outside the keys: C1 there too), at a local
    # extreme (0.3 at frame 4, -0.2 at frame 7) and next to a flat segment (0.1 -> 0.1)
    assert np.all(m[0] == 0) and np.all(m[-1] == 0)
    assert m[1, 0] == 0 and m[2, 0] == 0 and m[3, 0] == 0
    # a channel keyed at a constant rate keeps it through its interior keys
    fr2 = np.array([0.0, 3.0, 9.0, 15.0, 18.0])
    y2, m2 = _curve(fr2, [0.0, 3.0, 9.0, 15.0, 18.0])
    assert np.allclose(m2[1:-1, 0], 1.0)
    # monotone: no overshoot past the keys on any segment
    ff = np.linspace(fr[0], fr[-1], 2001)
    c = np.array([hermite_at(f, fr, y, m) for f in ff])
    seg = np.searchsorted(fr, ff, side="right").clip(1, len(fr) - 1) - 1
    lo = np.minimum(y[seg], y[seg + 1]) - 1e-12
    hi = np.maximum(y[seg], y[seg + 1]) + 1e-12
    assert np.all((c >= lo) & (c <= hi))


def test_smooth_two_keys_is_smoothstep_and_holds_outside():
    fr = np.array([2.0, 6.0])
    y, m = _curve(fr, [[1.0], [3.0]])
    assert np.all(m == 0)
    assert hermite_at(4.0, fr, y, m)[0] == pytest.approx(2.0)
    assert hermite_at(3.0, fr, y, m)[0] == pytest.approx(1.0 + 2.0 * (3 * 0.25**2 - 2 * 0.25**3))
    assert hermite_at(0.0, fr, y, m)[0] == 1.0 and hermite_at(9.0, fr, y, m)[0] == 3.0


def test_linear_default_bitwise_unchanged(scene_file):
    """No field and an explicit ``linear`` give the same bits, and they are the per-channel
    np.interp pose (the code path as before the field existed)."""
    a, va = _trajectory(_scene(scene_file))
    b, vb = _trajectory(_scene(scene_file, "linear"))
    assert np.array_equal(a, b) and np.array_equal(va, vb)
    c = compile_file(_scene(scene_file))
    q0 = c.model.particle_q0
    fr = np.array([1.0, 4, 7, 12])
    tr = np.array([[0, 0, 0], [0.3, 0.1, 0], [-0.2, 0.3, 0], [0.1, 0.3, 0.4]])
    rot = np.array([[0, 0, 0], [10, 40, 0], [20, 100, -30], [20, 160, 15]])
    piv = np.array([[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0.1, 0]])
    for k in (1, 7, 20, 33):
        f = 1.0 + k / (24 * 3) * 24
        t = np.array([np.interp(f, fr, tr[:, i]) for i in range(3)])
        r = np.array([np.interp(f, fr, rot[:, i]) for i in range(3)])
        pv = np.array([np.interp(f, fr, piv[:, i]) for i in range(3)])
        assert np.allclose(a[k], (q0 - pv) @ rotation_matrix_xyz(r).T + pv + t, atol=1e-12)


def test_smooth_scene_pose_and_velocity(scene_file):
    """The simulated poses lie on the curve, and the kinematic velocity (finite difference of
    consecutive substep poses) is continuous: no jump at the keys, as linear has."""
    pos, vel = _trajectory(_scene(scene_file, "smooth"))
    c = compile_file(_scene(scene_file, "smooth"))
    q0 = c.model.particle_q0
    fr = np.array([1.0, 4, 7, 12])
    y = np.array([[0, 0, 0, 0, 0, 0, 0, 0, 0], [0.3, 0.1, 0, 10, 40, 0, 0, 0, 0],
                  [-0.2, 0.3, 0, 20, 100, -30, 0, 0, 0], [0.1, 0.3, 0.4, 20, 160, 15, 0, 0.1, 0]])
    m = monotone_slopes(fr, y)
    for k in (3, 10, 17, 30):
        cv = hermite_at(1.0 + k / 3, fr, y, m)
        expect = (q0 - cv[6:]) @ rotation_matrix_xyz(cv[3:6]).T + cv[6:] + cv[:3]
        assert np.allclose(pos[k], expect, atol=1e-12)
    lin_pos, lin_vel = _trajectory(_scene(scene_file, "linear"))
    # largest change of velocity between consecutive substeps, over the ball's vertices: with
    # twice the substeps it halves on a C1 curve (acceleration x h); linear keeps its jumps
    jump = lambda v: np.abs(np.diff(v, axis=0)).max()  # noqa: E731
    _, vel6 = _trajectory(_scene(scene_file, "smooth", substeps=6))
    _, lin_vel6 = _trajectory(_scene(scene_file, "linear", substeps=6))
    assert jump(vel6) < 0.6 * jump(vel)
    assert jump(lin_vel6) > 0.9 * jump(lin_vel)
    assert jump(vel) < 0.5 * jump(lin_vel)
    # the ball ends each key exactly on the key pose in both modes
    assert np.allclose(pos[9], lin_pos[9], atol=1e-12)  # frame 4 = 9 substeps after frame 1


def test_bad_interpolation_is_a_clear_error(scene_file):
    with pytest.raises(InputError) as e:
        compile_file(_scene(scene_file, "cubic"))
    msg = str(e.value)
    assert "interpolation" in msg and "linear" in msg and "smooth" in msg


def test_smooth_with_two_keys_at_one_frame_is_refused(scene_file):
    keys = """
              - {frame: 1, translate: [0, 0, 0]}
              - {frame: 5, translate: [0.1, 0, 0]}
              - {frame: 5, translate: [0.2, 0, 0]}
"""
    with pytest.raises(InputError) as e:
        compile_file(_scene(scene_file, "smooth", keys))
    assert "strictly increasing" in str(e.value)
    compile_file(_scene(scene_file, "linear", keys))  # a jump is fine when linear
