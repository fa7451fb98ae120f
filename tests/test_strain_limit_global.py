"""The global strain-limit step (strain_limit.global_passes, Goldenthal et al. 2007 fast
projection): a cloth draped over a sphere saturates its strain limit over a region, which the
Gauss-Seidel limit cannot relax; the global step holds it, with the sphere's contacts kept."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from lokigraph.api import compile_file
from lokigraph.behaviors.topology import triangle_edges
from lokigraph.run import Simulation

EX = Path(__file__).resolve().parent.parent / "graphs" / "examples"

#: the global step's defaults (as of stop 27), which the comparisons below were measured
#: against: set explicitly, so that each compares one setting with another whatever the
#: defaults become
OLD = dict(global_tolerance=0.001, global_every="substep", global_smooth=0, global_alpha=1e-3,
           global_chord=0, global_chord_rate=0.5, global_fast_lu=False,
           inextensible_joint_iterations=10)


def _ex(**kw):
    """The ``extra`` overrides of ``_drape``: OLD updated with ``kw``."""
    d = {**OLD, **kw}
    return "".join(f", {k}: {json.dumps(v)}" for k, v in d.items())


def _drape(scene_file, passes, contacts="filter", frames=8, res=32, eps=0.01, near=0.0,
           pivots=0, extra="", calls=None, glob=None):
    p = scene_file(f"""
    lokigraph: 1
    frames: {{start: 1, end: {frames + 1}, fps: 24}}
    substeps: 2
    graph_overrides: {{strain_limit: {{inextensible_max_strain: {eps}, global_passes: {passes},
                                       global_contacts: {contacts}, global_near: {near},
                                       global_pivots: {pivots}{extra}}}}}
    elements:
      - name: cloth
        geometry:
          generator: grid
          params: {{size: [0.8, 0.8], resolution: [{res}, {res}], plane: xz, center: [0, 0.33, 0]}}
        components:
          Dynamic: {{mass_density: 0.15, damping: 0.2}}
          DiscreteShell: {{bend_resistance: 2.0e-6}}
          Collider: {{thickness: 0.002, friction: 0.3}}
      - name: ball
        geometry: {{generator: sphere, params: {{radius: 0.3, subdivisions: 4}}}}
        components:
          Kinematic: {{}}
          Collider: {{thickness: 0.002, friction: 0.5, one_sided: true}}
      - name: contact
        components:
          CollisionGroup: {{members: [cloth, ball], methods: [vertex_face, edge_edge, self]}}
    """, f"drape_{passes}_{contacts}_{pivots}.yaml")
    c = compile_file(p)
    sim = Simulation(c)
    if calls is not None:  # count the global step's runs and passes
        sl = c.schedule.find("StrainLimitConstraint")[0].data.glob
        run0 = sl.run

        def run(*a, **k):
            n0 = sl.stats["passes"]
            out = run0(*a, **k)
            calls.append(sl.stats["passes"] - n0)
            return out

        sl.run = run
        if glob is not None:
            glob.append(sl)
    return _measure(c, sim, frames, centred=True)


def _measure(c, sim, frames, centred=False):
    """Step ``frames`` frames: per frame the worst edge strain of the element "cloth", the
    smallest distance of a cloth vertex from the centre of "ball" (the origin if ``centred``,
    else the mean of its vertices) minus the ball's inradius [m] (a cloth vertex nearer is
    inside it), and the frame's penetration count."""
    cl, b = c.scene.element("cloth"), c.scene.element("ball")
    E = triangle_edges(cl.geometry.triangles)
    X = cl.geometry.points
    L0 = np.linalg.norm(X[E[:, 1]] - X[E[:, 0]], axis=1)
    strain, depth, pen = [], [], []
    for _ in range(frames):
        st = sim.step_frame()
        q = sim.state.particle_q
        qc, qb = q[cl.vertex_slice], q[b.vertex_slice]
        strain.append((np.linalg.norm(qc[E[:, 1]] - qc[E[:, 0]], axis=1) / L0 - 1).max())
        T = qb[b.geometry.triangles]
        nrm = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
        inr = np.abs(np.einsum("ij,ij->i", nrm, T[:, 0]) / np.linalg.norm(nrm, axis=1)).min()
        centre = 0.0 if centred else qb.mean(axis=0)
        depth.append(np.linalg.norm(qc - centre, axis=1).min() - inr)
        pen.append(int(st.get("penetrations", 0) or 0))
    return np.array(strain), np.array(depth), np.array(pen)



def test_global_step_holds_a_saturated_drape(scene_file):
    """A 32 x 32 inextensible cloth draped over a sphere with a 1 % strain limit: the Gauss-Seidel
    limit (with its joint passes in the final collision rounds) leaves 3.3 % (measured, frame 7);
    with the global step every edge stays under 1.5 % (measured 1.1-1.3 % depending on the
    step's safeguards: what the CCD safe step and the next substep's iterations add after it),
    and no cloth vertex enters the ball (measured: every vertex 4 mm or more outside the ball's
    inradius) or crosses anything."""
    s0, d0, pen0 = _drape(scene_file, 0)
    assert s0[3:].max() > 0.025
    # at the old stopping test (1e-3): the default global_tolerance 0.005 (stop 29) lets the
    # step stop at 1.505 %
    s, d, pen = _drape(scene_file, 20, extra=", global_tolerance: 0.001")
    assert s.max() < 0.015
    assert (d > 0.0).all() and (pen == 0).all()
    # the filter with setting B's sweeps (global_smooth 40, global_alpha 1e-4, once a frame, 3
    # joint passes): its sweeps are followed by the filter's contact planes (measured 1.10 %,
    # vertices 4.1 mm outside the ball; 3.18 % and 0.8 mm without the planes)
    s, d, pen = _drape(scene_file, 20, extra=_ex(global_smooth=40, global_alpha=1e-4,
                                                 global_every="frame",
                                                 inextensible_joint_iterations=3))
    assert s.max() < 0.015
    assert (d > 0.0).all() and (pen == 0).all()


def test_global_tolerance_and_every_frame(scene_file):
    """global_tolerance: the global step stops once every edge is within that excess of its
    limit (here 0.5 % over a 1 % limit: under 1.55 % with what the CCD safe step adds),
    in fewer passes than at the default tolerance (1e-3); global_every 'frame': the step runs
    in the last substep of each frame only (2 substeps: once a frame) and the frames' strain
    still holds."""
    pv = dict(contacts="rows", near=0.02, pivots=2, frames=8)
    c0, c1, c2 = [], [], []
    s0, d0, pen0 = _drape(scene_file, 20, calls=c0, extra=_ex(), **pv)
    s1, d1, pen1 = _drape(scene_file, 20, calls=c1, extra=_ex(global_tolerance=0.005), **pv)
    s2, d2, pen2 = _drape(scene_file, 20, calls=c2, extra=_ex(global_tolerance=0.005,
                                                              global_every="frame"), **pv)
    assert s0.max() < 0.0115 and s1.max() < 0.0155 and s2.max() < 0.0155
    assert sum(c1) < sum(c0)
    assert len(c0) == len(c1) == 2 * 8 and len(c2) == 8
    for d, pen in ((d0, pen0), (d1, pen1), (d2, pen2)):
        assert (d > 0.0).all() and (pen == 0).all()


def test_global_smooth_converges_in_fewer_passes(scene_file):
    """global_smooth: Gauss-Seidel sweeps of the edge limits after each pass of the global step
    take out the second-order stretch of the linear step (edges rotated by it), so the step
    is taken whole instead of halved, and global_alpha 1e-4 then converges faster than the
    1e-3 the plain step needs. The drape holds the same bound in fewer passes, no cloth
    vertex inside the ball, no penetration."""
    pv = dict(contacts="rows", near=0.02, pivots=2, frames=8)
    c0, c1 = [], []
    s0, d0, pen0 = _drape(scene_file, 20, calls=c0, extra=_ex(global_tolerance=0.005), **pv)
    s1, d1, pen1 = _drape(scene_file, 20, calls=c1, extra=_ex(
        global_tolerance=0.005, global_smooth=40, global_alpha=1e-4), **pv)
    assert s0.max() < 0.0155 and s1.max() < 0.0155
    assert sum(c1) <= 0.6 * sum(c0)  # measured 15 against 32 passes
    for d, pen in ((d0, pen0), (d1, pen1)):
        assert (d > 0.0).all() and (pen == 0).all()


def test_global_chord_and_fast_lu(scene_file):
    """global_chord: passes after a factorised one re-solve its active set with its factor
    (chord Newton) while the passes converge; global_fast_lu: SuperLU with small supernodes.
    The drape holds the same bound as with every pass factorised, with fewer factorisations
    (the chord passes are counted), no cloth vertex inside the ball, no penetration; and the
    fast factorisation solves the same systems (the step's result within round-off of the
    plain one over a frame)."""
    pv = dict(contacts="rows", near=0.005, pivots=2, frames=8)
    ex = dict(global_tolerance=0.005, global_smooth=40, global_alpha=1e-4)
    c0, c1, g0, g1 = [], [], [], []
    s0, d0, pen0 = _drape(scene_file, 20, calls=c0, glob=g0, extra=_ex(**ex), **pv)
    s1, d1, pen1 = _drape(scene_file, 20, calls=c1, glob=g1, extra=_ex(
        **ex, global_chord=3, global_chord_rate=0.8, global_fast_lu=True), **pv)
    assert s0.max() < 0.0155 and s1.max() < 0.0155
    assert g1[0].stats.get("chord", 0) > 0 and "chord" not in g0[0].stats
    assert g1[0].stats["factorisations"] < g0[0].stats["factorisations"]
    for d, pen in ((d0, pen0), (d1, pen1)):
        assert (d > 0.0).all() and (pen == 0).all()


def test_fast_lu_and_chord_pass_solve_the_same_system():
    """GlobalStrainStep._splu with ``fast`` (relax 1, panel_size 1) solves a symmetric
    positive definite system as the plain SuperLU does (within round-off)."""
    import scipy.sparse as sp

    from lokigraph.behaviors.materials.strain_limit_global import GlobalStrainStep

    rng = np.random.default_rng(3)
    n = 300
    Jm = sp.random(n, 2 * n, density=0.01, random_state=rng, format="csr")
    R = (Jm @ Jm.T + sp.identity(n)).tocsr()
    b = rng.standard_normal(n)
    g = GlobalStrainStep(4, np.array([[0, 1]], np.int64), np.ones(1), np.arange(1))
    g.fast = False
    x0 = g._splu(R).solve(b)
    g.fast = True
    x1 = g._splu(R).solve(b)
    assert np.abs(R @ x1 - b).max() < 1e-10 and np.abs(x1 - x0).max() < 1e-10


def _drop(tmp_path, frames, **sl):
    """cloth_on_sphere (64 x 64) with strain_limit overrides ``sl``: worst edge strain and the
    smallest distance of a cloth vertex from the ball's centre minus the ball's inradius [m]
    per frame, and the penetration counts."""
    s = yaml.safe_load((EX / "cloth_on_sphere.yaml").read_text())
    s["graph_overrides"] = {"strain_limit": sl}
    s["output"] = {"dir": str(tmp_path / "out")}
    f = tmp_path / f"drop_{len(list(tmp_path.glob('*.yaml')))}.yaml"
    f.write_text(yaml.safe_dump(s))
    c = compile_file(f)
    return _measure(c, Simulation(c), frames)


@pytest.mark.slow
def test_pivoted_rows_step_holds_the_64_drop(tmp_path):
    """The 64 x 64 drop at a 1 % limit, 10 frames (the cloth lands at frame 6-7): the equality
    step with the tangent-plane filter stalls where the cloth is stretched over the ball (it
    may not lift off) and leaves 2.6 % at frame 10 (graphs/bench/cloth_strain.py, 12
    frames: 2.62 %); the contacts as one-sided rows and the inequalities solved by pivoting
    (global_contacts 'rows', global_near 0.02, global_pivots 10) converge in every substep
    (measured 1.08-1.10 % at every frame's end, the limit plus the tolerance 1e-3 of the
    limit), no cloth vertex inside the ball, no penetration."""
    base = dict(inextensible_max_strain=0.01, global_passes=20, global_contacts="filter",
                global_near=0.0, global_pivots=0, **OLD)
    s0, _, _ = _drop(tmp_path, 10, **base)
    assert s0.max() > 0.015
    s, d, pen = _drop(tmp_path, 10, **{**base, "global_contacts": "rows", "global_near": 0.02,
                                       "global_pivots": 10})
    assert s.max() < 0.0115
    assert (d > 0.0).all() and (pen == 0).all()


def test_schur_update_matches_a_fresh_factorisation():
    """A pivot's solve through the last factor and a Schur complement over the swapped rows
    (global_update) equals the solve with the new active set factorised."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    from lokigraph.behaviors.materials.strain_limit_global import GlobalStrainStep

    rng = np.random.default_rng(3)
    n = 300
    J = sp.random(n, 2 * n, density=0.01, random_state=4, format="csr")
    R = (J @ J.T + sp.diags(0.1 + rng.random(n))).tocsr()
    C = rng.standard_normal(n)
    F0 = rng.random(n) < 0.6
    idx0 = np.flatnonzero(F0)
    pos = np.full(n, -1, np.int64)
    pos[idx0] = np.arange(len(idx0))
    base = (spla.splu(R[idx0][:, idx0].tocsc()), idx0, F0.copy(), pos)
    F = F0.copy()
    F[rng.choice(idx0, 7, replace=False)] = False
    F[rng.choice(np.flatnonzero(~F0), 5, replace=False)] = True
    idx = np.flatnonzero(F)
    drop, add = idx0[~F[idx0]], idx[~F0[idx]]
    assert len(drop) == 7 and len(add) == 5
    x = GlobalStrainStep._schur(R, C, base, drop, add, idx)
    ref = spla.spsolve(R[idx][:, idx].tocsc(), C[idx])
    assert np.abs(x - ref).max() < 1e-9 * np.abs(ref).max()


if __name__ == "__main__":
    import sys
    import tempfile
    import time
    from pathlib import Path

    from conftest import write_scene

    with tempfile.TemporaryDirectory() as tmp:
        for args, kw in [((0,), {}), ((20, "filter"), {}), ((20, "rows"), {}),
                         ((20, "none"), {}), ((20, "rows"), dict(near=0.02, pivots=10)),
                         ((20, "filter"), dict(near=0.02, pivots=10))]:
            t = time.process_time()
            s, d, pen = _drape(lambda t, n: write_scene(Path(tmp), t, n), *args,
                               frames=int(sys.argv[1]), res=int(sys.argv[2]), **kw)
            print(args, kw, np.round(100 * s, 2), np.round(1000 * d, 2), pen,
                  f"{time.process_time() - t:.1f} s CPU")
