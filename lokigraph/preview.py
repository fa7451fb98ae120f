"""Headless previews of a run's output: ``lokigraph preview OUT``.

Reads ``OUT/run.json`` (scene, written elements and frames, format, fps) and every written frame
(:func:`lokigraph.meshfile.read_mesh`; for a ``--format usd`` run, the stage run.json names in
``output.usd.stage``: each element's prim, points and velocities at time code = frame, topology
from the prim; needs usd-core), and renders them headless (no display needed):

- triangles shaded with Lambert's law from a light above and to the left of the camera, both
  sides lit (the back side of cloth a little darker in tint), dynamic elements in a colour each,
  kinematic elements (colliders written with ``output: {kinematic: true}``, compliant surfaces)
  in grey; hair and other curves as lines; analytic ``ShapeCollider`` planes as a checker
  floor, spheres and capsules in grey;
- optional per-vertex colouring (``--color strain``: the mean signed strain of the edges at a
  vertex, against the scene's rest lengths, or the run's first frame when the scene cannot be
  loaded; ``--color speed``: from the written velocities (PLY, VTU) or from consecutive frames
  and the fps), with one colour scale over all frames and a colour bar;
- one camera for every frame (azimuth and elevation about the scene's up axis, the opposite of
  gravity), framing the union of the bounding boxes of all frames; frame number and time in a
  corner.

Each frame is projected with our own perspective camera and rasterised with a depth buffer
(:mod:`lokigraph._raster`, numba, 2 x 2 supersampled for antialiasing; per-vertex colours and
shading interpolated across triangles), then placed pixel for pixel into one reused Agg figure
that adds the caption and colour bar. Colliders get their own depth buffer: where one is in
front of a simulated surface, the surface shows through it (``--solid`` turns that off), so
cloth between two plates or inside a body stays visible. A 64 x 64 cloth (8k triangles) takes
about 0.1 s a frame; 48 frames to a GIF about 7 s on 2 busy cores. (A painter's algorithm with
one 2D PolyCollection was as fast but drew colliders through tight cloth, such as a skirt 6 mm
outside its body, where triangles of different sizes sort wrongly by depth.)

Outputs: ``OUT/preview/NNNN.png``, ``OUT/preview.gif`` or ``OUT/preview.mp4`` (imageio; MP4
through imageio-ffmpeg's bundled ffmpeg, falling back to a GIF with a message when it is not
installed), and ``OUT/run_stats.png``: the per-frame statistics of run.json (time per frame and
every numeric solver statistic) over frames.

matplotlib and imageio are imported only here, lazily: they come with the ``preview`` extra
(``pip install 'lokigraph[preview]'``); without them a preview fails with a message naming it.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError, OutputError

EXTRA = "pip install 'lokigraph[preview]'"
MESH_FORMATS = ("obj", "ply", "vtu")
READ_FORMATS = MESH_FORMATS + ("usd",)
DEFAULT_SIZE = (640, 480)
DEFAULT_CAMERA = (35.0, 25.0)
#: colours of dynamic elements (RGB in [0, 1]), in element order
PALETTE = [(0.30, 0.52, 0.85), (0.90, 0.52, 0.22), (0.35, 0.70, 0.40), (0.75, 0.35, 0.65),
           (0.85, 0.75, 0.25), (0.30, 0.70, 0.75)]
HAIR_PALETTE = [(0.55, 0.32, 0.12), (0.20, 0.20, 0.20), (0.80, 0.60, 0.25)]
GREY = (0.62, 0.62, 0.62)
BACKGROUND = (1.0, 1.0, 1.0)
#: how much of a simulated surface shows through a collider in front of it (0: opaque)
GHOST = 0.4


# ----------------------------------------------------------------------------- dependencies

def _need_matplotlib():
    try:
        import matplotlib
    except ImportError:
        raise InputError(f"preview needs matplotlib: {EXTRA}") from None
    return matplotlib


def _need_imageio():
    try:
        import imageio.v2 as iio
    except ImportError:
        raise InputError(f"preview --gif/--mp4 needs imageio: {EXTRA}") from None
    return iio


def has_ffmpeg() -> bool:
    """imageio-ffmpeg (and its bundled ffmpeg binary) is installed."""
    try:
        import imageio_ffmpeg

        return bool(imageio_ffmpeg.get_ffmpeg_exe())
    except Exception:  # noqa: BLE001 - not installed, or no binary for this platform
        return False


def check_available(kind: str = "gif") -> None:
    """Raise InputError (naming the extra) when what a preview of ``kind`` needs is missing."""
    _need_matplotlib()
    if kind in ("gif", "mp4"):
        _need_imageio()


# ----------------------------------------------------------------------------- the run

@dataclass
class Part:
    """One written element: topology (from its first frame) and positions per frame."""

    name: str
    role: str                      # "dynamic" or "kinematic"
    triangles: np.ndarray
    segments: np.ndarray           # curve edges (elements without triangles)
    points: list = field(default_factory=list)       # per frame, (n, 3) float64
    velocities: list = field(default_factory=list)   # per frame, (n, 3) or None
    rest: np.ndarray | None = None                   # rest positions for strain


@dataclass
class RunData:
    out: Path
    info: dict
    frames: list
    fps: float
    fmt: str
    parts: list
    shapes: list                   # analytic ShapeCollider dicts from the scene
    up: np.ndarray
    scene_name: str
    start: int
    written: list = field(default_factory=list)
    rest_source: str = ""
    reader: object = None          # (element, frame) -> Geometry; MeshReadError if unreadable

    def read(self, name: str, frame: int):
        return self.reader(name, frame)


def parse_frames(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        a, b = text.split(":")
        a, b = int(a), int(b)
    except ValueError:
        raise InputError(f"--frames {text!r}: expected A:B (two frame numbers)") from None
    if a > b:
        raise InputError(f"--frames {text}: the first frame is after the last")
    return a, b


def parse_camera(text: str | None) -> tuple[float, float, float | None]:
    if text is None:
        return (*DEFAULT_CAMERA, None)
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) not in (2, 3) or not all(math.isfinite(v) for v in vals) or \
            (len(vals) == 3 and vals[2] <= 0):
        raise InputError(f"--camera {text!r}: expected AZ,EL[,DIST] (degrees, degrees, a "
                         f"positive distance in scene units)")
    if not -90 <= vals[1] <= 90:
        raise InputError(f"--camera {text!r}: elevation must be within -90..90 degrees")
    return vals[0], vals[1], (vals[2] if len(vals) == 3 else None)


def parse_size(text: str | None) -> tuple[int, int]:
    if text is None:
        return DEFAULT_SIZE
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size {text!r}: expected WxH in pixels, e.g. 640x480") from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise InputError(f"--size {text}: width and height must be within 16..8192 pixels")
    return w, h


def _frame_name(frame: int) -> str:
    return f"{frame:04d}"


def load_run(out: str | Path, frames: tuple[int, int] | None = None,
             need_rest: bool = False) -> RunData:
    """Read run.json and the frames it lists as written (within ``frames`` A:B)."""
    from .meshfile import MeshReadError

    out = Path(out)
    rj = out / "run.json"
    if not out.is_dir():
        raise InputError(f"preview: {out} is not a folder (give a run's output folder)")
    if not rj.is_file():
        raise InputError(f"preview: no run.json in {out} (not the output folder of "
                         f"`lokigraph run`)")
    try:
        info = json.loads(rj.read_text())
        written = [int(f) for f in info["frames"]["written"]]
        fps = float(info["frames"].get("fps") or 24.0)
        start = int(info["frames"].get("start", written[0] if written else 0))
        fmt = str(info.get("format") or info["output"]["format"])
        names = list(info["output"]["elements"])
    except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
        raise InputError(f"preview: {rj} is not a readable run.json ({type(exc).__name__}: "
                         f"{exc})") from None
    if fmt not in READ_FORMATS:
        raise InputError(f"preview: this run wrote {fmt!r} frames; preview reads "
                         f"{', '.join(READ_FORMATS)} frames")
    if not written:
        raise InputError(f"preview: {out} has no written frames (run.json status "
                         f"{info.get('status')})")
    if frames is not None:
        a, b = frames
        chosen = [f for f in written if a <= f <= b]
        if not chosen:
            raise InputError(f"preview: --frames {a}:{b} holds none of the written frames "
                             f"({written[0]}..{written[-1]})")
    else:
        chosen = written
    scene = info.get("scene") or {}
    raw_elements = {e.get("name"): e for e in scene.get("elements", []) if isinstance(e, dict)}
    roles = info["output"].get("roles") if isinstance(info.get("output"), dict) else None
    reader = _usd_reader(out, info) if fmt == "usd" else _file_reader(out, fmt)
    parts = []
    for name in names:
        comps = (raw_elements.get(name) or {}).get("components") or {}
        role = "kinematic" if "Kinematic" in comps else "dynamic"
        given = roles.get(name) if isinstance(roles, dict) else None
        if isinstance(given, str):  # run.json's output.roles, where a run records them
            role = "dynamic" if given == "dynamic" else "kinematic"
        first = None
        part = None
        for f in chosen:
            path = out / name / f"{_frame_name(f)}.{fmt}" if fmt != "usd" else out / "run.usd"
            try:
                geo = reader(name, f)
            except MeshReadError as exc:
                raise InputError(f"preview: {exc}") from None
            if part is None:
                first = geo
                tris = np.asarray(geo.triangles, np.int64).reshape(-1, 3)
                segs = np.asarray(geo.edges, np.int64).reshape(-1, 2) if not len(tris) \
                    else np.zeros((0, 2), np.int64)
                part = Part(name, role, tris, segs)
            elif geo.vertex_count != first.vertex_count:
                raise InputError(f"preview: {path}: {geo.vertex_count} vertices, the element's "
                                 f"first frame has {first.vertex_count}")
            part.points.append(np.asarray(geo.points, np.float64))
            part.velocities.append(_velocities(geo))
        parts.append(part)
    shapes = []
    for e in scene.get("elements", []):
        comps = (e or {}).get("components") or {} if isinstance(e, dict) else {}
        sc = comps.get("ShapeCollider")
        if isinstance(sc, dict):
            shapes.append(sc)
    g = scene.get("gravity", [0.0, -9.81, 0.0])
    try:
        g = np.asarray(g, np.float64).reshape(3)
        up = -g / np.linalg.norm(g) if np.linalg.norm(g) > 0 else np.array([0.0, 1.0, 0.0])
    except (ValueError, TypeError):
        up = np.array([0.0, 1.0, 0.0])
    sf = info.get("scene_file") or "run"
    run = RunData(out, info, chosen, fps, fmt, parts, shapes, up, Path(str(sf)).stem, start,
                  written, reader=reader)
    if need_rest:
        _attach_rest(run)
    return run


def _file_reader(out: Path, fmt: str):
    """Frames written as one mesh file per element per frame."""
    from .meshfile import read_mesh

    return lambda name, f: read_mesh(out / name / f"{_frame_name(f)}.{fmt}")


def _usd_reader(out: Path, info: dict):
    """Frames of a ``--format usd`` run: the stage run.json names (``output.usd.stage``, else
    ``OUT/run.usd``), each element's prim (``output.usd.prims``) at time code = frame. Topology
    from the prim: mesh faces (fan-triangulated), tet mesh surface faces, or curves (consecutive
    points of each curve joined); velocities when authored."""
    from .geometry import Geometry, MeshReadError
    from .usd import INSTALL_HINT, have_pxr

    if not have_pxr():
        raise InputError(f"preview: this run wrote a USD stage; reading it needs usd-core, "
                         f"which is not installed; {INSTALL_HINT}")
    from pxr import Usd, UsdGeom

    from .usd import _fan

    usd = (info.get("output") or {}).get("usd") or {}
    path = out / "run.usd"
    given = usd.get("stage")
    if given and not path.is_file() and Path(given).is_file():
        path = Path(given)
    stage = Usd.Stage.Open(str(path)) if path.is_file() else None
    if stage is None:
        raise InputError(f"preview: cannot open the run's USD stage {path}")
    prims = usd.get("prims") or {}
    topo: dict = {}

    def read(name: str, frame: int):
        prim = stage.GetPrimAtPath(prims.get(name) or f"/lokigraph/{name}")
        if not prim or not prim.IsA(UsdGeom.PointBased):
            raise MeshReadError(f"{path}: no point-based prim for element {name!r}")
        gp = UsdGeom.PointBased(prim)
        tc = Usd.TimeCode(float(frame))
        pts = gp.GetPointsAttr().Get(tc)
        if pts is None:
            raise MeshReadError(f"{path}: prim {prim.GetPath()} has no points at frame {frame}")
        pts = np.array(pts, np.float64).reshape(-1, 3)
        if name not in topo:
            tris = np.zeros((0, 3), np.int64)
            segs = np.zeros((0, 2), np.int64)
            if prim.IsA(UsdGeom.Mesh):
                m = UsdGeom.Mesh(prim)
                tris = _fan(np.asarray(m.GetFaceVertexCountsAttr().Get() or [], np.int64),
                            np.asarray(m.GetFaceVertexIndicesAttr().Get() or [], np.int64))
            elif hasattr(UsdGeom, "TetMesh") and prim.IsA(UsdGeom.TetMesh):
                tris = np.asarray(UsdGeom.TetMesh(prim).GetSurfaceFaceVertexIndicesAttr().Get()
                                  or [], np.int64).reshape(-1, 3)
            elif prim.IsA(UsdGeom.BasisCurves):
                counts = np.asarray(UsdGeom.BasisCurves(prim).GetCurveVertexCountsAttr().Get()
                                    or [], np.int64)
                starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
                segs = np.array([(s + k, s + k + 1) for s, c in zip(starts, counts)
                                 for k in range(c - 1)], np.int64).reshape(-1, 2)
            topo[name] = (tris, segs)
        tris, segs = topo[name]
        g = Geometry(pts, edges=segs, triangles=tris)
        vel = gp.GetVelocitiesAttr().Get(tc)
        if vel is not None and len(vel) == len(pts):
            g.channels["velocity"] = np.array(vel, np.float64).reshape(-1, 3)
        return g

    return read


def _velocities(geo) -> np.ndarray | None:
    ch = geo.channels
    if "velocity" in ch and np.shape(ch["velocity"]) == (geo.vertex_count, 3):
        return np.asarray(ch["velocity"], np.float64)
    if all(c in ch for c in ("vx", "vy", "vz")):
        return np.stack([np.asarray(ch[c], np.float64).reshape(-1) for c in ("vx", "vy", "vz")],
                        axis=1)
    return None


def _attach_rest(run: RunData) -> None:
    """Rest positions for strain: the scene's geometry (loaded from run.json's scene, relative
    to its file), else the run's start frame if it was written, else the first frame shown."""
    rest = {}
    try:
        from .scene import scene_from_data
        from .yamlio import Locations

        sf = Path(run.info.get("scene_file") or "scene.yaml")
        with contextlib.redirect_stderr(open(os.devnull, "w")):  # noqa: SIM115
            sc = scene_from_data(run.info["scene"], Locations(str(sf)), sf, partial=True)
        for el in sc.elements:
            if el.geometry is not None:
                rest[el.name] = np.asarray(el.geometry.points, np.float64)
    except Exception:  # noqa: BLE001 - the scene's files moved or changed: use a frame
        rest = {}
    from .meshfile import MeshReadError

    sources = set()
    for p in run.parts:
        r = rest.get(p.name)
        if r is not None and r.shape == p.points[0].shape:
            p.rest, src = r, "scene rest"
        else:
            try:
                g = run.read(p.name, run.start)
                ok = g.vertex_count == len(p.points[0])
            except MeshReadError:
                ok = False
            if ok:
                p.rest, src = np.asarray(g.points, np.float64), f"frame {run.start}"
            else:
                p.rest, src = p.points[0], f"frame {run.frames[0]}"
        if p.role == "dynamic":
            sources.add(src)
    run.rest_source = ", ".join(sorted(sources))


# ----------------------------------------------------------------------------- geometry

def _edges(part: Part) -> np.ndarray:
    if len(part.triangles):
        t = part.triangles
        e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
        e.sort(axis=1)
        return np.unique(e, axis=0)
    return part.segments


def vertex_strain(points: np.ndarray, rest: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Mean signed strain (length / rest length - 1) of the edges at each vertex [1]."""
    n = len(points)
    if not len(edges):
        return np.zeros(n)
    L = np.linalg.norm(points[edges[:, 0]] - points[edges[:, 1]], axis=1)
    L0 = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    s = np.where(L0 > 0, L / np.where(L0 > 0, L0, 1.0) - 1.0, 0.0)
    tot = np.bincount(edges.ravel(), np.repeat(s, 2), minlength=n)
    cnt = np.bincount(edges.ravel(), minlength=n)
    return tot / np.maximum(cnt, 1)


def _speeds(run: RunData, part: Part) -> list[np.ndarray]:
    """Per frame, per vertex speed [m/s]: the written velocities, else finite differences with
    the previous written frame (the next one for the run's first frame; zero for a run of one
    frame), read from its file when it is outside the frames shown."""
    from .meshfile import MeshReadError

    out = []
    shown = dict(zip(run.frames, part.points))
    written = run.written

    def points(f):
        if f not in shown:
            try:
                g = run.read(part.name, f)
            except MeshReadError as exc:
                raise InputError(f"preview: {exc}") from None
            shown[f] = np.asarray(g.points, np.float64)
        return shown[f]

    for i, f in enumerate(run.frames):
        v = part.velocities[i]
        if v is not None:
            out.append(np.linalg.norm(v, axis=1))
            continue
        k = written.index(f)
        if len(written) == 1:
            out.append(np.zeros(len(part.points[i])))
            continue
        a, b = (written[k - 1], f) if k > 0 else (f, written[k + 1])
        dt = (b - a) / run.fps
        out.append(np.linalg.norm(points(b) - points(a), axis=1) / dt)
    return out


def _icosphere(level: int = 3):
    from .generators import make_geometry

    g = make_geometry("sphere", {"radius": 1.0, "subdivisions": level})
    return np.asarray(g.points), np.asarray(g.triangles, np.int64)


def _shape_meshes(shapes: list, lo: np.ndarray, hi: np.ndarray):
    """(points, triangles, kind) for analytic colliders; kind "floor" for planes."""
    out = []
    size = max(float(np.linalg.norm(hi - lo)), 1e-3)
    mid = (lo + hi) / 2
    for sc in shapes:
        kind = sc.get("shape", "plane")
        c = np.asarray(sc.get("center", (0, 0, 0)), np.float64)
        try:
            if kind == "plane":
                n = np.asarray(sc.get("normal", (0, 1, 0)), np.float64)
                n = n / np.linalg.norm(n)
                a = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 0, 1.0])
                a /= np.linalg.norm(a)
                b = np.cross(n, a)
                o = mid - np.dot(mid - c, n) * n   # the framing centre dropped onto the plane
                m = 16
                s = np.linspace(-1.2 * size, 1.2 * size, m + 1)
                uu, vv = np.meshgrid(s, s, indexing="ij")
                pts = o + uu.reshape(-1, 1) * a + vv.reshape(-1, 1) * b
                idx = np.arange((m + 1) ** 2).reshape(m + 1, m + 1)
                q = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1)
                q = q.reshape(-1, 4)
                tris = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
                checker = (np.add.outer(np.arange(m), np.arange(m)) % 2).reshape(-1)
                out.append((pts, tris, "floor", np.concatenate([checker, checker]), n, c))
            elif kind == "sphere":
                p, t = _icosphere()
                out.append((c + p * float(sc.get("radius", 0.1)), t, "solid", None, None, None))
            elif kind == "capsule":
                p, t = _icosphere()
                ax = np.asarray(sc.get("axis", (0, 0, 1)), np.float64)
                ax /= np.linalg.norm(ax)
                half = 0.5 * float(sc.get("length", 1.0))
                along = p @ ax
                q = p * float(sc.get("radius", 0.1)) + np.where(along >= 0, half, -half)[:, None] \
                    * ax
                out.append((c + q, t, "solid", None, None, None))
        except (ValueError, TypeError, ZeroDivisionError, FloatingPointError):
            continue
    return out


class Camera:
    """Perspective camera looking at ``target`` from azimuth/elevation about ``up``."""

    def __init__(self, target, radius, up, az, el, dist=None):
        up = np.asarray(up, np.float64)
        a = np.array([0.0, 0.0, 1.0]) if abs(up[2]) < 0.9 else np.array([0.0, -1.0, 0.0])
        h1 = a - np.dot(a, up) * up
        h1 /= np.linalg.norm(h1)
        h2 = np.cross(up, h1)
        az, el = math.radians(az), math.radians(el)
        d = math.cos(el) * (math.cos(az) * h1 + math.sin(az) * h2) + math.sin(el) * up
        self.back = d / np.linalg.norm(d)
        ref = up if abs(np.dot(up, self.back)) < 0.999 else h1
        self.right = np.cross(ref, self.back)
        self.right /= np.linalg.norm(self.right)
        self.cup = np.cross(self.back, self.right)
        self.dist = float(dist) if dist else 5.0 * max(radius, 1e-6)
        self.eye = np.asarray(target, np.float64) + self.dist * self.back
        self.near = 1e-3 * self.dist
        # light: from above and to the left of the camera, a headlight otherwise
        light = 0.9 * self.back + 0.45 * self.cup - 0.35 * self.right
        self.light = light / np.linalg.norm(light)

    def project(self, p: np.ndarray):
        """(n, 2) image-plane coordinates and (n,) depths (distance along the view)."""
        rel = p - self.eye
        z = np.maximum(-(rel @ self.back), self.near)
        uv = np.stack([rel @ self.right, rel @ self.cup], axis=1) / z[:, None]
        return uv, z


# ----------------------------------------------------------------------------- rendering

class Renderer:
    """A z-buffered software rasteriser (numba, supersampled ``ss`` x ``ss`` for antialiasing)
    and one reused Agg figure for the caption and colour bar; ``draw(i)`` renders frame ``i``
    of the run to an RGB array (H, W, 3) uint8."""

    def __init__(self, run: RunData, size=DEFAULT_SIZE, camera=None, color: str = "none",
                 ss: int = 2, ghost: float = GHOST):
        mpl = _need_matplotlib()
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        self.run = run
        self.color = color
        self.W, self.H = size
        self.ss = ss
        self.ghost = ghost
        az, el, dist = camera if camera is not None else (*DEFAULT_CAMERA, None)
        allp = [p for part in run.parts for p in part.points]
        lo = np.min([p.min(0) for p in allp], axis=0)
        hi = np.max([p.max(0) for p in allp], axis=0)
        shapes = _shape_meshes(run.shapes, lo, hi)
        solids = [s[0] for s in shapes if s[2] == "solid"]
        if solids:
            lo = np.minimum(lo, np.min([s.min(0) for s in solids], axis=0))
            hi = np.maximum(hi, np.max([s.max(0) for s in solids], axis=0))
        centre = (lo + hi) / 2
        radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-4)
        self.cam = Camera(centre, radius, run.up, az, el, dist)
        self.shapes = shapes
        self.edges = [_edges(p) for p in run.parts]
        # per-vertex values and their fixed range
        self.values = None
        self.cmap = None
        if color == "strain":
            self.values = [[vertex_strain(P, part.rest, e) for P in part.points]
                           if part.role == "dynamic" else None
                           for part, e in zip(run.parts, self.edges)]
            m = max([np.abs(v).max() for vs in self.values if vs for v in vs] or [0.0])
            m = max(m, 1e-4)
            self.vrange = (-m, m)
            self.cmap = mpl.colormaps["coolwarm"]
            self.clabel = f"edge strain (rest: {run.rest_source})"
        elif color == "speed":
            self.values = [_speeds(run, part) if part.role == "dynamic" else None
                           for part in run.parts]
            m = max([v.max() for vs in self.values if vs for v in vs if len(v)] or [0.0])
            self.vrange = (0.0, max(m, 1e-6))
            self.cmap = mpl.colormaps["YlOrRd"]
            self.clabel = "speed [m/s]"
        # fixed framing: every frame's points (and solid shapes), projected, fit in the image
        uv = np.concatenate([self.cam.project(p)[0] for p in allp + solids])
        ulo, uhi = uv.min(0), uv.max(0)
        span = np.maximum(uhi - ulo, 1e-12)
        right_pad = 0.16 if self.cmap is not None else 0.0
        top = 0.07  # room for the caption
        avail_w, avail_h = self.W * (1 - right_pad) * 0.92, self.H * (1 - top) * 0.92
        self.scale = min(avail_w / span[0], avail_h / span[1])
        mid = (ulo + uhi) / 2
        self.offset = np.array([self.W * (1 - right_pad) / 2, self.H * (1 + top) / 2])
        self.mid = mid
        # the figure: the rendered image, caption, colour bar
        dpi = 100
        self.fig = Figure(figsize=(self.W / dpi, self.H / dpi), dpi=dpi, facecolor=BACKGROUND)
        self.canvas = FigureCanvasAgg(self.fig)
        # placed pixel for pixel (no resampling), under the caption and the colour bar
        self.im = self.fig.figimage(np.full((self.H, self.W, 3), 255, np.uint8), 0, 0,
                                    origin="upper", zorder=-1)
        scale = math.sqrt(self.W * self.H) / math.sqrt(640 * 480)
        self.hair_rad = max(0.6, 0.75 * scale) * ss
        fs = max(7.0, 9.0 * scale)
        self.caption = self.fig.text(0.012, 0.985, "", ha="left", va="top", fontsize=fs,
                                     family="monospace", color=(0.15, 0.15, 0.15))
        self.fig.text(0.988 - right_pad, 0.012, f"{run.scene_name}  az {az:g} el {el:g}",
                      ha="right", va="bottom", fontsize=fs * 0.85, color=(0.45, 0.45, 0.45))
        if self.cmap is not None:
            from matplotlib.cm import ScalarMappable
            from matplotlib.colors import Normalize

            cax = self.fig.add_axes([1 - right_pad + 0.03, 0.12, 0.03, 0.76])
            cb = self.fig.colorbar(ScalarMappable(Normalize(*self.vrange), self.cmap), cax=cax)
            cb.ax.tick_params(labelsize=fs * 0.8)
            cb.set_label(self.clabel, fontsize=fs * 0.85)
        self._static = [self._mesh_colours(pts, tris, None if kind == "floor" else GREY,
                                           checker=checker, smooth=kind != "floor",
                                           ambient=0.75 if kind == "floor" else 0.28)
                        + (pts,) for pts, tris, kind, checker, n, c in shapes]

    def _pixels(self, P):
        uv, z = self.cam.project(P)
        s = self.scale * self.ss
        xy = np.empty_like(uv)
        xy[:, 0] = (uv[:, 0] - self.mid[0]) * s + self.offset[0] * self.ss
        xy[:, 1] = -(uv[:, 1] - self.mid[1]) * s + self.offset[1] * self.ss
        return xy, 1.0 / z

    def _mesh_colours(self, P, tris, base, vcol=None, checker=None, smooth=True,
                      ambient=0.28, back_tint=0.8):
        """Triangles and their shaded corner colours (T, 3, 3).

        Lambert shading, two-sided, from the light: per vertex from area-weighted vertex
        normals (``smooth``) or per triangle; the side facing away from the camera is tinted
        ``back_tint``. ``vcol``: per-vertex colours instead of ``base``; ``checker``: per
        triangle 0/1, a light/lighter grey floor."""
        from .meshfile import vertex_normals

        a, b, c = P[tris[:, 0]], P[tris[:, 1]], P[tris[:, 2]]
        fn = np.cross(b - a, c - a)
        front = np.einsum("ij,ij->i", fn, self.cam.eye - (a + b + c) / 3) >= 0
        tint = np.where(front, 1.0, back_tint)[:, None, None]
        if smooth:
            lam = np.abs(vertex_normals(P, tris) @ self.cam.light)[tris]
        else:
            fn = fn / np.maximum(np.linalg.norm(fn, axis=1), 1e-30)[:, None]
            lam = np.repeat(np.abs(fn @ self.cam.light)[:, None], 3, axis=1)
        k = (ambient + (1 - ambient) * lam)[:, :, None] * tint
        if checker is not None:
            rgb = np.where(checker[:, None, None] == 1, 0.80, 0.90) * np.ones((1, 3, 3))
        elif vcol is not None:
            rgb = vcol[tris]
        else:
            rgb = np.broadcast_to(np.asarray(base, np.float64), (len(tris), 3, 3))
        return (tris, np.clip(rgb * k, 0, 1))

    def draw(self, i: int) -> np.ndarray:
        from ._raster import raster_segments as seg_k, raster_triangles as tri_k

        run = self.run
        H, W = self.H * self.ss, self.W * self.ss
        # two passes, each with its own depth buffer: simulated elements, then colliders
        # (kinematic elements and analytic shapes); composited so that a collider in front of
        # a simulated surface lets it show through (``GHOST``)
        bufs = {"dynamic": (np.ones((H, W, 3)), np.zeros((H, W))),
                "kinematic": (np.ones((H, W, 3)), np.zeros((H, W)))}
        for tris, ccol, pts in self._static:
            xy, iz = self._pixels(pts)
            tri_k(xy, iz, tris, ccol, *bufs["kinematic"])
        k_dyn = k_hair = 0
        for j, part in enumerate(run.parts):
            P = part.points[i]
            vals = self.values[j][i] if self.values is not None and self.values[j] else None
            if part.role == "kinematic":
                base = GREY
            elif len(part.triangles):
                base = PALETTE[k_dyn % len(PALETTE)]
                k_dyn += 1
            else:
                base = HAIR_PALETTE[k_hair % len(HAIR_PALETTE)]
                k_hair += 1
            vrgb = None
            if vals is not None:
                lo, hi = self.vrange
                vrgb = self.cmap(np.clip((vals - lo) / (hi - lo), 0, 1))[:, :3]
            xy, iz = self._pixels(P)
            img, zb = bufs[part.role]
            if len(part.triangles):
                tris, ccol = self._mesh_colours(P, part.triangles, base, vcol=vrgb,
                                                ambient=0.28 if vrgb is None else 0.5)
                tri_k(xy, iz, tris, ccol, img, zb)
            elif len(part.segments):
                s = part.segments
                if vrgb is None:
                    # shaded along the strand by its tangent (Kajiya-Kay diffuse)
                    t = P[s[:, 1]] - P[s[:, 0]]
                    t /= np.maximum(np.linalg.norm(t, axis=1), 1e-30)[:, None]
                    sin = np.sqrt(np.clip(1 - (t @ self.cam.light) ** 2, 0, 1))
                    cols = np.clip(np.asarray(base) * (0.55 + 0.6 * sin)[:, None], 0, 1)
                else:
                    cols = vrgb[s].mean(1)
                rad = self.hair_rad if part.role == "dynamic" else 1.2 * self.hair_rad
                seg_k(xy, iz, s, np.ascontiguousarray(cols), rad, img, zb)
        (img, zd), (kimg, zk) = bufs["dynamic"], bufs["kinematic"]
        front = zk > zd                      # a collider is nearest (or alone)
        ghost = front & (zd > 0)             # ... with a simulated surface behind it
        if self.ghost > 0:
            a = 1.0 - self.ghost
            img[ghost] = a * kimg[ghost] + (1 - a) * img[ghost]
        else:
            ghost[:] = False
        alone = front & ~ghost
        img[alone] = kimg[alone]
        if self.ss > 1:  # box filter: the mean of each ss x ss block
            ss = self.ss
            acc = img[0::ss, 0::ss].copy()
            for dy in range(ss):
                for dx in range(ss):
                    if dy or dx:
                        acc += img[dy::ss, dx::ss]
            img = acc / (ss * ss)
        self.im.set_data((img * 255 + 0.5).astype(np.uint8))
        f = run.frames[i]
        t = (f - run.start) / run.fps
        self.caption.set_text(f"frame {f:4d}   t = {t:6.3f} s")
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()


# ----------------------------------------------------------------------------- outputs

def _write_png(path: Path, img: np.ndarray) -> None:
    from PIL import Image  # matplotlib depends on pillow

    from .run import atomic_write

    atomic_write(path, lambda p: Image.fromarray(img).save(p, format="PNG"))


def render(out: str | Path, kind: str = "gif", frames: tuple[int, int] | None = None,
           camera=None, color: str = "none", size=DEFAULT_SIZE, fps: float | None = None,
           dest: str | Path | None = None, log=None, ghost: float | None = None) -> Path:
    """Render a run's frames; returns the file (GIF/MP4) or folder (PNG) written.

    kind: ``png`` (``OUT/preview/NNNN.png``), ``gif`` (``OUT/preview.gif``) or ``mp4``
    (``OUT/preview.mp4``; a GIF with a message when imageio-ffmpeg is missing). ``dest``
    replaces the default path. Raises InputError for a missing run, frames or dependency and
    OutputError when the result cannot be written.
    """
    log = log or (lambda msg: print(msg, file=sys.stderr))
    if color not in ("none", "strain", "speed"):
        raise InputError(f"--color {color!r}: one of none, strain, speed")
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise InputError(f"--fps {fps:g}: must be a positive number of frames per second")
    check_available(kind)
    if kind == "mp4" and not has_ffmpeg():
        log("preview: MP4 needs imageio-ffmpeg (pip install imageio-ffmpeg); writing a GIF "
            "instead")
        kind = "gif"
        if dest is not None and Path(dest).suffix.lower() == ".mp4":
            dest = Path(dest).with_suffix(".gif")
    out = Path(out)
    run = load_run(out, frames, need_rest=(color == "strain"))
    r = Renderer(run, size, camera, color, ghost=GHOST if ghost is None else ghost)
    fps = float(run.fps if fps is None else fps)
    n = len(run.frames)
    try:
        if kind == "png":
            folder = Path(dest) if dest is not None else out / "preview"
            folder.mkdir(parents=True, exist_ok=True)
            for i in range(n):
                _write_png(folder / f"{_frame_name(run.frames[i])}.png", r.draw(i))
            return folder
        iio = _need_imageio()
        path = Path(dest) if dest is not None else out / f"preview.{kind}"
        path.parent.mkdir(parents=True, exist_ok=True)
        from .run import temp_path

        tmp = temp_path(path)
        if kind == "mp4":  # imageio picks ffmpeg's container from the extension
            tmp = tmp.with_name(tmp.name + ".mp4")
        try:
            if kind == "gif":
                writer = iio.get_writer(tmp, format="GIF", mode="I", duration=1000.0 / fps,
                                        loop=0)
            else:
                writer = iio.get_writer(tmp, format="FFMPEG", mode="I", fps=fps,
                                        codec="libx264", quality=7, macro_block_size=2,
                                        ffmpeg_log_level="error")
            with writer:
                for i in range(n):
                    img = r.draw(i)
                    if kind == "mp4":  # yuv420p needs even sizes
                        img = img[: img.shape[0] // 2 * 2, : img.shape[1] // 2 * 2]
                    writer.append_data(img)
            os.replace(tmp, path)
        finally:
            with contextlib.suppress(OSError):
                tmp.unlink(missing_ok=True)
        return path
    except OSError as exc:
        raise OutputError(f"preview: cannot write: {exc.strerror or exc}"
                          + (f": {exc.filename}" if exc.filename else "")) from None


def plot_stats(out: str | Path, dest: str | Path | None = None) -> Path:
    """Plot run.json's per-frame statistics over frames: ``OUT/run_stats.png``.

    One panel per numeric key (time per frame first, then the solver's statistics: contacts,
    strain, energy ... whatever the run recorded); keys that never change are listed in the
    title instead of given a panel.
    """
    _need_matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    out = Path(out)
    rj = out / "run.json"
    if not rj.is_file():
        raise InputError(f"preview: no run.json in {out} (not the output folder of "
                         f"`lokigraph run`)")
    try:
        info = json.loads(rj.read_text())
        rec = list(info.get("per_frame") or [])
        frames = np.array([float(r["frame"]) for r in rec])
        series = {"time per frame [ms]": np.array([1e3 * float(r["seconds"]) for r in rec])}
        keys = []
        for r in rec:
            for k, v in (r.get("stats") or {}).items():
                if k not in keys and isinstance(v, (int, float)) and not isinstance(v, bool):
                    keys.append(k)
        for k in keys:
            series[k] = np.array([float((r.get("stats") or {}).get(k, np.nan)) for r in rec])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"preview: {rj} is not a readable run.json ({type(exc).__name__}: "
                         f"{exc})") from None
    if not len(rec):
        raise InputError(f"preview: {rj} records no simulated frame (nothing to plot)")
    shown, const = {}, []
    for k, v in series.items():
        fin = v[np.isfinite(v)]
        if k != "time per frame [ms]" and len(fin) and np.all(fin == fin[0]):
            const.append(f"{k} = {fin[0]:g}")
        else:
            shown[k] = v
    n = len(shown)
    cols = 1 if n <= 2 else 2
    rows = math.ceil(n / cols)
    fig = Figure(figsize=(5.2 * cols, 2.1 * rows + 0.6), dpi=100)
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False, sharex=True)
    for ax, (k, v) in zip(axes.ravel(), shown.items()):
        ax.plot(frames, v, lw=1.3, color="C0" if "time" in k else "C1",
                marker="." if len(frames) <= 60 else None, ms=3)
        title = k
        if "time" in k:
            med = float(np.median(v))
            ax.axhline(med, color="0.5", lw=0.8, ls="--")
            title += f" (median {med:.1f}, dashed)"
        ax.set_title(title, fontsize=9, loc="left")
        ax.tick_params(labelsize=8)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("frame", fontsize=8)
    name = Path(str(info.get("scene_file") or "run")).name
    head = (f"{name}: {len(rec)} frames, {float(info.get('total_seconds') or 0):.1f} s, "
            f"status {info.get('status')}")
    if const:
        head += "\nconstant: " + ", ".join(const)
    height = 2.1 * rows + 0.6
    fig.suptitle(head, fontsize=9, x=0.01, y=1 - 0.08 / height, ha="left", va="top")
    fig.tight_layout()  # (leaves room for the suptitle)
    path = Path(dest) if dest is not None else out / "run_stats.png"
    from .run import atomic_write

    try:
        atomic_write(path, lambda p: fig.savefig(p, format="png"))
    except OSError as exc:
        raise OutputError(f"preview: cannot write {path}: {exc.strerror or exc}") from None
    return path


def fluid_slice_image(velocity: np.ndarray, axis: str = "z", vmin: float | None = None,
                      vmax: float | None = None, scale: int = 8) -> np.ndarray:
    """RGB image (uint8) of the speed |u| on the middle slice of a fluid grid across ``axis``,
    ``velocity`` (nx, ny, nz, 3); colour map viridis from ``vmin`` to ``vmax`` (default: the
    slice's range); each cell ``scale`` pixels wide, image rows top to bottom along the second
    axis."""
    from matplotlib import colormaps

    a = "xyz".index(axis)
    sl = np.take(velocity, velocity.shape[a] // 2, axis=a)  # (m, k, 3), the other two axes
    speed = np.linalg.norm(sl, axis=-1)
    lo = float(speed.min()) if vmin is None else float(vmin)
    hi = float(speed.max()) if vmax is None else float(vmax)
    rgba = colormaps["viridis"](np.clip((speed - lo) / max(hi - lo, 1e-12), 0.0, 1.0))
    img = (255 * rgba[..., :3]).astype(np.uint8).transpose(1, 0, 2)[::-1]  # second axis up
    return np.repeat(np.repeat(img, scale, axis=0), scale, axis=1)


def fluid_slices(out: str | Path, axis: str = "z", frames: tuple[int, int] | None = None
                 ) -> list[Path]:
    """PNG slices of every fluid grid a run wrote (``OUT/<element>/NNNN.vti``): the speed on
    the middle plane across ``axis``, one colour scale per element (its speed range over the
    frames), to ``OUT/<element>/slice_<axis>/NNNN.png``. Returns the folders written."""
    _need_matplotlib()
    from .behaviors.fluid.vti import read_vti  # the reader of the files the coupling writes

    out = Path(out)
    if axis not in ("x", "y", "z"):
        raise InputError(f"preview --fluid-slices: axis must be x, y or z (got {axis!r})")
    written = []
    for folder in sorted(d for d in out.iterdir() if d.is_dir()) if out.is_dir() else []:
        files = sorted(f for f in folder.glob("[0-9]*.vti") if f.stem.isdigit())
        if frames is not None:
            files = [f for f in files if frames[0] <= int(f.stem) <= frames[1]]
        if not files:
            continue
        fields = [read_vti(f)["velocity"] for f in files]
        speeds = [np.linalg.norm(v, axis=-1) for v in fields]
        lo, hi = min(float(x.min()) for x in speeds), max(float(x.max()) for x in speeds)
        dest = folder / f"slice_{axis}"
        dest.mkdir(exist_ok=True)
        for f, v in zip(files, fields):
            _write_png(dest / f"{f.stem}.png", fluid_slice_image(v, axis, lo, hi))
        written.append(dest)
    if not written:
        raise InputError(f"{out}: no fluid fields (.vti) to slice; a simulated FluidDomain "
                         f"writes them with write_fields: true")
    return written


def preview_after_run(out: str | Path, log=None) -> list[Path]:
    """``lokigraph run --preview``: ``OUT/preview.gif`` and ``OUT/run_stats.png``."""
    paths = [render(out, "gif", log=log)]
    with contextlib.suppress(InputError):  # a run of a single (unsimulated) frame: no stats
        paths.append(plot_stats(out))
    return paths


# ----------------------------------------------------------------------------- command line

def add_parser(sub) -> None:
    """Add the ``preview`` sub-command to the CLI's sub-parsers."""
    p = sub.add_parser("preview", help="render a run's frames to PNG, GIF or MP4 (matplotlib, "
                       "headless) and plot its run.json statistics",
                       description="Render the frames a run wrote (OUT/run.json) headless: "
                       "shaded triangles, hair as lines, kinematic colliders in grey. Writes "
                       "OUT/preview.gif (default), OUT/preview.mp4 or OUT/preview/NNNN.png; "
                       "--stats writes OUT/run_stats.png (alone, or with a format flag as well). "
                       f"Needs the preview extra: {EXTRA}.")
    p.add_argument("out", help="a run's output folder (holds run.json)")
    p.add_argument("--frames", help="render frames A:B of those written (default: all)")
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--gif", dest="kind", action="store_const", const="gif",
                     help="OUT/preview.gif (default)")
    fmt.add_argument("--mp4", dest="kind", action="store_const", const="mp4",
                     help="OUT/preview.mp4 (needs imageio-ffmpeg; a GIF otherwise)")
    fmt.add_argument("--png", dest="kind", action="store_const", const="png",
                     help="OUT/preview/NNNN.png, one per frame")
    p.add_argument("--camera", help="AZ,EL[,DIST]: azimuth and elevation in degrees about the "
                   "up axis (against gravity), distance in scene units (default 5 radii of the "
                   f"bounding sphere; the view always frames every frame); default {DEFAULT_CAMERA[0]:g},"
                   f"{DEFAULT_CAMERA[1]:g} (a negative azimuth: --camera=-60,30)")
    p.add_argument("--color", default="none", choices=["none", "strain", "speed"],
                   help="colour dynamic elements per vertex by edge strain or speed")
    p.add_argument("--size", help=f"WxH in pixels (default {DEFAULT_SIZE[0]}x{DEFAULT_SIZE[1]})")
    p.add_argument("--solid", action="store_true", help="draw colliders opaque (default: a "
                   "simulated surface behind a collider shows through it)")
    p.add_argument("--fps", type=float, help="playback rate of GIF/MP4 (default: the scene's)")
    p.add_argument("--stats", action="store_true", help="plot run.json's per-frame statistics "
                   "to OUT/run_stats.png")
    p.add_argument("-o", "--output", help="write here instead (a file for GIF/MP4, a folder "
                   "for PNG)")
    p.add_argument("--fluid-slices", metavar="AXIS", choices=["x", "y", "z"],
                   help="also write PNG slices of the fluid grids the run wrote (speed on the "
                   "middle plane across AXIS) to OUT/<fluid element>/slice_AXIS/NNNN.png")
    p.add_argument("--quiet", action="store_true", help="no summary line")


def dispatch(args) -> int:
    """Run ``lokigraph preview`` (errors are LokigraphError subclasses for the CLI to print)."""
    frames = parse_frames(args.frames)
    camera = parse_camera(args.camera)
    size = parse_size(args.size)
    say = (lambda m: None) if args.quiet else print
    if args.stats:
        path = plot_stats(args.out)
        say(f"wrote {path}")
    if args.fluid_slices:
        for folder in fluid_slices(args.out, args.fluid_slices, frames):
            say(f"wrote {folder}/")
    if args.kind is not None or not (args.stats or args.fluid_slices):
        t0 = time.perf_counter()
        path = render(args.out, args.kind or "gif", frames, camera, args.color, size, args.fps,
                      dest=args.output, ghost=0.0 if args.solid else GHOST)
        say(f"wrote {path} ({time.perf_counter() - t0:.1f} s)")
    return 0
