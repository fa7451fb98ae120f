"""Strain limits in the implicit solve (issue #11, ``strain_limit.implicit``): worst edge strain,
intersecting pairs and CPU of each setting, one run after the other in one process.

    NUMBA_NUM_THREADS=1 python graphs/bench/implicit_strain_limit.py pushed 1:energy 1:projection 4:energy 4:projection
    NUMBA_NUM_THREADS=1 python graphs/bench/implicit_strain_limit.py drop 64 12 energy projection

``pushed SUBSTEPS:IMPLICIT[:MODE] ...``: the pushed cloth of tests/test_strain_limit.py (a soft
20 x 20 cloth, E t = 0.3 N/m, max_strain 0.1, pinned at two sides, pushed up by a kinematic ball;
36 frames) with ``solver: implicit``; MODE ``constitutive`` (default) or ``post``. ``drop N
FRAMES IMPLICIT ...``: graphs/bench/cloth_sphere_64.yaml at N x N with ``solver: implicit``, one
substep and a painted ``max_strain: 0.01``; per run the worst edge strain (and its frame), the
largest count of intersecting cloth triangle pairs and the CPU per frame from frame 6 on.
"""

from __future__ import annotations

import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))


def pushed(specs, tmp):
    from conftest import write_scene
    from test_strain_limit import measure, pushed_cloth

    for spec in specs:
        sub, impl, *mode = spec.split(":")
        mode = mode[0] if mode else "constitutive"
        path = write_scene(tmp, pushed_cloth(mode, frames=36, substeps=int(sub),
                                             head="solver: implicit\n    ",
                                             overrides=f", implicit: {impl}"),
                           f"pushed_{sub}_{impl}_{mode}.yaml")
        t = time.process_time()
        s, pen, _, _ = measure(path, 36)
        cpu = time.process_time() - t
        print(f"{mode:12s} {impl:10s} substeps {sub}: worst {100 * s.max():.2f} % (frames 9-36 "
              f"{100 * s[8:].max():.2f} %), pairs with the ball max {pen.max()} in "
              f"{(pen > 0).sum()} frames, CPU {cpu:.1f} s", flush=True)


def drop(n, frames, impls, tmp):
    from lokigraph.api import compile_file
    from lokigraph.behaviors.collision.intersect import intersect_meshes
    from lokigraph.bench.sweep import max_strain
    from lokigraph.run import Simulation

    base = (ROOT / "graphs" / "bench" / "cloth_sphere_64.yaml").read_text()
    for impl in impls:
        s = base.replace("resolution: [64, 64]", f"resolution: [{n}, {n}]")
        s = s.replace("lokigraph: 1", "lokigraph: 1\nsolver: implicit", 1)
        s = re.sub(r"substeps: \d+", "substeps: 1", s)
        s = s.replace("DiscreteShell: {", "DiscreteShell: {max_strain: 0.01, ", 1)
        s += f"\ngraph_overrides: {{strain_limit: {{implicit: {impl}}}}}\n"
        path = tmp / f"drop_{n}_{impl}.yaml"
        path.write_text(s)
        c = compile_file(path)
        sim = Simulation(c)
        cl = c.scene.element("cloth")
        rows = []
        for _ in range(frames):
            t = time.process_time()
            sim.step_frame()
            dt = time.process_time() - t
            q = sim.state.particle_q
            _, pairs = intersect_meshes([(q[cl.vertex_slice], cl.geometry.triangles)],
                                        touching=False)
            rows.append((max_strain(c, q), len(pairs), dt))
        a = np.array(rows)
        print(f"{impl:10s} {n}x{n}: worst {100 * a[:, 0].max():.2f} % (frame "
              f"{int(a[:, 0].argmax()) + 1}), pairs max {int(a[:, 1].max())}, CPU "
              f"{a[5:, 2].mean():.2f} s a frame (frames 6-{frames})", flush=True)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] not in ("pushed", "drop"):
        print(__doc__)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        if argv[0] == "pushed":
            pushed(argv[1:] or ["1:energy", "1:projection"], Path(tmp))
        else:
            drop(int(argv[1]), int(argv[2]), argv[3:] or ["energy", "projection"], Path(tmp))
    return 0


if __name__ == "__main__":
    sys.exit(main())
