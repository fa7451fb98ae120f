"""The friction block's curvature along the slip (implicit_solver.friction_slip_curvature):
IPC's exact block has none there while sliding, so a soft shell on a rough ground left the
Newton matrix singular along the slip and the shipped pressure_ball example blew up with the
implicit solver (vertices at 8.7-2,593 m/s after landing, measured); a floor keeps it bounded."""

import numpy as np
import pytest

from conftest import EXAMPLES
from lokigraph.api import compile_file
from lokigraph.behaviors.solvers.implicit.contact import contact_energy, lag_contacts
from lokigraph.run import Simulation

#: the ball lands (lowest vertex 0.78 m up) at sqrt(2 g 0.78) = 3.9 m/s; nothing after should
#: move faster than that by much
LANDING_BOUND = 5.0


def _ball(tmp_path, value):
    text = (EXAMPLES / "pressure_ball.yaml").read_text()
    text = text.replace("graph: default\n", "graph: default\nsolver: implicit\ngraph_overrides: "
                        f"{{implicit_solver: {{friction_slip_curvature: {value}}}}}\n", 1)
    p = tmp_path / f"ball_{value}.yaml"
    p.write_text(text)
    sim = Simulation(compile_file(p))
    speeds = []
    for _ in range(20):
        sim.step_frame()
        assert np.isfinite(sim.state.particle_q).all()
        speeds.append(float(np.linalg.norm(sim.state.particle_qd, axis=1).max()))
    return np.array(speeds)


def test_pressure_ball_lands_with_the_floor_and_not_without(tmp_path):
    with_floor = _ball(tmp_path, 0.2)  # the default
    exact = _ball(tmp_path, 0.0)
    assert with_floor[:10].max() < LANDING_BOUND  # free fall (frames 1-10)
    assert with_floor[11:].max() < LANDING_BOUND, with_floor  # measured 2.7 m/s (48 frames)
    # the cause: without the floor the bound fails (measured 8.7 m/s at frame 12 with the
    # volume row in the solve; 2,593 m/s within 48 frames, 805 without Pressure)
    assert exact[11:].max() > LANDING_BOUND, exact


@pytest.mark.parametrize("floor", [0.0, 0.2, 0.5, 1.0])
def test_slip_curvature_floor_of_the_block(floor):
    """The friction block of a sliding vertex on a plane: curvature across the slip mu lam / y,
    along it max(0, floor) times that (0 exact, 1 IRLS); the gradient does not depend on it."""
    x0 = np.array([[0.0, 0.0, 0.0]])
    x = np.array([[0.01, -0.001, 0.0]])  # slid 1 cm along x, 1 mm into the plane y = 0
    kinds = np.array([0], np.int64)
    centers, dirs = np.zeros((1, 3)), np.array([[0.0, 1.0, 0.0]])
    radii, lengths, mus = np.zeros(1), np.zeros(1), np.array([0.5])
    fixed = np.zeros(1, bool)
    kc = np.full(1, 100.0)
    lam, nrm = np.zeros((1, 1)), np.zeros((1, 1, 3))
    assert lag_contacts(x, fixed, kinds, centers, dirs, radii, lengths, kc, lam, nrm) == 1
    eps = 1e-5  # y = 1 cm >> eps: sliding
    g, A = np.zeros((1, 3)), np.zeros((1, 3, 3))
    contact_energy(x, x0, fixed, kinds, centers, dirs, radii, lengths, mus, kc, lam, nrm, eps,
                   2, g, A, np.arange(1), floor)
    ml = 0.5 * lam[0, 0]
    assert ml > 0
    across = ml / 0.01
    assert A[0, 2, 2] == pytest.approx(across, rel=1e-12)
    assert A[0, 0, 0] == pytest.approx(floor * across, rel=1e-9, abs=1e-12 * across)
    assert g[0, 0] == pytest.approx(ml, rel=1e-12)  # mu lam along the slip, whatever the floor
