"""Fuzz corpus of scene and graph YAML: no input may crash ``lokigraph`` (exit 1, a traceback)
or hang it.

The corpus (see :func:`build_corpus`) is deterministic: every mutant is drawn from a
``random.Random`` seeded by its base file's name and its number, so the list of cases, their ids
and their contents are the same on every machine and every run. It holds

* **structured mutants** of every shipped scene (``graphs/examples/*.yaml``,
  ``graphs/bench/*.yaml``) and of the README's scene, ``MUTANTS_PER_SCENE`` each: a key
  deleted; a value retyped (NaN, +-inf, 1e308, 2**64, -2**63, -1, 0, strings, lists, maps, null,
  booleans, deep lists, unicode, a 5000-character string); a value wrapped in a list or a map; an
  unknown key added; a vertex index made huge or negative (lists of ints, ``Pins``, channels,
  ``Stitch.pairs``, ``Collider.nocollide_sets``, ``Attachment.vertices``); extreme frame ranges,
  frame rates and substeps; a bad sequence pattern; bad ``graph_overrides``; elements
  duplicated, dropped or replaced by junk; a component added with junk parameters;
* **text mutants** of the same files: a line re-indented (spaces or a tab), duplicated (a
  duplicate key) or deleted, the file truncated, a character replaced by YAML punctuation,
  unicode or binary junk inserted (the file then may not be UTF-8), a BOM or CRLF line ends;
* **graph mutants** of the shipped graphs (``graphs/default.yaml``,
  ``graphs/bench/minimal_cloth.yaml``), each referenced from a small valid scene;
* **hand-written cases** of every crash and hang seen: alias bombs ("billion laughs"), a
  recursive alias, nesting 10^4 deep in flow and block style, integers of 5000 and 10^5 digits,
  NaN in gravity, ``Wind.speed`` and keys, ``fps: 1e308``, ``frames.start: -2**63``, sequence
  patterns such as ``{frame:zz}.obj`` and ``{frame[0]}.obj``, huge indices in every field that
  holds vertex indices, bad tags (``!!python/object``, ``!!binary``, ``!!float abc``),
  impossible dates, NUL characters, empty and binary files, a folder as the scene or the graph.

Each case is checked with ``lokigraph.cli.main(["validate", path])`` run in-process inside a
worker subprocess (fast: the package is imported once); a handful of valid mutants are also
*run* for 2 frames (``main(["run", ...])``) to catch crashes that only happen at run time (the
``fps: 1e308`` division by zero did). Every case must exit 0 or 2 (``run``: 0, 2 or 3) and print
no traceback. The parent enforces a per-case time limit (``CASE_LIMIT_S``): a case that exceeds
it kills the worker (a hang inside compiled code included), fails with its id, and the worker is
restarted on the next case. The worker's address space is capped so that a runaway allocation
fails fast instead of exhausting the machine.

Run one case by hand: ``python tests/test_fuzz_yaml.py --show CASE_ID`` prints its file.
"""

from __future__ import annotations

import json
import os
import queue
import random
import re
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
GRAPHS = ROOT / "graphs"
BASE_DIRS = {"examples": GRAPHS / "examples", "bench": GRAPHS / "bench"}
MUTANTS_PER_SCENE = 10
TEXT_MUTANTS_PER_SCENE = 4
MUTANTS_PER_GRAPH = 10
CASE_LIMIT_S = 20.0  # validate of a small scene takes well under a second
RUN_LIMIT_S = 45.0   # a run may compile kernels on a cold numba cache
MEMORY_LIMIT = 6 << 30

NAN, INF = float("nan"), float("inf")
HUGE_INDICES = [2**31, 2**31 - 1 + 7, 2**63, 2**64 + 1, 10**40, -1, -(2**63)]
JUNK = [NAN, INF, -INF, 1e308, -1e308, 1e-320, 10**30, 2**64, -(2**63), -1, 0, -0.5, 1.5,
        "", "abc", "x" * 5000, [], {}, [1, 2, 3], [[[[[[[[]]]]]]]], {"a": {"b": {"c": 1}}}, None,
        True, False, "ünïcødé ☃ \u202e\u200b", "{frame:zz}", ["a", None, 2.5], "-1", "1e999",
        "../../../../nonexistent"]
BAD_PATTERNS = ["{frame:zz}.obj", "{frame[0]}.obj", "{frame.real}.obj", "{frame!r}.obj",
                "{0}.obj", "{}.obj", "{frame", "frame}.obj", "{frame:999999999d}.obj",
                "{frame:>{frame}}.obj", "{f}.obj", "no_field.obj", "{frame:04d}{x}.obj",
                "{frame:,}.obj", "{frame:%}.obj", "{{frame}}.obj", "\u202e{frame}.obj"]
BAD_FRAMES = [{"start": -(2**63), "end": 2}, {"start": 1, "end": 2**63}, {"start": 5, "end": 1},
              {"start": 1, "end": 10**7 + 5}, {"fps": 1e308}, {"fps": 1e-300}, {"fps": 0},
              {"fps": -24}, {"fps": NAN}, {"fps": INF}, {"start": 1.5}, {"start": "one"},
              {"end": None}, {"start": -10**7, "end": 10**7}, {"fps": 99999.0}]
COMPONENT_NAMES = ["Dynamic", "Pins", "DiscreteShell", "Rod", "Volume", "Goal", "Attachment",
                   "Stitch", "Pressure", "Rigid", "Collider", "CollisionGroup",
                   "CollisionResponse", "Wind", "Drag", "ShapeCollider", "FluidDomain",
                   "Kinematic", "RestSpring", "Dinamic", "NoSuchComponent"]


@dataclass
class Case:
    id: str
    argv: list
    limit: float = CASE_LIMIT_S
    codes: tuple = (0, 2)
    note: str = ""


@dataclass
class Result:
    id: str
    rc: object = None
    output: str = ""
    secs: float = 0.0
    problems: list = field(default_factory=list)


# ---------------------------------------------------------------------------------------------
# corpus


def _readme_scenes() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```yaml\n(.*?)```", text, re.S)
    return [b for b in blocks if re.search(r"^lokigraph: 1", b, re.M)]


def _bases() -> tuple[list, list]:
    """(scenes, graphs): (name, subdir, text) of every shipped scene and graph, sorted."""
    import yaml

    scenes, graphs = [], []
    for sub, d in sorted(BASE_DIRS.items()):
        for p in sorted(d.glob("*.yaml")):
            text = p.read_text(encoding="utf-8")
            data = yaml.safe_load(text)
            if isinstance(data, dict) and "lokigraph" in data:
                scenes.append((p.name, sub, text))
            elif isinstance(data, dict) and "domains" in data:
                graphs.append((p.name, sub, text))
    for i, text in enumerate(_readme_scenes()):
        scenes.append((f"readme{i}.yaml", "readme", text))
    graphs.append(("default.yaml", "graphs", (GRAPHS / "default.yaml").read_text("utf-8")))
    return scenes, graphs


def _paths(data, prefix=()):
    """Every (path, value) below ``data`` (mapping keys and list indices), depth first."""
    out = []
    if isinstance(data, dict):
        for k, v in data.items():
            out.append((prefix + (k,), v))
            out.extend(_paths(v, prefix + (k,)))
    elif isinstance(data, list):
        for i, v in enumerate(data):
            out.append((prefix + (i,), v))
            out.extend(_paths(v, prefix + (i,)))
    return out


def _parent(data, path):
    for p in path[:-1]:
        data = data[p]
    return data


def _set(data, path, value):
    _parent(data, path)[path[-1]] = value


def _elements(data) -> list[dict]:
    els = data.get("elements") if isinstance(data, dict) else None
    return [e for e in els if isinstance(e, dict)] if isinstance(els, list) else []


def _mutate(data: dict, rng: random.Random) -> str:
    """Apply one structured mutation to ``data`` in place; return its description."""
    op = rng.choice(["delete", "retype", "retype", "wrap", "unknown_key", "huge_index",
                     "huge_index", "numeric", "frames", "sequence", "overrides", "elements",
                     "component", "selection_field"])
    paths = _paths(data)
    if op == "delete" and paths:
        path, _ = rng.choice(paths)
        del _parent(data, path)[path[-1]]
        return f"delete {_fmt(path)}"
    if op in ("retype", "delete") and paths:
        path, _ = rng.choice(paths)
        value = rng.choice(JUNK)
        _set(data, path, value)
        return f"retype {_fmt(path)}={_short(value)}"
    if op == "wrap" and paths:
        path, v = rng.choice(paths)
        _set(data, path, [v] if rng.random() < 0.5 else {"x": v})
        return f"wrap {_fmt(path)}"
    if op == "unknown_key":
        maps = [(p, v) for p, v in paths if isinstance(v, dict)] + [((), data)]
        path, m = rng.choice(maps)
        key = rng.choice(["extra", "nmae", "Dynamic", "", "ключ", "1", "null"])
        m[key] = rng.choice(JUNK)
        return f"unknown key {key!r} in {_fmt(path)}"
    if op == "huge_index":
        return _huge_index(data, paths, rng)
    if op == "numeric":
        nums = [(p, v) for p, v in paths if isinstance(v, (int, float)) and not isinstance(v,
                                                                                          bool)]
        if nums:
            path, _ = rng.choice(nums)
            value = rng.choice([NAN, INF, -INF, 1e308, -1e308, 0, -1, 10**30, 2**63, 1e-320,
                                -(10**9)])
            _set(data, path, value)
            return f"numeric {_fmt(path)}={_short(value)}"
    if op == "frames":
        change = rng.choice(BAD_FRAMES)
        fr = data.get("frames") if isinstance(data.get("frames"), dict) else {}
        data["frames"] = {**fr, **change}
        if rng.random() < 0.3:
            data["substeps"] = rng.choice([10**9, 0, -4, 10000, 2**63, 1.5])
        return f"frames {_short(change)} substeps={data.get('substeps')}"
    if op == "sequence":
        els = [e for e in _elements(data)]
        pattern = rng.choice(BAD_PATTERNS)
        if els:
            e = rng.choice(els)
            e["geometry"] = {"sequence": pattern}
            e.setdefault("components", {})
            if isinstance(e["components"], dict):
                e["components"]["Kinematic"] = {}
            return f"sequence {pattern!r} on {e.get('name')!r}"
    if op == "overrides":
        choice = rng.choice([
            {"stretch": {"importance": NAN}}, {"stretch": {"importanc": 0.5}},
            {"nucleus_solver": {"iterations": 10**12}}, {"nucleus_solver": {"iterations": -1}},
            {"no_such_node": {"x": 1}}, {"bend": 5}, {"bend": [1, 2]}, {"": {}},
            {"collisions": {"final_rounds": "many"}}, {"nucleus_solver": None},
            {"stretch": {"order": 10**40}}, {"tethers": {"importance": 0.0}}])
        data["graph_overrides"] = choice
        return f"graph_overrides={_short(choice)}"
    if op == "elements":
        els = data.get("elements")
        if isinstance(els, list) and els:
            sub = rng.choice(["dup", "drop", "junk", "shuffle_dup"])
            if sub == "dup":
                els.append(json.loads(json.dumps(rng.choice(els), default=str)))
            elif sub == "drop":
                els.pop(rng.randrange(len(els)))
            elif sub == "junk":
                els[rng.randrange(len(els))] = rng.choice(JUNK)
            else:
                els.insert(0, els[-1])
            return f"elements {sub}"
    if op == "component":
        els = _elements(data)
        if els:
            e = rng.choice(els)
            comps = e.get("components")
            if not isinstance(comps, dict):
                comps = e["components"] = {}
            name = rng.choice(COMPONENT_NAMES)
            comps[name] = rng.choice([{"junk_field": 1}, {"stiffness": NAN}, None, [], "x",
                                      {"members": ["nobody", 5]}, {"source": "nobody",
                                                                   "target": "ghost"},
                                      {"thickness": -1}, {"mass_density": INF},
                                      {"speed": NAN, "keys": [{"frame": NAN}]},
                                      {"keys": [{"frame": 10**40}]}])
            return f"component {name}={_short(comps[name])} on {e.get('name')!r}"
    if op == "selection_field":
        els = _elements(data)
        if els:
            e = rng.choice(els)
            value = rng.choice([{"vertices": [2**63]}, {"file": "/nonexistent/map.npy"},
                                {"vertices": "abc"}, 7, {"vertices": [0], "value": NAN},
                                {"select": "top"}, {"attribute": "nope"}])
            chans = e.get("channels")
            if not isinstance(chans, dict):
                chans = e["channels"] = {}
            chans["fz"] = value
            return f"channel fz={_short(value)} on {e.get('name')!r}"
    # fallback: retype the root's first key
    data["frames"] = rng.choice(JUNK)
    return f"retype frames={_short(data['frames'])}"


def _huge_index(data, paths, rng) -> str:
    value = rng.choice(HUGE_INDICES)
    int_lists = [(p, v) for p, v in paths if isinstance(v, list) and v
                 and all(isinstance(x, int) and not isinstance(x, bool) for x in v)]
    if int_lists and rng.random() < 0.5:
        path, lst = rng.choice(int_lists)
        lst[rng.randrange(len(lst))] = value
        return f"huge index {_fmt(path)}={value}"
    els = _elements(data)
    if not els:
        data["elements"] = els = [{"name": "fz"}]
    e = rng.choice(els)
    comps = e.get("components")
    if not isinstance(comps, dict):
        comps = e["components"] = {}
    where = rng.choice(["Pins", "channels", "Stitch", "nocollide", "Attachment"])
    if where == "Pins":
        comps["Pins"] = {"vertices": [0, value]}
    elif where == "channels":
        e["channels"] = {"fz": {"vertices": [value]}}
    elif where == "Stitch":
        comps["Stitch"] = {"a": e.get("name", "x"), "b": e.get("name", "x"),
                           "pairs": [[0, value]]}
    elif where == "nocollide":
        comps["Collider"] = {"nocollide_sets": {"s": [value]}}
    else:
        comps["Attachment"] = {"source": e.get("name", "x"), "target": e.get("name", "x"),
                               "vertices": [value]}
    return f"huge index {where}={value} on {e.get('name')!r}"


def _fmt(path) -> str:
    return ".".join(str(p) for p in path) or "<root>"


def _short(value, n: int = 40) -> str:
    s = repr(value)
    return s if len(s) <= n else s[:n - 3] + "..."


def _text_mutate(text: str, rng: random.Random) -> tuple[bytes, str]:
    lines = text.splitlines(keepends=True) or ["\n"]
    op = rng.choice(["indent", "dup_line", "del_line", "truncate", "punct", "unicode", "junk",
                     "bom_crlf", "tab"])
    i = rng.randrange(len(lines))
    if op == "indent":
        d = rng.choice([-4, -2, -1, 1, 3])
        lines[i] = (" " * d + lines[i]) if d > 0 else lines[i][min(-d, len(lines[i]) - len(
            lines[i].lstrip(" "))):]
    elif op == "tab":
        lines[i] = "\t" + lines[i]
    elif op == "dup_line":
        lines.insert(i, lines[i])
    elif op == "del_line":
        del lines[i]
    elif op == "truncate":
        t = "".join(lines)
        return t[:rng.randrange(len(t) + 1)].encode("utf-8"), "truncate"
    elif op == "punct":
        t = "".join(lines)
        k = rng.randrange(len(t))
        c = rng.choice(list(":{}[]-&*!|>'\"%@`#,?\\"))
        return (t[:k] + c + t[k + 1:]).encode("utf-8"), f"punct {c!r} at {k}"
    elif op == "unicode":
        t = "".join(lines)
        k = rng.randrange(len(t))
        u = rng.choice(["\u202e", "\u200b", "\ufeff", "☃", "\U0001f600", "\x85", "\u2028",
                        "\x07", "\x00", "é"])
        return (t[:k] + u + t[k:]).encode("utf-8"), f"unicode {u!r} at {k}"
    elif op == "junk":
        t = "".join(lines).encode("utf-8")
        k = rng.randrange(len(t))
        junk = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 16)))
        return t[:k] + junk + t[k:], f"junk {len(junk)} bytes at {k}"
    else:
        t = "".join(lines)
        return ("\ufeff" + t.replace("\n", "\r\n")).encode("utf-8"), "bom_crlf"
    return "".join(lines).encode("utf-8"), f"{op} line {i + 1}"


SMALL_SCENE = """\
lokigraph: 1
graph: {graph}
frames: {{start: 1, end: 2, fps: 24}}
output: {{dir: out_small}}
elements:
  - name: cloth
    geometry: {{generator: grid, params: {{resolution: [4, 4]}}}}
    components:
      Dynamic: {{mass_density: 0.2}}
      DiscreteShell: {{}}
      Pins: {{vertices: [0, 4]}}
"""
"""A small valid scene; the hand-written cases append elements or top-level keys to it."""


def _special_cases() -> dict[str, bytes]:
    """Hand-written cases: name -> file contents (bytes)."""
    s = SMALL_SCENE.format(graph="default")
    laughs = "lokigraph: 1\n" + "".join(
        f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * 9)}]\n" if i else "l0: &l0 [lol, lol, lol]\n"
        for i in range(10)) + "elements: *l9\n"
    cases = {
        "alias_bomb": laughs,
        "alias_bomb_map": "lokigraph: 1\na: &a {x: 1, y: 2, z: 3, w: 4}\n" + "".join(
            f"b{i}: &b{i} [{', '.join(['*a' if i == 0 else f'*b{i - 1}'] * 10)}]\n"
            for i in range(8)) + "graph_overrides: {stretch: *b7}\n",
        "alias_recursive": "lokigraph: 1\nelements: &e [*e]\n",
        "alias_recursive_map": "lokigraph: 1\nframes: &f {start: 1, end: *f}\n",
        "alias_ok": s.replace("Pins: {vertices: [0, 4]}", "Pins: {vertices: &v [0, 4]}")
        + "seed: 3\n",
        "deep_flow_list": "lokigraph: 1\nelements: " + "[" * 10000 + "]" * 10000 + "\n",
        "deep_flow_map": "lokigraph: 1\nframes: " + "{a: " * 5000 + "1" + "}" * 5000 + "\n",
        "deep_block": "lokigraph: 1\nx:\n" + "".join(" " * (i + 1) + f"k{i}:\n"
                                                   for i in range(3000)) + "\n",
        "deep_unclosed": "lokigraph: 1\nx: " + "[" * 50000 + "\n",
        "bigint_5000": s + "seed: " + "9" * 5000 + "\n",
        "bigint_100000": s + "seed: " + "7" * 100000 + "\n",
        "bigint_in_vertices": s.replace("[0, 4]", "[0, " + "1" * 4400 + "]"),
        "bigint_negative": s + "seed: -" + "9" * 4301 + "\n",
        "bigint_key": s + "9" * 5000 + ": 1\n",
        "bigint_hex": s + "seed: 0x" + "f" * 5000 + "\n",
        "bigint_sexagesimal": s + "seed: 1:" + "5" * 5000 + "\n",
        "float_overflow": s + "gravity: [0, -1e999, 0]\n",
        "nan_gravity": s + "gravity: [.nan, -9.81, 0]\n",
        "inf_gravity": s + "gravity: [0, -.inf, 0]\n",
        "nan_wind": s + "  - name: w\n    components: {Wind: {speed: .nan}}\n",
        "nan_wind_key": s + "  - name: w\n    components: {Wind: {keys: [{frame: 1, speed: .nan}"
                            "]}}\n",
        "nan_kinematic_key": s + "  - name: k\n    geometry: {generator: grid}\n    components: "
                                 "{Kinematic: {keys: [{frame: .nan}]}}\n",
        "fps_huge": s.replace("fps: 24", "fps: 1e308"),
        "fps_tiny": s.replace("fps: 24", "fps: 1e-308"),
        "fps_substeps": s.replace("fps: 24", "fps: 100000") + "substeps: 10000\n",
        "start_min_int64": s.replace("start: 1", "start: -9223372036854775808"),
        "end_max_int64": s.replace("end: 2", "end: 9223372036854775807"),
        "seq_zz": s.replace("{generator: grid, params: {resolution: [4, 4]}}",
                            "{sequence: '{frame:zz}.obj'}"),
        "seq_index": s.replace("{generator: grid, params: {resolution: [4, 4]}}",
                               "{sequence: '{frame[0]}.obj'}"),
        "seq_width": s.replace("{generator: grid, params: {resolution: [4, 4]}}",
                               "{sequence: '{frame:999999999999d}.obj'}"),
        "pins_huge": s.replace("[0, 4]", "[0, 99999999999999999999999]"),
        "pins_int64": s.replace("[0, 4]", "[0, 9223372036854775807]"),
        "pins_negative": s.replace("[0, 4]", "[0, -1]"),
        "channel_huge": s.replace("    components:",
                                  "    channels: {p: {vertices: [0, 2147483648]}}\n"
                                  "    components:"),
        "stitch_huge": s + "  - name: st\n    components: {Stitch: {a: cloth, b: cloth, pairs: "
                           "[[0, 99999999999999999999]]}}\n",
        "nocollide_huge": s.replace("DiscreteShell: {}", "Collider: {nocollide_sets: {a: "
                                    "[99999999999999999999]}}"),
        "attachment_huge": s + "  - name: at\n    components: {Attachment: {source: cloth, target:"
                               " cloth, vertices: [18446744073709551617]}}\n",
        "tag_python": s + "x: !!python/object/apply:os.system ['echo hi']\n",
        "tag_binary": s + "x: !!binary '%%%'\n",
        "tag_float": s + "seed: !!float abc\n",
        "tag_int": s + "seed: !!int xyz\n",
        "tag_unknown": s + "seed: !custom 3\n",
        "bad_date": s + "x: 2001-13-45\n",
        "nul_in_string": s.replace("graph: default", 'graph: "def\\0ault"'),
        "nul_in_file": s.replace("{generator: grid, params: {resolution: [4, 4]}}",
                                 '{file: "a\\0b.obj"}'),
        "long_graph_name": s.replace("graph: default", "graph: " + "g" * 5000 + ".yaml"),
        "graph_is_folder": s.replace("graph: default", "graph: gdir.yaml"),
        "empty": "",
        "comments_only": "# nothing\n# here\n",
        "top_list": "- lokigraph: 1\n",
        "top_scalar": "42\n",
        "multi_document": s + "---\n" + s,
        "binary": bytes(range(256)) * 4,
        "utf16": s.encode("utf-16"),
        "latin1": s.replace("cloth", "clöth").encode("latin-1"),
        "control_chars": s.replace("cloth", "cl\x07oth"),
        "duplicate_keys": s + "seed: 1\nseed: 2\n",
        "complex_key": s + "? [a, b]\n: 1\n",
        "four_mistakes": s.replace("fps: 24", "fps: -24").replace("mass_density: 0.2",
                                                                  "mass_densty: 0.2")
        + "  - name: g\n    components: {CollisionGroup: {members: [cloth, nobody]}}\n"
        + "graph_overrides: {stretch: {importanc: 1}}\n",
        "overrides_bad_value": s + "graph_overrides: {nucleus_solver: {iterations: .nan}}\n",
        "overrides_not_map": s + "graph_overrides: [stretch]\n",
        "elements_map": "lokigraph: 1\nelements: {cloth: {}}\n",
        "element_scalar": "lokigraph: 1\nelements: [3, null, [], cloth]\n",
        "components_list": "lokigraph: 1\nelements:\n  - name: a\n    components: [Dynamic]\n",
        "component_scalar": "lokigraph: 1\nelements:\n  - name: a\n    geometry: {generator: grid}"
                            "\n    components: {Dynamic: 5, Pins: [0]}\n",
        "generator_unknown": "lokigraph: 1\nelements:\n  - {name: a, geometry: {generator: "
                             "blob}}\n",
        "generator_params_junk": "lokigraph: 1\nelements:\n  - {name: a, geometry: {generator: "
                                 "grid, params: {resolution: [.nan, 4], size: 'x', nope: 1}}}\n",
        "generator_params_list": "lokigraph: 1\nelements:\n  - {name: a, geometry: {generator: "
                                 "grid, params: [1, 2]}}\n",
        "transform_junk": "lokigraph: 1\nelements:\n  - {name: a, geometry: {generator: grid, "
                          "transform: {scale: 0, rotate: [.inf, 0, 0], translate: [1]}}}\n",
        "rest_channel_scalar": s.replace("DiscreteShell: {}", "DiscreteShell: {rest_channel: rp}")
        .replace("    components:", "    channels: {rp: {vertices: [0]}}\n    components:"),
        "seed_negative": s + "seed: -1\n",
        "wind_seed_huge": s + "  - name: w\n    components: {Wind: {speed: 1, noise: 0.5, seed: "
                              "99999999999999999999999}}\n",
        "fluid_zero_size": s + "  - name: f\n    components: {FluidDomain: {size: [0, 1, 1]}}\n",
        "tethers_huge": s.replace("DiscreteShell: {}", "DiscreteShell: {max_tether_anchors: "
                                  "1000000000000}"),
    }
    return {k: (v if isinstance(v, bytes) else v.encode("utf-8")) for k, v in cases.items()}


RUN_TWEAKS = [
    ("pinned_particles.yaml", {"frames": {"start": 1, "end": 2, "fps": 100000},
                               "substeps": 1}),
    ("pinned_particles.yaml", {"frames": {"start": -10000000, "end": -9999999, "fps": 24}}),
    ("pinned_particles.yaml", {"frames": {"start": 1, "end": 2, "fps": 1e-3},
                               "gravity": [0, -1e30, 0]}),
    ("projectile.yaml", {"frames": {"start": 1, "end": 2, "fps": 1000}, "substeps": 10000}),
    ("spring.yaml", {"frames": {"start": 1, "end": 2, "fps": 24}, "substeps": 1,
                     "seed": 2**63 - 1}),
    ("pinned_particles.yaml", {"frames": {"start": 1, "end": 2, "fps": 24},
                               "gravity": [0, -1e300, 0]}),
    ("spring.yaml", {"frames": {"start": 1, "end": 2, "fps": 1e-3}, "substeps": 1}),
    ("terminal_velocity.yaml", {"frames": {"start": 1, "end": 2, "fps": 0.5}, "substeps": 1}),
]
"""Valid mutants *run* for 2 frames: scenes whose kernels compile fast on a cold numba cache
(hair and wind compile for 15 s or more there, which the time budget cannot hold)."""


def build_corpus(dest: Path) -> list[Case]:
    """Write every mutant under ``dest`` and return the cases, in a fixed order."""
    import yaml

    for sub, d in BASE_DIRS.items():
        shutil.copytree(d, dest / sub, dirs_exist_ok=True)
    for sub in ("readme", "graphs", "special"):
        (dest / sub).mkdir(exist_ok=True)
    (dest / "special" / "gdir.yaml").mkdir(exist_ok=True)
    scenes, graphs = _bases()
    cases: list[Case] = []

    def add(sub: str, name: str, content: bytes, note: str, argv=None, **kw):
        p = dest / sub / name
        p.write_bytes(content)
        cases.append(Case(f"{sub}/{name}", argv or ["validate", str(p)], note=note, **kw))

    def dump(data) -> bytes:
        return yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=100).encode()

    for name, sub, text in scenes:
        stem = name[:-5]
        for k in range(MUTANTS_PER_SCENE):
            rng = random.Random(f"{sub}/{name}:{k}")
            data = yaml.safe_load(text)
            note = _mutate(data, rng)
            if rng.random() < 0.35:  # two mistakes in one file
                note += "; " + _mutate(data, rng)
            add(sub, f"fz_{stem}_{k:02d}.yaml", dump(data), note)
        for k in range(TEXT_MUTANTS_PER_SCENE):
            rng = random.Random(f"{sub}/{name}:text{k}")
            content, note = _text_mutate(text, rng)
            add(sub, f"fz_{stem}_t{k}.yaml", content, note)
    for name, sub, text in graphs:
        stem = name[:-5]
        for k in range(MUTANTS_PER_GRAPH):
            rng = random.Random(f"graph/{name}:{k}")
            if k % 3 == 2:
                content, note = _text_mutate(text, rng)
            else:
                data = yaml.safe_load(text)
                note = _graph_mutate(data, rng)
                content = dump(data)
            gname = f"g_{stem}_{k:02d}.yaml"
            (dest / "graphs" / gname).write_bytes(content)
            add("graphs", f"fz_{stem}_{k:02d}.yaml",
                SMALL_SCENE.format(graph=gname).encode(), f"graph {name}: {note}")
    for name, content in _special_cases().items():
        add("special", f"{name}.yaml", content, name)
    add("special", "scene_is_folder", b"", "a folder as the scene",
        argv=["validate", str(dest / "special" / "gdir.yaml")])
    for k, (name, tweak) in enumerate(RUN_TWEAKS):
        src = next(t for n, _, t in scenes if n == name)
        sub = next(s for n, s, _ in scenes if n == name)
        data = yaml.safe_load(src)
        data.update(tweak)
        p = dest / sub / f"run_{k:02d}_{name}"
        p.write_bytes(dump(data))
        out = dest / f"run_out_{k:02d}"
        cases.append(Case(f"run/{k:02d}_{name}", ["run", str(p), "--out", str(out), "--quiet"],
                          limit=RUN_LIMIT_S, codes=(0, 2, 3), note=_short(tweak, 80)))
    return cases


def _graph_mutate(data: dict, rng: random.Random) -> str:
    op = rng.choice(["params_list", "after_int", "unknown_type", "retype", "delete", "dup_name",
                     "domains_list", "node_junk", "params_nan"])
    nodes = [(d, i, n) for d, items in (data.get("domains") or {}).items()
             if isinstance(items, list) for i, n in enumerate(items)]
    d, i, node = rng.choice(nodes)
    items = data["domains"][d]
    if isinstance(node, str):
        node = items[i] = {"type": node}
    if op == "params_list":
        node["params"] = [1, 2]
    elif op == "after_int":
        node["after"] = rng.choice([5, [1, None], {"a": 1}, "nobody"])
    elif op == "unknown_type":
        node["type"] = rng.choice(["Gravty", "", None, 3, ["x"]])
    elif op == "retype":
        paths = _paths(data)
        path, _ = rng.choice(paths)
        _set(data, path, rng.choice(JUNK))
        return f"retype {_fmt(path)}"
    elif op == "delete":
        del node["type"]
    elif op == "dup_name":
        items.append(dict(node))
    elif op == "domains_list":
        data["domains"] = rng.choice([[], "x", None, {"forces": "Gravity"}])
    elif op == "node_junk":
        items[i] = rng.choice(JUNK)
    else:
        node["params"] = {"importance": NAN, "order": 10**40, "iterations": INF}
    return f"{op} {d}[{i}]"


# ---------------------------------------------------------------------------------------------
# worker (in a subprocess) and parent


def _worker(corpus: Path, start: int) -> None:
    """Run cases from ``start`` on; one JSON line per event on the original stdout."""
    import contextlib
    import io
    import resource

    try:
        resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))
    except (ValueError, OSError):  # pragma: no cover
        pass
    proto = os.fdopen(os.dup(1), "w", buffering=1)
    from lokigraph.cli import main

    cases = json.loads(corpus.read_text())
    for i in range(start, len(cases)):
        c = cases[i]
        proto.write(json.dumps({"start": i}) + "\n")
        out, err = io.StringIO(), io.StringIO()
        t = time.perf_counter()
        try:
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
                rc = main(c["argv"])
        except SystemExit as exc:  # argparse
            rc = exc.code
        except BaseException as exc:  # noqa: BLE001 - reported as a failure of the case
            rc = f"raised {type(exc).__name__}: {exc}"[:300]
        secs = time.perf_counter() - t
        text = out.getvalue()[-2000:] + err.getvalue()[-3000:]
        proto.write(json.dumps({"end": i, "rc": rc, "secs": secs, "output": text}) + "\n")
    proto.write(json.dumps({"done": True}) + "\n")


def run_corpus(cases: list[Case], corpus_file: Path, cwd: Path) -> dict[str, Result]:
    corpus_file.write_text(json.dumps([asdict(c) for c in cases]))
    results: dict[str, Result] = {}
    i = 0
    env = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONFAULTHANDLER="1")
    while i < len(cases):
        proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker",
                                 str(corpus_file), str(i)], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, cwd=cwd, env=env)
        lines: queue.Queue = queue.Queue()

        def pump(stream=proc.stdout):
            for line in stream:
                lines.put(line)
            lines.put(None)

        threading.Thread(target=pump, daemon=True).start()
        errs: list[str] = []
        threading.Thread(target=lambda s=proc.stderr: errs.extend(s), daemon=True).start()
        current, deadline = None, time.monotonic() + 120.0  # start-up (imports)
        while True:
            try:
                line = lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                line = "TIMEOUT"
            if line is None or line == "TIMEOUT":
                proc.kill()
                proc.wait()
                if current is None:
                    pytest.fail("fuzz worker died before its first case: " + "".join(errs)[-3000:])
                c = cases[current]
                why = (f"did not finish within {c.limit:g} s (hang)" if line == "TIMEOUT"
                       else "worker process died: " + "".join(errs)[-1500:])
                results[c.id] = Result(c.id, rc="hang" if line == "TIMEOUT" else "died",
                                       problems=[why])
                i = current + 1
                break
            msg = json.loads(line)
            if "start" in msg:
                current = msg["start"]
                deadline = time.monotonic() + cases[current].limit
            elif "end" in msg:
                c = cases[msg["end"]]
                r = Result(c.id, msg["rc"], msg["output"], msg["secs"])
                if r.rc not in c.codes:
                    r.problems.append(f"exit code {r.rc!r}, expected one of {c.codes}")
                if "Traceback" in r.output:
                    r.problems.append("traceback in the output")
                results[c.id] = r
                current = None
                deadline = time.monotonic() + 60.0
            elif msg.get("done"):
                proc.wait()
                i = len(cases)
                break
    return results


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    dest = tmp_path_factory.mktemp("fuzz_yaml")
    t = time.perf_counter()
    cases = build_corpus(dest)
    results = run_corpus(cases, dest / "corpus.json", dest)
    return cases, results, time.perf_counter() - t


def test_corpus_size_and_determinism(corpus, tmp_path):
    a = corpus[0]
    b = build_corpus(tmp_path / "again")
    assert len(a) >= 300
    assert [c.id for c in a] == [c.id for c in b]
    for ca, cb in zip(a, b):
        pa, pb = Path(ca.argv[1]), Path(cb.argv[1])
        if pa.is_file():
            assert pa.read_bytes() == pb.read_bytes(), ca.id
        assert ca.note == cb.note


def test_no_crash_no_hang(corpus):
    cases, results, secs = corpus
    bad = [(c.id, c.note, results[c.id].rc, results[c.id].problems,
            results[c.id].output[-600:]) for c in cases if results[c.id].problems]
    report = "\n\n".join(f"{cid} [{note}]: {probs} (rc {rc})\n{out}"
                         for cid, note, rc, probs, out in bad)
    # the whole corpus's time is reported, not asserted: every case has its own hang limit
    # (Case.limit), and a total budget only measured the machine's load (66 s against 60 s
    # with four other test runs beside it)
    print(f"YAML fuzz corpus: {len(cases)} cases in {secs:.1f} s")
    assert not bad, f"{len(bad)} of {len(cases)} fuzz cases failed:\n{report}"


def test_corpus_exercises_both_outcomes(corpus):
    """Most mutants are invalid (exit 2), and the valid ones really ran (exit 0)."""
    cases, results, _ = corpus
    rcs = [results[c.id].rc for c in cases]
    assert rcs.count(2) > len(cases) // 2
    assert rcs.count(0) >= 10
    ran = [results[c.id].rc for c in cases if c.id.startswith("run/")]
    assert ran.count(0) >= len(RUN_TWEAKS) // 2, ran


@pytest.mark.parametrize("name, pattern", [
    ("four_mistakes", r"^4 errors:"),
    ("alias_bomb", r"alias"),
    ("alias_recursive", r"recursive alias"),
    ("deep_flow_list", r"nesting deeper than 100"),
    ("bigint_5000", r"integer with 5000 digits is too large"),
    ("seq_zz", r"bad sequence pattern '\{frame:zz\}\.obj'"),
    ("seq_index", r"bad sequence pattern '\{frame\[0\]\}\.obj'"),
    ("fps_huge", r"fps: must be <= 100000"),
    ("start_min_int64", r"frames\.start: must be >= -10000000"),
    ("nan_gravity", r"gravity\.0: must be a finite number \(got nan\)"),
    ("nan_wind", r"Wind\.speed: must be a finite number"),
    ("pins_huge", r"Pins\.vertices\.1: must be <= 2147483647"),
    ("stitch_huge", r"Stitch\.pairs\.0\.1: must be <= 2147483647"),
    ("nocollide_huge", r"nocollide_sets\.a\.0: must be <= 2147483647"),
    ("attachment_huge", r"Attachment\.vertices.*2147483647"),
])
def test_special_case_messages(corpus, name, pattern):
    _, results, _ = corpus
    r = results[f"special/{name}.yaml"]
    assert r.rc == 2, (r.rc, r.output)
    assert re.search(pattern, r.output, re.M), r.output
    assert re.search(rf"{name}\.yaml:\d+:\d+: ", r.output), r.output  # the user's file:line


if __name__ == "__main__":
    if sys.argv[1:2] == ["--worker"]:
        _worker(Path(sys.argv[2]), int(sys.argv[3]))
    elif sys.argv[1:2] == ["--show"]:
        import tempfile

        with tempfile.TemporaryDirectory() as d:
            for c in build_corpus(Path(d)):
                if c.id == sys.argv[2]:
                    print(f"# {c.note}\n# lokigraph {' '.join(c.argv)}")
                    p = Path(c.argv[1])
                    print(p.read_bytes().decode("utf-8", "replace") if p.is_file() else "")
    else:
        print(__doc__)
