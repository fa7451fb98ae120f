"""Twist of Rod strands: a material frame per segment (behaviors/materials/rod.py, issue #13):
the torsional period of a strand twisted at its root against the closed form, the geometric
phase of the reference twist, the frames staying orthonormal on moving hair, positions unchanged
by the twist, and checkpoint/resume carrying the frames."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from lokigraph.api import compile_file
from lokigraph.run import Simulation

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "graphs" / "examples"


def _strand_scene(tmp_path, rod: str, lam: float, L: float, n: int, frames: int,
                  substeps: int = 4) -> Path:
    """A straight vertical strand of n segments hanging from its pinned root, no gravity (it
    stays straight), Nucleus defaults but the given substeps (4 is the default)."""
    p = tmp_path / "s.yaml"
    p.write_text(f"""
lokigraph: 1
frames: {{start: 1, end: {frames + 1}, fps: 24}}
substeps: {substeps}
gravity: [0, 0, 0]
elements:
  - name: strand
    geometry: {{generator: strands, params: {{count: [1, 1], length: {L}, segments: {n},
                direction: [0, -1, 0]}}}}
    components:
      Dynamic: {{mass_density: {lam}}}
      Rod: {{{rod}}}
      Pins: {{vertices: [0]}}
""")
    return p


def _tip_twist(path: Path, frames: int):
    """Times [s] and the tip segment's twist angle [rad] after every frame (0 at the start)."""
    c = compile_file(path)
    sim = Simulation(c)
    tw = c.schedule.find("RodConstraint")[0].data.twist
    q0 = sim.state.particle_q.copy()
    fps = c.model.fps
    t, th = [0.0], [0.0]
    for f in range(frames):
        sim.step_frame()
        t.append((f + 1) / fps)
        th.append(float(tw.theta[-1]))
    return np.array(t), np.array(th), q0, sim.state.particle_q.copy()


def _period(t, y):
    """Mean period of y from its zero crossings (linear interpolation), leaving out the first
    half period (the front of the step travelling to the tip)."""
    i = np.flatnonzero(np.sign(y[:-1]) != np.sign(y[1:]))
    z = t[i] - y[i] * (t[i + 1] - t[i]) / (y[i + 1] - y[i])
    assert len(z) >= 4, z
    return 2.0 * float(np.mean(np.diff(z)[1:]))


@pytest.mark.parametrize("rod, GJ", [
    # twist stiffness given directly
    ("radius: 1.0e-3, bend_resistance: 1.0e-6, twist_resistance: 3.2e-9, root_twist: 0.5",
     3.2e-9),
    # the default: GJ = E J / (2 (1 + nu)) = E pi r^4 / (4 (1 + nu)) (extensible strand)
    ("radius: 1.0e-3, youngs_modulus: 5.0e3, poisson_ratio: 0.3, root_twist: 0.5",
     5.0e3 * math.pi * 1.0e-3 ** 4 / (4 * 1.3)),
])
def test_root_step_twist_reaches_the_tip_with_the_torsional_period(tmp_path, rod, GJ):
    """A straight strand (length L, linear density lam [kg/m], fibre radius r) whose root is
    turned by Theta at t = 0 and held: a fixed-free torsional shaft. Its twist obeys the wave
    equation rho J theta_tt = G J theta_ss (rho J = lam r^2 / 2 per unit length, a solid circular
    fibre), theta(0, t) = Theta, theta_s(L, t) = 0; its modes are sin((2k - 1) pi s / (2 L)) with
    omega_k = (2k - 1) pi c / (2 L), c = sqrt(G J / (rho J)), all odd multiples of omega_1, so
    the tip twist oscillates about Theta with the fundamental period T = 4 L / c (and reaches
    2 Theta at most). At the default 4 substeps the measured period is within 5 % of T
    (measured +0.04 % and +0.05 %; the implicit time stepping stretches it by atan(omega h) /
    (omega h): 2.2 % at one substep per frame)."""
    L, n, lam, r, Th = 0.2, 20, 0.01, 1.0e-3, 0.5
    frames = 72
    t, th, q0, q = _tip_twist(_strand_scene(tmp_path, rod, lam, L, n, frames), frames)
    c = math.sqrt(GJ / (lam * r * r / 2.0))
    T = 4.0 * L / c
    assert 0.5 < T < 1.5  # three periods or more within the run
    Tm = _period(t, th - Th)
    assert abs(Tm / T - 1.0) < 0.05, (Tm, T)
    assert 1.5 * Th < th.max() < 2.0 * Th * 1.02  # the tip overshoots to about 2 Theta
    # the twist did not move the (straight) strand
    assert np.array_equal(q[:, 0], q0[:, 0]) and np.array_equal(q[:, 2], q0[:, 2])


def test_root_carried_by_a_turning_body_twists_the_strand_with_it(tmp_path):
    """A strand hanging on the spin axis of a kinematic ball (``Pins: {follow: body}``) that
    turns by Phi = 45 degrees about +y over half a second and then holds: the root takes its
    twist from the body, and once the torsional waves have died out (twist damped by
    ``Dynamic.damping``) the static fixed-free shaft is twisted uniformly by the root angle:
    every segment's material frame turned by Phi about +y, i.e. theta = -Phi about the
    strand's tangent -y (measured within 0.1 % of Phi at the tip after 4 s; the root angle
    itself 0.04 %)."""
    p = tmp_path / "s.yaml"
    p.write_text("""
lokigraph: 1
frames: {start: 1, end: 97, fps: 24}
elements:
  - name: body
    geometry: {generator: sphere, params: {radius: 0.1, subdivisions: 2, center: [0, 1, 0]}}
    components:
      Kinematic:
        keys:
          - {frame: 1, pivot: [0, 1, 0]}
          - {frame: 13, rotate: [0, 45, 0], pivot: [0, 1, 0]}
  - name: strand
    geometry: {generator: strands, params: {count: [1, 1], length: 0.2, segments: 20,
               direction: [0, -1, 0], center: [0, 0.899, 0]}}
    components:
      Dynamic: {mass_density: 0.01, damping: 3.0}
      Rod: {radius: 1.0e-3, bend_resistance: 1.0e-6, twist_resistance: 3.2e-9}
      Pins: {map: root, follow: body}
""")
    c = compile_file(p)
    sim = Simulation(c)
    tw = c.schedule.find("RodConstraint")[0].data.twist
    assert tw.fstrand is not None and list(tw.fstrand) == [0]
    peak = 0.0
    for _ in range(96):
        sim.step_frame()
        peak = max(peak, abs(tw.theta[-1]))
    Phi = math.pi / 4
    assert peak > 1.1 * Phi  # the twist arrived at the tip as a wave and overshot
    assert abs(tw.bphi[0] + Phi) < 0.01 * Phi, tw.bphi[0]
    assert np.abs(tw.theta + Phi).max() < 0.01 * Phi, tw.theta


def test_twist_does_not_change_positions_of_moving_hair(tmp_path):
    """hair_head_gusts (roots riding a turning head, gusts, contacts: bent, moving strands):
    the positions with the default twist and with ``twist_resistance: 0`` (no material frame)
    are bit-identical: the frame follows the centre line and never acts on it."""
    text = (EXAMPLES / "hair_head_gusts.yaml").read_text()
    assert "Rod: {" in text
    finals = []
    for extra in ("", "twist_resistance: 0, "):
        p = tmp_path / f"s{len(finals)}.yaml"
        p.write_text(text.replace("Rod: {", "Rod: {" + extra))
        c = compile_file(p)
        d = c.schedule.find("RodConstraint")[0].data
        assert (d.twist is None) == bool(extra)
        sim = Simulation(c)
        for _ in range(8):
            sim.step_frame()
        finals.append(sim.state.particle_q.copy())
    assert np.array_equal(finals[0], finals[1])


def test_frames_stay_orthonormal_on_moving_hair_and_twist_free_in_a_plane(tmp_path):
    """After frames of hair on a turning head, every reference director is a unit vector normal
    to its segment's current tangent and the material frame (t, m1, m2) is orthonormal; on
    hair_strands (every strand droops in its own vertical plane) the reference twist stays 0
    and, with no root twist, the twist angle too."""
    from lokigraph.behaviors.materials.rod import material_frames

    c = compile_file(EXAMPLES / "hair_head_gusts.yaml")
    sim = Simulation(c)
    for _ in range(12):
        sim.step_frame()
    d = c.schedule.find("RodConstraint")[0].data
    S = len(d.vptr) - 1
    seg = np.concatenate([np.arange(d.vptr[s], d.vptr[s + 1] - 1) for s in range(S)])
    e = sim.state.particle_q[d.verts[seg + 1]] - sim.state.particle_q[d.verts[seg]]
    t_now = e / np.linalg.norm(e, axis=1, keepdims=True)
    t, m1, m2 = material_frames(d)
    # the frame is carried to the tangents of the substep's final positions (the contacts'
    # last safe step may move them by rounding-level amounts after that)
    assert np.abs(t - t_now).max() < 1e-6
    tw = d.twist
    assert np.abs(np.linalg.norm(tw.d1, axis=1) - 1).max() < 1e-12
    assert np.abs(np.einsum("ij,ij->i", tw.d1, tw.tan)).max() < 1e-12
    for a, b in ((t, m1), (t, m2), (m1, m2)):
        assert np.abs(np.einsum("ij,ij->i", a, b)).max() < 1e-12
    assert np.abs(tw.theta).max() > 0  # the moving roots do twist the hair a little

    c = compile_file(EXAMPLES / "hair_strands.yaml")
    sim = Simulation(c)
    for _ in range(12):
        sim.step_frame()
    tw = c.schedule.find("RodConstraint")[0].data.twist
    assert np.abs(tw.reft).max() < 1e-9 and np.abs(tw.theta).max() < 1e-9


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_reference_twist_is_the_geometric_phase_of_a_cone(direction):
    """Two segments: the first fixed along z, the second swept once around a cone of half
    angle a about z in small steps and back to where it started. Parallel transport of its
    reference director around that loop of tangents turns it by the solid angle the loop
    encloses, 2 pi (1 - cos a); the reference twist at the joint (the angle between the first
    director carried along the strand and the second) changes by exactly that, with the sign of
    the sweep (the rod's geometric phase; positive for a counter-clockwise sweep about z)."""
    from lokigraph.behaviors.materials.rod import bishop_frames, twist_step_seq

    a = math.radians(45.0)
    N = 4000
    verts = np.arange(3)
    vptr = np.array([0, 3])
    p = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.1], [0.0, 0.0, 0.2]])
    M = 2
    d1, tan = np.zeros((M, 3)), np.zeros((M, 3))
    bishop_frames(p, verts, vptr, d1, tan)
    w = np.zeros(3)
    on = np.ones(1, bool)
    theta, omega, reft = np.zeros(M), np.zeros(M), np.zeros(M)
    winv = np.zeros(M)  # infinite rotational inertia: theta stays 0, only the frames move
    alpha = np.full(M, np.inf)
    ws = [np.zeros(M) for _ in range(3)]
    # tilt to the cone, sweep around it, tilt back
    path = [(a * k / 200, 0.0) for k in range(1, 201)]
    path += [(a, direction * 2 * math.pi * k / N) for k in range(1, N + 1)]
    path += [(a * (1 - k / 200), 0.0) for k in range(1, 201)]
    for tilt, phi in path:
        p[2] = p[1] + 0.1 * np.array([math.sin(tilt) * math.cos(phi),
                                      math.sin(tilt) * math.sin(phi), math.cos(tilt)])
        twist_step_seq(p, w, verts, vptr, on, d1, tan, theta, omega, winv, reft, alpha,
                       np.zeros(1), np.zeros((1, 3)), np.zeros(1), np.zeros(M), *ws, 1e-3)
    expect = 2 * math.pi * (1 - math.cos(a))
    assert np.allclose(tan[1], [0, 0, 1])  # back along z
    # measured 1.8403019 against 1.8403024 rad (the polygonal loop of 4000 steps)
    assert abs(reft[1] - direction * expect) < 1e-5 * expect, (reft[1], expect)
    assert theta[1] == 0.0


def test_resume_from_a_checkpoint_carries_the_twist(tmp_path):
    """A checkpoint taken mid-run (lokigraph.checkpoint.capture) holds the material frames:
    a new simulation restored from it continues with the same twist angles, rates and frames
    bit for bit."""
    from lokigraph import checkpoint as ckpt

    L, n, lam = 0.2, 20, 0.01
    path = _strand_scene(tmp_path, "radius: 1.0e-3, twist_resistance: 3.2e-9, root_twist: "
                         "{keys: {1: 0.0, 4: 0.8}, interp: smooth}", lam, L, n, 12)
    c = compile_file(path)
    sim = Simulation(c)
    for _ in range(5):
        sim.step_frame()
    arrays = ckpt.capture(sim)
    assert any(k.endswith("/twist_theta") for k in arrays)
    for _ in range(5):
        sim.step_frame()
    a = c.schedule.find("RodConstraint")[0].data.twist
    c2 = compile_file(path)
    sim2 = Simulation(c2)
    sim2.begin(checkpoint=arrays)
    for _ in range(5):
        sim2.step_frame()
    b = c2.schedule.find("RodConstraint")[0].data.twist
    assert np.abs(a.theta).max() > 0.1  # the keyed root twist reached the strand
    for k in ("theta", "omega", "d1", "tan", "reft"):
        assert np.array_equal(getattr(a, k), getattr(b, k)), k


def test_parallel_and_sequential_twist_kernels_agree():
    """``twist_step`` (strands in prange) and ``twist_step_seq`` give the same frames, angles
    and rates bit for bit (strands are independent), on bent random strands with pinned roots,
    root angles and damping, moved over a few substeps."""
    from lokigraph.behaviors.materials.rod import bishop_frames, twist_step, twist_step_seq

    rng = np.random.default_rng(7)
    S, n = 40, 12
    p = np.cumsum(rng.normal(scale=0.01, size=(S, n + 1, 3)), axis=1).reshape(-1, 3)
    verts = np.arange(S * (n + 1))
    vptr = np.arange(S + 1) * (n + 1)
    w = np.ones(len(p))
    w[vptr[:-1]] = 0.0  # pinned roots
    M = S * n
    d1, tan = np.zeros((M, 3)), np.zeros((M, 3))
    bishop_frames(p, verts, vptr, d1, tan)
    winv, alpha = rng.uniform(1e3, 1e5, M), rng.uniform(1e-6, 1e-4, M)
    root, damp = rng.normal(size=S), np.full(M, 0.5)
    moves = [rng.normal(scale=1e-3, size=p.shape) * w[:, None] for _ in range(5)]
    states = []
    for fn in (twist_step, twist_step_seq):
        st = dict(d1=d1.copy(), tan=tan.copy(), theta=np.zeros(M), omega=np.zeros(M),
                  reft=np.zeros(M), bphi=np.zeros(S))
        q = p.copy()
        for mv in moves:
            q += mv
            fn(q, w, verts, vptr, np.ones(S, bool), st["d1"], st["tan"], st["theta"],
               st["omega"], winv, st["reft"], alpha, root, np.zeros((S, 3)), st["bphi"], damp,
               np.zeros(M), np.zeros(M), np.zeros(M), 1e-3)
        states.append(st)
    assert np.abs(states[0]["theta"]).max() > 0.1
    assert np.abs(states[0]["reft"]).max() > 1e-3  # bent, moving strands: nonzero twist
    for k in states[0]:
        assert np.array_equal(states[0][k], states[1][k]), k


def test_twist_runs_with_the_implicit_solver(tmp_path):
    """The twist step is a per-substep hook on the final positions, so the implicit solver
    runs it too: the same root-step strand gives the same torsional period (within 5 % of
    T = 4 L / c)."""
    L, n, lam, r, Th, GJ = 0.2, 20, 0.01, 1.0e-3, 0.5, 3.2e-9
    frames = 72
    path = _strand_scene(tmp_path, "radius: 1.0e-3, bend_resistance: 1.0e-6, "
                         "twist_resistance: 3.2e-9, root_twist: 0.5", lam, L, n, frames)
    path.write_text(path.read_text().replace("lokigraph: 1\n", "lokigraph: 1\nsolver: implicit\n"))
    t, th, q0, q = _tip_twist(path, frames)
    T = 4.0 * L / math.sqrt(GJ / (lam * r * r / 2.0))
    assert abs(_period(t, th - Th) / T - 1.0) < 0.05
    assert np.abs(q - q0).max() < 1e-9  # the straight, weightless strand does not move
