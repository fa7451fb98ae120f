"""Mesh files: reading (OBJ and PLY directly, everything else through meshio) and writing frames.

Reading
-------
:func:`read_mesh` returns a :class:`~lokigraph.geometry.Geometry` or raises
:class:`~lokigraph.geometry.MeshReadError` (``"path:line: why"`` where a line is known); no other
exception leaves it, whatever the file holds.

- OBJ (own reader, vectorised: a 10^6-vertex file reads in about a second): ``v`` (optionally
  ``v x y z r g b``: channel ``color`` (n, 3)), ``vt`` and ``vn`` (face-varying ``Geometry.uv`` /
  ``tri_uv`` and ``normals`` / ``tri_normals``), ``f`` (any polygon, fan-triangulated; ``a``,
  ``a/b``, ``a//c``, ``a/b/c``; negative indices count back from the last ``v`` read), ``l``
  polylines (curve edges), ``g`` and ``o`` (``Geometry.groups[name]`` = the vertices of that
  group's faces and lines). Comments (``#``) and other statements (``s``, ``usemtl`` ...) are
  ignored; line continuations (``\\``) are not supported.
- PLY (own reader for ascii and binary little/big endian, falling back to meshio for layouts it
  does not handle, such as binary faces of mixed polygon sizes): the header is checked before
  anything is allocated (bounded size, ``end_header``, non-negative counts within the size
  limits, binary body long enough for the counts). ``x y z``; ``nx ny nz`` -> normals;
  ``red green blue`` -> ``color`` in [0, 1]; ``u v``/``s t``/``texture_u texture_v`` -> per-vertex
  ``uv``; every other vertex property -> a channel of that name; ``face`` ``vertex_indices``;
  ``edge`` ``vertex1 vertex2``.
- Everything else (VTU, VTK, MSH, STL, OFF ...) through meshio; its point data become channels
  (``normals``/``Normals``, ``uv``/``UV``/``TCoords`` and ``color`` are recognised). meshio's
  ``sys.exit`` and every exception it raises become MeshReadError.

Counts above :data:`MAX_VERTICES` and :data:`MAX_FACES` are refused before allocation.

Writing
-------
:func:`write_mesh` writes one frame (OBJ and PLY directly, VTU through meshio): texture
coordinates and normals when the input had them (normals recomputed from the written positions,
area weighted, in the input's layout, so hard edges stay hard), curves in OBJ as one ``l``
polyline per strand, velocities in PLY (``vx vy vz``) and VTU (point data ``velocity``). OBJ has
no place for velocities; they are not written there. PLY has no polyline element and VTU curves
are written as two-point ``line`` cells: meshio (which writes VTU here and which most readers
of our output use) has no VTK ``poly_line`` cell type and cannot read one back. PLY and VTU
carry per-vertex uv only: with a UV seam (a vertex with two texture coordinates) uv goes to
OBJ alone.
"""

from __future__ import annotations

import contextlib
import io
import re
import warnings
from pathlib import Path

import numpy as np

MAX_VERTICES = 20_000_000
"""Largest vertex count a mesh file may declare or hold (checked before allocating)."""
MAX_FACES = 40_000_000
"""Largest count of faces (triangles after triangulation), edges, tetrahedra or texture/normal
rows a mesh file may hold (checked before allocating)."""
MAX_PLY_HEADER_BYTES = 1 << 16
"""A PLY header longer than this is refused (real headers are well under 1 KiB)."""

_Z2 = lambda: np.zeros((0, 2), np.int64)  # noqa: E731
_Z3 = lambda: np.zeros((0, 3), np.int64)  # noqa: E731


def _plural(word: str) -> str:
    return {"vertex": "vertices", "texture": "texture coordinates"}.get(word, word + "s")


def read_mesh(path: str | Path) -> Geometry:
    """Read a mesh file into a Geometry (see the module docstring for what each format gives).

    Raises MeshReadError (and nothing else) when the file cannot give geometry.
    """
    path = Path(path)
    try:
        if not path.is_file():
            raise MeshReadError(f"mesh file not found: {path}" if not path.exists()
                                else f"not a file: {path}")
        suffix = path.suffix.lower()
        if suffix == ".obj":
            return _read_obj(path)
        if suffix == ".ply":
            geo = _read_ply(path)
            if geo is not None:
                return geo
        return _read_meshio(path)
    except MeshReadError:
        raise
    except RecursionError:
        raise MeshReadError(f"cannot read mesh {path}: nesting too deep") from None
    except MemoryError:
        raise MeshReadError(f"cannot read mesh {path}: not enough memory") from None
    except OSError as exc:
        raise MeshReadError(f"cannot read mesh {path}: {exc.strerror or exc}") from None
    except Exception as exc:  # noqa: BLE001 - a reader bug must still be a clean error
        raise MeshReadError(f"cannot read mesh {path}: {type(exc).__name__}: {exc}") from None


def _check_count(path, what: str, count: int, limit: int) -> None:
    if count > limit:
        raise MeshReadError(f"{path}: {count} {what} exceed the limit of {limit} "
                            f"(lokigraph.meshfile.MAX_{'VERTICES' if limit == MAX_VERTICES else 'FACES'})")


# ----------------------------------------------------------------------------- meshio

def _read_meshio(path: Path) -> Geometry:
    import meshio

    size = path.stat().st_size
    if size == 0:
        raise MeshReadError(f"cannot read mesh {path}: empty file")
    if path.suffix.lower() == ".stl":
        _check_stl(path, size)
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            mesh = _meshio_read(meshio, path)
    except MeshReadError:
        raise
    except SystemExit:  # meshio.read calls sys.exit(1) on some malformed files
        raise MeshReadError(f"cannot read mesh {path}: malformed file") from None
    except RecursionError:
        raise MeshReadError(f"cannot read mesh {path}: nesting too deep") from None
    except Exception as exc:  # noqa: BLE001 - meshio raises many types; report them all
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise MeshReadError(f"cannot read mesh {path}: {msg[:200]}") from None
    pts = np.asarray(mesh.points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] not in (2, 3):
        raise MeshReadError(f"cannot read mesh {path}: points have shape {pts.shape}")
    _check_count(path, "vertices", len(pts), MAX_VERTICES)
    if pts.shape[1] == 2:
        pts = np.hstack([pts, np.zeros((len(pts), 1))])
    geo = _from_cells(pts, [(c.type, np.asarray(c.data)) for c in mesh.cells])
    for name, data in mesh.point_data.items():
        arr = np.asarray(data)
        if arr.shape[:1] != (len(pts),) or arr.dtype.kind not in "biuf":
            continue
        _attach_point_data(geo, str(name), arr.astype(np.float64))
    return geo


def _meshio_read(meshio, path: Path):
    """meshio.read without its print and sys.exit: each reader the extension allows, in turn;
    the last reader's error is raised."""
    try:
        from meshio._helpers import _filetypes_from_path, reader_map
    except ImportError:  # pragma: no cover - meshio's layout changed: the public call
        return meshio.read(path)
    fmts = _filetypes_from_path(path)
    if not fmts:
        raise MeshReadError(f"cannot read mesh {path}: unknown file extension")
    err: Exception | None = None
    for fmt in fmts:
        reader = reader_map.get(fmt)
        if reader is None:
            continue
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                return reader(str(path))
        except meshio.ReadError as exc:
            err = exc
    raise MeshReadError(f"cannot read mesh {path} as {' or '.join(fmts)}: {err}")


def _check_stl(path: Path, size: int) -> None:
    """An STL file is binary (84 + 50 bytes per triangle) or text starting with ``solid`` and
    holding ``facet``/``vertex`` lines; meshio reads anything else as numbers or exits."""
    with open(path, "rb") as fh:
        head = fh.read(84)
        if len(head) == 84 and 84 + 50 * int.from_bytes(head[80:84], "little") == size:
            return
        text = head + fh.read(4096)
    if not text.lstrip().lower().startswith(b"solid") or b"vertex" not in text.lower():
        raise MeshReadError(f"cannot read mesh {path}: not an STL file (neither binary, with "
                            f"84 + 50 bytes per triangle, nor text starting with 'solid')")


def _attach_point_data(geo: Geometry, name: str, arr: np.ndarray) -> None:
    """Per-vertex data from a file: normals and uv go to their fields, the rest to channels."""
    low = name.lower()
    tri = geo.triangles
    if low in ("normals", "normal", "n") and arr.ndim == 2 and arr.shape[1] == 3:
        geo.normals, geo.tri_normals = arr, tri.copy()
    elif (low in ("uv", "st", "tcoords", "texture_coordinates", "texcoords")
          and arr.ndim == 2 and arr.shape[1] >= 2):
        geo.uv, geo.tri_uv = arr[:, :2].copy(), tri.copy()
    elif low in ("color", "colors", "colour", "rgb", "rgba") and arr.ndim == 2 \
            and arr.shape[1] >= 3:
        geo.channels["color"] = arr[:, :3]
    else:
        geo.channels[name] = arr


def _from_cells(pts, cells) -> Geometry:
    edges, tris, tets = [], [], []
    for ctype, data in cells:
        if data.ndim != 2 or data.dtype.kind not in "iu":
            continue
        data = data.astype(np.int64)
        if ctype == "line":
            edges.append(data)
        elif ctype == "triangle":
            tris.append(data)
        elif ctype == "quad":
            tris.append(data[:, [0, 1, 2]])
            tris.append(data[:, [0, 2, 3]])
        elif ctype == "tetra":
            tets.append(data)
        elif ctype.startswith("polygon"):
            k = data.shape[1]
            for j in range(1, k - 1):  # fan (loop over polygon corners, not over faces)
                tris.append(data[:, [0, j, j + 1]])
    cat = lambda lst, w: np.concatenate(lst) if lst else np.zeros((0, w), np.int64)  # noqa: E731
    return Geometry(pts, cat(edges, 2), cat(tris, 3), cat(tets, 4))


# ----------------------------------------------------------------------------- text helpers

class _Lines:
    """Line table of a text buffer: ``start[i]``/``end[i]`` byte offsets of line i (end at its
    newline), all (L,) int64."""

    def __init__(self, data: bytes):
        self.buf = np.frombuffer(data, np.uint8)
        nl = np.flatnonzero(self.buf == 10)
        self.start = np.empty(len(nl), np.int64)
        if len(nl):
            self.start[0] = 0
            self.start[1:] = nl[:-1] + 1
        self.end = nl.astype(np.int64)

    def char(self, k: int) -> np.ndarray:
        """Byte k of every line (a newline where the line is shorter), shape (L,)."""
        pos = np.minimum(self.start + k, self.end)
        return self.buf[pos]

    def gather(self, sel: np.ndarray, skip: int):
        """Text of lines ``sel`` from byte ``skip`` on, each ended by its newline, and the token
        count of every selected line: (str, (len(sel),) int64)."""
        if not len(sel):
            return "", np.zeros(0, np.int64)
        s = self.start[sel] + skip
        e = self.end[sel] + 1
        brk = np.flatnonzero(np.diff(sel) != 1) + 1
        if len(brk) < 64:  # a few blocks of consecutive lines: copy them, blank the tags
            a = np.concatenate([[0], brk])
            b = np.concatenate([brk, [len(sel)]]) - 1
            text = np.concatenate([self.buf[self.start[sel[i]]:e[j]] for i, j in zip(a, b)])
            lens = e - self.start[sel]
            pos = np.cumsum(lens) - lens
            for k in range(skip):
                text[pos + k] = 32
            s = self.start[sel]
        else:
            d = np.zeros(len(self.buf) + 1, np.int8)
            d[s] = 1
            d[e] -= 1
            text = self.buf[np.cumsum(d[:-1], dtype=np.int8).view(bool)]
        sp = (text == 32) | (text == 9) | (text == 10) | (text == 11) | (text == 12)
        tok = ~sp
        tok[1:] &= sp[:-1]
        bounds = np.zeros(len(sel) + 1, np.int64)
        np.cumsum(e - s, out=bounds[1:])
        counts = np.diff(np.searchsorted(np.flatnonzero(tok), bounds))
        return text.tobytes().decode("latin-1"), counts


def _numbers(text: str, expected: int) -> np.ndarray | None:
    """All numbers of a whitespace-separated text, or None when a token is not a number."""
    if expected == 0:
        return np.zeros(0)
    try:
        vals = np.fromstring(text, sep=" ")
    except ValueError:
        return None
    return vals if vals.size == expected else None


# ----------------------------------------------------------------------------- OBJ

def _read_obj(path: Path) -> Geometry:
    """OBJ reader (see the module docstring). Vectorised: lines are classified by their first
    bytes and each statement kind is parsed in bulk; a kind whose bulk parse fails is parsed
    again line by line to name the bad line."""
    data = path.read_bytes()
    if b"\r" in data:
        data = data.replace(b"\r", b" ")
    if b"#" in data:
        data = re.sub(rb"#[^\n]*", b"", data)
    if data[:1] in (b" ", b"\t") or b"\n " in data or b"\n\t" in data:
        data = re.sub(rb"(?m)^[ \t]+", b"", data)
    if not data.endswith(b"\n"):
        data += b"\n"
    L = _Lines(data)
    c0, c1, c2 = L.char(0), L.char(1), L.char(2)

    def ws(c):
        return (c == 32) | (c == 9) | (c == 10)

    kind = {
        "v": np.flatnonzero((c0 == 118) & ws(c1)),
        "vt": np.flatnonzero((c0 == 118) & (c1 == 116) & ws(c2)),
        "vn": np.flatnonzero((c0 == 118) & (c1 == 110) & ws(c2)),
        "f": np.flatnonzero((c0 == 102) & ws(c1)),
        "l": np.flatnonzero((c0 == 108) & ws(c1)),
        "g": np.flatnonzero(((c0 == 103) | (c0 == 111)) & ws(c1)),
    }
    nv = len(kind["v"])
    _check_count(path, "vertices", nv, MAX_VERTICES)
    for k in ("vt", "vn", "f", "l"):
        _check_count(path, f"'{k}' lines", len(kind[k]), MAX_FACES)
    if nv == 0:
        raise MeshReadError(f"{path}: no vertices ('v' lines) in OBJ file")

    def slow_line(i):
        return data[L.start[i]:L.end[i]].decode("latin-1").split()

    # ---- v / vt / vn: floats
    def floats(k, skip, need, width, pad=None):
        sel = kind[k]
        text, cnt = L.gather(sel, skip)
        short = cnt < need
        vals = _numbers(text, int(cnt.sum())) if not short.any() else None
        if vals is None:  # slow path: name the bad line
            rows = []
            for i in sel:
                parts = slow_line(i)[1:]
                try:
                    if len(parts) < need:
                        raise ValueError
                    rows.append([float(p) for p in parts])
                except ValueError:
                    raise MeshReadError(f"{path}:{i + 1}: cannot parse OBJ '{k}' line: "
                                        f"{data[L.start[i]:L.end[i]][:80].decode('latin-1')!r}"
                                        f" (expected {need} numbers)") from None
            cnt = np.array([len(r) for r in rows], np.int64)
            vals = np.array([x for r in rows for x in r], np.float64)
        off = np.cumsum(cnt) - cnt
        out = np.zeros((len(sel), width))
        for c in range(width):
            have = cnt > c
            if pad is None or have.all():
                out[:, c] = vals[off + c] if have.all() else np.where(have, vals[np.minimum(
                    off + c, len(vals) - 1)], 0.0)
            else:
                out[have, c] = vals[off[have] + c]
        return out, cnt, vals, off

    pts, vcnt, vvals, voff = floats("v", 1, 3, 3)
    geo = Geometry(pts)
    if nv and np.all(vcnt >= 6):
        geo.channels["color"] = np.stack([vvals[voff + 3], vvals[voff + 4], vvals[voff + 5]], 1)
    uvt = floats("vt", 2, 1, 2, pad=0.0)[0]
    nrm = floats("vn", 2, 3, 3)[0]

    # ---- f / l: index tuples
    def indices(k):
        """(counts per line (m,), raw components (ntok, 3) int64, 0 = absent)."""
        sel = kind[k]
        text, cnt = L.gather(sel, 1)
        comp = None
        ntok = int(cnt.sum())
        if ntok and "/" in text:
            text = text.replace("//", "/0/")
            s = text.count("/")
            if s % ntok == 0 and s // ntok in (1, 2):
                w = s // ntok + 1
                vals = _numbers(text.replace("/", " "), ntok * w)
                if vals is not None:
                    # every token must have the same slash count: check line by line totals
                    comp = vals.reshape(ntok, w)
            # a file mixing 'a', 'a/b' and 'a/b/c' forms falls to the slow path below
        elif ntok:
            vals = _numbers(text, ntok)
            comp = None if vals is None else vals.reshape(ntok, 1)
        else:
            comp = np.zeros((0, 1))
        if comp is not None and comp.size and not (
                np.all(np.abs(comp) <= 2.0 ** 53) and np.all(comp == np.trunc(comp))):
            comp = None
        if comp is not None:
            out = np.zeros((ntok, 3), np.int64)
            out[:, :comp.shape[1]] = comp.astype(np.int64)
            return cnt, out
        rows, counts = [], []
        for i in sel:  # slow path: mixed forms or a bad line
            parts = slow_line(i)[1:]
            for p in parts:
                sub = p.split("/")
                try:
                    if len(sub) > 3 or not sub[0]:
                        raise ValueError
                    r = [int(x) if x else 0 for x in sub] + [0] * (3 - len(sub))
                    if max(abs(x) for x in r) > 2 ** 53:
                        raise ValueError
                except ValueError:
                    raise MeshReadError(f"{path}:{i + 1}: cannot parse OBJ '{k}' index {p[:40]!r}"
                                        ) from None
                rows.append(r)
            counts.append(len(parts))
        return (np.array(counts, np.int64),
                np.array(rows, np.int64).reshape(-1, 3))

    def resolve(k, cnt, raw, col, table_lines, n_table, what):
        """Raw OBJ indices of column col -> 0-based rows; errors name the line."""
        r = raw[:, col]
        if not len(r) or (r.min() > 0 and r.max() <= n_table):
            return r - 1
        line_of_tok = np.repeat(kind[k], cnt)
        before = np.searchsorted(table_lines, line_of_tok)  # table rows defined before the line
        idx = np.where(r > 0, r - 1, before + r)
        bad = (r == 0) | (idx < 0) | (idx >= n_table)
        if bad.any():
            t = int(np.argmax(bad))
            raise MeshReadError(f"{path}:{int(line_of_tok[t]) + 1}: {what} index {int(r[t])} out "
                                f"of range (the file has {n_table} {_plural(what)}"
                                + (f", {int(before[t])} before this line)" if r[t] < 0 else ")"))
        return idx

    fcnt, fraw = indices("f")
    if (fcnt < 3).any():
        i = int(kind["f"][np.argmax(fcnt < 3)])
        raise MeshReadError(f"{path}:{i + 1}: a face needs at least 3 vertices")
    ntri = int((fcnt - 2).sum()) if len(fcnt) else 0
    _check_count(path, "triangles", ntri, MAX_FACES)
    fv = resolve("f", fcnt, fraw, 0, kind["v"], nv, "vertex")
    # fan triangulation: corners (first, first + j, first + j + 1) of every polygon
    if len(fcnt) and np.all(fcnt == 3):
        corners = np.arange(3 * len(fcnt), dtype=np.int64).reshape(-1, 3)
    else:
        first = np.cumsum(fcnt) - fcnt
        tri_line = np.repeat(np.arange(len(fcnt)), fcnt - 2)
        j = np.arange(ntri) - np.repeat(np.cumsum(fcnt - 2) - (fcnt - 2), fcnt - 2) + 1
        b = first[tri_line]
        corners = np.stack([b, b + j, b + j + 1], axis=1)
    geo.triangles = fv[corners]
    if ntri and np.all(fraw[:, 1] != 0) and len(uvt):
        geo.uv = uvt
        geo.tri_uv = resolve("f", fcnt, fraw, 1, kind["vt"], len(uvt), "texture")[corners]
    if ntri and np.all(fraw[:, 2] != 0) and len(nrm):
        geo.normals = nrm
        geo.tri_normals = resolve("f", fcnt, fraw, 2, kind["vn"], len(nrm), "normal")[corners]

    lcnt, lraw = indices("l")
    lv = resolve("l", lcnt, lraw, 0, kind["v"], nv, "vertex")
    if len(lv):
        last = np.zeros(len(lv), bool)
        last[np.cumsum(lcnt)[lcnt > 0] - 1] = True  # no edge from a line's last token onwards
        a = np.flatnonzero(~last)
        geo.edges = np.stack([lv[a], lv[a + 1]], axis=1)
        _check_count(path, "edges", len(geo.edges), MAX_FACES)

    if len(kind["g"]):
        geo.groups = _obj_groups(data, L, kind, fcnt, fv, lcnt, lv)
    return geo


def _obj_groups(data, L, kind, fcnt, fv, lcnt, lv) -> dict[str, np.ndarray]:
    """Vertices of every ``g``/``o`` group: a face or line belongs to the current ``o`` object
    and to every name of the current ``g`` statement."""
    glines = kind["g"]
    is_o = L.char(0)[glines] == 111
    names: list[list[str]] = []
    for i in glines:  # loop over group statements (few), not over faces
        names.append(data[L.start[i] + 1:L.end[i]].decode("utf-8", "replace").split())
    out: dict[str, list[np.ndarray]] = {}
    tok_line = np.concatenate([np.repeat(kind["f"], fcnt), np.repeat(kind["l"], lcnt)])
    tok_v = np.concatenate([fv, lv])
    for want_o in (False, True):
        stmt = np.flatnonzero(is_o == want_o)
        if not len(stmt):
            continue
        owner = np.searchsorted(glines[stmt], tok_line, side="right") - 1  # current statement
        keep = owner >= 0
        own, vv = owner[keep], tok_v[keep]
        nv = int(vv.max()) + 1 if len(vv) else 1
        key = np.unique(own * nv + vv)
        own_u, v_u = key // nv, key % nv
        bounds = np.searchsorted(own_u, np.arange(len(stmt) + 1))
        for s, gi in enumerate(stmt):
            verts = v_u[bounds[s]:bounds[s + 1]]
            for name in names[gi]:
                out.setdefault(name, []).append(verts)
    return {k: np.unique(np.concatenate(v)).astype(np.int64) for k, v in out.items()}


# ----------------------------------------------------------------------------- PLY

_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2",
              "int16": "i2", "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4",
              "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4", "double": "f8",
              "float64": "f8"}


def _ply_header(path: Path):
    """Parse and check a PLY header without reading the body.

    Returns (format, elements, body_offset, file_size); elements is a list of
    ``(name, count, props)`` with props a list of ``(name, type)`` or
    ``(name, ("list", count_type, item_type))``.
    """
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(MAX_PLY_HEADER_BYTES)
    if not head.startswith(b"ply") or head[3:4] not in (b"\n", b"\r", b""):
        raise MeshReadError(f"{path}: not a PLY file (no 'ply' magic line)")
    m = re.search(rb"(^|\n)end_header[ \t]*\r?\n", head)
    if m is None:
        raise MeshReadError(f"{path}: PLY header has no 'end_header' line within the first "
                            f"{MAX_PLY_HEADER_BYTES} bytes (truncated or not a PLY file)")
    body = m.end()
    fmt = None
    elements: list = []
    for lineno, raw in enumerate(head[:m.start()].decode("latin-1").splitlines()[1:], 2):
        parts = raw.split()
        if not parts or parts[0] in ("comment", "obj_info"):
            continue
        where = f"{path}:{lineno}"
        if parts[0] == "format":
            if len(parts) < 2 or parts[1] not in ("ascii", "binary_little_endian",
                                                  "binary_big_endian"):
                raise MeshReadError(f"{where}: unknown PLY format {raw.strip()[:60]!r}")
            fmt = parts[1]
        elif parts[0] == "element":
            if len(parts) != 3 or not re.fullmatch(r"[+-]?\d{1,30}", parts[2]):
                raise MeshReadError(f"{where}: bad PLY element line {raw.strip()[:60]!r}")
            count = int(parts[2])
            if count < 0:
                raise MeshReadError(f"{where}: negative element count {count}")
            limit = MAX_VERTICES if parts[1] == "vertex" else MAX_FACES
            if count > limit:
                raise MeshReadError(f"{where}: {count} {parts[1]} elements exceed the limit of "
                                    f"{limit} (lokigraph.meshfile."
                                    f"{'MAX_VERTICES' if limit == MAX_VERTICES else 'MAX_FACES'})")
            elements.append((parts[1], count, []))
        elif parts[0] == "property":
            if not elements:
                raise MeshReadError(f"{where}: PLY property before any element")
            if len(parts) == 5 and parts[1] == "list" and parts[2] in _PLY_TYPES \
                    and parts[3] in _PLY_TYPES and _PLY_TYPES[parts[2]][0] in "iu" \
                    and _PLY_TYPES[parts[3]][0] in "iuf":
                elements[-1][2].append((parts[4], ("list", _PLY_TYPES[parts[2]],
                                                   _PLY_TYPES[parts[3]])))
            elif len(parts) == 3 and parts[1] in _PLY_TYPES:
                elements[-1][2].append((parts[2], _PLY_TYPES[parts[1]]))
            else:
                raise MeshReadError(f"{where}: bad PLY property line {raw.strip()[:60]!r}")
        else:
            raise MeshReadError(f"{where}: unknown PLY header line {raw.strip()[:60]!r}")
    if fmt is None:
        raise MeshReadError(f"{path}: PLY header has no 'format' line")
    if fmt != "ascii":
        need = 0
        for name, count, props in elements:
            rec = sum(np.dtype(t).itemsize if isinstance(t, str) else np.dtype(t[1]).itemsize
                      for _, t in props)
            need += count * rec  # lower bound: lists may be empty
        if size - body < need:
            raise MeshReadError(f"{path}: PLY body has {size - body} bytes, the header's element "
                                f"counts need at least {need} (truncated file or bad counts)")
    elif size - body < sum(c for _, c, _ in elements):
        raise MeshReadError(f"{path}: PLY body has {size - body} bytes, too short for "
                            f"{sum(c for _, c, _ in elements)} records (truncated file or bad "
                            f"counts)")
    return fmt, elements, body, size


def _read_ply(path: Path) -> Geometry | None:
    """Own PLY reader; None when the layout is one it leaves to meshio (after the header
    checks, so meshio never sees a header that could make it exit, hang or over-allocate)."""
    fmt, elements, body, size = _ply_header(path)
    with open(path, "rb") as fh:
        fh.seek(body)
        raw = fh.read()
    parsed: dict[str, dict] = {}
    if fmt == "ascii":
        text = raw.replace(b"\r", b" ")
        if not text.endswith(b"\n"):
            text += b"\n"
        L = _Lines(text)
        nonblank = np.flatnonzero(L.end > L.start)  # blank lines hold no record
        pos = 0
        for name, count, props in elements:
            sel = nonblank[pos:pos + count]
            if len(sel) < count:
                raise MeshReadError(f"{path}: PLY body ends inside element {name!r} "
                                    f"({len(sel)} of {count} records)")
            pos += count
            txt, cnt = L.gather(sel, 0)
            vals = _numbers(txt, int(cnt.sum()))
            if vals is None:
                raise MeshReadError(f"{path}: non-numeric value in PLY element {name!r}")
            lists = [i for i, (_, t) in enumerate(props) if not isinstance(t, str)]
            if not lists:
                if np.any(cnt != len(props)):
                    return None  # records not one per line: meshio's problem
                parsed[name] = {p: vals[i::len(props)] if len(props) else vals
                                for i, (p, _) in enumerate(props)}
            elif len(lists) == 1 and lists[0] == 0 and name == "face":
                k = vals[np.cumsum(cnt) - cnt] if len(cnt) else np.zeros(0)
                if np.any(k != cnt - len(props)) or np.any(k < 0):
                    return None
                parsed[name] = {props[0][0]: (k.astype(np.int64), vals, cnt)}
            else:
                return None
        return _ply_geometry(path, parsed)
    end = "<" if fmt == "binary_little_endian" else ">"
    off = 0
    for name, count, props in elements:
        lists = [i for i, (_, t) in enumerate(props) if not isinstance(t, str)]
        if not lists:
            dt = np.dtype([(f"p{i}", end + t) for i, (_, t) in enumerate(props)])
            if off + count * dt.itemsize > len(raw):
                raise MeshReadError(f"{path}: PLY body ends inside element {name!r}")
            rec = np.frombuffer(raw, dt, count=count, offset=off)
            parsed[name] = {p: rec[f"p{i}"] for i, (p, _) in enumerate(props)}
            off += count * dt.itemsize
        elif name == "face" and lists == [0] and count:
            _, (_, ct, it) = props[0]
            first = np.frombuffer(raw, end + ct, count=1, offset=off)[0] \
                if off + np.dtype(ct).itemsize <= len(raw) else -1
            k = int(first)
            if k < 3 or k > 64:
                return None
            dt = np.dtype([("k", end + ct), ("i", end + it, (k,))]
                          + [(f"p{i}", end + t) for i, (_, t) in enumerate(props[1:])])
            if off + count * dt.itemsize > len(raw):
                return None  # mixed sizes or truncated: meshio decides
            rec = np.frombuffer(raw, dt, count=count, offset=off)
            if np.any(rec["k"] != k):
                return None  # mixed polygon sizes: meshio
            parsed[name] = {props[0][0]: rec["i"].astype(np.int64)}
            off += count * dt.itemsize
        elif count == 0:
            parsed[name] = {}
        else:
            return None
    return _ply_geometry(path, parsed)


def _fan(polys) -> np.ndarray:
    """Triangles of polygons: a (F, k) index array, or ascii ``(k (F,), values, tokens (F,))``."""
    if isinstance(polys, np.ndarray):
        k = polys.shape[1]
        if k == 3:
            return polys
        return np.concatenate([polys[:, [0, j, j + 1]] for j in range(1, k - 1)]) \
            if k > 3 else np.zeros((0, 3), np.int64)
    k, vals, cnt = polys
    if np.any(k < 3):
        raise MeshReadError("a face needs at least 3 vertices")
    if np.any(vals != np.trunc(vals)) or np.any(np.abs(vals) > 2.0 ** 53):
        raise MeshReadError("non-integer vertex index in a face")
    ntri = int((k - 2).sum())
    _check_count("PLY", "triangles", ntri, MAX_FACES)
    first = np.cumsum(cnt) - cnt + 1
    tri_f = np.repeat(np.arange(len(k)), k - 2)
    j = np.arange(ntri) - np.repeat(np.cumsum(k - 2) - (k - 2), k - 2) + 1
    b = first[tri_f]
    return vals[np.stack([b, b + j, b + j + 1], axis=1)].astype(np.int64)


def _ply_geometry(path: Path, parsed: dict) -> Geometry:
    vx = parsed.get("vertex")
    if vx is None or not all(c in vx for c in "xyz"):
        raise MeshReadError(f"{path}: PLY file has no vertex element with x, y, z")
    pts = np.stack([np.asarray(vx[c], np.float64) for c in "xyz"], axis=1)
    geo = Geometry(pts)
    face = parsed.get("face", {})
    poly = face.get("vertex_indices", face.get("vertex_index"))
    if poly is not None:
        try:
            geo.triangles = _fan(poly)
        except MeshReadError as exc:
            raise MeshReadError(f"{path}: {exc}") from None
    edge = parsed.get("edge", {})
    if "vertex1" in edge and "vertex2" in edge:
        e1, e2 = np.asarray(edge["vertex1"]), np.asarray(edge["vertex2"])
        if np.any(e1 != np.trunc(e1)) or np.any(e2 != np.trunc(e2)):
            raise MeshReadError(f"{path}: non-integer vertex index in an edge")
        geo.edges = np.stack([e1, e2], axis=1).astype(np.int64)
    used = set("xyz")
    if all(c in vx for c in ("nx", "ny", "nz")):
        geo.normals = np.stack([np.asarray(vx[c], np.float64) for c in ("nx", "ny", "nz")], 1)
        geo.tri_normals = geo.triangles.copy()
        used |= {"nx", "ny", "nz"}
    for u, v in (("u", "v"), ("s", "t"), ("texture_u", "texture_v")):
        if u in vx and v in vx:
            geo.uv = np.stack([np.asarray(vx[u], np.float64), np.asarray(vx[v], np.float64)], 1)
            geo.tri_uv = geo.triangles.copy()
            used |= {u, v}
            break
    if all(c in vx for c in ("red", "green", "blue")):
        cols = [vx[c] for c in ("red", "green", "blue")]
        scale = 255.0 if np.asarray(cols[0]).dtype.kind in "iu" or (
            len(cols[0]) and max(float(np.max(c)) for c in cols) > 1.0) else 1.0
        geo.channels["color"] = np.stack([np.asarray(c, np.float64) for c in cols], 1) / scale
        used |= {"red", "green", "blue"}
    for name, arr in vx.items():
        if name not in used:
            geo.channels[name] = np.asarray(arr, np.float64)
    return geo


# ----------------------------------------------------------------------------- writing

def vertex_normals(points: np.ndarray, triangles: np.ndarray,
                   corners: np.ndarray | None = None, rows: int | None = None) -> np.ndarray:
    """Area-weighted unit normals [1]: the sum of the (unnormalised, twice-area) normals of
    the triangles around each row, normalised.

    points: (n, 3) [m]; triangles: (T, 3). corners: the row of each triangle corner (T, 3),
    default ``triangles`` (one row per vertex); rows: row count, default n.
    Returns (rows, 3); rows touched by no triangle (or only degenerate ones) get (0, 0, 0).
    """
    corners = triangles if corners is None else corners
    rows = len(points) if rows is None else rows
    p0, p1, p2 = points[triangles[:, 0]], points[triangles[:, 1]], points[triangles[:, 2]]
    fn = np.cross(p1 - p0, p2 - p0)
    out = np.zeros((rows, 3))
    for c in range(3):  # loop over the 3 vector components, bincount over corners
        out[:, c] = np.bincount(corners.ravel(), np.repeat(fn[:, c], 3), minlength=rows)
    ln = np.sqrt(np.einsum("ij,ij->i", out, out))
    ok = ln > 0
    out[ok] /= ln[ok, None]
    return out


_CHAIN_MEMO: list = []  # (edges copy, n, chains) of the last few topologies written


def curve_chains(edges: np.ndarray, n: int) -> list[np.ndarray]:
    """:func:`_curve_chains`, remembered for the last few topologies: a run writes the same
    strands every frame, so the walk over edges happens once per run, not once per frame."""
    e = np.asarray(edges, np.int64)
    for key, kn, chains in _CHAIN_MEMO:
        if kn == n and key.shape == e.shape and np.array_equal(key, e):
            return chains
    chains = _curve_chains(e, n)
    _CHAIN_MEMO.insert(0, (e.copy(), n, chains))
    del _CHAIN_MEMO[4:]
    return chains


def _curve_chains(edges: np.ndarray, n: int) -> list[np.ndarray]:
    """Split curve edges into chains (strands): maximal paths through vertices of degree 2.

    Returns a list of vertex index arrays, each a polyline. A closed loop repeats its first
    vertex at the end; vertices of degree 3 or more end chains (each branch its own chain).
    For strands stored in order (edges (i, i+1)) this is vectorised; otherwise a walk over
    the edges (at write time only).
    """
    e = np.asarray(edges, np.int64)
    if not len(e):
        return []
    # fast path: edges (i, i+1) in increasing order: chains are runs of consecutive edges
    if np.all(e[:, 1] == e[:, 0] + 1) and np.all(e[1:, 0] > e[:-1, 0]):
        brk = np.flatnonzero(e[1:, 0] != e[:-1, 1]) + 1
        starts = np.concatenate([[0], brk])
        stops = np.concatenate([brk, [len(e)]])
        return [np.arange(e[a, 0], e[b - 1, 1] + 1) for a, b in zip(starts, stops)]
    deg = np.bincount(e.ravel(), minlength=n)
    adj: dict[int, list[tuple[int, int]]] = {}
    for k, (a, b) in enumerate(e.tolist()):  # write-time walk over edges
        adj.setdefault(a, []).append((b, k))
        adj.setdefault(b, []).append((a, k))
    used = np.zeros(len(e), bool)
    chains = []

    def walk(v, k):
        chain = [v]
        while True:
            used[k] = True
            a, b = e[k]
            v = int(b if a == v else a)
            chain.append(v)
            if deg[v] != 2:
                break
            nxt = [kk for _, kk in adj[v] if not used[kk]]
            if not nxt:
                break
            k = nxt[0]
        return np.asarray(chain, np.int64)

    for v in sorted(adj, key=lambda x: (deg[x] == 2, x)):  # chain ends first, then loops
        for _, k in adj[v]:
            if not used[k]:
                chains.append(walk(v, k))
    return chains


def write_mesh(path: Path, points: np.ndarray, geo: Geometry, fmt: str, *,
               velocities: np.ndarray | None = None) -> None:
    """Write one frame.

    path: output file; points: positions [m], (n, 3); geo: topology (and the input's uv and
    normal layout); fmt: ``obj``, ``ply`` or ``vtu``; velocities: [m/s], (n, 3), written to PLY
    (``vx vy vz``) and VTU (point data ``velocity``); OBJ cannot hold them.

    Triangles are written as faces (with ``vt``/``vn`` when the input had them; normals
    recomputed from ``points``), curve edges as OBJ polylines (one per strand; PLY ``edge``
    elements and VTU ``line`` cells), tetrahedra in VTU only (OBJ and PLY get their triangles,
    if any). Positions are written with 10 significant digits in OBJ (relative error below
    5e-10) and as doubles in PLY and VTU.
    """
    points = np.asarray(points, np.float64)
    if fmt == "obj":
        _write_obj(path, points, geo)
    elif fmt == "ply":
        _write_ply(path, points, geo, velocities)
    elif fmt == "vtu":
        _write_vtu(path, points, geo, velocities)
    else:
        raise ValueError(f"unknown mesh format {fmt!r}")


def _fmt_rows(prefix: str, arr: np.ndarray, spec: str) -> bytes:
    """Rows of a 2-d array as text lines ``prefix v0 v1 ...`` (vectorised %-formatting)."""
    if not len(arr):
        return b""
    w = arr.shape[1]
    line = prefix + " ".join([spec] * w) + "\n"
    return (line * len(arr) % tuple(arr.ravel().tolist())).encode()


def _write_obj(path: Path, points: np.ndarray, geo: Geometry) -> None:
    tri = geo.triangles
    parts = [_fmt_rows("v ", points, "%.10g")]  # 5e-10 relative
    has_uv, has_n = geo.has_uv, geo.has_normals
    if has_uv:
        parts.append(_fmt_rows("vt ", geo.uv, "%.10g"))
    if has_n:
        nrm = vertex_normals(points, tri, geo.tri_normals, len(geo.normals))
        parts.append(_fmt_rows("vn ", nrm, "%.6g"))
    if len(tri):
        cols = [tri + 1]
        if has_uv:
            cols.append(geo.tri_uv + 1)
        if has_n:
            cols.append(geo.tri_normals + 1)
        if len(cols) == 1:
            parts.append(_fmt_rows("f ", tri + 1, "%d"))
        else:
            sep = "/" if has_uv else "//"
            corner = sep.join(["%d"] * len(cols))
            stacked = np.stack(cols, axis=2).reshape(len(tri), -1)
            line = "f " + " ".join([corner] * 3) + "\n"
            parts.append((line * len(tri) % tuple(stacked.ravel().tolist())).encode())
    if len(geo.edges):
        for ch in curve_chains(geo.edges, len(points)):  # loop over strands, not vertices
            parts.append(("l " + " ".join(map(str, (ch + 1).tolist())) + "\n").encode())
    with open(path, "wb") as fh:
        fh.write(b"".join(parts))


def _write_ply(path: Path, points, geo, velocities) -> None:
    n = len(points)
    fields = [("x", points[:, 0]), ("y", points[:, 1]), ("z", points[:, 2])]
    if geo.has_normals:
        nrm = vertex_normals(points, geo.triangles)
        fields += [("nx", nrm[:, 0]), ("ny", nrm[:, 1]), ("nz", nrm[:, 2])]
    vuv = geo.vertex_uv()
    if vuv is not None:
        fields += [("s", vuv[:, 0]), ("t", vuv[:, 1])]
    if velocities is not None:
        vel = np.asarray(velocities, np.float64).reshape(n, 3)
        fields += [("vx", vel[:, 0]), ("vy", vel[:, 1]), ("vz", vel[:, 2])]
    vdt = np.dtype([(name, "<f8") for name, _ in fields])
    vrec = np.empty(n, vdt)
    for name, arr in fields:
        vrec[name] = arr
    head = ["ply", "format binary_little_endian 1.0", "comment written by lokigraph",
            f"element vertex {n}"] + [f"property double {name}" for name, _ in fields]
    tri = geo.triangles
    frec = np.empty(len(tri), np.dtype([("k", "u1"), ("i", "<i4", (3,))]))
    frec["k"] = 3
    frec["i"] = tri
    head += [f"element face {len(tri)}", "property list uchar int vertex_indices"]
    e = geo.edges
    erec = np.empty(len(e), np.dtype([("a", "<i4"), ("b", "<i4")]))
    erec["a"], erec["b"] = (e[:, 0], e[:, 1]) if len(e) else (0, 0)
    if len(e):
        head += [f"element edge {len(e)}", "property int vertex1", "property int vertex2"]
    head.append("end_header\n")
    with open(path, "wb") as fh:
        fh.write("\n".join(head).encode())
        fh.write(vrec.tobytes())
        fh.write(frec.tobytes())
        if len(e):
            fh.write(erec.tobytes())


def _write_vtu(path: Path, points, geo, velocities) -> None:
    import meshio

    cells = []
    if len(geo.tetrahedra):
        cells.append(("tetra", geo.tetrahedra))
    if len(geo.triangles):
        cells.append(("triangle", geo.triangles))
    if len(geo.edges):
        cells.append(("line", geo.edges))
    if not cells:
        cells.append(("vertex", np.arange(len(points)).reshape(-1, 1)))
    pdata = {}
    if velocities is not None:
        pdata["velocity"] = np.asarray(velocities, np.float64).reshape(len(points), 3)
    if geo.has_normals:
        pdata["normals"] = vertex_normals(points, geo.triangles)
    vuv = geo.vertex_uv()
    if vuv is not None:
        pdata["uv"] = vuv
    meshio.write(path, meshio.Mesh(points, cells, point_data=pdata), file_format="vtu")


# At the end: geometry.py re-exports read_mesh/write_mesh from here, so either module can be
# imported first (the names below are only needed at call time).
from .geometry import Geometry, MeshReadError  # noqa: E402
