"""The knee of graphs/examples/trouser_knee.yaml with ``solver: implicit`` (issue #11), the first
24 frames (the bend to 150 degrees), measured as tests/test_knee.py measures the Nucleus run.

Open: the implicit solver keeps the trouser out of the leg (0 intersecting pairs in every frame)
but not the Nucleus speed bound: measured up to 4.95 m/s in frames 8-25 (11 m/s at frame 29 of the
whole run), with Newton at its 20-iteration cap in every substep, with the compliant back of the
knee held at its animation in the solve (``compliant_kinematics: dirichlet``, the default) or
made an unknown of it (``energy``: 10 m/s, the compliant surface receding 14 cm). Figures and
the other settings tried: graphs/bench/implicit_knee.py and the solver's Field descriptions.
"""

import pytest

from conftest import EXAMPLES
from test_knee import SPEED_BOUND, knee_run

FRAMES = 24


@pytest.fixture(scope="module")
def knee_implicit(tmp_path_factory):
    text = (EXAMPLES / "trouser_knee.yaml").read_text()
    assert text.count("lokigraph: 1\n") == 1
    text = text.replace("lokigraph: 1\n", "lokigraph: 1\nsolver: implicit\n", 1)
    r = knee_run(frames=FRAMES, scene_text=text, tmp_path=tmp_path_factory.mktemp("knee"))
    print(f"knee (implicit): cpu {r['cpu_s']:.1f} s, pairs {r['pen'].tolist()}, self max "
          f"{r['self'].max()}, vmax {r['vmax'].round(2).tolist()}")
    return r


@pytest.mark.slow
def test_implicit_knee_no_intersections(knee_implicit):
    r = knee_implicit
    assert r["finite"]
    assert (r["pen"] == 0).all()  # measured 0 in every frame
    assert (r["self"] == 0).all()  # measured 0


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="issue #11 open: the implicit knee exceeds the Nucleus "
                   "speed bound (measured 4.95 m/s against 2.2 m/s in frames 8-25)")
def test_implicit_knee_speed_bound(knee_implicit):
    assert knee_implicit["vmax"][6:].max() < SPEED_BOUND
