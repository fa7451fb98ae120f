"""USD caches (``run --format usd``) and USD input for kinematic elements
(``geometry: {usd: body.usd, prim: /char/body}``).

Needs usd-core (``pip install "lokigraph[usd]"``); ``pxr`` is imported only when USD is used.

Stage written by a run
----------------------
One stage per run, opened through ``OUT/run.usd`` (``run.json`` records it as
``output.usd.stage``)::

    OUT/run.usd                   root layer (text, a few hundred bytes): stage metadata and one
                                  sublayer, the frame layer last completed
    OUT/run.<token>.a.usdc        two crate layers with the same prims ("frame layers"); every
    OUT/run.<token>.b.usdc        frame's samples go into both, each frame saves one of them

    /lokigraph                    Xform, the default prim
      /lokigraph/<element>        UsdGeomMesh (triangles), UsdGeomBasisCurves (hair: linear,
                                  one curve per strand), UsdGeomTetMesh (tetrahedra) or
                                  UsdGeomPoints (points only); customData lokigraph:element is
                                  the element's name (prim names replace characters USD does
                                  not allow by "_")

Topology (``faceVertexCounts``/``faceVertexIndices``, ``curveVertexCounts``,
``tetVertexIndices``/``surfaceFaceVertexIndices``), texture coordinates (``primvars:st``,
face-varying, when the input had them), ``subdivisionScheme = none`` and widths are written once
(not time-sampled). ``points`` (point3f), ``velocities`` (vector3f, m/s), ``extent`` and, for
meshes, ``normals`` (vertex interpolation, area-weighted, recomputed from each frame's points)
are time-sampled at time code = frame number. Stage metadata: ``timeCodesPerSecond`` =
``framesPerSecond`` = the scene's fps, ``startTimeCode`` = the first written frame,
``endTimeCode`` = the last finished frame, ``metersPerUnit = 1``, ``upAxis = Y``. Written
elements are those of the other formats (dynamic ones, compliant surfaces, kinematic colliders
with ``output.kinematic``: :func:`lokigraph.run.output_elements`). An element with both
triangles and curve edges is written as a mesh (its edges are left out).

Flushing, and why two frame layers
----------------------------------
A crate layer's ``Save()`` updates its file in place and writes only the new samples, so its
cost does not grow with the frames already written; exporting the whole layer again (temporary +
rename) costs time proportional to the frames so far (measured for a 64x64 cloth: 10 ms per
frame at frame 48, 80 ms at frame 480). But the in-place update first overwrites the end of the
file (the old table of contents) with new data and then rewrites the header, so a process
killed between those two writes leaves an unreadable file (measured: 4 of 40 runs killed at
random times). Hence two frame layers: a frame's samples are authored into both, the layer
*not* named by the root is saved in place, then the root is rewritten atomically (temporary +
rename) to name it. A kill at any point leaves the root naming a layer whose save completed,
holding exactly the frames finished (``startTimeCode``..``endTimeCode``; 0 of 25 random kills
lost or damaged a frame). Layers are saved alternately: each save writes two frames' samples.
Measured cost of a frame (64x64 cloth, 4225 vertices: points, velocities, normals and extent
into both layers, one in-place save, the root's rename): about 2.5 ms, constant over the run;
writing the same frame as OBJ takes about 4 ms. At the end of a run the layer not named by the
root is removed. (Files survive a killed process, not a power cut: there is no fsync.)

USD input
---------
``geometry: {usd: FILE, prim: /path}`` reads an animated UsdGeomMesh: topology from the prim
(polygons fan-triangulated, ``leftHanded`` orientation flipped), points at frame f from time
code ``f * timeCodesPerSecond / fps`` (= f when the stage's rate is the scene's fps), in world
space (the prim's local-to-world transform at that time; skipped when it is the identity so
values pass unchanged). The stage's ``metersPerUnit`` converts to metres when authored and
``geometry.units`` is not given. Frames available are the time samples of ``points`` that fall
on whole frames; it behaves like a mesh ``sequence`` (``hold``, the missing-frame check,
linear interpolation between frames). A prim without time samples is static.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
from pathlib import Path

import numpy as np

from .geometry import Geometry, MeshReadError, boundary_triangles
from .meshfile import curve_chains, vertex_normals

ROOT_NAME = "run.usd"
ROOT_PRIM = "lokigraph"
#: files of a run's stage in its output folder: ``run.usd`` and the frame layers
STAGE_FILE_RE = re.compile(r"^run\.usd$|^run\.[0-9a-f]+\.[ab]\.usdc$")
#: width [m] written for curves and points without a ``width`` channel
DEFAULT_WIDTH = 0.001
INSTALL_HINT = "install usd-core: pip install \"lokigraph[usd]\""


def have_pxr() -> bool:
    try:
        import pxr.Usd  # noqa: F401
    except ImportError:
        return False
    return True


def stage_files(out: Path) -> list[Path]:
    """The files of a previous run's stage in ``out`` (no pxr needed)."""
    found = []
    with contextlib.suppress(OSError), os.scandir(out) as it:
        for e in it:
            if STAGE_FILE_RE.match(e.name) and e.is_file(follow_symlinks=False):
                found.append(Path(e.path))
    return sorted(found)


def prim_name(name: str, used: set) -> str:
    """A valid, unique USD prim name for an element name."""
    base = re.sub(r"[^A-Za-z0-9_]", "_", name) or "_"
    if base[0].isdigit():
        base = "_" + base
    out, k = base, 2
    while out in used:
        out, k = f"{base}_{k}", k + 1
    used.add(out)
    return out


# ----------------------------------------------------------------------------- writing

class _Item:
    """One written element: its prim, kind and what a frame needs."""

    def __init__(self, el, path, kind, order=None, triangles=None):
        self.el = el
        self.path = path
        self.kind = kind
        self.order = order  # curves: vertex order of the written points (strand by strand)
        self.triangles = triangles  # meshes: for normals


class StageWriter:
    """Writes a run's frames into one USD stage (see the module docstring for the layout).

    ``StageWriter(out, elements, fps, first)`` defines the prims and topology;
    ``write(frame, positions, velocities)`` adds one frame (global (n, 3) arrays, the run's
    state; each element takes its ``vertex_slice``) and makes it durable; ``close()`` removes
    the stale frame layer. Raises OSError on a write failure.
    """

    def __init__(self, out: Path, elements: list, fps: float, first: int, info: dict | None = None):
        from pxr import Sdf, Usd, UsdGeom, Vt

        self.out = Path(out)
        self.fps = float(fps)
        self.first = int(first)
        self.root_path = self.out / ROOT_NAME
        token = secrets.token_hex(4)
        self.layer_paths = [self.out / f"run.{token}.{c}.usdc" for c in "ab"]
        self.frames: list[int] = []
        self.current: int | None = None  # index of the frame layer the root names
        self.prims: dict[str, str] = {}
        self._Vt = Vt
        self._Sdf = Sdf

        layer = Sdf.Layer.CreateNew(str(self.layer_paths[0]))
        stage = Usd.Stage.Open(layer)
        self._stage_metadata(layer)
        root_prim = UsdGeom.Xform.Define(stage, f"/{ROOT_PRIM}").GetPrim()
        layer.defaultPrim = ROOT_PRIM
        used: set = set()
        self.items: list[_Item] = []
        for el in elements:
            path = f"/{ROOT_PRIM}/{prim_name(el.name, used)}"
            self.items.append(self._define(stage, el, path, Vt, UsdGeom))
            self.prims[el.name] = path
        if info:
            root_prim.SetCustomDataByKey("lokigraph:run", {k: str(v) for k, v in info.items()})
        layer.Save()
        other = Sdf.Layer.CreateNew(str(self.layer_paths[1]))
        other.TransferContent(layer)
        other.Save()
        self.layers = [layer, other]
        self._stage = stage  # keeps the layer open
        root = Sdf.Layer.CreateAnonymous(".usda")
        self._stage_metadata(root)
        root.defaultPrim = ROOT_PRIM
        root.pseudoRoot.SetInfo("metersPerUnit", 1.0)
        root.pseudoRoot.SetInfo("upAxis", "Y")
        root.documentation = ("lokigraph run: frames in the sublayer (a crate layer written "
                              "frame by frame)")
        self.root = root

    def _stage_metadata(self, layer) -> None:
        layer.timeCodesPerSecond = self.fps
        layer.framesPerSecond = self.fps

    def _define(self, stage, el, path, Vt, UsdGeom) -> _Item:
        g = el.geometry
        n = g.vertex_count
        if len(g.tetrahedra) and hasattr(UsdGeom, "TetMesh"):  # usd-core >= 24.03
            tm = UsdGeom.TetMesh.Define(stage, path)
            tm.CreateTetVertexIndicesAttr(Vt.Vec4iArray.FromNumpy(
                np.ascontiguousarray(g.tetrahedra, np.int32)))
            surf = g.triangles if len(g.triangles) else boundary_triangles(g.tetrahedra)
            tm.CreateSurfaceFaceVertexIndicesAttr(Vt.Vec3iArray.FromNumpy(
                np.ascontiguousarray(surf, np.int32)))
            item, prim = _Item(el, path, "tetmesh"), tm
        elif len(g.triangles) or len(g.tetrahedra):
            m = UsdGeom.Mesh.Define(stage, path)
            tri = np.ascontiguousarray(g.triangles if len(g.triangles) else
                                       boundary_triangles(g.tetrahedra), np.int32)
            m.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(tri), 3, np.int32)))
            m.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(tri.ravel()))
            m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
            m.CreateNormalsAttr()
            m.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
            if g.has_uv:
                from pxr import Sdf

                st = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                          UsdGeom.Tokens.faceVarying)
                st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(g.uv, np.float32)))
                st.SetIndices(Vt.IntArray.FromNumpy(
                    np.ascontiguousarray(g.tri_uv, np.int32).ravel()))
            item, prim = _Item(el, path, "mesh", triangles=tri.astype(np.int64)), m
        elif len(g.edges):
            c = UsdGeom.BasisCurves.Define(stage, path)
            chains = curve_chains(g.edges, n)
            order = np.concatenate(chains) if chains else np.zeros(0, np.int64)
            c.CreateTypeAttr(UsdGeom.Tokens.linear)
            c.CreateWrapAttr(UsdGeom.Tokens.nonperiodic)
            c.CreateCurveVertexCountsAttr(Vt.IntArray.FromNumpy(
                np.asarray([len(ch) for ch in chains], np.int32)))
            self._widths(c, el, order, Vt, UsdGeom)
            item, prim = _Item(el, path, "curves", order=order), c
        else:
            p = UsdGeom.Points.Define(stage, path)
            self._widths(p, el, None, Vt, UsdGeom)
            item, prim = _Item(el, path, "points"), p
        prim.CreatePointsAttr()
        prim.CreateVelocitiesAttr()
        prim.CreateExtentAttr()
        prim.GetPrim().SetCustomDataByKey("lokigraph:element", el.name)
        return item

    @staticmethod
    def _widths(gprim, el, order, Vt, UsdGeom) -> None:
        w = el.geometry.channels.get("width")
        if w is not None and np.ndim(w) == 1:
            w = np.asarray(w, np.float32)
            gprim.CreateWidthsAttr(Vt.FloatArray.FromNumpy(w if order is None else w[order]))
            gprim.SetWidthsInterpolation(UsdGeom.Tokens.vertex)
        else:
            gprim.CreateWidthsAttr(Vt.FloatArray([DEFAULT_WIDTH]))
            gprim.SetWidthsInterpolation(UsdGeom.Tokens.constant)

    def write(self, frame: int, positions: np.ndarray, velocities: np.ndarray) -> None:
        """Add frame ``frame`` and make it durable (the root names a layer holding it)."""
        Vt, Sdf = self._Vt, self._Sdf
        t = float(frame)
        samples = []
        for it in self.items:
            sl = it.el.vertex_slice
            q = positions[sl]
            v = velocities[sl]
            if it.order is not None:
                q, v = q[it.order], v[it.order]
            q32 = np.ascontiguousarray(q, np.float32)
            samples.append((it.path + ".points", Vt.Vec3fArray.FromNumpy(q32)))
            samples.append((it.path + ".velocities",
                            Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(v, np.float32))))
            ext = (np.stack([q32.min(0), q32.max(0)]) if len(q32) else np.zeros((2, 3), np.float32))
            samples.append((it.path + ".extent", Vt.Vec3fArray.FromNumpy(ext)))
            if it.kind == "mesh":
                nrm = vertex_normals(np.asarray(q, np.float64), it.triangles)
                samples.append((it.path + ".normals",
                                Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(nrm, np.float32))))
        for layer in self.layers:
            for path, value in samples:
                layer.SetTimeSample(Sdf.Path(path), t, value)
        target = 0 if self.current is None else 1 - self.current
        if not self.layers[target].Save():
            raise OSError(f"cannot save {self.layer_paths[target]}")
        self.frames.append(int(frame))
        self._write_root(target)
        self.current = target

    def _write_root(self, target: int) -> None:
        root = self.root
        root.subLayerPaths.clear()
        root.subLayerPaths.append("./" + self.layer_paths[target].name)
        root.startTimeCode = float(self.first)
        root.endTimeCode = float(self.frames[-1])
        text = root.ExportToString()
        from .run import atomic_write

        atomic_write(self.root_path, lambda p: p.write_text(text, encoding="utf-8"))

    @property
    def stage_path(self) -> Path | None:
        """``run.usd`` once a frame is written, else None."""
        return self.root_path if self.current is not None else None

    def close(self) -> None:
        """Remove the frame layer the root does not name (all of them when no frame was
        written). Safe to call twice."""
        keep = None if self.current is None else self.layer_paths[self.current]
        for p in self.layer_paths:
            if p != keep:
                with contextlib.suppress(OSError):
                    p.unlink(missing_ok=True)
        self.layers = []
        self._stage = None


# ----------------------------------------------------------------------------- reading

class UsdReadError(MeshReadError):
    """A USD input problem; ``key`` is the geometry field to point at (``usd`` or ``prim``)."""

    def __init__(self, message: str, key: str = "usd"):
        super().__init__(message)
        self.key = key


_STAGES: dict = {}


def _open(path: Path):
    try:
        from pxr import Usd
    except ImportError:
        raise UsdReadError(f"geometry.usd needs usd-core, which is not installed; "
                           f"{INSTALL_HINT}") from None
    try:
        st = path.stat()
    except OSError as exc:
        raise UsdReadError(f"USD file not found: {path} ({exc.strerror or exc})") from None
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    stage = _STAGES.get(key)
    if stage is None:
        try:
            stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
        except Exception as exc:  # noqa: BLE001 - pxr raises Tf.ErrorException
            msg = " ".join(str(exc).split())
            raise UsdReadError(f"cannot open {path} as a USD stage: {msg}") from None
        if stage is None:
            raise UsdReadError(f"cannot open {path} as a USD stage")
        if len(_STAGES) >= 4:
            _STAGES.clear()
        _STAGES[key] = stage
    return stage


def _mesh(stage, path: Path, prim_path: str):
    from pxr import Sdf, UsdGeom

    prim = stage.GetPrimAtPath(Sdf.Path(prim_path)) if Sdf.Path.IsValidPathString(
        prim_path) else None
    if prim is not None and prim.IsValid() and prim.IsA(UsdGeom.Mesh):
        return UsdGeom.Mesh(prim)
    meshes, others = [], []
    for p in stage.Traverse():
        (meshes if p.IsA(UsdGeom.Mesh) else others).append(str(p.GetPath()))

    def listing(names, what):
        if not names:
            return f"no {what}"
        shown = ", ".join(names[:12]) + (f" and {len(names) - 12} more" if len(names) > 12 else "")
        return f"{what}: {shown}"

    if prim is not None and prim.IsValid():
        why = f"prim {prim_path} in {path} is a {prim.GetTypeName() or 'typeless prim'}, not a Mesh"
    else:
        why = f"no prim {prim_path} in {path}"
    raise UsdReadError(f"{why}; {listing(meshes, 'meshes')} ({listing(others, 'other prims')})",
                       key="prim")


def _rate(stage, fps: float | None) -> float:
    """Time codes per scene frame."""
    tcps = float(stage.GetTimeCodesPerSecond())
    return 1.0 if fps is None or tcps == fps else tcps / float(fps)


def usd_frames(path: Path, prim: str, fps: float | None = None) -> np.ndarray | None:
    """Scene frames that have a time sample of the prim's points (sorted), or None when the
    points are not time-sampled (a static prim: every frame shows it)."""
    stage = _open(Path(path))
    mesh = _mesh(stage, path, prim)
    times = mesh.GetPointsAttr().GetTimeSamples()
    if not times:
        return None
    rate = _rate(stage, fps)
    f = np.asarray(times, np.float64) / rate
    whole = np.abs(f - np.round(f)) <= 1e-9 * np.maximum(1.0, np.abs(f))
    return np.unique(np.round(f[whole]).astype(np.int64))


def read_usd_mesh(path: Path, prim: str, frame: int | None, fps: float | None = None,
                  units_given: bool = True) -> Geometry:
    """The mesh prim's geometry at scene frame ``frame`` (None: its default value, or the first
    time sample). Points are float64 copies of the stored values (world space; metres when the
    stage authors metersPerUnit and ``units_given`` is false)."""
    from pxr import Usd, UsdGeom

    path = Path(path)
    stage = _open(path)
    mesh = _mesh(stage, path, prim)
    if frame is None:
        tc = Usd.TimeCode.Default()
        times = mesh.GetPointsAttr().GetTimeSamples()
        if times and not mesh.GetPointsAttr().HasAuthoredValue():
            tc = Usd.TimeCode(times[0])
    else:
        tc = Usd.TimeCode(float(frame) * _rate(stage, fps))
    pts = mesh.GetPointsAttr().Get(tc)
    if pts is None:
        raise UsdReadError(f"prim {prim} in {path} has no points", key="prim")
    pts = np.array(pts, dtype=np.float64).reshape(-1, 3)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(tc) or [], np.int64)
    idx = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(tc) or [], np.int64)
    if counts.sum() != len(idx) or (len(counts) and counts.min() < 3):
        raise UsdReadError(f"prim {prim} in {path}: faceVertexCounts (sum {int(counts.sum())}) "
                           f"do not match faceVertexIndices ({len(idx)})", key="prim")
    tris = _fan(counts, idx)
    if mesh.GetOrientationAttr().Get(tc) == UsdGeom.Tokens.leftHanded:
        tris = tris[:, [0, 2, 1]]
    xf = np.asarray(UsdGeom.Xformable(mesh.GetPrim()).ComputeLocalToWorldTransform(tc))
    if not np.array_equal(xf, np.eye(4)):
        pts = pts @ xf[:3, :3] + xf[3, :3]
    if not units_given and UsdGeom.StageHasAuthoredMetersPerUnit(stage):
        mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
        if mpu != 1.0:
            pts = pts * mpu
    return Geometry(pts, triangles=tris)


def _fan(counts: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Fan triangulation of polygons (vectorised over polygons of each size)."""
    if not len(counts):
        return np.zeros((0, 3), np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    if np.all(counts == 3):
        return idx.reshape(-1, 3)
    out = []
    for k in range(1, int(counts.max()) - 1):  # loop over fan positions, not polygons
        sel = counts > k + 1
        s = starts[sel]
        out.append((np.flatnonzero(sel), k, np.stack([idx[s], idx[s + k], idx[s + k + 1]], 1)))
    # order: polygon by polygon, fan triangles in order
    poly = np.concatenate([p for p, _, _ in out])
    pos = np.concatenate([np.full(len(p), k) for p, k, _ in out])
    tri = np.concatenate([t for _, _, t in out])
    return tri[np.lexsort((pos, poly))]


def load_usd_geometry(spec, base: Path, frame: int | None) -> Geometry:
    """Geometry of a ``geometry: {usd, prim}`` spec at scene frame ``frame`` (a frame without a
    time sample follows ``hold``), before units and transform (lokigraph.scene applies them).
    The scene's fps comes from ``spec.sequence`` when it is a :class:`UsdSource`."""
    from .sequence import describe_frames, map_frame

    src = spec.sequence
    fps = getattr(src, "fps", None)
    path = Path(base) / spec.usd
    units_given = "units" in spec.model_fields_set
    if frame is None:
        return read_usd_mesh(path, spec.prim, None, fps, units_given)
    f = int(frame)
    avail = usd_frames(path, spec.prim, fps)
    if avail is not None:
        shown = map_frame(f, avail, spec.hold)
        if shown is None:
            raise UsdReadError(f"frame {f}: prim {spec.prim} in {path} has no time sample at "
                               f"that frame (it has {describe_frames(avail)}; geometry.hold: "
                               f"first, last or loop shows another frame instead)", key="usd")
        f = shown
    return read_usd_mesh(path, spec.prim, f, fps, units_given)


def missing_usd_frame(spec, base: Path, start: int, end: int) -> str | None:
    """For ``hold: error``: why frames ``start..end`` of a ``usd`` geometry are not all there
    (the first frame without a time sample), or None."""
    from .sequence import describe_frames, first_missing

    fps = getattr(spec.sequence, "fps", None)
    path = Path(base) / spec.usd
    avail = usd_frames(path, spec.prim, fps)
    if avail is None:
        return None  # not time-sampled: static
    miss = first_missing(avail, start, end)
    if miss is None:
        return None
    have = describe_frames(avail).replace("files", "time samples")
    return (f"frame {miss} has no time sample of {spec.prim}'s points in {path}: the run needs "
            f"frames {start}..{end} and the prim has {have}; set geometry.hold to first, last "
            f"or loop to run past its ends")
