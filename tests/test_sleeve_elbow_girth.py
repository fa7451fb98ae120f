"""graphs/bench/sleeve_elbow_girth.py: the shortest loop around the arm in a plane (issue #13,
sleeve_elbow): a loop must enclose the arm's centreline a net once, its length is the convex
hull's perimeter of the enclosed section plus 2 pi times the collision distance."""

import math
import sys

import numpy as np
import pytest

from conftest import EXAMPLES
from lokigraph.generators import tube

sys.path.insert(0, str(EXAMPLES.parent / "bench"))
try:
    import sleeve_elbow_girth as sg
finally:
    sys.path.pop(0)


def _cyl(radius, y=0.0, na=32):
    g = tube(radius=radius, length=0.4, segments=(na, 8), axis="x", center=(0.0, y, 0.0),
             capped=True)
    return np.asarray(g.points), np.asarray(g.triangles)


def test_plane_girth_straight_cylinder():
    """A plane across a straight capped tube: the 32-gon's perimeter plus 2 pi GAP; a tilted
    plane's ellipse is longer; a plane that misses the centreline has no loop."""
    V, F = _cyl(0.05)
    axis = np.array([[-1.0, 0, 0], [1.0, 0, 0]])
    got = sg.plane_girth([(V, F)], axis, np.zeros(3), np.array([1.0, 0, 0]))
    assert got == pytest.approx(64 * 0.05 * math.sin(math.pi / 32) + 2 * math.pi * sg.GAP)
    n = np.array([math.cos(0.5), math.sin(0.5), 0.0])
    assert sg.plane_girth([(V, F)], axis, np.zeros(3), n) > got * 1.05
    # a plane along the axis (no crossing of the centreline): no ring can sit in it
    assert sg.plane_girth([(V, F)], axis + [0, 0, 0.01], np.zeros(3),
                          np.array([0, 0, 1.0])) == math.inf


def test_plane_girth_folded_centreline():
    """Two parallel tubes, the centreline up one and back down the other (a fold, as the
    upper arm and the forearm near full bend): a plane across both crosses it twice in opposite
    directions. Touching (closer than 2 GAP), no loop links it once; apart, a loop around
    either tube does."""
    r = 0.05
    for y, want in ((2 * r + 0.004, math.inf), (2 * r + 0.02, None)):
        a, b = _cyl(r), _cyl(r, y=y)
        axis = np.array([[-1.0, 0, 0], [0.3, 0, 0], [0.3, y, 0], [-1.0, y, 0]])
        got = sg.plane_girth([a, (b[0], b[1])], axis, np.zeros(3), np.array([1.0, 0, 0]))
        one = 64 * r * math.sin(math.pi / 32) + 2 * math.pi * sg.GAP
        assert got == (want if want is not None else pytest.approx(one))


def test_sleeve_elbow_at_rest_nothing_forced():
    """The scene as animated at frame 0 (straight arm): every ring's loop is well under its
    rest girth (the sleeve has 12 mm of ease over the upper arm)."""
    arm = sg.Arm(sg.SCENE)
    meshes, axis, d = arm.pose(0)
    for ring in (4, 9, 13):
        best = min(sg.plane_girth(meshes, axis, c, n)
                   for c, n in sg._ring_family(arm, ring, d, 0.0175, 40))
        assert best < arm.ring_rest[ring] * 0.9
    assert arm.angle(0) == 0.0 and arm.angle(24) == pytest.approx(140.0)


def test_sleeve_elbow_sleeve_mesh_is_the_scripts():
    """graphs/examples/sleeve_elbow_sleeve.obj is sleeve_mesh() as written (vertex order kept:
    the scene's cuff channel names ring 0), resting on the top of the arm at the collision
    distance and centred on it in y."""
    from lokigraph.api import compile_file

    c = compile_file(sg.SCENE)
    sl = c.scene.element("sleeve")
    P, F = sg.sleeve_mesh()
    assert np.allclose(c.model.particle_rest[sl.vertex_slice], P, atol=1e-8)
    assert np.array_equal(sl.geometry.triangles, F)
    R = P.reshape(17, 24, 3)
    assert np.allclose(R[:, 6, 2], np.where(R[:, 6, 0] < 0, 0.048, 0.045) + sg.GAP)  # the top
    assert np.allclose(R[:, :, 1].mean(1), 0.0, atol=1e-12)
