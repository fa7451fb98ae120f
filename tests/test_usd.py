"""USD caches (``run --format usd``) and USD input for kinematic elements (lokigraph.usd).

Skipped when usd-core is not installed (``pip install "lokigraph[usd]"``; the dev extra has it).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

pxr = pytest.importorskip("pxr", reason="usd-core is not installed (pip install 'lokigraph[usd]')")
from pxr import Sdf, Usd, UsdGeom, UsdUtils, Vt  # noqa: E402

from conftest import run_cli, write_scene  # noqa: E402
from lokigraph.api import compile_file, run_file  # noqa: E402
from lokigraph.errors import InputError  # noqa: E402
from lokigraph.generators import grid, icosphere  # noqa: E402
from lokigraph.meshfile import read_mesh  # noqa: E402
from lokigraph.run import Simulation  # noqa: E402
from lokigraph.scene import GeometrySpec, _load_geometry  # noqa: E402
from lokigraph.sequence import available_frames  # noqa: E402

FRAMES = 48

# a 16 x 16 cloth falls on an analytic sphere; 6 hair strands hang from their roots; a mesh
# ball, a tet block and two points (kinematic, written with output.kinematic): every prim kind
# of the stage (Mesh, BasisCurves, TetMesh, Points) in one run
CLOTH = f"""
lokigraph: 1
frames: {{start: 1, end: {FRAMES}, fps: 24}}
substeps: 1
elements:
  - name: cloth
    geometry:
      generator: grid
      params: {{size: [1.0, 1.0], resolution: [16, 16], plane: xz, center: [0, 0.45, 0]}}
    components:
      Dynamic: {{mass_density: 0.15, damping: 0.2}}
      DiscreteShell: {{bend_resistance: 2.0e-6}}
  - name: hair-1
    geometry:
      generator: strands
      params: {{count: [3, 2], spacing: 0.02, length: 0.1, segments: 5, direction: [1, 0, 0],
               center: [0, 1, 0]}}
    components:
      Dynamic: {{mass_density: 2.0e-4, damping: 0.5}}
      Pins: {{map: root}}
  - name: ball
    geometry: {{generator: sphere, params: {{radius: 0.3, subdivisions: 1}}}}
    components:
      Kinematic: {{}}
  - name: block
    geometry: {{generator: tet_box, params: {{size: [0.1, 0.1, 0.1], center: [1, 0, 0]}}}}
    components: {{Kinematic: {{}}}}
  - name: dots
    geometry: {{generator: points, params: {{positions: [[1, 1, 1], [1, 1.1, 1]]}}}}
    components: {{Kinematic: {{}}}}
  - name: sphere
    components:
      ShapeCollider: {{shape: sphere, radius: 0.3, friction: 0.3}}
output: {{kinematic: true}}
"""


def _stage_points(stage, prim, frame):
    return np.array(UsdGeom.PointBased(stage.GetPrimAtPath(prim)).GetPointsAttr().Get(frame))


def _within_ulp(a32: np.ndarray, b64: np.ndarray) -> bool:
    """float32 ``a32`` equals ``b64`` to float precision: within one float32 ulp."""
    b32 = b64.astype(np.float32)
    return bool(np.all(np.abs(a32 - b32) <= np.spacing(np.abs(b32))))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The same scene run twice: --format usd and --format obj."""
    tmp = tmp_path_factory.mktemp("usd_run")
    scene = write_scene(tmp, CLOTH)
    t0 = time.perf_counter()
    res = run_file(scene, out_dir=tmp / "usd", fmt="usd", progress=False)
    t_usd = time.perf_counter() - t0
    run_file(scene, out_dir=tmp / "obj", fmt="obj", progress=False)
    return {"scene": scene, "usd": tmp / "usd", "obj": tmp / "obj", "result": res,
            "seconds": t_usd}


def test_stage_holds_every_frame_equal_to_obj(runs):
    out = runs["usd"]
    info = json.loads((out / "run.json").read_text())
    assert info["status"] == "ok" and info["format"] == "usd"
    assert info["output"]["usd"]["stage"] == str(out / "run.usd")
    prims = info["output"]["usd"]["prims"]
    assert prims == {"cloth": "/lokigraph/cloth", "hair-1": "/lokigraph/hair_1",
                     "ball": "/lokigraph/ball", "block": "/lokigraph/block",
                     "dots": "/lokigraph/dots"}
    # one stage: the root and the frame layer it names; no element folders, no temporaries
    names = sorted(p.name for p in out.iterdir())
    assert names[-2:] == ["run.json", "run.usd"] and len(names) == 3, names
    assert names[0].startswith("run.") and names[0].endswith(".usdc")

    stage = Usd.Stage.Open(str(out / "run.usd"))
    assert stage.GetTimeCodesPerSecond() == 24 and stage.GetFramesPerSecond() == 24
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (1, FRAMES)
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == Sdf.Path("/lokigraph")

    cloth = UsdGeom.Mesh(stage.GetPrimAtPath(prims["cloth"]))
    hair = UsdGeom.BasisCurves(stage.GetPrimAtPath(prims["hair-1"]))
    ball = UsdGeom.Mesh(stage.GetPrimAtPath(prims["ball"]))
    assert cloth and hair and ball
    assert stage.GetPrimAtPath(prims["block"]).GetTypeName() == "TetMesh"
    assert stage.GetPrimAtPath(prims["dots"]).GetTypeName() == "Points"
    assert stage.GetPrimAtPath(prims["hair-1"]).GetCustomDataByKey("lokigraph:element") == "hair-1"
    # topology once (not time-sampled), and equal to the OBJ's
    obj1 = read_mesh(runs["obj"] / "cloth" / "0001.obj")
    for m, el in ((cloth, "cloth"), (ball, "ball")):
        g = read_mesh(runs["obj"] / el / "0001.obj")
        assert m.GetFaceVertexIndicesAttr().GetNumTimeSamples() == 0
        assert m.GetFaceVertexCountsAttr().GetNumTimeSamples() == 0
        assert np.array_equal(np.array(m.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3),
                              g.triangles)
        assert set(m.GetFaceVertexCountsAttr().Get()) == {3}
        assert m.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    assert len(obj1.triangles) == 2 * 16 * 16 and len(obj1.points) == 289
    assert hair.GetTypeAttr().Get() == UsdGeom.Tokens.linear
    assert list(hair.GetCurveVertexCountsAttr().Get()) == [6] * 6
    assert hair.GetCurveVertexCountsAttr().GetNumTimeSamples() == 0
    # every frame's points equal the OBJ output to float precision (OBJ: 10 digits)
    for el, prim in prims.items():
        attr = UsdGeom.PointBased(stage.GetPrimAtPath(prim)).GetPointsAttr()
        assert list(attr.GetTimeSamples()) == list(range(1, FRAMES + 1))
        for f in range(1, FRAMES + 1):
            obj = read_mesh(runs["obj"] / el / f"{f:04d}.obj").points
            assert _within_ulp(np.array(attr.Get(f)), obj), (el, f)
    # the cloth moved (fell onto the sphere) and the written velocities are the run's
    last = _stage_points(stage, prims["cloth"], FRAMES)
    assert last[:, 1].min() < 0.3
    st = runs["result"].state
    vel = np.array(cloth.GetVelocitiesAttr().Get(FRAMES))
    assert np.array_equal(vel, st.particle_qd[:289].astype(np.float32))
    # normals: unit, per vertex, time-sampled; extent holds the points
    nrm = np.array(cloth.GetNormalsAttr().Get(FRAMES))
    assert cloth.GetNormalsInterpolation() == UsdGeom.Tokens.vertex
    assert nrm.shape == (289, 3) and np.allclose(np.linalg.norm(nrm, axis=1), 1, atol=1e-5)
    assert cloth.GetNormalsAttr().GetNumTimeSamples() == FRAMES
    ext = np.array(cloth.GetExtentAttr().Get(FRAMES))
    assert np.array_equal(ext, np.stack([last.min(0), last.max(0)]))


def test_stage_passes_usd_validation(runs):
    """usdchecker's checks (usd-core >= 24.x: the UsdValidation framework; older:
    UsdUtils.ComplianceChecker), every registered validator, no errors."""
    path = str(runs["usd"] / "run.usd")
    if hasattr(UsdUtils, "ComplianceChecker"):  # usdchecker before the validation framework
        checker = UsdUtils.ComplianceChecker()
        checker.CheckCompliance(path)
        assert not checker.GetErrors() and not checker.GetFailedChecks(), (
            checker.GetErrors(), checker.GetFailedChecks())
        return
    from pxr import UsdValidation

    stage = Usd.Stage.Open(path)
    validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
    assert len(validators) > 10
    errors = UsdValidation.ValidationContext(validators).Validate(stage)
    assert not errors, [e.GetMessage() for e in errors]


def test_killed_run_keeps_a_readable_stage(runs, tmp_path):
    """SIGKILL after some frames: the stage opens and holds every finished frame, equal to
    the uninterrupted run's."""
    out = tmp_path / "killed"
    env = dict(os.environ)
    proc = subprocess.Popen([sys.executable, "-m", "lokigraph.cli", "run", str(runs["scene"]),
                             "--format", "usd", "--out", str(out), "--quiet"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    root = out / "run.usd"
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            if root.exists() and "endTimeCode = " in root.read_text():
                text = root.read_text()
                end = int(float(text.split("endTimeCode = ")[1].split()[0]))
                if end >= 4:
                    break
            time.sleep(0.02)
        assert proc.poll() is None, "the run ended before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert not (out / "run.json").exists()  # killed: no run.json, the stage is all there is
    stage = Usd.Stage.Open(str(root))
    end = int(stage.GetEndTimeCode())
    assert 4 <= end < FRAMES
    full = Usd.Stage.Open(str(runs["usd"] / "run.usd"))
    attr = UsdGeom.Mesh(stage.GetPrimAtPath("/lokigraph/cloth")).GetPointsAttr()
    times = list(attr.GetTimeSamples())
    assert times == list(range(1, end + 1))  # every finished frame
    for f in times:
        assert np.array_equal(np.array(attr.Get(f)),
                              _stage_points(full, "/lokigraph/cloth", f)), f
    # a rerun into the folder is refused (another run's output), then --overwrite replaces it
    r = run_cli("run", runs["scene"], "--format", "usd", "--out", out, "--frames", "1:2",
                "--quiet")
    assert r.returncode == 2 and "USD stage" in r.stderr, r.stderr
    r = run_cli("run", runs["scene"], "--format", "usd", "--out", out, "--frames", "1:2",
                "--quiet", "--overwrite")
    assert r.returncode == 0, r.stderr
    assert len(list(out.glob("*.usdc"))) == 1


# ----------------------------------------------------------------------------- USD input

def _animated_sphere(n_frames: int):
    """Points of a sphere moving up through frames 1..n (float64 of float32 values: the same
    numbers on both input paths) and its triangles."""
    s = icosphere(0.2, 1)
    frames = {}
    for f in range(1, n_frames + 1):
        q = s.points + np.array([0.0, -0.45 + 0.035 * f, 0.01 * np.sin(f)])
        frames[f] = q.astype(np.float32).astype(np.float64)
    return s, frames


def _write_usd(path, tris, frames: dict, prim="/char/body", tcps=24.0, step=1):
    stage = Usd.Stage.CreateNew(str(path))
    stage.SetTimeCodesPerSecond(tcps)
    UsdGeom.Xform.Define(stage, "/char")
    m = UsdGeom.Mesh.Define(stage, prim)
    m.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(tris), 3, np.int32)))
    m.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(tris.astype(np.int32).ravel()))
    pa = m.CreatePointsAttr()
    for f, q in frames.items():
        pa.Set(Vt.Vec3fArray.FromNumpy(q.astype(np.float32)), f * step)
    stage.GetRootLayer().Save()
    del stage


def _write_obj_sequence(folder, tris, frames: dict):
    folder.mkdir(parents=True, exist_ok=True)
    for f, q in frames.items():
        lines = ["v " + " ".join(repr(float(x)) for x in row) for row in q]
        lines += ["f " + " ".join(str(i + 1) for i in t) for t in tris]
        (folder / f"body.{f:04d}.obj").write_text("\n".join(lines) + "\n")


COLLIDE = """
lokigraph: 1
frames: {{start: 1, end: 12, fps: 24}}
substeps: 2
elements:
  - name: cloth
    geometry:
      generator: grid
      params: {{size: [0.6, 0.6], resolution: [8, 8], plane: xz, center: [0, 0, 0]}}
    channels: {{pin: {{vertices: [0, 8]}}}}
    components:
      Dynamic: {{mass_density: 0.15, damping: 0.1}}
      Pins: {{map: pin}}
      Collider: {{thickness: 0.003}}
  - name: body
    geometry: {geometry}
    components:
      Kinematic: {{}}
      Collider: {{thickness: 0.003}}
  - name: contact
    components:
      CollisionGroup: {{members: [cloth, body], methods: [vertex_face]}}
"""


def test_usd_collider_drives_the_same_result_as_an_obj_sequence(tmp_path):
    s, frames = _animated_sphere(12)
    _write_usd(tmp_path / "body.usd", s.triangles, frames)
    _write_obj_sequence(tmp_path / "anim", s.triangles, frames)
    usd_scene = write_scene(tmp_path, COLLIDE.format(
        geometry="{usd: body.usd, prim: /char/body}"), "usd.yaml")
    obj_scene = write_scene(tmp_path, COLLIDE.format(
        geometry="{sequence: 'anim/body.{frame:04d}.obj'}"), "obj.yaml")
    # honest inputs: both paths read the very same numbers for every frame
    us = GeometrySpec(usd="body.usd", prim="/char/body").with_usd_source(24.0)
    os_ = GeometrySpec(sequence="anim/body.{frame:04d}.obj")
    assert list(available_frames(us.sequence, tmp_path)) == list(range(1, 13))
    for f in range(1, 13):
        a, b = _load_geometry(us, tmp_path, f), _load_geometry(os_, tmp_path, f)
        assert np.array_equal(a.points, frames[f]) and np.array_equal(b.points, frames[f])
        assert np.array_equal(a.triangles, b.triangles)
    sims = []
    for scene in (usd_scene, obj_scene):
        sim = Simulation(compile_file(scene))
        qs = [sim.state.particle_q.copy()]
        for _ in range(11):
            sim.step_frame()
            qs.append(sim.state.particle_q.copy())
        sims.append(np.array(qs))
    usd_q, obj_q = sims
    cloth = slice(0, 81)
    # the collider moved the cloth (it is not a trivial comparison) ...
    free = Simulation(compile_file(write_scene(tmp_path, COLLIDE.format(
        geometry="{file: anim/body.0001.obj}"), "static.yaml")))
    for _ in range(11):
        free.step_frame()
    assert np.abs(free.state.particle_q[cloth] - usd_q[-1][cloth]).max() > 1e-3
    # ... and both inputs give bitwise the same positions in every frame
    assert np.array_equal(usd_q, obj_q)


def test_usd_input_hold_frames_and_time_scale(tmp_path):
    s, frames = _animated_sphere(5)
    _write_usd(tmp_path / "body.usda", s.triangles, frames)
    # tcps 48 with a sample every 2 time codes: frame f of a 24 fps scene is time code 2 f
    _write_usd(tmp_path / "body48.usdc", s.triangles, frames, tcps=48.0, step=2)
    src = GeometrySpec(usd="body48.usdc", prim="/char/body").with_usd_source(24.0)
    assert list(available_frames(src.sequence, tmp_path)) == [1, 2, 3, 4, 5]
    assert np.array_equal(_load_geometry(src, tmp_path, 3).points, frames[3])
    scene = """
lokigraph: 1
frames: {{start: 1, end: 8, fps: 24}}
elements:
  - name: body
    geometry: {{usd: body.usda, prim: /char/body{hold}}}
    components: {{Kinematic: {{}}}}
"""
    p = write_scene(tmp_path, scene.format(hold=""), "err.yaml")
    with pytest.raises(InputError) as ei:
        compile_file(p)
    msg = str(ei.value)
    assert "err.yaml:5:16:" in msg and "geometry.usd" in msg, msg
    assert "frame 6 has no time sample" in msg and "frames 1..5" in msg, msg
    assert "geometry.sequence" not in msg and msg.count("frame 6") == 1, msg  # reported once
    p = write_scene(tmp_path, scene.format(hold=", hold: last"), "last.yaml")
    sim = Simulation(compile_file(p))
    for _ in range(7):
        sim.step_frame()
    assert np.array_equal(sim.state.particle_q, frames[5])  # held after the last sample


def test_usd_input_errors_name_the_line_and_the_prims(tmp_path):
    s, frames = _animated_sphere(3)
    _write_usd(tmp_path / "body.usd", s.triangles, frames)
    base = """
lokigraph: 1
frames: {{start: 1, end: 3}}
elements:
  - name: body
    geometry:
      usd: body.usd
      prim: {prim}
    components: {{Kinematic: {{}}}}
"""
    p = write_scene(tmp_path, base.format(prim="/char/bdy"), "a.yaml")
    r = run_cli("validate", p)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "a.yaml:7:" in r.stderr and "no prim /char/bdy" in r.stderr
    assert "meshes: /char/body" in r.stderr and "/char" in r.stderr
    p = write_scene(tmp_path, base.format(prim="/char"), "b.yaml")
    r = run_cli("validate", p)
    assert r.returncode == 2 and "b.yaml:7:" in r.stderr and "is a Xform, not a Mesh" in r.stderr
    p = write_scene(tmp_path, base.format(prim="/char/body\n      file: x.obj"), "c.yaml")
    r = run_cli("validate", p)
    assert r.returncode == 2 and "only source" in r.stderr
    p = write_scene(tmp_path, base.format(prim="/char/body").replace("body.usd", "nope.usd"),
                    "d.yaml")
    r = run_cli("validate", p)
    assert r.returncode == 2 and "d.yaml:6:" in r.stderr and "not found" in r.stderr
    p = write_scene(tmp_path, base.format(prim="char"), "e.yaml")
    r = run_cli("validate", p)
    assert r.returncode == 2 and "e.yaml:7:" in r.stderr


def test_write_cost_is_constant_per_frame(tmp_path):
    """The stage write costs about the new samples only (in-place crate saves), not the frames
    so far: 240 frames of a 64 x 64 cloth, the last 24 no slower than 3x the first 24."""
    from types import SimpleNamespace

    from lokigraph.usd import StageWriter

    g = grid(size=(1.0, 1.0), resolution=(64, 64))
    el = SimpleNamespace(name="cloth", geometry=g, vertex_slice=slice(0, g.vertex_count))
    w = StageWriter(tmp_path, [el], 24.0, 1)
    v = np.zeros_like(g.points)
    times = []
    for f in range(1, 241):
        q = g.points + [0.0, -0.001 * f, 0.0]
        t0 = time.perf_counter()
        w.write(f, q, v)
        times.append(time.perf_counter() - t0)
    w.close()
    first, last = np.median(times[:24]), np.median(times[-24:])
    assert last < 3 * first + 2e-3, (first, last)
    stage = Usd.Stage.Open(str(tmp_path / "run.usd"))
    assert stage.GetEndTimeCode() == 240


def test_without_usd_core_the_errors_say_what_to_install(tmp_path, runs):
    """pxr not importable: --format usd and a usd geometry are input errors (exit 2)."""
    fake = tmp_path / "nopxr" / "pxr"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError('usd-core hidden for this test')\n")
    env = {"PYTHONPATH": os.pathsep.join([str(fake.parent)] + [
        p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])}
    r = run_cli("run", runs["scene"], "--format", "usd", "--out", tmp_path / "o", "--quiet",
                env=env)
    assert r.returncode == 2 and "lokigraph[usd]" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "o").exists()
    s, frames = _animated_sphere(2)
    p = write_scene(tmp_path, """
lokigraph: 1
frames: {start: 1, end: 2}
elements:
  - name: body
    geometry: {usd: body.usd, prim: /char/body}
    components: {Kinematic: {}}
""")
    (tmp_path / "body.usd").write_text("#usda 1.0\n")
    r = run_cli("validate", p, env=env)
    assert r.returncode == 2 and "scene.yaml:5:" in r.stderr and "usd-core" in r.stderr, r.stderr


def test_texture_coordinates_are_face_varying_primvars(tmp_path):
    from types import SimpleNamespace

    from lokigraph.geometry import Geometry
    from lokigraph.usd import StageWriter

    g = Geometry(np.array([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1.0]]),
                 triangles=np.array([[0, 2, 1], [0, 3, 2]]),
                 uv=np.array([[0, 0], [1, 0], [1, 1], [0, 1.0], [0.5, 0.5]]),
                 tri_uv=np.array([[0, 2, 1], [4, 3, 2]]))
    el = SimpleNamespace(name="quad", geometry=g, vertex_slice=slice(0, 4))
    w = StageWriter(tmp_path, [el], 30.0, 5)
    w.write(5, g.points, np.zeros((4, 3)))
    w.close()
    stage = Usd.Stage.Open(str(tmp_path / "run.usd"))
    assert stage.GetTimeCodesPerSecond() == 30 and stage.GetStartTimeCode() == 5
    st = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/lokigraph/quad")).GetPrimvar("st")
    assert st.GetInterpolation() == UsdGeom.Tokens.faceVarying
    assert np.allclose(np.array(st.ComputeFlattened()), g.uv[g.tri_uv.ravel()])
    nrm = np.array(UsdGeom.Mesh(stage.GetPrimAtPath("/lokigraph/quad")).GetNormalsAttr().Get(5))
    assert np.allclose(nrm, [0, 1, 0])  # right-handed winding, normals up
