"""Kinematic animation: rigid keys and mesh sequences of Kinematic elements, and the pinned
vertices that follow them (binding in :mod:`lokigraph.behaviors.attachments.pins`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lokigraph.behavior import Behavior
from lokigraph.errors import SimulationError
from lokigraph.geometry import MeshReadError, rotation_matrix_xyz
from lokigraph.scene import _load_geometry
from lokigraph.components.core import Kinematic

from .attachments.pins import _Follow, bind_follow_pins, follow_positions


@dataclass
class _Anim:
    slices: list  # per element: (slice, rest points (n,3), keys arrays or None, element)
    start_frame: float
    fps: float
    cache: dict = field(default_factory=dict)  # sequence frame -> points (file memo, not state)
    frames: dict = field(default_factory=dict)  # element name -> available sequence frames
    follow: _Follow | None = None


def monotone_slopes(fr: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Tangents dy/dframe at the keys of a C1 monotone cubic Hermite curve (Fritsch & Carlson
    1980, the weighted harmonic mean of scipy's PCHIP): zero at a key where the neighbouring
    slopes differ in sign or one is zero, and zero at the first and last key (the pose holds
    outside the keys, so the curve stays C1 there). ``fr``: strictly increasing frames (n,);
    ``y``: values (n, k), one column per channel."""
    y = np.asarray(y, dtype=np.float64)
    m = np.zeros_like(y)
    if len(fr) < 3:
        return m
    h = np.diff(fr)[:, None]
    s = np.diff(y, axis=0) / h
    s0, s1, h0, h1 = s[:-1], s[1:], h[:-1], h[1:]
    w0, w1 = 2.0 * h1 + h0, h1 + 2.0 * h0
    same = (s0 * s1) > 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        d = (w0 + w1) / (w0 / s0 + w1 / s1)
    m[1:-1] = np.where(same, d, 0.0)
    return m


def hermite_at(f: float, fr: np.ndarray, y: np.ndarray, m: np.ndarray) -> np.ndarray:
    """The cubic Hermite curve through keys (``fr``, ``y`` (n, k)) with tangents ``m`` at frame
    ``f``; it holds the first / last key outside them (as ``np.interp``)."""
    if f <= fr[0]:
        return y[0].copy()
    if f >= fr[-1]:
        return y[-1].copy()
    i = int(np.searchsorted(fr, f, side="right")) - 1  # fr[i] <= f < fr[i + 1]
    h = float(fr[i + 1] - fr[i])
    u = (f - float(fr[i])) / h
    u2, u3 = u * u, u * u * u
    return ((2 * u3 - 3 * u2 + 1) * y[i] + (u3 - 2 * u2 + u) * h * m[i]
            + (-2 * u3 + 3 * u2) * y[i + 1] + (u3 - u2) * h * m[i + 1])


def _sequence_frame(e, frame: int):
    """Geometry of frame ``frame`` of element ``e``'s mesh sequence (units and transform applied;
    a frame without a file follows ``geometry.hold``)."""
    spec = e.spec.model_copy(update={"file": None, "generator": None})
    return _load_geometry(spec, Path(e.base_dir), frame)


class KinematicAnimation(Behavior):
    """Moves kinematic elements to their animated pose at the end of each substep, and the
    pinned vertices that follow them (``Pins.follow``).

    Rigid keys are interpolated per channel (translation, XYZ angles, pivot) linearly or, with
    ``Kinematic.interpolation: smooth``, along a C1 monotone cubic Hermite curve
    (:func:`monotone_slopes`); mesh sequences linearly between consecutive frames. The animated
    vertices' velocity is the finite difference of two poses of that curve (end of substep minus
    its start, over h: ``Simulation.step_substep``), so sub-frame positions and collider
    velocities come from the same curve. A sequence must have a file for every frame the run needs
    (``frames.start`` .. ``frames.end``) unless ``geometry.hold`` says what a missing frame shows
    (``first``, ``last`` or ``loop``; see :mod:`lokigraph.sequence`); checked at bind (validate).
    Follow-pinned vertices become kinematic vertices (inverse mass 0) placed, every substep, by
    their body triangle's barycentric point plus the offset fixed at bind in the triangle's
    frame (see :class:`~lokigraph.components.core.Pins`).
    """

    stage = "control"
    requires = (Kinematic,)
    writes = ("kinematic_q",)

    def bind(self, ctx, elements):
        spec = ctx.scene.spec
        start, end = int(spec.frames.start), int(spec.frames.end)
        items = []
        frames = {}
        for e in elements:
            k = e.get(Kinematic)
            keys = None
            if k.keys:
                keys = (np.array([x.frame for x in k.keys]),
                        np.array([x.translate for x in k.keys]),
                        np.array([x.rotate for x in k.keys]), np.array([x.pivot for x in k.keys]))
                if k.interpolation == "smooth":  # one (n, 9) curve: translate, rotate, pivot
                    y = np.concatenate([np.asarray(a, dtype=np.float64).reshape(len(keys[0]), 3)
                                        for a in keys[1:]], axis=1)
                    fr = keys[0].astype(np.float64)
                    keys = ("smooth", fr, y, monotone_slopes(fr, y))
            seq = e.sequence
            if seq is None and e.spec is not None and e.spec.usd is not None:
                seq = e.spec.usd  # a USD prim's time samples behave as a mesh sequence
            if seq is not None and e.spec is not None:
                avail = self._check_sequence(ctx, e, start, end)
                if avail is not None:
                    frames[e.name] = avail
            if keys is None and seq is None:
                continue
            items.append((e.vertex_slice, e.geometry.points.copy(), keys, e))
        data = _Anim(items, float(start), ctx.model.fps, frames=frames)
        data.follow = bind_follow_pins(ctx)
        return data

    # -- mesh sequences ------------------------------------------------------------------
    @staticmethod
    def _check_sequence(ctx, e, start: int, end: int):
        """Check that the frames the run needs exist (or that ``hold`` covers them) and have
        the element's vertex count. Returns the available frames (None if unknown)."""
        from lokigraph.sequence import (available_frames, describe_frames, first_missing,
                                        frame_file)

        spec = e.spec
        base = Path(e.base_dir)
        locs = ctx.scene.locations
        source = "usd" if spec.usd is not None else "sequence"
        where = ("elements", e.index, "geometry", source)

        def err(msg, key=source):
            ctx.diagnostics.append(locs.diag(where[:-1] + (key,), msg, element=e.name,
                                             field=f"geometry.{key}"))

        if spec.usd is not None:  # frames: the time samples of the prim's points
            from lokigraph.usd import usd_frames

            try:
                avail = usd_frames(base / spec.usd, spec.prim, ctx.scene.spec.frames.fps)
            except MeshReadError as exc:
                err(str(exc), getattr(exc, "key", None) or "usd")
                return None
            if spec.hold == "error" and avail is not None and \
                    first_missing(avail, start, end) is not None:
                return avail  # reported by the scene (lokigraph.usd.missing_usd_frame)
        else:
            avail = available_frames(spec.sequence, base)
            if spec.hold == "error":
                if avail is not None:
                    miss = first_missing(avail, start, end)
                else:  # cannot list the folder: check the first and last frame the run needs
                    miss = next((f for f in (start, end)
                                 if not (base / frame_file(spec.sequence, f)).exists()), None)
                if miss is not None:
                    missing = base / frame_file(spec.sequence, miss)
                    err(f"frame {miss} of the sequence is missing: {missing} not found; the "
                        f"run needs frames {start}..{end} and the sequence has "
                        f"{describe_frames(avail) if avail is not None else 'fewer'}; set "
                        f"geometry.hold to first, last or loop to run past its ends")
                    return avail
            elif avail is not None and not len(avail):
                err(f"no file of the sequence found ({base / spec.sequence})")
                return avail
        for f in sorted({start, end}):
            try:
                g = _sequence_frame(e, f)
            except (MeshReadError, KeyError, ValueError) as exc:
                err(str(exc), getattr(exc, "key", None) or source)
                break
            if g.vertex_count != e.vertex_count:
                err(f"frame {f} has {g.vertex_count} vertices, the element has "
                    f"{e.vertex_count}")
                break
        return avail

    def _sequence_points(self, data, e, frame: int) -> np.ndarray | None:
        from lokigraph.sequence import map_frame

        avail = data.frames.get(e.name)
        if avail is not None:
            shown = map_frame(frame, avail, e.spec.hold)
            if shown is None:  # 'error' mode: only past the frames checked at bind
                shown = map_frame(frame, avail, "last")
            frame = shown
        key = (e.name, frame)
        if key not in data.cache:
            if len(data.cache) > 8:
                data.cache.clear()
            try:
                pts = _sequence_frame(e, frame).points
            except MeshReadError as exc:
                raise SimulationError(f"mesh sequence: {exc}", element=e.name) from None
            if len(pts) != e.vertex_count:
                raise SimulationError(f"mesh sequence frame {frame} has {len(pts)} vertices, "
                                      f"the element has {e.vertex_count}", element=e.name)
            data.cache[key] = pts
        return data.cache[key]

    def step(self, ctx, data):
        f = data.start_frame + ctx.control.time * data.fps
        # mesh sequences land exactly on frames (no spurious read of the next file at the last
        # frame); rigid keys interpolate the unrounded time
        fs = float(round(f)) if abs(f - round(f)) < 1e-9 else f
        q = ctx.control.kinematic_q
        for sl, rest, keys, e in data.slices:
            if keys is not None and isinstance(keys[0], str):  # smooth
                _, fr, y, m = keys
                c = hermite_at(f, fr, y, m)
                R = rotation_matrix_xyz(c[3:6])
                q[sl] = (rest - c[6:9]) @ R.T + c[6:9] + c[0:3]
            elif keys is not None:
                fr, tr, rot, piv = keys
                t = np.array([np.interp(f, fr, tr[:, i]) for i in range(3)])
                r = np.array([np.interp(f, fr, rot[:, i]) for i in range(3)])
                pv = np.array([np.interp(f, fr, piv[:, i]) for i in range(3)])
                R = rotation_matrix_xyz(r)
                q[sl] = (rest - pv) @ R.T + pv + t
            else:
                f0 = int(np.floor(fs))
                s = fs - f0
                a = self._sequence_points(data, e, f0)
                q[sl] = a if s == 0.0 else (1 - s) * a + s * self._sequence_points(data, e,
                                                                                   f0 + 1)
        if data.follow is not None:
            q[data.follow.idx] = follow_positions(q, data.follow)

    def describe(self, data):
        extra = "" if data.follow is None else f", {len(data.follow.idx)} follow-pinned vertices"
        return f"{len(data.slices)} animated elements{extra}"
