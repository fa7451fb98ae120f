"""Which contact rows ``contacts.SLIDE_APART`` makes inactive on graphs/examples/sleeve_elbow.yaml
and what that does to the near-joint sleeve speed tests/test_elbow.py bounds (0.733 m/s).

Runs the slow tests' scene (``test_sleeve_elbow_with_mechanisms``: defaults, 15 iterations;
``--iterations 14``: ``test_sleeve_elbow_compression_near_contacts``'s second run) once per
setting, the settings interleaved frame by frame, and reports per frame the near-joint speed
(sleeve vertices within 0.15 m of the joint, as the test) and the rows the slid-apart test
deactivates: counted at the start of every contact pass (``contacts._project_contacts``, the
solver iterations, the final rounds and the CCD safe step's pass), as (row, pass) events and
distinct rows per frame, by kind (vertex-face / edge-edge) and by the collider element of their
immovable side (w = 0); their lateral distance across the start normal and the depth across
it; and whether the fastest near-joint vertex of the frame is a vertex of a deactivated row.

Settings: ``S`` = ``contacts.SLIDE_APART`` value (0-3), optionally ``S:SITE,...`` with the
flag forced to 0 at the named sites (ablation): ``pass`` (the contact passes), ``ccd``
(``CCD_SLIDE``), ``pinch`` (``strain_limit.count_pinched``), ``global`` (the global strain
step's ``contact_rows``), or ``gate`` (below); ``NAME=VALUE`` parts after ``/`` set other
contacts module globals::

    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/elbow_slide.py 0 1 1:pinch 1:pass
    NUMBA_NUM_THREADS=1 .venv/bin/python graphs/bench/elbow_slide.py 0 1 --iterations 14

``--diff``: per frame, each setting's sleeve against the first setting's (largest displacement,
how many of the 10 most displaced vertices belong to that frame's slid rows, those vertices'
speeds in both runs). ``--moving``: the same census on cloth_sphere_moving_128 (2x15; the
metric is then the worst edge strain at the frame end; its frame labels are one more than
peer_collision.py's). The census flags rows by the test of ``SLIDE_APART`` 1 whatever the
setting (with ``--census-all`` in runs at 0 too).

Measured (stop 31, NUMBA_NUM_THREADS=1, ``0 1 1:pass 1:pinch,ccd,global --iterations 14`` and
``0 3 1 --iterations 14 --diff``): near-joint maximum 0.638 m/s (frame 35) with 0, 0.776 (35)
with 1, 0.638 with 1 but 0 in the passes (bitwise 0), 0.776 with 1 but 0 at the other sites;
with 1 the passes skip 3-102 distinct rows a frame in frames 22-36 (81 % edge-edge, against
the forearm but for a few against the upper arm; 4.0-8.2 mm across n0, target 4 mm; 0-4.8 mm
behind it; the forearm moving 0.8-1.6 mm a substep there, 4.8 mm at most in frame 26); the
sleeve parts from the run with 0 from frame 23 (1.1 mm, 10-16 mm by frames 32-37), 0-1 of the
10 most displaced vertices a frame are vertices of skipped rows, the frame-35 peak vertex (306)
is of none. With 3 every frame is bitwise that of 0 (14 and 15 iterations). ``0 3 3:global
3:pinch 1 --without --no-census`` (test_sleeve_elbow_without_mechanisms' scene): sleeve-arm
pairs 0 from frame 37 to 61 with 0; 16-30 in each of those frames with 3 (the sleeve pushed
through the arm stays through it); with 3 but 0 in the global step's rows bitwise 0, with 0 in
the pinch count the same as 3; with 1, 0 only from frame 54. Site ``gate`` (experiment, a
wrapper around ``strain_limit_global.contact_rows``): the global step skips a slid row only
where its collider side moved over the substep at least the row's target across the start
normal (largest over its immovable vertices; the other rows go in with slide 0, after the
gated ones). ``0 3 3:gate --without --no-census``: 3:gate bitwise 0 (0 pairs from frame 37);
``3 3:gate --moving --frames 12 --no-census``: worst edge at the end of the moving ball's frames
7-12 (peer_collision numbering) 2.7 / 1.6 / 14.1 / 17.0 / 11.6 / 1.4 % with 3, 48.9 / 27.9 /
16.2 / 7.3 / 1.6 / 1.4 % with 3:gate: the gate loses frames 7-8, so no rule measured holds the
ball, the elbow and the elbow without mechanisms together.

The row census costs a numba pass over every row at each contact pass (diagnostic only;
``--no-census`` for timings).
"""

from __future__ import annotations

import argparse
import ast
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from numba import njit

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))

from lokigraph.behaviors.collision import contacts as C  # noqa: E402
from lokigraph.behaviors.collision.narrowphase import row_coefficients  # noqa: E402
from lokigraph.behaviors.materials import strain_limit as SL  # noqa: E402
from lokigraph.behaviors.materials import strain_limit_global as SLG  # noqa: E402

NEAR = 0.15  # [m] the test's near-joint radius
BOUND = 0.3 * np.radians(140.0)  # 0.733 m/s


@njit(cache=True)
def slid_census(p, x, w, rows, nrm, target, onesided, is_vf, mode, out):
    """Per row: out[r] = (flag, lateral, depth, target, slide): flag 1 where the row is
    two-sided, against a collider (one side's inverse masses sum to 0), on the far side of its
    start normal (dn <= 0) and ``contacts._slid_apart`` (mode 1) holds; lateral =
    sqrt(d2 - dn^2), depth = -dn, slide = the collider side's closest point's motion x -> p
    across the start normal (its own, animated motion over the substep). Returns the count
    flagged."""
    k = 0
    for r in range(rows.shape[0]):
        out[r, 0] = 0.0
        if is_vf and onesided[r]:
            continue
        i0, i1, i2, i3 = rows[r, 0], rows[r, 1], rows[r, 2], rows[r, 3]
        if is_vf:
            wa, wb = w[i0], w[i1] + w[i2] + w[i3]
        else:
            wa, wb = w[i0] + w[i1], w[i2] + w[i3]
        if wa > 0.0 and wb > 0.0:
            continue
        d2, c0, c1, c2, c3 = row_coefficients(p, rows, is_vf, r)
        dv0 = c0 * p[i0, 0] + c1 * p[i1, 0] + c2 * p[i2, 0] + c3 * p[i3, 0]
        dv1 = c0 * p[i0, 1] + c1 * p[i1, 1] + c2 * p[i2, 1] + c3 * p[i3, 1]
        dv2 = c0 * p[i0, 2] + c1 * p[i1, 2] + c2 * p[i2, 2] + c3 * p[i3, 2]
        dn = dv0 * nrm[r, 0] + dv1 * nrm[r, 1] + dv2 * nrm[r, 2]
        if np.sqrt(d2) > 1e-12 and dn > 0.0:
            continue
        if not C._slid_apart(d2, dn, target[r], wa, wb, 1):
            continue
        # the collider side: the one whose inverse masses sum to 0
        m0 = m1 = m2 = 0.0
        for q in range(4):
            i = rows[r, q]
            cf = (c0, c1, c2, c3)[q]
            if (q == 0 or not is_vf and q == 1) == (wa <= 0.0):
                m0 += abs(cf) * (p[i, 0] - x[i, 0])
                m1 += abs(cf) * (p[i, 1] - x[i, 1])
                m2 += abs(cf) * (p[i, 2] - x[i, 2])
        mn = m0 * nrm[r, 0] + m1 * nrm[r, 1] + m2 * nrm[r, 2]
        out[r, 4] = np.sqrt(max(m0 * m0 + m1 * m1 + m2 * m2 - mn * mn, 0.0))
        out[r, 0] = 1.0
        out[r, 1] = np.sqrt(max(d2 - dn * dn, 0.0))
        out[r, 2] = -dn
        out[r, 3] = target[r]
        k += 1
    return k


class Census:
    """Accumulates, per frame, the rows flagged by ``slid_census`` at each contact pass."""

    def __init__(self, elem_of, names, sleeve):
        self.elem_of, self.names, self.sleeve = elem_of, names, sleeve
        self.active = None  # the Run being stepped
        self.buf = np.zeros((0, 5))

    def __call__(self, c, p, x, w):
        run = self.active
        if run is None or (run.mode == 0 and not run.census0):
            return
        for kind, rows, nrm, tgt in (("vf", c.vf, c.vf_n, c.vf_target),
                                     ("ee", c.ee, c.ee_n, c.ee_target)):
            n = len(rows)
            if not n:
                continue
            if self.buf.shape[0] < n:
                self.buf = np.zeros((2 * n, 5))
            out = self.buf[:n]
            k = slid_census(p, x, w, rows, nrm, tgt, c.vf_onesided if kind == "vf"
                            else np.zeros(0, np.bool_), kind == "vf", run.mode, out)
            run.events[kind] += k
            if not k:
                continue
            sel = np.flatnonzero(out[:, 0] > 0)
            for r in sel:
                key = (kind, *map(int, rows[r]))
                if key not in run.rows:
                    rv = rows[r]
                    kin = [int(v) for v in rv if w[v] <= 0.0]
                    cloth = [int(v) for v in rv if self.sleeve[0] <= v < self.sleeve[1]]
                    run.rows[key] = dict(elem=self.names[self.elem_of[kin[0]]] if kin else "?",
                                         cloth=cloth, lateral=out[r, 1], depth=out[r, 2],
                                         target=out[r, 3], slide=out[r, 4], n=0)
                run.rows[key]["n"] += 1
                run.rows[key]["lateral"] = max(run.rows[key]["lateral"], out[r, 1])


class Run:
    def __init__(self, spec, tmp, iterations, moving=False, census0=False, without=False):
        mode, _, rest = spec.partition("/")
        mode, _, sites = mode.partition(":")
        self.spec, self.mode = spec, int(mode)
        self.census0 = census0
        self.off = set(filter(None, sites.split(",")))
        self.flags = {}
        for part in filter(None, rest.split(",")):
            k, _, v = part.partition("=")
            self.flags[k] = ast.literal_eval(v)
        self.moving = moving
        if moving:  # graphs/bench/cloth_sphere_moving_128.yaml at peer_collision's --loki 2x15
            sys.path.insert(0, str(ROOT / "graphs" / "bench"))
            from peer_collision import MOVING, ClothSphere, LokiRun

            sc = ClothSphere(MOVING)
            self.sim = LokiRun(sc, 2, iterations or 15).sim
            self.c = None
            self.sl = sc.cloth_slice
            self.elements = {"cloth": sc.cloth_slice, "ball": sc.ball_slice}
            self.edges, self.rest = sc.edges, sc.rest
        else:
            from test_elbow import MAPS, _scene_text
            from conftest import EXAMPLES
            import shutil

            from lokigraph.api import compile_file
            from lokigraph.run import Simulation

            d = Path(tmp) / "".join(ch if ch.isalnum() else "_" for ch in spec)
            d.mkdir()
            for m in MAPS:
                shutil.copy(EXAMPLES / m, d / m)
            ov = {"nucleus_solver": {"iterations": iterations}} if iterations else None
            (d / "elbow.yaml").write_text(_scene_text(not without, ov))
            self.c = compile_file(d / "elbow.yaml")
            self.sim = Simulation(self.c)
            self.sl = self.c.scene.element("sleeve").vertex_slice
            self.elements = {nm: self.c.scene.element(nm).vertex_slice
                             for nm in ("sleeve", "upper_arm", "forearm", "elbow")}
        self.vpinch, self.vmax, self.arg, self.cpu = [], [], [], []
        self.events = {"vf": 0, "ee": 0}
        self.rows = {}
        self.frames = []  # per frame: (events vf, events ee, rows dict)
        self.pinched = []
        self.diffs = []  # --diff: against the first setting, per frame
        self.pen = []  # sleeve-arm intersecting triangle pairs per frame (as tests/test_elbow)

    def step(self):
        saved = {k: getattr(C, k) for k in self.flags}
        for k, v in self.flags.items():
            setattr(C, k, v)
        C.SLIDE_APART = self.mode
        C.CCD_SLIDE = "ccd" not in self.off
        _state["off"] = self.off
        self.events = {"vf": 0, "ee": 0}
        self.rows = {}
        _state["pinch"] = 0
        t = time.process_time()
        try:
            self.sim.step_frame()
        finally:
            for k, v in saved.items():
                setattr(C, k, v)
            C.SLIDE_APART = 0
            C.CCD_SLIDE = True
        self.cpu.append(time.process_time() - t)
        q, v = self.sim.state.particle_q, self.sim.state.particle_qd
        if self.moving:  # worst edge strain of the cloth instead of the near-joint speed
            qc = q[self.sl]
            st = np.linalg.norm(qc[self.edges[:, 1]] - qc[self.edges[:, 0]], axis=1) / self.rest - 1
            self.vpinch.append(st.max())
            self.vmax.append(st.max())
            self.arg.append(int(self.edges[np.argmax(st), 0]) + self.sl.start)
            self.frames.append((dict(self.events), self.rows))
            self.pinched.append(_state["pinch"])
            return
        from lokigraph.behaviors.collision.intersect import intersect_meshes

        slv = self.c.scene.element("sleeve")
        cloth = (q[self.sl], slv.geometry.triangles)
        pen = 0
        for nm in ("upper_arm", "forearm", "elbow"):
            e = self.c.scene.element(nm)
            _, pairs = intersect_meshes([cloth, (q[e.vertex_slice], e.geometry.triangles)],
                                        touching=False)
            pen += int((pairs[:, 0] != pairs[:, 2]).sum())
        self.pen.append(pen)
        sp = np.linalg.norm(v[self.sl], axis=1)
        near = np.flatnonzero(np.linalg.norm(q[self.sl], axis=1) < NEAR)
        i = near[np.argmax(sp[near])]
        self.vpinch.append(sp[i])
        self.vmax.append(sp.max())
        self.arg.append(int(i) + self.sl.start)
        self.frames.append((dict(self.events), self.rows))
        self.pinched.append(_state["pinch"])


_state = {"off": set(), "pinch": 0}


def install(census):
    orig_pc = C._project_contacts

    def project_contacts(c, p, x, w, slide=None):
        if census is not None:
            census(c, p, x, w)
        if "pass" in _state["off"]:
            s = C.SLIDE_APART
            C.SLIDE_APART = 0
            try:
                return orig_pc(c, p, x, w, 0)
            finally:
                C.SLIDE_APART = s
        return orig_pc(c, p, x, w, slide)

    C._project_contacts = project_contacts
    orig_cp = SL.count_pinched

    def count_pinched(*a):
        a = list(a)
        if "pinch" in _state["off"]:
            a[-1] = 0
        k = orig_cp(*a)
        _state["pinch"] += k
        return k

    SL.count_pinched = count_pinched
    orig_cr = SLG.contact_rows

    def contact_rows(*a):
        a = list(a)
        if "global" in _state["off"]:
            a[-1] = 0
        x = _state.get("x")
        if "gate" not in _state["off"] or not a[-1] or x is None:
            return orig_cr(*a)
        # experiment ("gate"): the global step skips a slid row only where its collider side
        # moved over the substep (x -> p, largest over its immovable vertices) at least the
        # row's target across the start normal; the other rows go in with slide 0
        p, w, rows, nrm, tgt, one, is_vf, keep = a[:8]
        outs = a[8:12]
        m = p[rows] - x[rows]  # (n, 4, 3)
        m -= np.einsum("nkj,nj->nk", m, nrm)[:, :, None] * nrm[:, None, :]
        mv = np.where(w[rows] <= 0.0, np.linalg.norm(m, axis=2), 0.0).max(axis=1)
        k = 0
        for sel, sl in ((np.flatnonzero(mv < tgt), 0), (np.flatnonzero(mv >= tgt), a[-1])):
            if not len(sel):
                continue
            kp = keep[sel].copy()
            k += orig_cr(p, w, np.ascontiguousarray(rows[sel]), np.ascontiguousarray(nrm[sel]),
                         np.ascontiguousarray(tgt[sel]),
                         np.ascontiguousarray(one[sel]) if len(one) == len(rows) else one,
                         is_vf, kp, *(o[k:] for o in outs), *a[12:-1], sl)
            keep[sel] = kp
        return k

    SLG.contact_rows = contact_rows
    orig_fin = SL.StrainLimitConstraint.finalize

    def finalize(self, ctx, d, p):
        _state["x"] = ctx.state.particle_q
        try:
            return orig_fin(self, ctx, d, p)
        finally:
            _state["x"] = None

    SL.StrainLimitConstraint.finalize = finalize


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("settings", nargs="+", help="SLIDE_APART[:SITE,...][/NAME=VALUE,...]")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--iterations", type=int, default=None, help="nucleus_solver.iterations")
    ap.add_argument("--no-census", action="store_true")
    ap.add_argument("--without", action="store_true", help="test_sleeve_elbow_without_mechanisms"
                    "' scene (no compliant skin, proximity tolerance, recovery or CCD)")
    ap.add_argument("--diff", action="store_true", help="per frame, each setting's sleeve "
                    "against the first setting's: largest displacement, whether the 10 most "
                    "displaced vertices are vertices of this frame's slid rows, and the speed "
                    "of those rows' vertices in both")
    ap.add_argument("--census-all", action="store_true",
                    help="count the rows the test flags in SLIDE_APART 0 runs too")
    ap.add_argument("--moving", action="store_true", help="cloth_sphere_moving_128 (2 "
                    "substeps, 15 iterations unless --iterations) instead; its metric is the "
                    "worst edge strain")
    ap.add_argument("--top", type=int, default=6, help="frames detailed (fastest near joint)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        runs = [Run(s, tmp, args.iterations, args.moving, args.census_all, args.without)
                for s in args.settings]
        m = runs[0].sim.model
        elem_of = np.full(m.particle_count, -1, np.int64)
        names = []
        for nm, vs in runs[0].elements.items():
            elem_of[vs] = len(names)
            names.append(nm)
        sl = runs[0].sl
        census = None if args.no_census else Census(elem_of, names, (sl.start, sl.stop))
        install(census)
        w = m.particle_inv_mass
        print(f"sleeve vertices {sl.stop - sl.start}; immovable (w = 0) per element: " +
              ", ".join(f"{nm} {int((w[elem_of == i] <= 0).sum())}/{int((elem_of == i).sum())}"
                        for i, nm in enumerate(names)), flush=True)
        for f in range(args.frames):
            for r in runs:
                if census is not None:
                    census.active = r
                r.step()
            if args.diff and not args.moving:
                b = runs[0]
                qb = b.sim.state.particle_q[b.sl]
                vb = np.linalg.norm(b.sim.state.particle_qd[b.sl], axis=1)
                for r in runs[1:]:
                    dq = np.linalg.norm(r.sim.state.particle_q[r.sl] - qb, axis=1)
                    vr = np.linalg.norm(r.sim.state.particle_qd[r.sl], axis=1)
                    cl = sorted(set(v - r.sl.start for d in r.rows.values() for v in d["cloth"]))
                    top = set(np.argsort(dq)[::-1][:10].tolist())
                    r.diffs.append((f + 2, dq.max(), int(np.argmax(dq)) + r.sl.start,
                                    len(top & set(cl)), len(cl),
                                    vr[cl].max() if cl else np.nan,
                                    vb[cl].max() if cl else np.nan, vr.max() - vb.max()))
            print(f"frame {f + 2:2d}: " + "  ".join(
                f"[{r.spec}] v {r.vpinch[-1]:.3f} ev {r.frames[-1][0]['vf']}/"
                f"{r.frames[-1][0]['ee']} rows {len(r.frames[-1][1])} pin {r.pinched[-1]}"
                f"{'' if r.moving else f' pen {r.pen[-1]}'}"
                for r in runs), flush=True)
    print()
    print("| setting | near-joint max m/s (frame) | sleeve max m/s | CPU s | slid events vf/ee "
          "| frames with slid rows |")
    print("| --- | --- | --- | --- | --- | --- |")
    for r in runs:
        vp = np.array(r.vpinch)
        f = int(np.argmax(vp[3:])) + 3
        ev = [sum(fr[0][k] for fr in r.frames) for k in ("vf", "ee")]
        print(f"| {r.spec} | {vp[3:].max():.3f} ({f + 2}) | {np.max(r.vmax[3:]):.3f} | "
              f"{sum(r.cpu):.1f} | {ev[0]}/{ev[1]} | "
              f"{sum(1 for fr in r.frames if fr[1])} |")
    for r in runs[1:] if args.diff else ():
        print(f"\n[{r.spec}] against [{runs[0].spec}] (frames with a difference)")
        print("| frame | max displacement mm | at vertex | of the 10 most displaced, in slid "
              "rows | slid-row sleeve vertices | their max speed m/s (this, first) "
              "| sleeve max speed difference m/s |")
        print("| --- | --- | --- | --- | --- | --- | --- |")
        for fr, dm, at, ntop, ncl, v1, v0, dv in r.diffs:
            if dm > 0.0 or ncl:
                print(f"| {fr} | {dm * 1e3:.2f} | {at} | {ntop} | {ncl} | {v1:.3f}, {v0:.3f} "
                      f"| {dv:+.3f} |")
    for r in runs:
        if (r.mode == 0 and not args.census_all) or args.no_census:
            continue
        print(f"\n[{r.spec}] per frame (the {args.top} fastest near-joint frames and every "
              f"frame with slid rows summarised)")
        vp = np.array(r.vpinch)
        top = set((np.argsort(vp)[::-1][:args.top]).tolist())
        print("| frame | near-joint m/s | fastest vertex | in a slid row | slid rows (vf/ee) "
              "| by collider | lateral mm (median, max) | depth mm (median, max) | target mm "
              "| collider slide mm (median, max) | slide >= target | slide >= lateral |")
        print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
        for i, (ev, rows) in enumerate(r.frames):
            if not rows and i not in top:
                continue
            cloth = set(v for d in rows.values() for v in d["cloth"])
            by = {}
            for d in rows.values():
                by[d["elem"]] = by.get(d["elem"], 0) + 1
            lat = np.array([d["lateral"] for d in rows.values()]) * 1e3
            dep = np.array([d["depth"] for d in rows.values()]) * 1e3
            tg = np.array([d["target"] for d in rows.values()]) * 1e3
            sd = np.array([d["slide"] for d in rows.values()]) * 1e3
            nvf = sum(1 for k in rows if k[0] == "vf")
            fmt = (lambda a: f"{np.median(a):.1f}, {a.max():.1f}") if len(rows) else \
                (lambda a: "-")
            print(f"| {i + 2}{' *' if i in top else ''} | {vp[i]:.3f} | {r.arg[i]} | "
                  f"{'yes' if r.arg[i] in cloth else 'no'} | {nvf}/{len(rows) - nvf} | "
                  f"{', '.join(f'{k} {v}' for k, v in sorted(by.items()))} | {fmt(lat)} | "
                  f"{fmt(dep)} | {fmt(tg) if len(rows) else '-'} | {fmt(sd)} | "
                  f"{int((sd >= tg).sum())} | {int((sd >= lat).sum())} |")


if __name__ == "__main__":
    main()
