"""The cloth on a moving, spinning sphere (issue #12, ``graphs/bench/cloth_sphere_moving_128.yaml``
at a lower resolution): the safe step's incremental check (``contacts.CCD_INCREMENTAL``) must
leave the positions bitwise those of a full detection in every substep where the final rounds'
rows no longer cover the motion, and it must actually be taken there (the sphere's friction drags
a few vertices farther than the rows allow after their detection)."""

from pathlib import Path

import numpy as np
import pytest

from lokigraph.api import compile_file
from lokigraph.behaviors.collision import contacts as C
from lokigraph.run import Simulation

BENCH = Path(__file__).resolve().parents[1] / "graphs" / "bench"


def _moving_scene(scene_file, res, frames):
    """The benchmark's moving scene with a ``res`` x ``res`` cloth, ``frames`` frames."""
    text = (BENCH / "cloth_sphere_moving_128.yaml").read_text()
    text = text.replace("resolution: [128, 128]", f"resolution: [{res}, {res}]")
    text = text.replace("frames: {start: 1, end: 24, fps: 24}",
                        f"frames: {{start: 1, end: {frames}, fps: 24}}")
    assert f"resolution: [{res}, {res}]" in text and f"end: {frames}," in text
    return scene_file(text, "moving.yaml")


def _run(path, frames, inc, monkeypatch):
    monkeypatch.setattr(C, "CCD_INCREMENTAL", inc)
    sim = Simulation(compile_file(path))
    qs, stats = [], []
    for _ in range(frames):
        st = sim.step_frame()
        qs.append(sim.state.particle_q.copy())
        stats.append(st)
    return qs, stats


def test_incremental_ccd_check_is_bitwise_and_taken(scene_file, monkeypatch):
    # with contacts.SLIDE_APART 1 (opt-in) this scene's safe steps that took the incremental
    # check are covered by the last detection's rows (no detection at all, the cheaper path: 1
    # full detection a frame in frames 7-9 either way): the check is exercised at 0
    monkeypatch.setattr(C, "SLIDE_APART", 0)
    frames = 11
    path = _moving_scene(scene_file, 48, frames)
    q0, s0 = _run(path, frames, 0.0, monkeypatch)
    q1, s1 = _run(path, frames, C.CCD_INCREMENTAL or 0.02, monkeypatch)
    for f, (a, b) in enumerate(zip(q0, q1), 1):
        assert np.array_equal(a, b), f"frame {f}: positions differ"
    taken = sum(s.get("ccd_incremental", 0) for s in s1)
    full0 = sum(s.get("ccd_detections", 0) for s in s0)
    full1 = sum(s.get("ccd_detections", 0) for s in s1)
    assert taken > 0, "the incremental check was never taken"
    assert full1 <= full0 - taken, (full0, full1, taken)
    assert all(s.get("ccd_incremental", 0) == 0 for s in s0)
    assert max(s.get("penetrations", 0) for s in s1) == 0


@pytest.mark.slow
def test_incremental_ccd_check_finds_the_hits_of_a_full_detection(scene_file, monkeypatch):
    """Where the incremental check says 'no hit', a full detection over x -> p finds none
    either; where it finds one, so does the full detection (checked at every safe step of a
    run, on copies of the contacts)."""
    import copy

    frames = 10
    path = _moving_scene(scene_file, 40, frames)
    monkeypatch.setattr(C, "CCD_INCREMENTAL", 1.0)  # take it whatever the count
    orig = C.ccd_safe_step
    seen = {"inc": 0, "agree": 0}

    def safe(c, x, p, w, v, h, frac, *a, **k):
        if not C._rows_cover(c, x, p, frac):
            work = c.ccd
            if work is None or len(work.parent) != len(x):
                n = len(x)
                work = C._CCDWork(np.arange(n), np.zeros(n, np.bool_), np.zeros(n, np.int64),
                                  np.zeros((n, 8)), np.zeros((n, 3)))
            c2 = copy.deepcopy(c)
            res = C._ccd_incremental(c2, work, x, p, v, h, frac)
            c3 = copy.deepcopy(c)
            C._detect_all(c3, x, p, v, h, C.SPACETIME)
            full = (len(C._ccd_hits(work, c3.vf, c3.vf_n, c3.vf_target, True, x, p, frac)[0])
                    + len(C._ccd_hits(work, c3.ee, c3.ee_n, c3.ee_target, False, x, p,
                                      frac)[0]))
            seen["inc"] += 1
            assert (res is True) == (full == 0), (res, full)
            seen["agree"] += 1
        return orig(c, x, p, w, v, h, frac, *a, **k)

    monkeypatch.setattr(C, "ccd_safe_step", safe)
    sim = Simulation(compile_file(path))
    for _ in range(frames):
        sim.step_frame()
    assert seen["inc"] > 0


def test_round_incremental_ccd_check_is_bitwise_and_taken(scene_file, monkeypatch):
    """``contacts.CCD_ROUND_INCREMENTAL``: the safe step's check after a round of contacts at
    the time of impact tries the last detection's rows plus an incremental query first; the
    positions must be bitwise those of a full detection there, and the path must be taken (the
    spinning sphere gives safe steps with hits)."""
    monkeypatch.setattr(C, "SLIDE_APART", 0)
    frames = 11
    path = _moving_scene(scene_file, 48, frames)
    inc = C.CCD_INCREMENTAL or 0.05
    monkeypatch.setattr(C, "CCD_ROUND_INCREMENTAL", False)
    q0, s0 = _run(path, frames, inc, monkeypatch)
    monkeypatch.setattr(C, "CCD_ROUND_INCREMENTAL", True)
    q1, s1 = _run(path, frames, inc, monkeypatch)
    for f, (a, b) in enumerate(zip(q0, q1), 1):
        assert np.array_equal(a, b), f"frame {f}: positions differ"
    taken = sum(s.get("ccd_round_incremental", 0) for s in s1)
    full0 = sum(s.get("ccd_detections", 0) for s in s0)
    full1 = sum(s.get("ccd_detections", 0) for s in s1)
    assert taken > 0, "the incremental check after a round was never taken"
    assert full1 <= full0 - taken, (full0, full1, taken)
    assert all(s.get("ccd_round_incremental", 0) == 0 for s in s0)
    assert max(s.get("penetrations", 0) for s in s1) == 0
