"""Keyed parameters (lokigraph.keys): evaluation, exact change at a key, located errors."""

import math

import numpy as np
import pytest
from pydantic import ValidationError

from conftest import run_cli
from lokigraph.api import compile_file
from lokigraph.keys import Keyed, value_at
from lokigraph.run import Simulation


# ---- evaluation ------------------------------------------------------------------------------

def test_evaluate_linear_smooth_step():
    k = Keyed(keys={10: 2.0, 1: 0.0, 20: 2.0})  # unsorted on input
    assert k.interp == "linear"
    assert k.evaluate(-5) == 0.0 and k.evaluate(1) == 0.0  # before / at the first key
    assert k.evaluate(5.5) == pytest.approx(1.0)
    assert k.evaluate(10) == 2.0 and k.evaluate(15) == 2.0 and k.evaluate(99) == 2.0
    s = Keyed(keys={0: 0.0, 10: 4.0, 20: 4.0}, interp="smooth")
    assert s.evaluate(5) == pytest.approx(2.0)  # symmetric ease
    assert s.evaluate(2.5) == pytest.approx(4.0 * (0.25 ** 2 * (3 - 0.5)))
    assert s.evaluate(0) == 0.0 and s.evaluate(10) == 4.0
    # C1 with zero tangents at the keys, and no overshoot anywhere
    eps = 1e-6
    assert abs(s.evaluate(10 + eps) - s.evaluate(10 - eps)) < 1e-9
    assert all(0.0 <= s.evaluate(f) <= 4.0 for f in np.linspace(-3, 23, 263))
    st = Keyed(keys={1: 3.0, 10: 7.0}, interp="step")
    assert st.evaluate(9.999999) == 3.0 and st.evaluate(10) == 7.0 and st.evaluate(1e6) == 7.0
    one = Keyed(keys={4: 1.5}, interp="smooth")
    assert one.evaluate(-1) == one.evaluate(4) == one.evaluate(9) == 1.5
    assert value_at(2.5, 3.0) == 2.5 and value_at(st, 10) == 7.0


@pytest.mark.parametrize("bad", [{"keys": {}}, {"keys": {1: float("nan")}},
                                 {"keys": {"a": 1.0}}, {"keys": {1: 1.0}, "interp": "cubic"},
                                 {"keys": {1: 1.0}, "extra": 1}])
def test_keyed_model_rejects(bad):
    with pytest.raises(ValidationError):
        Keyed(**bad)


# ---- keyed stiffness: a particle on a spring (symplectic Euler, in closed form) ----------------

def _spring_scene(tmp_path, stiffness, name="s", substeps=4, frames=24):
    p = tmp_path / f"{name}.yaml"
    p.write_text(f"""
lokigraph: 1
frames: {{start: 1, end: {frames + 1}, fps: 24}}
substeps: {substeps}
gravity: [0, 0, 0]
elements:
  - name: mass
    geometry: {{generator: points, params: {{positions: [[0.1, 0, 0]]}}}}
    components:
      Dynamic: {{point_mass: 2.0}}
      RestSpring: {{stiffness: {stiffness}, anchor: [0, 0, 0]}}
""")
    return p


def _trajectory(path, frames):
    """x and v of the particle at frames start..start+frames (index 0 = frame 1)."""
    sim = Simulation(compile_file(path))
    xs, vs = [sim.state.particle_q[0].copy()], [sim.state.particle_qd[0].copy()]
    for _ in range(frames):
        sim.step_frame()
        xs.append(sim.state.particle_q[0].copy())
        vs.append(sim.state.particle_qd[0].copy())
    return np.array(xs), np.array(vs), sim.model.dt


def _symplectic_euler(x0, v0, k, m, h, n):
    """Closed form of n steps of v += -h k/m x; x += h v (the nucleus solver with one force):
    x_j = a cos(j theta) + b sin(j theta) with cos theta = 1 - h^2 k / (2 m)."""
    theta = math.acos(1.0 - h * h * k / (2.0 * m))
    xm1 = x0 - h * v0  # the x_{-1} that the recurrence x_{j+1} = 2 c x_j - x_{j-1} implies
    a = x0
    b = (a * math.cos(theta) - xm1) / math.sin(theta)
    j = np.arange(n + 1)
    x = a * np.cos(j * theta) + b * np.sin(j * theta)
    return x


def test_keyed_stiffness_step_changes_exactly_at_key(tmp_path):
    k1, k2, m, sub = 30.0, 120.0, 2.0, 4
    frames = 24
    keyed = _spring_scene(tmp_path, f"{{keys: {{1: {k1}, 10: {k2}}}, interp: step}}", "keyed")
    plain = _spring_scene(tmp_path, k1, "plain")
    xk, vk, h = _trajectory(keyed, frames)
    xp, vp, _ = _trajectory(plain, frames)
    # frames 1..10 (indices 0..9) bit-identical to the unkeyed run; frame 11 is the first to
    # differ: the substeps starting at frame 10 see k2
    assert np.array_equal(xk[:10], xp[:10]) and np.array_equal(vk[:10], vp[:10])
    assert not np.array_equal(xk[10], xp[10])
    # analytic response (symplectic Euler in closed form): k1 for the 9 frames up to frame 10,
    # then k2 from the state at frame 10. The closed form and the solver differ only by
    # rounding: about 1e-16 * (number of steps) relative to the 0.1 m amplitude; 1e-12 m is
    # 10^4 times that and 10^9 times smaller than the change the key makes.
    n1 = 9 * sub
    x1 = _symplectic_euler(0.1, 0.0, k1, m, h, n1)
    assert np.allclose(xk[:10, 0], x1[::sub], rtol=0, atol=1e-12)
    x10, v10 = xk[9, 0], vk[9, 0]
    x2 = _symplectic_euler(x10, v10, k2, m, h, (frames - 9) * sub)
    assert np.allclose(xk[9:, 0], x2[::sub], rtol=0, atol=1e-12)
    # and the keyed run is not the k1 response after the key
    assert np.max(np.abs(xk[11:, 0] - xp[11:, 0])) > 1e-2
    # the discrete angular frequency approaches the exact sqrt(k/m) (harmonic oscillator):
    # theta / h = omega (1 + O(h^2 omega^2)), 0.3 % at h omega = 0.08
    theta = math.acos(1.0 - h * h * k2 / (2.0 * m))
    assert theta / h == pytest.approx(math.sqrt(k2 / m), rel=3e-3)


def test_keyed_stiffness_constant_keys_equal_plain(tmp_path):
    """A single key is the plain value at every substep (bitwise: the force uses the same
    numbers in the same order)."""
    xk, vk, _ = _trajectory(_spring_scene(tmp_path, "{keys: {5: 30.0}}", "one"), 12)
    xp, vp, _ = _trajectory(_spring_scene(tmp_path, 30.0, "plain"), 12)
    assert np.array_equal(xk, xp) and np.array_equal(vk, vp)


def test_keyed_stiffness_linear_between_frames(tmp_path):
    """interp linear: substep j of frame f sees the value at f + j / substeps."""
    from lokigraph.behavior import StepContext
    from lokigraph.keys import step_frame

    c = compile_file(_spring_scene(tmp_path, "{keys: {1: 0.0, 3: 8.0}}", "lin", substeps=4))
    sim = Simulation(c)
    seen = []
    for _ in range(3):
        for _ in range(4):
            ctx = StepContext(sim.model, sim.state, sim.control, sim.model.dt, sim.state.time,
                              sim.substep_index, sim.frame)
            seen.append(step_frame(ctx))
            sim.step_substep()
        sim.frame += 1
    assert seen == [1 + j / 4 for j in range(12)]
    # the last substep started at frame 3.75: past the last key
    assert c.model.data["rest_spring_force"].values[0] == 8.0


# ---- keyed wind speed: terminal velocity of a particle with linear drag ------------------------

def _wind_scene(tmp_path, speed, name, frames=96):
    p = tmp_path / f"{name}.yaml"
    p.write_text(f"""
lokigraph: 1
frames: {{start: 1, end: {frames + 1}, fps: 24}}
substeps: 2
gravity: [0, 0, 0]
elements:
  - name: wind
    components:
      Wind: {{speed: {speed}, direction: [1, 0, 0]}}
  - name: p
    geometry: {{generator: points, params: {{positions: [[0, 0, 0]]}}}}
    components:
      Dynamic: {{point_mass: 0.5}}
      Drag: {{model: linear, coefficient: 5.0}}
""")
    return p


def test_keyed_wind_speed_step_terminal_velocities(tmp_path):
    """Linear drag b = 5 kg/s on m = 0.5 kg (tau = 0.1 s) and no gravity: the particle's
    velocity tends to the wind speed. Keys 2 m/s up to frame 48, 6 m/s from frame 48: it
    reaches 2 m/s, then 6 m/s (backward Euler: the fixed point is exact), and up to frame 48
    it is bit-identical to a run with a constant 2 m/s."""
    keyed = _wind_scene(tmp_path, "{keys: {1: 2.0, 48: 6.0}, interp: step}", "keyed")
    plain = _wind_scene(tmp_path, "2.0", "plain")
    xk, vk, _ = _trajectory(keyed, 96)
    xp, vp, _ = _trajectory(plain, 96)
    assert np.array_equal(xk[:48], xp[:48]) and np.array_equal(vk[:48], vp[:48])
    assert not np.array_equal(vk[48], vp[48])
    # 47 frames = 19.6 tau: e^-19.6 ~ 3e-9 of the initial gap left (the backward-Euler
    # contraction per substep, 1 / (1 + h b / m) = 0.828, gives 0.828^94 ~ 2e-8)
    assert vk[47, 0] == pytest.approx(2.0, abs=1e-6)
    assert vk[96, 0] == pytest.approx(6.0, abs=1e-6)
    assert np.allclose(vk[:, 1:], 0.0)
    # the transient after the key is the backward-Euler response to a 4 m/s step:
    # v_n = 6 - 4 / (1 + h b / m)^n, n substeps after frame 48
    h, r = 1.0 / 48, 1.0 / (1.0 + (1.0 / 48) * 5.0 / 0.5)
    for f in (49, 50, 52):
        n = 2 * (f - 48)
        assert vk[f - 1, 0] == pytest.approx(6.0 - (6.0 - vk[47, 0]) * r ** n, abs=1e-12)
    assert h > 0


def test_wind_key_list_interpolates_at_the_substep_frame(tmp_path):
    """The older ``Wind.keys`` list (linear) takes its key time from the same substep frame as
    keyed fields: it equals ``speed: {keys: ..., interp: linear}`` bit for bit. (It used to add
    the elapsed frames twice, reaching its keys at about half their frame numbers.)"""
    keyed = _wind_scene(tmp_path, "{keys: {1: 0.0, 21: 10.0}, interp: linear}", "keyed", 30)
    listed = _wind_scene(tmp_path, "0.0", "listed", 30)
    listed.write_text(listed.read_text().replace(
        "Wind: {speed: 0.0, direction: [1, 0, 0]}",
        "Wind: {speed: 0.0, direction: [1, 0, 0], keys: [{frame: 1, speed: 0.0}, "
        "{frame: 21, speed: 10.0}]}"))
    xk, vk, _ = _trajectory(keyed, 30)
    xl, vl, _ = _trajectory(listed, 30)
    assert np.array_equal(xk, xl) and np.array_equal(vk, vl)
    assert 0.0 < vk[10, 0] < 10.0


def test_keyed_wind_direction_and_drag_and_damping(tmp_path):
    """Direction components, the drag coefficient and Dynamic.damping accept keys too."""
    p = tmp_path / "mix.yaml"
    p.write_text("""
lokigraph: 1
frames: {start: 1, end: 12, fps: 24}
substeps: 1
gravity: [0, 0, 0]
elements:
  - name: wind
    components:
      Wind: {speed: 3.0, direction: [{keys: {1: 1.0, 6: 0.0}, interp: smooth}, 0,
                                     {keys: {1: 0.0, 6: 1.0}, interp: smooth}]}
  - name: p
    geometry: {generator: points, params: {positions: [[0, 0, 0]]}}
    components:
      Dynamic: {point_mass: 0.5, damping: {keys: {1: 0.0, 8: 1.0}}}
      Drag: {model: linear, coefficient: {keys: {1: 5.0, 4: 20.0}, interp: linear}}
""")
    x, v, _ = _trajectory(p, 11)
    assert np.isfinite(x).all()
    assert v[3, 0] > 0.5 and v[11, 2] > 1.0  # blown along x first, then along z


# ---- validation: exit 2 at the key's line ------------------------------------------------------

_BAD_HEAD = """lokigraph: 1
frames: {start: 1, end: 2, fps: 24}
gravity: [0, 0, 0]
elements:
  - name: p
    geometry: {generator: points, params: {positions: [[0, 0, 0]]}}
    components:
      Dynamic: {point_mass: 1.0}
      RestSpring:
        stiffness:
          keys:
            1: 2.0
"""


@pytest.mark.parametrize("tail, line, field, words", [
    ("            4: .nan\n", 13, "RestSpring.stiffness.keys.4", "finite"),
    ("            4: -1.0\n", 13, "RestSpring.stiffness.keys.4", ">= 0"),
    ("            abc: 1.0\n", 13, "RestSpring.stiffness.keys.abc", "number"),
    ("          interp: cubic\n", 13, "RestSpring.stiffness.interp", "linear"),
    ("        anchor: [{keys: {1: 0.0}}, 0, 0]\n", 13, "RestSpring.anchor.0",
     "cannot be keyed"),
])
def test_bad_keys_located(tmp_path, tail, line, field, words):
    p = tmp_path / "bad.yaml"
    p.write_text(_BAD_HEAD + tail)
    r = run_cli("validate", p)
    assert r.returncode == 2, r.stdout + r.stderr
    text = r.stdout + r.stderr
    assert f"bad.yaml:{line}:" in text and field in text and words in text, text
    assert "Traceback" not in text


def test_keys_on_non_keyable_field(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text(_BAD_HEAD.replace("      Dynamic: {point_mass: 1.0}\n",
                                   "      Dynamic:\n        point_mass: {keys: {1: 1.0}}\n"))
    r = run_cli("validate", p)
    text = r.stdout + r.stderr
    assert r.returncode == 2 and "bad.yaml:9:" in text, text
    assert "Dynamic.point_mass" in text and "cannot be keyed" in text, text


def test_wind_keys_list_and_keyed_field_conflict(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("""lokigraph: 1
frames: {start: 1, end: 2, fps: 24}
elements:
  - name: w
    components:
      Wind: {speed: {keys: {1: 0.0}}, keys: [{frame: 1, speed: 2.0}]}
""")
    r = run_cli("validate", p)
    text = r.stdout + r.stderr
    assert r.returncode == 2 and "bad.yaml:6:" in text and "not both" in text, text
