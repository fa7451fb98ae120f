"""The elbow of graphs/examples/sleeve_elbow.yaml: a sleeve caught in the crease of a bending arm,
with and without Loki's mechanisms (compliant kinematics, proximity-tolerant contacts).

Frames: the forearm bends from 0 to 140 degrees over frames 1-25, straightens over 25-49 and
rests until 61. Array index i holds the state at the end of frame i + 2.
"""

import re
import shutil
import time

import numpy as np
import pytest

from conftest import EXAMPLES
from lokigraph.api import compile_file
from lokigraph.behaviors.collision.intersect import intersect_meshes
from lokigraph.run import Simulation

MAPS = ("elbow_upper_soft.npy", "elbow_forearm_soft.npy", "sleeve_elbow_sleeve.obj")
ARM = ("upper_arm", "forearm", "elbow")

# Speed bounds from the animation: the forearm turns 140 degrees in 24 frames at 24 fps, i.e.
# 2.44 rad/s, so its tip (0.3 m from the joint) moves at 0.73 m/s. Cloth carried or pushed by the
# forearm moves at most at its surface speed; the free hem at the wrist, kicked by the instant
# start and the instant reversal of the linear keys, whips at up to about twice that. Around the
# crease (within 0.15 m of the joint) the sleeve is carried at <= 0.15 m * 2.44 rad/s = 0.37 m/s
# or pushed ahead of the crease, whose crossing point runs along the upper arm at
# r w / (2 cos^2(angle / 2)) <= 0.50 m/s (at 140 degrees): a calm sleeve stays below the tip
# speed there; one caught at zero gap and thrown out of the crease does not.
RATE = np.radians(140.0) / (24 / 24.0)  # rad/s: 140 degrees in 24 frames at 24 fps
TIP_SPEED = 0.3 * RATE  # 0.73 m/s
SPEED_BOUND = 2.0 * TIP_SPEED  # 1.47 m/s, any sleeve vertex
PINCH_SPEED_BOUND = TIP_SPEED  # 0.73 m/s, sleeve vertices within 0.15 m of the joint


#: the defaults before issue #13 (graphs/bench/cloth_strain.py 'before')
BEFORE = {"stretch": {"long_range_levels": 0, "sweeps": 1, "inextensible_compression": None},
          "strain_limit": {"inextensible_max_strain": None}}


def _scene_text(mechanisms, overrides=None):
    text = (EXAMPLES / "sleeve_elbow.yaml").read_text()
    if overrides:
        import json

        text = text.replace("lokigraph: 1\n", f"lokigraph: 1\ngraph_overrides: "
                            f"{json.dumps(overrides)}\n", 1)
        assert "graph_overrides" in text
    if not mechanisms:  # no compliant kinematics, proximity tolerance and recovery off
        new = text.replace("Kinematic: {stiffness: soft}", "Kinematic: {}")
        new = re.sub(r"\n +stiffness: soft *\n", "\n", new)
        new = new.replace("methods: [vertex_face, edge_edge, self]}",
                          'methods: [vertex_face, edge_edge, self], proximity_tolerant: "off", '
                          'recover_crossings: false}')
        assert "stiffness: soft" not in new and 'proximity_tolerant: "off"' in new
        # and the CCD safe step off: it holds every pair on the side it starts a substep on, so
        # a sleeve pushed through the arm stays through it (16 pairs to the end, measured) where
        # the old pipeline let it come back out; this variant shows the pipeline without them
        new = new.replace("lokigraph: 1\n", "lokigraph: 1\ngraph_overrides: {collisions: "
                          "{ccd: false}}\n", 1)
        assert "ccd: false" in new
        text = new
    return text


def _axis_distance(p, a, b):
    """Distance [m] of points p from the line through a and b."""
    d = (b - a) / np.linalg.norm(b - a)
    return np.linalg.norm(np.cross(p - a, d), axis=1)


def _elbow(tmp_path, mechanisms=True, frames=60, overrides=None):
    for m in MAPS:
        shutil.copy(EXAMPLES / m, tmp_path / m)
    p = tmp_path / f"elbow_{mechanisms}.yaml"
    p.write_text(_scene_text(mechanisms, overrides))
    c = compile_file(p)
    sim = Simulation(c)
    sl = c.scene.element("sleeve")
    arm = {n: c.scene.element(n) for n in ARM}
    comp = {n: c.model.particle_compliant[e.vertex_slice] for n, e in arm.items()}
    out = {"vmax": [], "vpinch": [], "self": [], "follow": [], "depth": [],
           "finite": True, **{f"pen_{n}": [] for n in ARM}}
    t0 = time.perf_counter()
    for _ in range(frames):
        sim.step_frame()
        q, v = sim.state.particle_q, sim.state.particle_qd
        out["finite"] &= bool(np.isfinite(q).all() and np.isfinite(v).all())
        speed = np.linalg.norm(v[sl.vertex_slice], axis=1)
        out["vmax"].append(speed.max())
        # the sleeve around the crease: within 0.15 m of the joint (the crease reaches 0.13 m)
        out["vpinch"].append(speed[np.linalg.norm(q[sl.vertex_slice], axis=1) < 0.15].max())
        cloth = (q[sl.vertex_slice], sl.geometry.triangles)
        out["self"].append(intersect_meshes([cloth], touching=False)[0])
        follow, depth = 0.0, 0.0
        for n, e in arm.items():
            _, pairs = intersect_meshes([cloth, (q[e.vertex_slice], e.geometry.triangles)],
                                        touching=False)
            out[f"pen_{n}"].append(int((pairs[:, 0] != pairs[:, 2]).sum()))  # sleeve-arm pairs
            qe, anim, k = q[e.vertex_slice], sim.control.kinematic_q[e.vertex_slice], comp[n]
            follow = max(follow, np.abs(qe[~k] - anim[~k]).max())
            if k.any():
                # tube caps: vertex -2 is the centre of the x = -L/2 end, -1 of the +L/2 end
                a, b = anim[-2], anim[-1]
                inward = _axis_distance(anim[k], a, b) - _axis_distance(qe[k], a, b)
                depth = max(depth, inward.max())
        out["follow"].append(follow)
        out["depth"].append(depth)
    out["seconds"] = time.perf_counter() - t0
    res = {k: np.array(v) if isinstance(v, list) else v for k, v in out.items()}
    res["pen"] = sum(res[f"pen_{n}"] for n in ARM)
    return res


def _report(r, label):
    pen = r["pen"]
    print(f"{label}: {r['seconds']:.1f} s; max sleeve speed {r['vmax'][3:].max():.3f} m/s "
          f"(frame {int(np.argmax(r['vmax'][3:])) + 5}), around the crease "
          f"{r['vpinch'][3:].max():.3f} m/s (frame {int(np.argmax(r['vpinch'][3:])) + 5}); "
          f"sleeve-arm intersections per frame "
          f"{pen.tolist()}; max inward recession {r['depth'].max() * 1000:.1f} mm; "
          f"sleeve self-intersections max {r['self'].max()}")


def test_elbow_bend_start_with_mechanisms(tmp_path):
    """The first 10 frames (the forearm bends to 58 degrees): finite, calm, no sleeve-arm
    intersection, the unpainted arm on its animation exactly and the compliant inner elbow
    already pushed in by the sleeve caught in the crease. Measured with the cloth settings
    before issue #13 (BEFORE), which this test pins: at the defaults the sleeve caught in the
    crease buckles (compliant compression near contacts) and pushes the elbow in by 1.73 mm at
    frame 11 (4.3 mm before); the slow tests run the whole bend at the defaults."""
    r = _elbow(tmp_path, mechanisms=True, frames=10, overrides=BEFORE)
    _report(r, "bend start")
    assert r["finite"]
    # measured with the sleeve with ease at the elbow (sleeve_elbow.yaml's header; the 0.056 m
    # tube before issue #13 in brackets)
    assert r["vmax"][3:].max() < SPEED_BOUND  # measured 1.11 m/s (the free hem, frame 5; 1.20)
    assert r["vpinch"][3:].max() < PINCH_SPEED_BOUND  # measured 0.66 m/s (0.56)
    assert (r["pen"] == 0).all()  # measured 0 in every frame
    assert r["follow"].max() == 0.0  # unpainted vertices follow their animation exactly
    assert r["depth"][-3:].max() > 0.002  # measured 4.3 mm at frame 11 (4.3)


@pytest.mark.slow
def test_sleeve_elbow_with_mechanisms(tmp_path):
    """The whole bend and straightening with the mechanisms: finite, calm, no intersection
    between the sleeve and the arm in any frame (the full bend included, so nothing has to
    recover after straightening), the unpainted arm exactly on its animation, and the compliant
    inner elbow receding in the crease and coming back when the arm straightens."""
    r = _elbow(tmp_path, mechanisms=True)
    _report(r, "with mechanisms")
    assert r["finite"]
    assert r["vmax"][3:].max() < SPEED_BOUND  # measured 1.01 m/s (the hem, frame 5; 1.05)
    # measured 0.673 m/s (frame 27) and 0.658 m/s at 14 solver iterations with the sleeve with
    # ease at the elbow (0.062 m / 0.064 m to past the elbow: 0.778 m/s at 15 iterations /
    # 0.755 m/s at 14, over the bound; sleeve_elbow.yaml's header). The 0.056 m tube before:
    # 0.587 m/s (frame 16); 0.682, 0.635, 0.550 m/s at 14, 16, 17 solver iterations
    # (test_sleeve_elbow_compression_near_contacts). With the defaults before issue #13 it was
    # 0.65 m/s at 15 iterations but 1.27, 1.29, 1.22 m/s at 14, 16, 17: the frame-end
    # maximum is the residue of a fight the Gauss-Seidel iterations do not settle
    assert r["vpinch"][3:].max() < PINCH_SPEED_BOUND
    assert (r["pen"] == 0).all()  # measured 0 in every frame
    assert (r["self"] == 0).all()  # measured 0: the sleeve never passes through itself
    assert r["follow"].max() == 0.0  # unpainted vertices follow their animation exactly
    # around full bend (frames 21-29) the crease pushed the compliant surface in by centimetres
    assert r["depth"][19:28].max() > 0.01  # measured 26.8 mm (31.8 mm at frame 25 before)
    # after straightening it is back on its animation up to the sag under the sleeve's weight
    # (the painted band reaches round towards the top of the arm the sleeve hangs on)
    assert r["depth"][-6:].max() < 0.002  # measured 0.7 mm (0.6 mm)


@pytest.mark.slow
def test_sleeve_elbow_compression_near_contacts(tmp_path):
    """The cause of the crease speed and what holds it, at 14 solver iterations instead of
    15 (the frame-end maximum around the crease turns on the iteration count where the
    Gauss-Seidel iterations leave a fight unsettled). Inextensible cloth whose edges are hard
    in compression too (``stretch.inextensible_compression`` null): in the closing crease the
    sleeve must shorten, and its compression rows fight the contacts, the long-range rows and
    the strain limit (a vertex's edges at -20 % and +20 % strain in one iteration, the vertex
    moved 3-4 mm back and forth in every iteration); the frame-end speed is the residue, over
    the forearm's tip speed (measured 1.157 m/s, frame 19; with the 0.056 m tube before the
    sleeve's ease at the elbow 0.947 m/s, frame 24; 0.86, 1.15, 1.39 m/s at 15-17).
    With the defaults (edges near contacts compliant in compression, 10 N/m: the cloth
    buckles) the sleeve stays calm (measured 0.658 m/s, frame 28; 0.682 m/s, frame 22 before),
    without intersections."""
    hard = _elbow(tmp_path, mechanisms=True, overrides={
        "nucleus_solver": {"iterations": 14}, "stretch": {"inextensible_compression": None}})
    _report(hard, "14 iterations, hard compression")
    assert hard["finite"]
    assert hard["vpinch"][3:].max() > PINCH_SPEED_BOUND
    r = _elbow(tmp_path, mechanisms=True, overrides={"nucleus_solver": {"iterations": 14}})
    _report(r, "14 iterations, defaults")
    assert r["finite"]
    assert r["vmax"][3:].max() < SPEED_BOUND  # measured 0.99 m/s (frame 5; 1.04 before)
    assert r["vpinch"][3:].max() < PINCH_SPEED_BOUND
    assert (r["pen"] == 0).all()  # measured 0 in every frame
    assert (r["self"] == 0).all()  # measured 0
    assert r["depth"][19:28].max() > 0.01  # measured 26.7 mm (30.5 mm at frame 25 before)


@pytest.mark.slow
def test_sleeve_elbow_without_mechanisms(tmp_path):
    """No compliant kinematics, proximity tolerance off: the sleeve caught in the crease around
    full bend is pushed through the arm and thrown out of the crease; it comes back out of the
    arm while the elbow straightens, but stays tangled through itself. Measured and reported;
    only the clear signals are asserted."""
    r = _elbow(tmp_path, mechanisms=False)
    _report(r, "without mechanisms")
    assert r["finite"]
    # measured: sleeve-arm intersections in frames 23-26 only (16, 62, 96, 54; with the 0.056 m
    # tube before the sleeve's ease at the elbow 44, 88, 176, 72), 0 again from frame 27
    # (frames 23-29 with the cloth defaults before issue #13: 18 to 120 pairs)
    assert r["pen"][19:30].max() > 20
    assert (r["pen"][-12:] == 0).all()
    # measured 0.84 m/s around the crease at frame 25 (0.83 m/s at frame 27 with the 0.056 m
    # tube; 0.67 m/s with the mechanisms; 1.21 with the cloth defaults before issue #13); the
    # overall maximum 1.05 m/s (frame 26; the hem's 1.02 m/s, frame 5, with the 0.056 m tube)
    assert r["vpinch"][3:].max() > PINCH_SPEED_BOUND
    assert r["follow"].max() == 0.0 and r["depth"].max() == 0.0  # nothing is compliant
    # the sleeve stays through itself after the arm straightens: 18 pairs at frame 61 with the
    # 0.056 m tube (reported; 27 with the cloth defaults before issue #13; with the sleeve with
    # ease at the elbow up to 26 pairs in a frame)
