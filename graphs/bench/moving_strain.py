"""Edge strain per frame of the cloth on the moving, spinning sphere
(graphs/bench/cloth_sphere_moving_128.yaml) at a chosen resolution, with graph overrides: CPU
per frame, worst edge strain, its 99.9th percentile, the edges over 5 % and the frame's
global-step and CCD statistics. One setting per process (run settings back to back and
compare CPU within a run of the same load).

    NUMBA_NUM_THREADS=1 python graphs/bench/moving_strain.py 128 24 \
        "{strain_limit: {global_smooth: 100}}"

Arguments: resolution (N x N cloth), frames, optional graph_overrides as YAML flow text.
"""

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lokigraph.api import compile_file
from lokigraph.behaviors.collision.broadphase import mesh_edges
from lokigraph.run import Simulation

SCENE = Path(__file__).resolve().parent / "cloth_sphere_moving_128.yaml"


def main(argv):
    res = int(argv[0]) if argv else 128
    frames = int(argv[1]) if len(argv) > 1 else 24
    text = SCENE.read_text().replace("resolution: [128, 128]", f"resolution: [{res}, {res}]")
    if len(argv) > 2:
        text = text.replace("lokigraph: 1\n", f"lokigraph: 1\ngraph_overrides: {argv[2]}\n", 1)
    path = Path(tempfile.mkdtemp()) / "moving.yaml"
    path.write_text(text)
    c = compile_file(path)
    sim = Simulation(c)
    cloth = c.scene.element("cloth")
    sl = cloth.vertex_slice
    E = mesh_edges(cloth.geometry.triangles)
    X0 = c.model.particle_rest[sl]
    L0 = np.linalg.norm(X0[E[:, 0]] - X0[E[:, 1]], axis=1)
    print("| frame | CPU s | worst edge % | p99.9 % | edges > 5 % | global passes | CCD hits |")
    print("|---|---|---|---|---|---|---|")
    for f in range(frames):
        t0 = time.process_time()
        st = sim.step_frame()
        cpu = time.process_time() - t0
        q = sim.state.particle_q[sl]
        s = np.linalg.norm(q[E[:, 0]] - q[E[:, 1]], axis=1) / L0 - 1.0
        print(f"| {f + 1} | {cpu:.2f} | {100 * s.max():.1f} | {100 * np.quantile(s, 0.999):.1f} "
              f"| {int((s > 0.05).sum())} | {st.get('max_global_strain_passes', 0):.0f} "
              f"| {st.get('ccd_hits', 0):.0f} |", flush=True)
    print(json.dumps({"resolution": res, "frames": frames,
                      "overrides": argv[2] if len(argv) > 2 else None}))


if __name__ == "__main__":
    main(sys.argv[1:])
