"""VTK image data (``.vti``, XML, raw binary appended) of a fluid grid, written with numpy.

ParaView and Houdini read it: one ``ImageData`` piece of the cells, point data ``velocity``
[m/s] (3 components, cell-centred face averages) and ``pressure`` [Pa], at the cell centres
(``Origin`` = box origin + h / 2, ``Spacing`` = h).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lokigraph.run import atomic_write


def _f(x) -> str:
    return repr(float(x))


def _block(a: np.ndarray) -> bytes:
    raw = np.ascontiguousarray(a, dtype="<f4").tobytes()
    return np.uint64(len(raw)).astype("<u8").tobytes() + raw


def vti_bytes(origin, h, velocity: np.ndarray, pressure: np.ndarray) -> bytes:
    """The file as bytes; ``velocity`` (nx, ny, nz, 3), ``pressure`` (nx, ny, nz)."""
    nx, ny, nz = pressure.shape
    # VTK orders points x fastest: transpose (i, j, k) -> (k, j, i)
    vel = np.transpose(velocity, (2, 1, 0, 3)).reshape(-1, 3)
    pre = np.transpose(pressure, (2, 1, 0)).ravel()
    b_vel, b_pre = _block(vel), _block(pre)
    o = np.asarray(origin, float) + 0.5 * np.asarray(h, float)
    ext = f"0 {nx - 1} 0 {ny - 1} 0 {nz - 1}"
    head = (
        '<?xml version="1.0"?>\n'
        '<VTKFile type="ImageData" version="1.0" byte_order="LittleEndian" '
        'header_type="UInt64">\n'
        f'  <ImageData WholeExtent="{ext}" Origin="{_f(o[0])} {_f(o[1])} {_f(o[2])}" '
        f'Spacing="{_f(h[0])} {_f(h[1])} {_f(h[2])}">\n'
        f'    <Piece Extent="{ext}">\n'
        '      <PointData Vectors="velocity" Scalars="pressure">\n'
        '        <DataArray type="Float32" Name="velocity" NumberOfComponents="3" '
        'format="appended" offset="0"/>\n'
        '        <DataArray type="Float32" Name="pressure" format="appended" '
        f'offset="{len(b_vel)}"/>\n'
        '      </PointData>\n'
        '    </Piece>\n'
        '  </ImageData>\n'
        '  <AppendedData encoding="raw">\n   _')
    tail = '\n  </AppendedData>\n</VTKFile>\n'
    return head.encode() + b_vel + b_pre + tail.encode()


def write_vti(path: Path, origin, h, velocity, pressure) -> None:
    """Write atomically (temporary + rename, :func:`lokigraph.run.atomic_write`)."""
    data = vti_bytes(origin, h, velocity, pressure)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(Path(path), lambda p: Path(p).write_bytes(data))


def read_vti(path: Path) -> dict:
    """Read back what :func:`write_vti` wrote (tests, tools): origin, spacing, velocity
    (nx, ny, nz, 3), pressure (nx, ny, nz)."""
    import re

    raw = Path(path).read_bytes()
    head, _, body = raw.partition(b"<AppendedData encoding=\"raw\">")
    text = head.decode()
    ext = [int(t) for t in re.search(r'WholeExtent="([^"]+)"', text).group(1).split()]
    n = (ext[1] + 1, ext[3] + 1, ext[5] + 1)
    origin = [float(t) for t in re.search(r'Origin="([^"]+)"', text).group(1).split()]
    spacing = [float(t) for t in re.search(r'Spacing="([^"]+)"', text).group(1).split()]
    data = body[body.index(b"_") + 1:]
    out = []
    pos = 0
    for comps in (3, 1):
        size = int(np.frombuffer(data[pos:pos + 8], "<u8")[0])
        arr = np.frombuffer(data[pos + 8:pos + 8 + size], "<f4").astype(np.float64)
        pos += 8 + size
        arr = arr.reshape(n[2], n[1], n[0], comps) if comps == 3 else arr.reshape(n[2], n[1], n[0])
        out.append(np.transpose(arr, (2, 1, 0, 3) if comps == 3 else (2, 1, 0)))
    return {"origin": origin, "spacing": spacing, "velocity": out[0], "pressure": out[1]}
