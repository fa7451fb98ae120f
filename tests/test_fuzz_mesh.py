"""Fuzz corpus for mesh files: seeded mutants of OBJ/PLY/VTU/STL/MSH files (truncations, byte
flips, huge/negative counts, empty files, wrong extensions, junk, NaN/inf coordinates, huge
indices, 2**70 integers, very long lines) plus the hand-made files in tests/data/fuzz_mesh/.

Every case goes through ``read_mesh`` (only MeshReadError may leave it, within a per-case time
limit) and a seeded subset through ``lokigraph validate`` in-process (exit 0 or 2, never 1, no
traceback). The mutants are generated here, deterministically, so the corpus needs no storage.
"""

from __future__ import annotations

import contextlib
import io
import signal
import time
from pathlib import Path

import meshio
import numpy as np
import pytest

from lokigraph.geometry import Geometry, MeshReadError
from lokigraph.meshfile import read_mesh

DATA = Path(__file__).resolve().parent / "data" / "fuzz_mesh"
CASE_SECONDS = 10.0  # one read (or validate) may take this long before it counts as a hang
MUTANTS_PER_BASE = 40
CLI_EVERY = 5  # every 5th mutant also goes through `lokigraph validate`


class _Timeout(Exception):
    pass


@contextlib.contextmanager
def _time_limit(seconds: float):
    """Raise _Timeout in the main thread after ``seconds`` (a hang fails the case, not CI)."""
    def handler(signum, frame):
        raise _Timeout(f"no answer within {seconds} s")

    old = signal.signal(signal.SIGALRM, handler)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


# ----------------------------------------------------------------------------- base files

def _grid(m=4):
    x, z = np.meshgrid(np.linspace(0, 1, m), np.linspace(0, 1, m), indexing="ij")
    pts = np.stack([x.ravel(), np.zeros(m * m), z.ravel()], 1)
    i = np.arange(m * m).reshape(m, m)
    a, b, c, d = i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()
    return pts, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)


def _meshio_bytes(tmp: Path, name: str, **kw) -> bytes:
    pts, tris = _grid()
    p = tmp / name
    pd = {"nx": np.zeros(len(pts)), "ny": np.ones(len(pts)), "nz": np.zeros(len(pts))} \
        if name.endswith(".ply") else {}
    meshio.write(p, meshio.Mesh(pts, [("triangle", tris)], point_data=pd), **kw)
    return p.read_bytes()


def _bases(tmp: Path) -> dict[str, tuple[str, bytes]]:
    obj = ["# base", "o sheet"]
    pts, tris = _grid()
    obj += [f"v {x:.6g} {y:.6g} {z:.6g} 0.5 0.25 1" for x, y, z in pts]
    obj += [f"vt {x:.6g} {z:.6g}" for x, _, z in pts] + ["vn 0 1 0", "g top"]
    obj += [f"f {a + 1}/{a + 1}/1 {b + 1}/{b + 1}/1 {c + 1}/{c + 1}/1" for a, b, c in tris]
    obj += ["g hair", "l 1 2 3 4", "f -1 -2 -3 -4"]
    return {
        "obj": (".obj", ("\n".join(obj) + "\n").encode()),
        "ply_ascii": (".ply", _meshio_bytes(tmp, "a.ply", binary=False)),
        "ply_le": (".ply", _meshio_bytes(tmp, "b.ply", binary=True)),
        "vtu": (".vtu", _meshio_bytes(tmp, "c.vtu", binary=False)),
        "vtu_bin": (".vtu", _meshio_bytes(tmp, "d.vtu", binary=True)),
        "stl": (".stl", _meshio_bytes(tmp, "e.stl", binary=False)),
        "stl_bin": (".stl", _meshio_bytes(tmp, "f.stl", binary=True)),
        "msh": (".msh", _meshio_bytes(tmp, "g.msh", file_format="gmsh22", binary=False)),
    }


# ----------------------------------------------------------------------------- mutations

_NUM = rb"-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?"
_EXTS = [".obj", ".ply", ".vtu", ".stl", ".msh", ".vtk", ".off"]


def _replace_number(data: bytes, rng, new: bytes) -> bytes:
    import re

    hits = [m.span() for m in re.finditer(_NUM, data[:20000])]
    if not hits:
        return data + new
    a, b = hits[int(rng.integers(len(hits)))]
    return data[:a] + new + data[b:]


def _mutate(data: bytes, ext: str, rng) -> tuple[str, str, bytes]:
    """One seeded mutant: (what, extension, bytes)."""
    k = int(rng.integers(14))
    n = len(data)
    if k == 0:
        cut = int(rng.integers(0, n + 1))
        return f"truncate@{cut}", ext, data[:cut]
    if k == 1:
        b = bytearray(data)
        for _ in range(int(rng.integers(1, 9))):
            b[int(rng.integers(n))] = int(rng.integers(256))
        return "byteflip", ext, bytes(b)
    if k == 2:
        new = rng.choice([b"1180591620717411303424", b"-5", b"0", b"999999999999", b"-1",
                          b"4294967295", b"18446744073709551616"])
        return f"count={new.decode()}", ext, _replace_number(data, rng, new)
    if k == 3:
        return "empty", ext, b""
    if k == 4:
        other = str(rng.choice([e for e in _EXTS if e != ext]))
        return f"as{other}", other, data
    if k == 5:
        return "ply-only", ext, rng.choice([b"ply", b"ply\n", b"ply\r\n", b"ply\nformat ascii"])
    if k == 6:
        return "junk", ext, rng.integers(0, 256, int(rng.integers(1, 4000)), np.uint8).tobytes()
    if k == 7:
        new = rng.choice([b"nan", b"inf", b"-inf", b"1e400", b"NaN", b"-nan"])
        out = data
        for _ in range(int(rng.integers(1, 4))):
            out = _replace_number(out, rng, new)
        return f"nonfinite={new.decode()}", ext, out
    if k == 8:
        return "int2**70", ext, _replace_number(data, rng, str(2 ** 70).encode())
    if k == 9:
        cut = int(rng.integers(0, n + 1))
        line = rng.choice([b"v " + b"1 " * 200000, b"9" * 100000, b"f " + b"1/1/1 " * 50000,
                           b"#" * 300000, b"l " + b"-1 " * 100000])
        return "longline", ext, data[:cut] + b"\n" + line + b"\n" + data[cut:]
    if k == 10:  # duplicate a random chunk
        a = int(rng.integers(0, n + 1))
        b = min(n, a + int(rng.integers(1, 200)))
        return "dup", ext, data[:b] + data[a:b] * int(rng.integers(1, 50)) + data[b:]
    if k == 11:  # delete a random chunk
        a = int(rng.integers(0, n + 1))
        return "delete", ext, data[:a] + data[a + int(rng.integers(1, 300)):]
    if k == 12:
        new = rng.choice([b"-3", b"0", b"100000", b"2147483648", b"-2147483649", b"3.5"])
        out = data
        for _ in range(int(rng.integers(1, 4))):
            out = _replace_number(out, rng, new)
        return f"index={new.decode()}", ext, out
    # insert random tokens
    a = int(rng.integers(0, n + 1))
    tok = rng.choice([b" x ", b"\0", b"\n", b"\r", b" / ", b"//", b"\xff\xfe", b"end_header\n",
                      b"element vertex 3\n", b"<DataArray>", b"$EndNodes\n"])
    return "insert", ext, data[:a] + tok + data[a:]


def _cases(tmp: Path):
    bases = _bases(tmp)
    out = []
    for bi, (name, (ext, data)) in enumerate(sorted(bases.items())):
        out.append((f"{name}/original", ext, data))
        for m in range(MUTANTS_PER_BASE):
            rng = np.random.default_rng([20260, bi, m])
            what, e, b = _mutate(data, ext, rng)
            out.append((f"{name}/{m}:{what}", e, b))
    for p in sorted(DATA.iterdir()):
        if p.suffix != ".md":
            out.append((f"data/{p.name}", p.suffix, p.read_bytes()))
    return out


# ----------------------------------------------------------------------------- the test

_SCENE = """lokigraph: 1
frames: {{start: 1, end: 2, fps: 24}}
elements:
  - name: cloth
    geometry: {{file: {file}}}
    components:
      Dynamic: {{mass_density: 0.2}}
      DiscreteShell: {{bend_resistance: 1.0e-6}}
"""


def _validate(scene: Path) -> tuple[int, str]:
    from lokigraph.cli import main

    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            rc = main(["validate", str(scene)])
        except SystemExit as exc:  # argparse only
            rc = exc.code
    return rc, err.getvalue() + out.getvalue()


def test_mesh_fuzz_corpus(tmp_path):
    cases = _cases(tmp_path)
    assert len(cases) >= 300
    failures = []
    n_cli = 0
    t_start = time.perf_counter()
    for i, (name, ext, data) in enumerate(cases):
        p = tmp_path / f"case{i}{ext}"
        p.write_bytes(data)
        t0 = time.perf_counter()
        try:
            with _time_limit(CASE_SECONDS):
                geo = read_mesh(p)
            assert isinstance(geo, Geometry)
        except MeshReadError as exc:
            msg = str(exc)
            if str(p) not in msg or "\n" in msg.strip():
                failures.append(f"{name}: message lacks the path or spans lines: {msg[:200]!r}")
        except _Timeout:
            failures.append(f"{name}: read_mesh hung (> {CASE_SECONDS} s)")
        except BaseException as exc:  # noqa: BLE001 - anything else is the bug we look for
            failures.append(f"{name}: read_mesh raised {type(exc).__name__}: {str(exc)[:200]}")
        if time.perf_counter() - t0 > CASE_SECONDS:
            failures.append(f"{name}: read_mesh took {time.perf_counter() - t0:.1f} s")
        if i % CLI_EVERY == 0 or name.startswith("data/"):
            n_cli += 1
            scene = tmp_path / f"scene{i}.yaml"
            scene.write_text(_SCENE.format(file=p.name))
            try:
                with _time_limit(CASE_SECONDS * 2):
                    rc, text = _validate(scene)
            except _Timeout:
                failures.append(f"{name}: validate hung")
                continue
            if rc not in (0, 2) or "Traceback" in text:
                failures.append(f"{name}: validate exit {rc}: {text[-400:]!r}")
        p.unlink()
    assert n_cli >= 60
    assert not failures, f"{len(failures)} of {len(cases)} cases failed:\n" + "\n".join(failures)
    assert time.perf_counter() - t_start < 60.0


@pytest.mark.parametrize("name", sorted(p.name for p in DATA.iterdir() if p.suffix != ".md"))
def test_hand_made_nasty_files(name):
    with _time_limit(CASE_SECONDS):
        with pytest.raises(MeshReadError, match=name):
            read_mesh(DATA / name)
