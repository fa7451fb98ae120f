"""A walking skirt (graphs/examples/skirt_walk.yaml, issue #13): default inextensible cloth at the
default Nucleus settings, on a hip that sways while two legs swing +-20 degrees at a 1 s stride
and the body walks at 1 m/s.

What holds today and is asserted: finite, no skirt-body intersection in any frame, the skirt
carried along (its centre keeps up with the hip). The issue's target, under 2 % max edge strain
in every frame, does NOT hold at the defaults: measured 8.0 % worst frame (hem edges at the leg
extremes, frames 24, 36, 48), 6.8 % with ``chebyshev_rho: 0.9``; the test records the figure
and bounds it at today's level so a regression shows.
"""

import numpy as np

from conftest import EXAMPLES
from lokigraph.api import compile_file
from lokigraph.behaviors.collision.intersect import intersect_meshes
from lokigraph.bench.sweep import worst_strain
from lokigraph.run import Simulation


def test_skirt_walk():
    c = compile_file(EXAMPLES / "skirt_walk.yaml")
    sim = Simulation(c)
    skirt = c.scene.element("skirt")
    bodies = [c.scene.element(n) for n in ("hip", "left_leg", "right_leg")]
    strain, pairs = [], []
    for _ in range(c.scene.spec.frames.end - c.scene.spec.frames.start):
        sim.step_frame()
        q = sim.state.particle_q
        assert np.isfinite(q).all()
        strain.append(worst_strain(c, q)[0])
        cloth = (q[skirt.vertex_slice], skirt.geometry.triangles)
        n = 0
        for b in bodies:
            _, pr = intersect_meshes([cloth, (q[b.vertex_slice], b.geometry.triangles)],
                                     touching=False)
            n += int((pr[:, 0] != pr[:, 2]).sum())
        pairs.append(n)
    print(f"skirt_walk: worst-frame strain {100 * max(strain):.1f} %, median "
          f"{100 * np.median(strain):.1f} %, skirt-body pairs {max(pairs)}")
    assert max(pairs) == 0  # measured 0 in every frame
    assert max(strain) < 0.10  # measured 8.0 % (the target is 2 %: not met)
    hip = sim.state.particle_q[bodies[0].vertex_slice].mean(0)
    centre = sim.state.particle_q[skirt.vertex_slice].mean(0)
    assert abs(centre[2] - hip[2]) < 0.1  # walked 1.75 m and the skirt came along
