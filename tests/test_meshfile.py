"""Mesh files: OBJ/PLY/VTU reading (uv, normals, colours, groups, polylines), size limits,
writing with uv/normals/velocities/polylines, round trips, and validate of a large mesh.

Benchmark (10^6 vertices, 1996002 triangles, Dynamic + DiscreteShell + one pin)::

    python tests/test_meshfile.py 1000 /tmp/big      # writes big_bin.ply, big_asc.ply, big.obj
    time python -m lokigraph validate /tmp/big/big_bin_ply.yaml   # and big_asc_ply, big_obj

Measured on the 2-core development machine (shared, so wall times vary): before 40.4 s wall
and 1.43 GB for the binary PLY (352 s reported in issue 10); after: see the numbers printed
by the lead's closing note / the report of this change.
"""

import time

import meshio
import numpy as np
import pytest

from lokigraph import meshfile
from lokigraph.geometry import Geometry, MeshReadError
from lokigraph.meshfile import curve_chains, read_mesh, vertex_normals, write_mesh

QUAD_OBJ = """\
# two triangles of a unit square, with uv and normals
v 0 0 0 1 0 0
v 1 0 0 0 1 0
v 1 1 0 0 0 1
v 0 1 0 0.5 0.5 0.5
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 1
g front
f 1/1/1 2/2/1 3/3/1
g back
f 1/1/1 3/3/1 4/4/1
"""


def _obj(tmp_path, text, name="m.obj"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _grid(m=4):
    x, z = np.meshgrid(np.linspace(0, 1, m), np.linspace(0, 1, m), indexing="ij")
    pts = np.stack([x.ravel(), np.zeros(m * m), z.ravel()], 1)
    i = np.arange(m * m).reshape(m, m)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()
    return pts, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


# ----------------------------------------------------------------------------- OBJ reading

def test_obj_uv_normals_colours_groups(tmp_path):
    g = read_mesh(_obj(tmp_path, QUAD_OBJ))
    assert g.points.shape == (4, 3) and g.triangles.tolist() == [[0, 1, 2], [0, 2, 3]]
    assert np.allclose(g.channels["color"][1], [0, 1, 0])
    assert g.has_uv and g.uv.shape == (4, 2) and g.tri_uv.tolist() == [[0, 1, 2], [0, 2, 3]]
    assert g.has_normals and g.normals.shape == (1, 3) and np.all(g.tri_normals == 0)
    assert g.groups["front"].tolist() == [0, 1, 2] and g.groups["back"].tolist() == [0, 2, 3]
    assert np.allclose(g.vertex_uv(), [[0, 0], [1, 0], [1, 1], [0, 1]])
    assert g.problems() == []


def test_obj_forms_negative_polygons_polylines(tmp_path):
    text = """\
  v 0 0 0
v 1 0 0\r
v 1 1 0   # trailing comment
v 0 1 0
o body
f -4//1 -3//1 -2//1 -1//1
vn 0 0 1
v 2 0 0
v 3 0 0
g hair strand
l -2 -1
l 1/1 2/1
"""
    g = read_mesh(_obj(tmp_path, text))
    assert g.vertex_count == 6
    assert g.triangles.tolist() == [[0, 1, 2], [0, 2, 3]]  # quad fan, negative indices
    assert g.edges.tolist() == [[4, 5], [0, 1]]
    assert g.has_normals  # positive indices may refer to 'vn' lines further down
    assert g.groups["body"].tolist() == [0, 1, 2, 3, 4, 5]
    assert g.groups["hair"].tolist() == [0, 1, 4, 5] and "strand" in g.groups


def test_obj_mixed_index_forms_use_slow_path(tmp_path):
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nf 1 2 3\nf 2/1 4/1 3/1\n"
    g = read_mesh(_obj(tmp_path, text))
    assert g.triangles.tolist() == [[0, 1, 2], [1, 3, 2]]
    assert not g.has_uv  # only some faces have uv: dropped


@pytest.mark.parametrize("text, match", [
    ("v 0 0 0\nv 1 0\n", r"m\.obj:2: cannot parse OBJ 'v' line"),
    ("v 0 0 0\nv 1 0 x\n", r":2: cannot parse"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", r":4: vertex index 9 out of range"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -4\n", r":4: vertex index -4 out of range"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n", r":4: vertex index 0"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 " + str(2 ** 70) + "\n", r":4: cannot parse OBJ 'f'"),
    ("v 0 0 0\nv 1 0 0\nf 1 2\n", r":3: a face needs at least 3"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3.5\n", r":4: cannot parse OBJ 'f' index"),
    ("# nothing\n", r"no vertices"),
    ("", r"no vertices"),
])
def test_obj_errors_name_the_line(tmp_path, text, match):
    with pytest.raises(MeshReadError, match=match):
        read_mesh(_obj(tmp_path, text))


def test_obj_nan_coordinates_reported_by_problems(tmp_path):
    g = read_mesh(_obj(tmp_path, "v nan 0 0\nv inf 0 0\nv 0 1 0\nf 1 2 3\n"))
    assert any("non-finite" in p for p in g.problems())


def test_size_limits_checked_before_allocation(tmp_path, monkeypatch):
    monkeypatch.setattr(meshfile, "MAX_VERTICES", 3)
    with pytest.raises(MeshReadError, match="4 vertices exceed the limit of 3"):
        read_mesh(_obj(tmp_path, "v 0 0 0\n" * 4))
    ply = tmp_path / "big.ply"
    ply.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99999999999\n"
                    b"property float x\nproperty float y\nproperty float z\nend_header\n")
    monkeypatch.undo()
    with pytest.raises(MeshReadError, match="99999999999 vertex elements exceed the limit of "
                                            "20000000"):
        read_mesh(ply)


# ----------------------------------------------------------------------------- PLY reading

@pytest.mark.parametrize("binary", [True, False])
def test_ply_reader_matches_meshio_with_attributes(tmp_path, binary):
    pts, tris = _grid(5)
    n = len(pts)
    rng = np.random.default_rng(1)
    cols = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    pd = {"nx": np.zeros(n), "ny": np.ones(n), "nz": np.zeros(n), "s": pts[:, 0], "t": pts[:, 2],
          "red": cols[:, 0], "green": cols[:, 1], "blue": cols[:, 2], "stiff": rng.random(n)}
    p = tmp_path / "a.ply"
    meshio.write(p, meshio.Mesh(pts, [("triangle", tris)], point_data=pd), binary=binary)
    g = read_mesh(p)
    assert np.array_equal(g.points, pts) and np.array_equal(g.triangles, tris)
    assert np.allclose(g.channels["color"], cols / 255.0)
    assert g.has_normals and np.allclose(g.normals, [0, 1, 0])
    assert g.has_uv and np.array_equal(g.vertex_uv(), pts[:, [0, 2]])
    assert np.allclose(g.channels["stiff"], pd["stiff"])


def test_ply_mixed_polygons_and_big_endian(tmp_path):
    body = b"".join(np.array(r, ">f4").tobytes() for r in [[0, 0, 0], [1, 0, 0], [1, 1, 0],
                                                            [0, 1, 0], [2, 0, 0]])
    faces = (np.array([4], "u1").tobytes() + np.array([0, 1, 2, 3], ">i4").tobytes()
             + np.array([3], "u1").tobytes() + np.array([1, 4, 2], ">i4").tobytes())
    p = tmp_path / "b.ply"
    p.write_bytes(b"ply\nformat binary_big_endian 1.0\nelement vertex 5\nproperty float x\n"
                  b"property float y\nproperty float z\nelement face 2\n"
                  b"property list uchar int vertex_indices\nend_header\n" + body + faces)
    g = read_mesh(p)
    assert g.vertex_count == 5 and sorted(map(tuple, g.triangles.tolist())) == [
        (0, 1, 2), (0, 2, 3), (1, 4, 2)]


@pytest.mark.parametrize("content, match", [
    (b"ply", "no 'end_header'"),
    (b"ply\n", "no 'end_header'"),
    (b"", "not a PLY file"),
    (b"ply\nformat ascii 1.0\nelement vertex -3\nproperty float x\nend_header\n",
     "negative element count"),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 1000\nproperty float x\n"
     b"property float y\nproperty float z\nend_header\n" + b"\0" * 100,
     "needs? at least 12000"),
    (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
     b"property float z\nend_header\n0 0 0\n1 0 0\n", "ends inside element 'vertex'"),
])
def test_ply_header_checks(tmp_path, content, match):
    p = tmp_path / "bad.ply"
    p.write_bytes(content)
    with pytest.raises(MeshReadError, match=match):
        read_mesh(p)


@pytest.mark.parametrize("name, content", [
    ("junk.vtu", b"<VTKFile junk"), ("text.stl", b"v 0 0 0\nv 1 0 0\nf 1 2 3\n"),
    ("empty.vtu", b""), ("empty.msh", b""), ("x.stl", b"solid\n"), ("d.vtk", b"\xff" * 64),
])
def test_meshio_failures_are_mesh_read_errors(tmp_path, name, content):
    p = tmp_path / name
    p.write_bytes(content)
    with pytest.raises(MeshReadError, match=name.replace(".", r"\.")):
        read_mesh(p)


def test_missing_and_directory(tmp_path):
    with pytest.raises(MeshReadError, match="not found"):
        read_mesh(tmp_path / "nope.obj")
    with pytest.raises(MeshReadError, match="not a file"):
        read_mesh(tmp_path)


# ----------------------------------------------------------------------------- writing

def _moved(pts, seed=0):
    return pts + np.random.default_rng(seed).normal(0, 0.01, pts.shape)


def test_obj_round_trip_uv_normals(tmp_path):
    g = read_mesh(_obj(tmp_path, QUAD_OBJ))
    pts = _moved(g.points)
    out = tmp_path / "o.obj"
    write_mesh(out, pts, g, "obj")
    h = read_mesh(out)
    assert np.allclose(h.points, pts, rtol=1e-9, atol=0)
    assert np.array_equal(h.uv, g.uv) and np.array_equal(h.tri_uv, g.tri_uv)
    assert h.has_normals and np.array_equal(h.tri_normals, g.tri_normals)
    assert np.allclose(h.normals, vertex_normals(pts, g.triangles, g.tri_normals, 1), atol=1e-6)
    assert "f 1/1/1 2/2/1 3/3/1" in out.read_text()


def test_obj_normals_only_and_plain(tmp_path):
    pts, tris = _grid(3)
    g = Geometry(pts, triangles=tris, normals=np.zeros((len(pts), 3)), tri_normals=tris.copy())
    write_mesh(tmp_path / "n.obj", pts, g, "obj")
    text = (tmp_path / "n.obj").read_text()
    assert "f 1//1 " in text and text.count("vn ") == len(pts)
    assert np.allclose(read_mesh(tmp_path / "n.obj").normals, [0, -1, 0]) or np.allclose(
        read_mesh(tmp_path / "n.obj").normals, [0, 1, 0])
    write_mesh(tmp_path / "p.obj", pts, Geometry(pts, triangles=tris), "obj")
    assert "vn" not in (tmp_path / "p.obj").read_text()


def test_vertex_normals_area_weighted():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 2.0]])
    tris = np.array([[0, 1, 2], [0, 3, 1]])  # +z (area .5) and +y... (area 1)
    n = vertex_normals(pts, tris)
    assert np.allclose(n[2], [0, 0, 1]) and np.allclose(n[3], [0, 1, 0])
    expect = np.array([0, 2.0, 1.0]) / np.sqrt(5)  # cross products weighted by twice the area
    assert np.allclose(n[0], expect) and np.allclose(n[1], expect)


def _strands():
    pts = np.arange(30, dtype=float).reshape(10, 3)
    edges = np.array([[0, 1], [1, 2], [2, 3], [4, 5], [5, 6], [7, 8], [8, 9]])
    return pts, Geometry(pts, edges=edges)


def test_hair_written_as_polylines(tmp_path):
    pts, g = _strands()
    for fmt in ("obj",):
        write_mesh(tmp_path / f"h.{fmt}", pts, g, fmt)
    text = (tmp_path / "h.obj").read_text()
    assert [ln for ln in text.splitlines() if ln.startswith("l")] == [
        "l 1 2 3 4", "l 5 6 7", "l 8 9 10"]
    h = read_mesh(tmp_path / "h.obj")
    assert np.array_equal(h.edges, g.edges) and np.allclose(h.points, pts, rtol=1e-9)


def test_curve_chains_unordered_loops_and_branches():
    e = np.array([[3, 2], [0, 1], [2, 1], [5, 6], [6, 7], [7, 5], [8, 9], [8, 10], [8, 11]])
    chains = curve_chains(e, 12)
    got = sorted(tuple(c.tolist()) for c in chains)
    assert (0, 1, 2, 3) in got or (3, 2, 1, 0) in got
    loop = [c for c in got if 5 in c][0]
    assert len(loop) == 4 and loop[0] == loop[-1]
    assert sum(len(c) - 1 for c in chains) == len(e)  # every edge once


@pytest.mark.parametrize("fmt", ["ply", "vtu"])
def test_ply_vtu_velocities_normals_uv(tmp_path, fmt):
    pts, tris = _grid(4)
    n = len(pts)
    g = Geometry(pts, triangles=tris, uv=pts[:, [0, 2]].copy(), tri_uv=tris.copy(),
                 normals=np.zeros((n, 3)), tri_normals=tris.copy())
    vel = np.random.default_rng(2).normal(size=(n, 3))
    x = _moved(pts)
    out = tmp_path / f"f.{fmt}"
    write_mesh(out, x, g, fmt, velocities=vel)
    m = meshio.read(out)
    assert np.allclose(m.points, x, rtol=1e-9, atol=0)
    if fmt == "ply":
        assert np.array_equal(np.stack([m.point_data[k] for k in ("vx", "vy", "vz")], 1), vel)
    else:
        assert np.array_equal(m.point_data["velocity"], vel)
    h = read_mesh(out)
    assert np.array_equal(h.triangles, tris) and np.array_equal(h.vertex_uv(), g.uv)
    assert np.allclose(h.normals, vertex_normals(x, tris))


@pytest.mark.parametrize("fmt", ["ply", "vtu"])
def test_ply_vtu_curves(tmp_path, fmt):
    pts, g = _strands()
    write_mesh(tmp_path / f"h.{fmt}", pts, g, fmt)
    h = read_mesh(tmp_path / f"h.{fmt}")
    assert np.array_equal(h.edges, g.edges) and np.allclose(h.points, pts)


def test_uv_seam_not_written_per_vertex(tmp_path):
    pts, tris = _grid(3)
    uv = np.random.default_rng(0).random((len(tris) * 3, 2))
    g = Geometry(pts, triangles=tris, uv=uv, tri_uv=np.arange(len(uv)).reshape(-1, 3))
    assert g.vertex_uv() is None
    write_mesh(tmp_path / "s.ply", pts, g, "ply")
    assert "uv" not in meshio.read(tmp_path / "s.ply").point_data
    write_mesh(tmp_path / "s.obj", pts, g, "obj")
    h = read_mesh(tmp_path / "s.obj")
    assert np.allclose(h.uv[h.tri_uv], uv[g.tri_uv], rtol=1e-9)


def test_obj_write_not_slower_than_savetxt(tmp_path):
    """The 64x64 cloth frame: the vectorised writer is not slower than the old savetxt one."""
    pts, tris = _grid(64)
    g = Geometry(pts, triangles=tris)

    def old(path):
        with open(path, "w", encoding="utf-8") as fh:
            np.savetxt(fh, pts, fmt="v %.9g %.9g %.9g")
            np.savetxt(fh, tris + 1, fmt="f %d %d %d")

    def best(fn, path):
        ts = []
        for _ in range(5):
            t = time.perf_counter()
            fn(path)
            ts.append(time.perf_counter() - t)
        return min(ts)

    t_old = best(old, tmp_path / "a.obj")
    t_new = best(lambda p: write_mesh(p, pts, g, "obj"), tmp_path / "b.obj")
    assert np.allclose(read_mesh(tmp_path / "b.obj").points, pts, rtol=1e-9, atol=0)
    assert t_new < 1.2 * t_old + 2e-3


# ----------------------------------------------------------------------------- large meshes

def test_validate_large_mesh(tmp_path):
    """A 2e5-vertex cloth validates quickly (10^6 vertices: see tests/data/fuzz_mesh/README)."""
    from lokigraph.cli import main

    pts, tris = _grid(448)
    p = tmp_path / "big.ply"
    meshio.write(p, meshio.Mesh(pts, [("triangle", tris.astype(np.int32))]), binary=True)
    scene = tmp_path / "scene.yaml"
    scene.write_text("""lokigraph: 1
frames: {start: 1, end: 2, fps: 24}
elements:
  - name: cloth
    geometry: {file: big.ply}
    components:
      Dynamic: {mass_density: 0.2}
      DiscreteShell: {bend_resistance: 1.0e-6}
      Pins: {vertices: [0]}
""")
    t = time.perf_counter()
    assert main(["validate", str(scene)]) == 0
    assert time.perf_counter() - t < 60.0  # about 2 s when the machine is idle


def make_bench_scenes(m: int, out) -> None:
    """Write an m x m vertex cloth as binary PLY, ascii PLY and OBJ, with a validate scene for
    each (``<name>_yaml``), into folder ``out``."""
    from pathlib import Path

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    pts, tris = _grid(m)
    mesh = meshio.Mesh(pts, [("triangle", tris.astype(np.int32))])
    meshio.write(out / "big_bin.ply", mesh, binary=True)
    meshio.write(out / "big_asc.ply", mesh, binary=False)
    write_mesh(out / "big.obj", pts, Geometry(pts, triangles=tris), "obj")
    for f in ("big_bin.ply", "big_asc.ply", "big.obj"):
        (out / (f.replace(".", "_") + ".yaml")).write_text(f"""lokigraph: 1
frames: {{start: 1, end: 2, fps: 24}}
elements:
  - name: cloth
    geometry: {{file: {f}}}
    components:
      Dynamic: {{mass_density: 0.2}}
      DiscreteShell: {{bend_resistance: 1.0e-6}}
      Pins: {{vertices: [0]}}
""")


if __name__ == "__main__":
    import sys

    make_bench_scenes(int(sys.argv[1]), sys.argv[2])
