"""Fluid coupling: prescribed velocity grids (one way) and a simulated MAC grid (two ways).

**One way** (``FluidDomain`` with ``simulate: false``): :class:`FluidCoupling` samples the
velocity grids at every vertex into ``air_velocity`` (read by drag and lift).

**Two ways** (``simulate: true``, Avatar supplement section 2, Figure 2; with Nucleus one
weak-coupling pass per substep):

* (A) the fluid velocity ``u^k`` sampled at the vertices (trilinear on the MAC faces,
  :func:`step_a_sample`) goes into ``air_velocity`` (:class:`FluidCoupling`, forces stage),
  and the buoyancy ``-V grad P^k`` into the forces; the solid solve applies drag implicitly,
  ``(M + h D) v' = M v* + h D u`` (AirDrag's ``drag_D``, ``drag_u``);
* (B) the drag impulses the solids received, ``J = h D (u - v')`` (exactly ``M (v' - v*)``),
  are negated and rasterized to the faces with the transpose of the sampling weights
  (:func:`step_b_rasterize`): the fluid gains exactly the momentum the solids lost;
* (C) gravity on the fluid (if on) and the pressure projection (:func:`step_c_project`);
* then the fluid is advected (:func:`end_step`) and sampled again at the new vertex positions
  for the next substep.

:class:`FluidTwoWay` (stage ``coupling``, after the solve) runs B, C and the advection.
``v*`` (velocity after the explicit forces, before drag) is rebuilt exactly as the Nucleus
solver forms it from the velocity at the start of the substep (saved by
:class:`FluidCoupling` in ``fluid_v0``), the damping and the forces, and ``v'`` with the same
kernel the solver calls, so ``J`` is what drag really did.

**With the implicit solver** the loop of Figure 2 runs inside the solver
(:class:`NewtonFluid`, a :class:`lokigraph.behavior.SolverCoupling`): per substep, solid solve
(A) with drag toward ``u^k`` and buoyancy from ``P^k``, then (B) the reaction of the solids'
new velocities and (C) the projection from the fluid of the start of the step, then the new
``u^{k+1}`` sampled at the vertices, repeated until it changes by less than the solver's
``coupling_tolerance`` (or ``coupling_iterations`` solves); then the advection. The drag
tensor ``D`` and its evaluation points are those of the start of the step (lagged). Measured
on the thrown-cloth and cape scenes: 2 solid solves per substep reach 1e-3 m/s.

A ``Wind`` in the same scene adds to the sampled velocity (drag then acts relative to wind +
fluid and its reaction goes into the fluid): with a simulated domain, make wind with inflow
faces instead. Static ``ShapeCollider`` elements (plane, sphere, capsule) are obstacles for the
fluid: their solid face fractions phi_s (3 x 3 samples per face) enter the pressure matrix
once, at bind. **Moving obstacles**: closed kinematic triangle meshes (a character; every one
by default, or ``FluidDomain.obstacles``) are rasterized every substep at their pose at the end
of it (:mod:`lokigraph.behaviors.fluid.solids`, ray parity), their faces carry the mesh's
velocity (affine fit of its vertex velocities), and the matrix is re-assembled in place with
the preconditioner of construction kept (:meth:`MacGrid.set_moving_solid`; measured on the
cape: about 45 CG iterations per projection against 11 for a fresh AMG hierarchy, whose 2 s
setup would cost far more). Not coupled back: lift (explicit force; it is not separable from
the other forces in ``particle_f``) and buoyancy act on the solids only; thin solids are not
rasterized as solid face fractions (phi_s = 0: cloth and hair are porous, gamma * thickness
<< cell size); kinematic bodies feel no force from the fluid (they are animated).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numba import njit, prange

from lokigraph.behavior import Behavior, SolverCoupling
from lokigraph.components.air import Drag
from lokigraph.components.colliders import ShapeCollider
from lokigraph.components.core import Dynamic, Kinematic
from lokigraph.components.fluid import FluidDomain
from lokigraph.geometry import vertex_measure
from lokigraph.keys import Keyed, step_frame

from ..air.kernels import implicit_drag_update_inv_mass
from ..fluid.grid import FACES, KINDS, MAX_CELLS, MacGrid, solid_face_fractions
from ..fluid.solids import MeshRasterizer, affine_velocity, is_closed
from ..fluid.vti import write_vti
from ..solvers.damping import apply_damping, bind_damping


@njit(cache=True, parallel=True)
def sample_grid(x, origin, size, grid, out):
    """Add the trilinear sample of ``grid`` (nx, ny, nz, 3) over the box to ``out`` (n, 3);
    points outside the box get nothing."""
    nx, ny, nz = grid.shape[0], grid.shape[1], grid.shape[2]
    for i in prange(x.shape[0]):
        u = (x[i, 0] - origin[0]) / size[0] * (nx - 1)
        v = (x[i, 1] - origin[1]) / size[1] * (ny - 1)
        w = (x[i, 2] - origin[2]) / size[2] * (nz - 1)
        if u < 0 or v < 0 or w < 0 or u > nx - 1 or v > ny - 1 or w > nz - 1:
            continue
        i0 = min(int(u), nx - 2) if nx > 1 else 0
        j0 = min(int(v), ny - 2) if ny > 1 else 0
        k0 = min(int(w), nz - 2) if nz > 1 else 0
        fu, fv, fw = u - i0, v - j0, w - k0
        for c in range(3):
            acc = 0.0
            for a in range(2):
                for b in range(2):
                    for d in range(2):
                        ii = min(i0 + a, nx - 1)
                        jj = min(j0 + b, ny - 1)
                        kk = min(k0 + d, nz - 1)
                        wt = ((fu if a else 1 - fu) * (fv if b else 1 - fv)
                              * (fw if d else 1 - fw))
                        acc += wt * grid[ii, jj, kk, c]
            out[i, c] += acc


@njit(cache=True, parallel=True)
def drag_impulses(D, u, v_after, h, out):
    """J_i = h D_i (u_i - v'_i): the impulse drag gave vertex i in the substep [N s]."""
    for i in prange(D.shape[0]):
        r0 = u[i, 0] - v_after[i, 0]
        r1 = u[i, 1] - v_after[i, 1]
        r2 = u[i, 2] - v_after[i, 2]
        for a in range(3):
            out[i, a] = h * (D[i, a, 0] * r0 + D[i, a, 1] * r1 + D[i, a, 2] * r2)


# ---------------------------------------------------------------------------------------------
# the steps of Figure 2 (a solver's Newton loop calls these)
# ---------------------------------------------------------------------------------------------
def step_a_sample(grid: MacGrid, x, out_u, volume=None, out_f=None):
    """(A) inputs of the solid solve: fluid velocity at the vertices into ``out_u`` [m/s]
    (0 outside the box) and, with ``volume`` [m^3] per vertex, the buoyancy -V grad p into
    ``out_f`` [N] (overwritten)."""
    grid.sample(x, out_u)
    if volume is not None and out_f is not None:
        grid.sample_pressure_gradient(x, out_f)
        out_f *= -volume[:, None]


def step_b_rasterize(grid: MacGrid, x, impulse):
    """(B) the fluid receives minus the impulses [N s] the solids received, at the points where
    drag was evaluated (transpose of the sampling). Returns the number of points in the box."""
    return grid.splat(x, -np.ascontiguousarray(impulse))


def step_c_project(grid: MacGrid, dt, gravity=None):
    """(C) gravity on the fluid (if given) and the pressure projection; returns its stats."""
    if gravity is not None:
        grid.add_body_acceleration(gravity, dt)
    return grid.project(dt)


def end_step(grid: MacGrid, dt):
    """End of the time step: viscous diffusion (if any) and self-advection."""
    grid.diffuse(dt)
    grid.advect(dt)


class NewtonFluid(SolverCoupling):
    """Figure 2 inside the implicit solver (see :class:`lokigraph.behavior.SolverCoupling`):
    per substep ``begin`` keeps the fluid of the start of the step and prepares the projection
    (inflow, moving obstacles); after every solid solve ``iterate`` restarts the fluid from it,
    applies (B) the drag reaction of the solids' new velocities ``v = (x - x0) / h`` (drag
    ``D`` and the evaluation points ``x0`` from the start of the step: D is lagged) and (C)
    the projection, samples (A) the new fluid velocity and buoyancy at ``x0``, and updates
    the solids' inputs: ``drag_u`` (the velocity drag pulls toward) and the inertial target
    ``xt`` by the change of buoyancy. Returns the largest change of the sampled velocity
    [m/s]; the behavior's step then only advects."""

    def __init__(self, behavior, d):
        self.behavior, self.d = behavior, d
        n = len(d.v_star)
        self.u_start = np.zeros_like(d.grid._vel)
        self.fu = np.zeros((n, 3))
        self.fb = np.zeros((n, 3))
        self.ran = False

    def begin(self, ctx):
        d = self.d
        self.behavior.begin_substep(ctx, d)
        self.u_start[:] = d.grid._vel
        self.ran = False

    def iterate(self, ctx, x0, x, xt):
        d = self.d
        st, m = ctx.state, ctx.model
        h = ctx.dt
        grid = d.grid
        grid._vel[:] = self.u_start
        D = st.fields.get("drag_D")
        if D is not None:
            v = d.v_star
            np.subtract(x, x0, out=v)
            v *= 1.0 / h
            drag_impulses(D, st.fields["drag_u"], v, h, d.J)
        else:
            d.J[...] = 0.0
        self.behavior.exchange(ctx, d, x0, d.J if D is not None else None)
        self.ran = True
        fu_old, fb_old = st.fields["fluid_u"], st.fields["fluid_fb"]
        step_a_sample(grid, x0, self.fu, d.volume, self.fb)
        du = self.fu - fu_old
        if D is not None:
            st.fields["drag_u"] += du
        change = float(np.abs(du).max()) if len(du) else 0.0
        fu_old[...] = self.fu
        if d.volume is not None:
            df = self.fb - fb_old
            st.particle_f += df
            free = m.particle_inv_mass > 0
            xt[free] += (h * h * m.particle_inv_mass[free])[:, None] * df[free]
            fb_old[...] = self.fb
        return change


class TwoWayPass:
    """Figure 2 for a Newton loop: ``begin()`` keeps the fluid state of the start of the step;
    ``iterate(x, J)`` restarts from it and applies (B) and (C) for the solids' latest drag
    impulses ``J`` (so k iterations do not add k impulses); ``end()`` advects."""

    def __init__(self, grid: MacGrid, dt: float, gravity=None):
        self.grid, self.dt, self.gravity = grid, dt, gravity
        self._u0 = None

    def begin(self):
        g = self.grid
        self._u0 = (g.u.copy(), g.v.copy(), g.w.copy())

    def iterate(self, x, impulse):
        g = self.grid
        g.u[...], g.v[...], g.w[...] = self._u0
        step_b_rasterize(g, x, impulse)
        return step_c_project(g, self.dt, self.gravity)

    def end(self):
        end_step(self.grid, self.dt)


def _inside_shapes(pts, shapes):
    """Points inside any static ShapeCollider (plane: the half-space below it; the collision
    thickness is not part of the obstacle)."""
    out = np.zeros(len(pts), bool)
    for c in shapes:
        ctr = np.asarray(c.center, np.float64)
        if c.shape == "plane":
            nrm = np.asarray(c.normal, np.float64)
            out |= (pts - ctr) @ (nrm / max(np.linalg.norm(nrm), 1e-300)) < 0
        elif c.shape == "sphere":
            out |= ((pts - ctr) ** 2).sum(1) < c.radius ** 2
        else:  # capsule
            ax = np.asarray(c.axis, np.float64)
            ax = ax / max(np.linalg.norm(ax), 1e-300)
            s = np.clip((pts - ctr) @ ax, -c.length / 2, c.length / 2)
            out |= ((pts - ctr - s[:, None] * ax) ** 2).sum(1) < c.radius ** 2
    return out


# ---------------------------------------------------------------------------------------------
# behaviors
# ---------------------------------------------------------------------------------------------
class FluidCoupling(Behavior):
    """Samples every prescribed FluidDomain at the vertices into ``air_velocity``
    (accumulated); with a simulated domain, adds its sampled velocity (``fluid_u``) and
    buoyancy (``fluid_fb``) and saves the velocities of the start of the substep
    (``fluid_v0``) for :class:`FluidTwoWay`."""

    stage = "forces"  # sampled before drag reads it (graph domain: coupling)
    requires = (FluidDomain,)
    reads_optional = ("fluid_u", "fluid_fb")
    writes = ("fluid_v0",)
    accumulates = ("air_velocity", "particle_f")

    def bind(self, ctx, elements):
        items = []
        two_way = False
        for e in elements:
            c = e.get(FluidDomain)
            if c.simulate:
                two_way = True
                continue
            if c.file is None:
                g = np.tile(np.asarray(c.uniform, np.float64), (2, 2, 2, 1))[None]
                t = np.zeros(1)
            else:
                path = Path(e.base_dir) / c.file
                try:
                    data = np.load(path)
                    g = np.asarray(data["velocity"], np.float64)
                    t = np.asarray(data["times"], np.float64) if "times" in data else np.zeros(1)
                except (OSError, KeyError, ValueError) as exc:
                    ctx.error(e, "FluidDomain.file", f"cannot read velocity grid {path}: {exc}")
                    continue
                if g.ndim == 4:
                    g = g[None]
                if g.ndim != 5 or g.shape[-1] != 3 or len(t) != g.shape[0]:
                    ctx.error(e, "FluidDomain.file", f"velocity must be (nx, ny, nz, 3) or "
                              f"(nt, nx, ny, nz, 3) with matching times; got {g.shape}")
                    continue
                if not np.isfinite(g).all():
                    ctx.error(e, "FluidDomain.file", "velocity grid has non-finite values")
                    continue
            items.append((np.asarray(c.origin, np.float64), np.asarray(c.size, np.float64), g,
                          t))
        return _Domains(items, two_way)

    def init_state(self, model, state, data):
        state.accumulator("air_velocity", (model.particle_count, 3))
        if data is not None and data.two_way:
            state.fields["fluid_v0"] = np.zeros((model.particle_count, 3))

    def step(self, ctx, d):
        st = ctx.state
        u = st.fields["air_velocity"]
        for origin, size, g, t in d.items:  # loop over domains, not vertices
            k = int(np.clip(np.searchsorted(t, ctx.time, side="right") - 1, 0, len(t) - 1))
            sample_grid(st.particle_q, origin, size, g[k], u)
        if d.two_way:
            st.fields["fluid_v0"][...] = st.particle_qd
            fu = st.fields.get("fluid_u")
            if fu is not None:
                u += fu
                st.particle_f += st.fields["fluid_fb"]

    def describe(self, d):
        return (f"{len(d.items)} prescribed fluid domains (one-way)"
                + ("; samples the simulated domain (two-way)" if d.two_way else ""))


@dataclass
class _Domains:
    items: list  # (origin, size, grids (nt, nx, ny, nz, 3), times)
    two_way: bool = False


@dataclass
class _TwoWay:
    grid: MacGrid
    element: str
    inflow_keys: list  # (face index, Keyed)
    gravity: np.ndarray | None
    volume: np.ndarray | None  # buoyancy volume per vertex [m^3] or None
    damp: np.ndarray  # damping rate per vertex [1/s]
    keyed_damping: list
    fields_dir: Path | None
    #: fields_dir is the default (output.dir/<element>): a run's --out moves it
    fields_default: bool
    # scratch, allocated once
    v_star: np.ndarray = field(default=None)
    J: np.ndarray = field(default=None)
    last: dict = field(default_factory=dict)
    #: moving obstacles: (element name, vertex slice, triangles) of kinematic closed meshes
    movers: list = field(default_factory=list)
    mover_data: tuple | None = None  # (rasterizer, static phi, phi, us, face centres, axis)
    #: with the implicit solver: steps B and C inside its Newton loop (:class:`NewtonFluid`)
    solver_coupling: object = None


class FluidTwoWay(Behavior):
    """The simulated FluidDomain, coupled two ways with every element carrying Drag (see the
    module docstring): per substep, after the solve, (B) the drag reaction into the grid,
    (C) the pressure projection, then the advection, and (A) the sampling for the next
    substep."""

    stage = "coupling"
    requires = (FluidDomain,)
    reads_optional = ("fluid_v0", "drag", "particle_f")
    writes = ("fluid_u", "fluid_fb")

    def bind(self, ctx, elements):
        sim = [e for e in elements if e.get(FluidDomain).simulate]
        if not sim:
            return None
        if len(sim) > 1:
            ctx.error(sim[1], "FluidDomain.simulate", "one simulated fluid domain per scene "
                      f"(also {sim[0].name!r}); merge the boxes")
            return None
        e = sim[0]
        c = e.get(FluidDomain)
        solver = getattr(ctx.scene.spec, "solver", "nucleus")
        size = np.asarray(c.size, np.float64)
        n = tuple(int(max(2, round(s / c.cell_size))) for s in size)
        if int(np.prod(n)) > MAX_CELLS:
            ctx.error(e, "FluidDomain.cell_size", f"{n[0]}x{n[1]}x{n[2]} cells exceed the "
                      f"limit of {MAX_CELLS}; use a larger cell_size")
            return None
        h = size / np.asarray(n)
        m = ctx.model
        dt = m.dt
        if c.viscosity > 0 and c.viscosity / c.density * dt * float((2.0 / h ** 2).sum()) > 1:
            ctx.error(e, "FluidDomain.viscosity", "explicit viscosity is unstable at this cell "
                      "size and substep (nu h_t sum 2/dx^2 > 1): lower it or use more substeps")
            return None
        bounds = [getattr(c, f) for f in FACES]
        kinds = np.array([KINDS[b.type] for b in bounds])
        inflow = np.zeros(6)
        keys = []
        for i, b in enumerate(bounds):
            if isinstance(b.velocity, Keyed):
                keys.append((i, b.velocity))
                inflow[i] = b.velocity.evaluate(float(ctx.scene.spec.frames.start))
            else:
                inflow[i] = b.velocity
        shapes = [el.get(ShapeCollider) for el in ctx.scene.elements if el.has(ShapeCollider)]
        probe = MacGrid(np.asarray(c.origin, np.float64), n, h, c.density, kinds, inflow,
                        solver="cg") if shapes else None
        solid = None
        if shapes:  # static obstacles: solid face fractions, in the matrix once
            phi = solid_face_fractions(probe, lambda pts: _inside_shapes(pts, shapes))
            if phi.any():
                solid = (phi, np.zeros_like(phi))
        movers = self._movers(ctx, e, c)
        if movers is None:
            return None
        grid = MacGrid(np.asarray(c.origin, np.float64), n, h, c.density, kinds, inflow,
                       viscosity=c.viscosity, advection=c.advection, solver=c.pressure_solver,
                       tolerance=c.pressure_tolerance, solid=solid)
        grid.set_velocity(np.asarray(c.uniform, np.float64))
        grid.project(dt)  # start divergence free
        grid.p[...] = 0.0
        g_vec = np.asarray(m.gravity, np.float64) if c.gravity else None
        if g_vec is not None:  # start from the hydrostatic pressure (buoyancy of step 1)
            u0 = (grid.u.copy(), grid.v.copy(), grid.w.copy())
            step_c_project(grid, dt, g_vec)
            grid.u[...], grid.v[...], grid.w[...] = u0
        # per-vertex damping (the Nucleus solver's v *= exp(-damping h)) and buoyancy volume
        dynamic = [el for el in ctx.scene.elements if el.has(Dynamic)]
        damp, kd = bind_damping(m, dynamic)
        vol = np.zeros(m.particle_count) if c.buoyancy else None
        for el in dynamic:
            if vol is not None and el.has(Drag) and el.geometry is not None:
                dg = el.get(Drag)
                g = el.geometry
                meas = vertex_measure(g)
                if len(g.tetrahedra):
                    vol[el.vertex_slice] = meas
                elif len(g.triangles):
                    vol[el.vertex_slice] = meas * dg.thickness
                elif len(g.edges):
                    vol[el.vertex_slice] = meas * math.pi * (dg.fiber_diameter / 2) ** 2
        if vol is not None and not vol.any():
            vol = None
        fdir = None
        if c.write_fields:
            fdir = (Path(e.base_dir) / c.fields_dir if c.fields_dir is not None
                    else Path(ctx.scene.spec.output.dir) / e.name)
        d = _TwoWay(grid, e.name, keys, g_vec, vol, damp, kd, fdir, c.fields_dir is None,
                    np.zeros((m.particle_count, 3)), np.zeros((m.particle_count, 3)),
                    movers=movers)
        if solver == "implicit":
            d.solver_coupling = NewtonFluid(self, d)
        if movers:
            static = solid[0] if solid is not None else np.zeros(grid.face_count)
            d.mover_data = (MeshRasterizer(grid), static, np.zeros(grid.face_count),
                            np.zeros(grid.face_count), grid.face_centers(),
                            np.repeat(np.arange(3), [grid.u.size, grid.v.size, grid.w.size]))
        return d

    @staticmethod
    def _movers(ctx, e, c):
        """The kinematic closed meshes that displace the fluid (``FluidDomain.obstacles``);
        None after an error."""
        kin = {el.name: el for el in ctx.scene.elements if el.has(Kinematic)
               and el.geometry is not None and len(el.geometry.triangles)}
        if c.obstacles is None:
            names = [nm for nm, el in kin.items() if is_closed(el.geometry.triangles)]
        else:
            names = []
            known = {el.name for el in ctx.scene.elements}
            for nm in c.obstacles:
                if nm not in known:
                    ctx.error(e, "FluidDomain.obstacles", f"no element named {nm!r}")
                elif nm not in kin:
                    ctx.error(e, "FluidDomain.obstacles", f"element {nm!r} is not a Kinematic "
                              "triangle mesh (only animated meshes move the fluid; static "
                              "shapes are obstacles already)")
                elif not is_closed(kin[nm].geometry.triangles):
                    ctx.error(e, "FluidDomain.obstacles", f"the mesh of {nm!r} is not closed "
                              "(every edge must be shared by two triangles to tell inside "
                              "from outside)")
                else:
                    names.append(nm)
            if len(names) < len(c.obstacles):
                return None
        return [(nm, kin[nm].vertex_slice, np.ascontiguousarray(kin[nm].geometry.triangles,
                                                                 np.int64)) for nm in names]

    def _move_solids(self, ctx, d):
        """Rasterize the moving obstacles at the end of the substep (their pose in
        ``kinematic_q``) with their velocity over it, merge them with the static solids and
        hand the fractions to the grid."""
        rast, static, phi, us, centers, axis = d.mover_data
        ctl = ctx.control
        phi[:] = static
        us[:] = 0.0
        for _, sl, tris in d.movers:
            xk = ctl.kinematic_q[sl]
            vk = (xk - ctl.kinematic_q_prev[sl]) / ctx.dt
            f = rast.fractions(xk, tris)
            hit = np.flatnonzero(f > phi)
            if len(hit) == 0:
                continue
            c, vc, A = affine_velocity(xk, vk)
            vel = vc + (centers[hit] - c) @ A.T
            us[hit] = vel[np.arange(len(hit)), axis[hit]]
            phi[hit] = f[hit]
        d.grid.set_moving_solid(phi, us)
        return int(np.count_nonzero(phi > static))

    def init_state(self, model, state, d):
        if d is not None:  # a scene with only prescribed domains allocates nothing
            state.fields["fluid_u"] = np.zeros((model.particle_count, 3))
            state.fields["fluid_fb"] = np.zeros((model.particle_count, 3))
            step_a_sample(d.grid, state.particle_q, state.fields["fluid_u"], d.volume,
                          state.fields["fluid_fb"])

    def step(self, ctx, d):
        if d is None:
            return
        m, st = ctx.model, ctx.state
        h = ctx.dt
        grid = d.grid
        nw = d.solver_coupling
        if nw is not None and nw.ran:  # the implicit solver ran B and C in its loop
            nw.ran = False
        else:
            self.begin_substep(ctx, d)
            # v* = what the Nucleus solver had before its drag update; v' = after it
            vs = d.v_star
            vs[...] = st.fields["fluid_v0"]
            apply_damping(ctx, vs, d.damp, d.keyed_damping)  # as the solver damped it
            vs += (h * m.particle_inv_mass)[:, None] * st.particle_f
            D = st.fields.get("drag_D")
            J = d.J
            if D is not None:
                u = st.fields["drag_u"]
                implicit_drag_update_inv_mass(vs, m.particle_inv_mass, D, u, h)  # vs := v'
                drag_impulses(D, u, vs, h, J)
            else:
                J[...] = 0.0
            self.exchange(ctx, d, st.particle_q_prev, J if D is not None else None)
        pm2 = grid.momentum()
        end_step(grid, h)
        d.last["advection"] = grid.momentum() - pm2
        step_a_sample(grid, st.particle_q, st.fields["fluid_u"], d.volume, st.fields["fluid_fb"])
        s = ctx.stats
        ps = grid.stats
        s["fluid_pressure_iterations"] = float(ps.iterations)
        s["fluid_pressure_cpu_s"] = ps.seconds
        s["max_fluid_pressure_residual"] = ps.residual
        s["max_fluid_divergence"] = ps.max_divergence
        jsum = d.last["drag"]
        s["fluid_drag_impulse"] = float(np.linalg.norm(jsum))
        J = d.J
        scale = float(np.abs(J).sum())
        s["max_fluid_exchange_error"] = (float(np.abs(d.last["exchange"] + jsum).sum() / scale)
                                         if scale > 0 else 0.0)
        s["max_fluid_speed"] = float(max(np.abs(grid.u).max(), np.abs(grid.v).max(),
                                         np.abs(grid.w).max()))

    def begin_substep(self, ctx, d):
        """Inputs of the substep's projection: keyed inflow speeds, moving obstacles."""
        grid = d.grid
        if d.inflow_keys:
            f = step_frame(ctx) + 1.0 / ctx.model.substeps  # inflow at the end of the substep
            for i, key in d.inflow_keys:
                grid.inflow[i] = key.evaluate(f)
            grid.apply_boundaries()
        if d.movers:
            ctx.stats["fluid_obstacle_faces"] = float(self._move_solids(ctx, d))

    @staticmethod
    def exchange(ctx, d, x, J):
        """(B) the drag reaction ``-J`` [N s] into the grid at the points ``x`` where drag was
        evaluated (None: no drag), then (C) gravity and the pressure projection; records the
        momentum budget of the substep in ``d.last``: the solids got ``drag``, the fluid
        ``exchange`` in (B) (= -drag), the box faces gave ``wall``, the projection changed it
        by ``projection``; ``advection`` is added after the advection."""
        grid = d.grid
        pm0 = grid.momentum()
        if J is not None:
            step_b_rasterize(grid, x, J)
        pm1 = grid.momentum()
        step_c_project(grid, ctx.dt, d.gravity)
        d.last = {"drag": J.sum(axis=0) if J is not None else np.zeros(3),
                  "exchange": pm1 - pm0, "wall": grid.wall_impulse(ctx.dt),
                  "projection": grid.momentum() - pm1}

    def frame_end(self, ctx, d):
        if d is None or d.fields_dir is None:
            return
        g = d.grid
        folder = (ctx.out_dir / d.element if d.fields_default and ctx.out_dir is not None
                  else d.fields_dir)
        write_vti(folder / f"{ctx.frame:04d}.vti", g.origin, g.h, g.cell_velocity(), g.p)

    def state_arrays(self, d):
        if d is None:
            return {}
        g = d.grid
        return {"u": g.u, "v": g.v, "w": g.w, "p": g.p, "q": g._q}

    def load_state_arrays(self, d, arrays):
        if d is None:
            return
        g = d.grid
        for k in ("u", "v", "w", "p"):
            getattr(g, k)[...] = arrays[k]
        g._q[...] = arrays["q"]

    def describe(self, d):
        if d is None:
            return "no simulated fluid domain"
        g = d.grid
        kinds = ", ".join(f"{f} {k}" for f, k in zip(
            FACES, [next(n for n, v in KINDS.items() if v == x) for x in g.kinds]) if k != "wall")
        return (f"{d.element}: {g.n[0]}x{g.n[1]}x{g.n[2]} MAC cells of "
                f"{g.h[0]:.3g} m, {g.advection}, pressure CG/{g.solver}"
                + (f"; {kinds}" if kinds else "; closed box"))
