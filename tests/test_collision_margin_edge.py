"""contacts.MARGIN_EDGE (opt-in): the detection margin of a vertex is at most that many times
the shortest mesh edge at it. Where it does not bind (coarse meshes) the positions are bitwise
those without it; where it does, the boxes, the CCD's coverage bound (``infl_min``) and the rows
follow the smaller margin, and a fine cloth dropped on a sphere stays free of intersections."""

from pathlib import Path

import numpy as np
import pytest

from lokigraph.api import compile_file
from lokigraph.behaviors.collision import contacts as C
from lokigraph.behaviors.collision.intersect import find_intersections
from lokigraph.run import Simulation

_SRC = Path(__file__).resolve().parents[1] / "graphs" / "bench" / "cloth_sphere_64.yaml"


def _scene(tmp_path, res, size=None):
    text = _SRC.read_text().replace("resolution: [64, 64]", f"resolution: [{res}, {res}]")
    if size is not None:
        assert "size: [1.0, 1.0]" in text
        text = text.replace("size: [1.0, 1.0]", f"size: [{size}, {size}]")
    path = tmp_path / f"drop_{res}.yaml"
    path.write_text(text)
    return path


def _sim(path, monkeypatch, scale):
    monkeypatch.setattr(C, "MARGIN_EDGE", scale)
    sim = Simulation(compile_file(path))
    return sim, sim.state.fields["contacts"]


def test_edge_margin_is_the_shortest_edge_scaled_at_most_the_margin():
    q = np.array([[0.0, 0, 0], [0.004, 0, 0], [0.004, 0.010, 0], [0.5, 0, 0]])
    edges = np.array([[0, 1], [1, 2]])
    m = C._edge_margin(q, edges, 5, 0.002, 0.3)
    assert m[0] == m[1] == pytest.approx(0.3 * 0.004)  # the 4 mm edge
    assert m[2] == 0.002  # 0.3 x 10 mm = 3 mm, over the margin
    assert m[3] == m[4] == 0.002  # no edge


def test_coarse_mesh_unchanged_bitwise(tmp_path, monkeypatch):
    path = _scene(tmp_path, 20)  # 50 mm edges: 0.3 x 50 mm over the 2 mm margin everywhere
    out = []
    for scale in (0.0, 0.3):
        sim, d = _sim(path, monkeypatch, scale)
        assert (d.groups[0].margin_v is None) == (scale == 0.0)
        for _ in range(7):
            sim.step_frame()
        out.append(sim.state.particle_q.tobytes())
    assert out[0] == out[1]


def test_fine_cloth_margin_follows_edges_and_stays_free(tmp_path, monkeypatch):
    """A 0.15 m cloth at 48 x 48 (3.1 mm edges: a 0.94 mm margin with 0.3) dropped on the
    sphere: smaller boxes and CCD bound than with the 2 mm margin, fewer rows at the first
    contact detections, and no intersecting triangle pair in any frame."""
    path = _scene(tmp_path, 48, 0.15)
    rows = {}
    for scale in (0.0, 0.3):
        sim, d = _sim(path, monkeypatch, scale)
        g = d.groups[0]
        cloth = g.verts[g.vert_elem[g.verts] == 0]
        infl = C._infl(g)
        if scale:
            edge = 0.15 / 48
            assert g.margin_v[cloth].max() == pytest.approx(0.3 * edge)
            assert infl[cloth].max() == pytest.approx(0.002 + 0.15 * edge)
        else:
            assert infl[cloth].max() == pytest.approx(0.003)
        n = 0
        for f in range(8):  # contact from frame 6
            sim.step_frame()
            n += len(d.vf) + len(d.ee)
            q = sim.state.particle_q
            tris = np.concatenate([e.geometry.triangles + e.vertex_offset
                                   for e in sim.model.elements if e.geometry is not None])
            assert find_intersections(q, tris, touching=False).count == 0, f"frame {f + 1}"
        C._set_infl_min(d)
        rows[scale] = (n, d.infl_min)
    assert rows[0.3][1] < rows[0.0][1]
    assert rows[0.3][0] < rows[0.0][0]
