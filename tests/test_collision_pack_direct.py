"""contacts.PACK_DIRECT: the filters write their rows straight into the packed arrays, group
after group; every detection's packed arrays (rows, normals, targets, friction, one-sided
flags, strengths) and the positions are bitwise those of the filters' own buffers copied by
``_pack`` (False), with two collision groups of different strength and friction scale, and
with ``_detect_group`` wrapped (a caller that returns copies gets them packed as before)."""

from pathlib import Path

import numpy as np
import pytest

from lokigraph.api import compile_file
from lokigraph.behaviors.collision import contacts as C
from lokigraph.run import Simulation

_ARRAYS = ("vf", "vf_n", "vf_target", "vf_mu", "vf_onesided", "strength", "ee", "ee_n",
           "ee_target", "ee_mu", "ee_strength")


def _scene(tmp_path):
    src = Path(__file__).resolve().parents[1] / "graphs" / "bench" / "cloth_sphere_64.yaml"
    text = src.read_text().replace("resolution: [64, 64]", "resolution: [20, 20]")
    text = text.replace("output:", """  - name: second
    components:
      CollisionGroup: {members: [cloth], methods: [vertex_face, edge_edge, self]}
      CollisionResponse: {strength: 0.5, damping: 0.0, friction_scale: 0.7}
output:""")
    path = tmp_path / "two_groups.yaml"
    path.write_text(text)
    return path


def _run(path, monkeypatch, direct, wrap=False, frames=7):
    monkeypatch.setattr(C, "PACK_DIRECT", direct)
    seen = []
    cull = C._cull

    def record(d, x1):
        seen.append([getattr(d, k).copy() for k in _ARRAYS])
        return cull(d, x1)

    monkeypatch.setattr(C, "_cull", record)
    if wrap:
        orig = C._detect_group

        def copies(*a, **k):
            vf, ee, t = orig(*a, **k)
            return (tuple(np.copy(v) for v in vf), tuple(np.copy(v) for v in ee), t)

        monkeypatch.setattr(C, "_detect_group", copies)
    sim = Simulation(compile_file(path))
    for _ in range(frames):
        sim.step_frame()
    monkeypatch.undo()
    return seen, sim.state.particle_q.copy()


@pytest.mark.parametrize("wrap", [False, True])
def test_direct_pack_is_bitwise_the_copied_pack(tmp_path, monkeypatch, wrap):
    path = _scene(tmp_path)
    ref, q_ref = _run(path, monkeypatch, False)
    new, q_new = _run(path, monkeypatch, True, wrap)
    assert q_ref.tobytes() == q_new.tobytes()
    assert len(ref) == len(new) and len(ref) > 20
    strengths = set()
    for a, b in zip(ref, new):
        for u, w in zip(a, b):
            assert u.dtype == w.dtype and u.shape == w.shape
            assert u.tobytes() == w.tobytes()
        strengths |= set(np.unique(a[_ARRAYS.index("ee_strength")]).tolist())
    # both groups contributed rows to the same detections
    assert {0.5, 1.0} <= strengths
    assert max(len(a[0]) for a in ref) > 1000
