"""Volume-averaged Navier-Stokes solver for a given porosity field (physics.md sections 2-3).

Time step (fractional step / incremental pressure projection; Chorin 1968, van Kan 1986),
with eps_f the arithmetic face mean of the cell porosity, superscripts the time level:

1. predictor, explicit in advection, viscosity, Coriolis, centrifugal force, gravity and the
   source S, implicit in the linear drag ``-K (u - U_p)``::

       (eps_f^{n+1} + dt K/rho) u* = eps_f^{n+1} u^n
            + dt [ R^n - eps_f^{n+1} grad p^n / rho + (S + K U_p) / rho ]

   (R^n from :mod:`cfddem.gas.momentum`; the face porosity at the new time multiplies the
   pressure gradient and the body forces, so a hydrostatic rest state is exact);
2. pressure increment phi from the porous continuity equation
   ``(eps^{n+1} - eps^n)/dt + div(eps_f^{n+1} u^{n+1}) = 0``::

       -div(a_f grad phi) = -(rho/dt) [ div(eps_f^{n+1} u*) + (eps^{n+1} - eps^n)/dt ],
       a_f = (eps_f^{n+1})^2 / (eps_f^{n+1} + dt K/rho)

   solved by geometric-multigrid-preconditioned CG (:mod:`cfddem.gas.multigrid`, default) or
   AMG-preconditioned CG (pyamg, :mod:`cfddem.gas.pressure`);
3. correction ``u^{n+1} = u* - (dt/rho) eps_f/(eps_f + dt K/rho) grad phi`` on every face
   that is not prescribed by a boundary condition, ``p^{n+1} = p^n + phi``.

After step 3 the discrete porous continuity equation holds to the linear solver's
tolerance, and the drag is implicit in both the predictor and the correction (no drag
time-step limit).  The source S and the drag coefficient K are forces per unit volume of
the whole cell (N/m^3 and N s/m^4); the coupling passes S = -S_p's explicit part.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
import scipy.sparse.linalg as spla

from cfddem.errors import CaseError
from cfddem.gas.boundaries import BoundarySet
from cfddem.gas.grid import Field, StaggeredGrid
from cfddem.gas.momentum import momentum_rhs, viscous_laplacian
from cfddem.gas.multigrid import MGPressureSolver
from cfddem.gas.operators import interp_to_centre
from cfddem.gas.projection import (correction_kernel, local_advective_rate_kernel, porosity_copy_kernel,
                                   predictor_kernel, pressure_rhs_kernel, step_diagnostics_kernel)
from cfddem.gas.pressure import PressureSolver

_LOC = ("fcc", "cfc", "ccf")
_NAMES = ("u", "v", "w")
_UNIT = ((1, 0, 0), (0, 1, 0), (0, 0, 1))


@dataclass
class GasStepInfo:
    """Outcome of one gas step."""

    pressure_iterations: int
    pressure_residual: float
    cfl: float  # the largest local Courant number after the step (GasSolver._advective_rate times dt)
    max_divergence: float
    ok: bool
    message: str = ""
    amg_rebuilt: bool = False
    compatibility: float = 0.0
    viscous_iterations: int = 0


class GasSolver:
    """Staggered-grid volume-averaged Navier-Stokes solver.

    Parameters
    ----------
    grid: StaggeredGrid (halo 2 for ``advection="tvd"`` or pressure outlets).
    rho, mu: gas density [kg/m3] and viscosity [Pa s]; ``lambda_bulk`` bulk viscosity (0).
    bcs: dict side -> BC for the six sides "x-", "x+", "y-", "y+", "z-", "z+".
    gravity: (gx, gy, gz) [m/s2]; omega: frame rotation [rad/s]; axis_point: a point on
    the rotation axis.
    advection: "tvd" (van Leer, bounded) or "central" (second order).
    tol, maxiter: pressure solver tolerance (relative residual) and iteration limit.
    defect_tol: with ``pressure_solver="mg"`` the pressure solve also stops once its true
        residual guarantees a mass-balance defect ``max|d(eps)/dt + div(eps_f u)| dt`` of at
        most ``defect_tol`` (1e-10, the bound the verification tests assert): ``||r||_2 <= defect_tol rho/dt^2``, since the defect of
        a cell after the correction is ``dt^2/rho |r_c|``.  It stops at whichever of the two
        criteria is met first; 0 leaves the relative criterion alone.
    pressure_solver: "mg" (default: compiled geometric multigrid as CG preconditioner,
        :class:`~cfddem.gas.multigrid.MGPressureSolver`) or "amg" (pyamg smoothed aggregation,
        :class:`~cfddem.gas.pressure.PressureSolver`; ``rebuild_threshold`` applies to it only).
    rebuild_threshold: relative coefficient change that triggers an AMG rebuild (default inf:
        rebuild only when CG slows down, see :class:`~cfddem.gas.pressure.PressureSolver`).
    cfl_max: advective Courant number used by :meth:`max_stable_dt`.
    threads: most numba threads for the step's parallel kernels (None: the caller's count).
        Default 1: on the chute grids the threaded kernels cost more than they save (the
        coupled 16 rpm chute on 16 x 8 x 150, 2 threads, idle machine: 8.3 ms per gas step
        threaded against 6.2 ms serial); results are identical for any count.
    initial_guess: the pressure solve's first iterate. "scaled" (default): the last pressure
        increment times ``a = phi.b / phi.A phi``, the multiple of it closest to the new
        solution in the A-norm (never farther than the increment itself or zero); "previous":
        the last increment as it is; "zero".  In the coupled chute the increments of
        successive gas steps are anti-correlated (the sluice feeds a lattice layer every 5 gas
        steps, and each pulse is undone in the next step): the plain previous increment starts
        CG from a residual 1.7x ||b||, worse than zero, and costs 0.7 more iterations per
        solve than the scaled one (docs/gas.md, "Pressure solver").
    viscosity: "explicit" (forward Euler, viscous step limit) or "implicit" (semi-implicit:
    backward Euler for the Laplacian part of the stress divergence, the cross-derivative
    remainder explicit; solved per component by Jacobi-preconditioned CG to
    ``viscous_tol``).
    """

    def __init__(self, grid: StaggeredGrid, *, rho: float = 1.2, mu: float = 1.8e-5, bcs: dict,
                 gravity=(0.0, 0.0, 0.0), omega=(0.0, 0.0, 0.0), axis_point=(0.0, 0.0, 0.0),
                 advection: str = "tvd", tol: float = 1e-8, maxiter: int = 200, lambda_bulk: float = 0.0,
                 rebuild_threshold: float = float("inf"), cfl_max: float = 0.5, viscosity: str = "explicit",
                 viscous_tol: float = 1e-10, viscous_maxiter: int = 500, pressure_solver: str = "mg",
                 defect_tol: float = 1e-10, threads: int | None = 1, initial_guess: str = "scaled"):
        if rho <= 0:
            raise CaseError("gas.rho", f"must be positive, got {rho}")
        if mu < 0:
            raise CaseError("gas.mu", f"must be non-negative, got {mu}")
        if viscosity not in ("explicit", "implicit"):
            raise CaseError("gas.viscosity", f"'explicit' or 'implicit', got {viscosity!r}")
        if pressure_solver not in ("mg", "amg"):
            raise CaseError("gas.pressure_solver", f"'mg' or 'amg', got {pressure_solver!r}")
        if advection not in ("tvd", "central"):
            raise CaseError("gas.advection", f"'tvd' or 'central', got {advection!r}")
        if initial_guess not in ("scaled", "previous", "zero"):
            raise CaseError("gas.initial_guess", f"'scaled', 'previous' or 'zero', got {initial_guess!r}")
        self.initial_guess = initial_guess
        if not defect_tol >= 0:
            raise CaseError("gas.defect_tol", f"must be >= 0, got {defect_tol}")
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
            raise CaseError("gas.threads", f"a positive integer or None, got {threads!r}")
        self.threads = threads
        self.defect_tol = float(defect_tol)
        self.grid = grid
        self.bc = BoundarySet(grid, bcs)
        if viscosity == "implicit" and self.bc.patched_sides:
            raise CaseError("gas.viscosity", f"'implicit' is not available with a partly solved side "
                            f"({', '.join(self.bc.patched_sides)}: a patched side with an outlet part); use 'explicit'")
        if grid.halo < 2 and (advection == "tvd" or self.bc.needs_wide_halo):
            raise CaseError("gas.grid.halo", "TVD advection and pressure outlets need halo = 2")
        self.rho = float(rho)
        self.mu = float(mu)
        self.nu = self.mu / self.rho
        self.lam_ratio = float(lambda_bulk) / self.mu - 2.0 / 3.0 if self.mu > 0 else 0.0
        self.gravity = tuple(float(x) for x in gravity)
        self.omega = tuple(float(x) for x in omega)
        self.axis_point = tuple(float(x) for x in axis_point)
        self.advection = advection
        self._scheme = 1 if advection == "tvd" else 0
        self.cfl_max = float(cfl_max)
        self.viscosity = viscosity
        self.viscous_tol = float(viscous_tol)
        self.viscous_maxiter = int(viscous_maxiter)
        self.u, self.v, self.w = (grid.zeros(loc) for loc in _LOC)
        self.p = grid.zeros("ccc")
        self.eps = Field(grid, "ccc", np.ones(grid.array_shape("ccc")))
        self._eps_prev = self.eps.data.copy()
        self._eps_set = False
        self.pressure_solver = pressure_solver
        if pressure_solver == "mg":
            self.psolver = MGPressureSolver(grid, self.bc.pressure_bc, tol=tol, maxiter=maxiter)
        else:
            self.psolver = PressureSolver(grid, self.bc.pressure_bc, tol=tol, maxiter=maxiter,
                                          rebuild_threshold=rebuild_threshold)
        self._phi = np.zeros(grid.shape)
        # preallocated work arrays of the step (no temporaries in the time loop)
        self._coef = [np.zeros(grid.interior_shape(loc)) for loc in _LOC]  # pressure coefficients a_f
        self._ratio = [np.zeros(grid.interior_shape(loc)) for loc in _LOC]  # eps_f / (eps_f + dt K/rho)
        self._zero_face = [np.zeros(grid.interior_shape(loc)) for loc in _LOC]  # S, K, U_p when not given
        self._upd_slice = []
        for c in range(3):
            lo, hi = self.bc.face_range[c]
            sl = list(grid.interior(_LOC[c]))
            sl[c] = slice(grid.halo + lo, grid.halo + hi)
            self._upd_slice.append(tuple(sl))
        self._numer = [np.zeros(np.zeros(grid.array_shape(loc))[sl].shape) for loc, sl in zip(_LOC, self._upd_slice)]
        self._den = [np.zeros_like(a) for a in self._numer]
        self._b = np.zeros(grid.shape)
        self._diag_buf = np.zeros((3, grid.shape[2]))  # work rows of step_diagnostics_kernel
        self._phif = np.zeros(grid.array_shape("ccc"))
        self._rhs = [np.zeros(grid.array_shape(loc)) for loc in _LOC]
        self._work = [np.zeros(grid.array_shape(loc)) for loc in _LOC]
        self._lout = [np.zeros(grid.array_shape(loc)) for loc in _LOC]
        self.time = 0.0
        self.step_count = 0
        self._last_dt = None
        self._last_div = 0.0
        self._visc_fail = ""
        self.last_info: GasStepInfo | None = None
        #: a momentum budget (:class:`cfddem.measure.gas_budget.GasBudget`) or None: for every
        #: step starting at a time it ``wants``, ``before_step(self, dt, S)`` after the halo fill
        #: and ``after_step(self, dt, K, U_p)`` at the end (it reads, never writes)
        self.budget = None
        self.fill_halos()

    # --- state setting ------------------------------------------------------------------
    @property
    def velocity(self) -> tuple:
        return (self.u, self.v, self.w)

    def fill_halos(self) -> None:
        self.bc.fill_velocity(self.u.data, self.v.data, self.w.data)
        self.bc.fill_pressure(self.p.data)
        self.bc.fill_scalar(self.eps.data)

    def set_velocity(self, f) -> None:
        """Initial velocity: ``f(x, y, z) -> (u, v, w)`` evaluated at each component's faces
        (interior), or a tuple of three interior face arrays."""
        for c, loc in enumerate(_LOC):
            if callable(f):
                X, Y, Z = self.grid.mesh(loc)
                val = f(X, Y, Z)[c]
            else:
                val = f[c]
            self.velocity[c].interior = np.broadcast_to(np.asarray(val, dtype=float), self.grid.interior_shape(loc))
        self.fill_halos()

    def set_pressure(self, f) -> None:
        """Pressure at centres: ``f(x, y, z)`` or an (nx, ny, nz) array."""
        if callable(f):
            X, Y, Z = self.grid.mesh("ccc")
            f = f(X, Y, Z)
        self.p.interior = np.broadcast_to(np.asarray(f, dtype=float), self.grid.shape)
        self.bc.fill_pressure(self.p.data)

    def set_porosity(self, eps_centres: np.ndarray, *, initial: bool | None = None) -> None:
        """Porosity at the cell centres for the end of the next step, shape (nx, ny, nz).

        The porosity at the end of the last step is kept as eps^n for d(eps)/dt.  The first
        call (or ``initial=True``) sets both, i.e. starts from d(eps)/dt = 0.
        """
        e = np.asarray(eps_centres, dtype=float)
        if e.shape != self.grid.shape:
            raise CaseError("gas.porosity", f"shape {e.shape}, expected {self.grid.shape}")
        # range check and copy compiled (the field is written only if every value is valid)
        if porosity_copy_kernel(np.ascontiguousarray(e), self.eps.data, self.grid.halo, 1.0 + 1e-12):
            bad = np.argwhere(~((e > 0.0) & (e <= 1.0 + 1e-12)))[0]
            raise CaseError("gas.porosity", f"must lie in (0, 1]; cell {tuple(int(i) for i in bad)} has {e[tuple(bad)]}")
        self.bc.fill_scalar(self.eps.data)
        if initial or (initial is None and not self._eps_set):
            self._eps_prev = self.eps.data.copy()
        self._eps_set = True

    # --- time step ----------------------------------------------------------------------
    def _face_arrays(self, arrs, name):
        if arrs is None:
            return None
        if len(arrs) != 3:
            raise CaseError(name, "need a tuple of three face arrays")
        out = []
        for c, a in enumerate(arrs):
            a = np.asarray(a, dtype=float)
            shape = self.grid.interior_shape(_LOC[c])
            if a.shape != shape:
                raise CaseError(name, f"component {c} has shape {a.shape}, expected {shape}")
            out.append(a)
        return out

    def step(self, dt: float, *, source=None, drag_K=None, drag_Up=None) -> GasStepInfo:
        """Advance by dt.  source: explicit force density S [N/m3]; drag_K [N s/m4] >= 0 and
        drag_Up [m/s]: implicit drag ``-K (u - U_p)``; each a tuple of three interior face
        arrays of shapes (nx+1,ny,nz), (nx,ny+1,nz), (nx,ny,nz+1).  In a periodic direction
        face n is face 0: the values given for face 0 are used, those for face n ignored.
        Faces with a prescribed normal velocity (walls, inlets) are not updated.

        The step's parallel kernels run on at most ``threads`` numba threads (the caller's
        thread count is restored afterwards); the results do not depend on it."""
        nt = numba.get_num_threads()
        if self.threads is None or self.threads >= nt:
            return self._step(dt, source, drag_K, drag_Up)
        numba.set_num_threads(self.threads)
        try:
            return self._step(dt, source, drag_K, drag_Up)
        finally:
            numba.set_num_threads(nt)

    def _step(self, dt, source, drag_K, drag_Up) -> GasStepInfo:
        dt = float(dt)
        self._visc_fail = ""
        if not dt > 0:
            raise CaseError("gas.dt", f"must be positive, got {dt}")
        grid, g, rho = self.grid, self.grid.halo, self.rho
        S = self._face_arrays(source, "gas.source")
        K = self._face_arrays(drag_K, "gas.drag_K")
        Up = self._face_arrays(drag_Up, "gas.drag_Up")
        if K is not None and any(float(np.min(k)) < 0.0 for k in K):  # a reduction, no temporary
            raise CaseError("gas.drag_K", "must be >= 0")
        if K is not None and Up is None:
            raise CaseError("gas.drag_Up", "needed with drag_K")
        eo, en = self._eps_prev, self.eps.data
        self.fill_halos()
        hook = self.budget if self.budget is not None and self.budget.wants(self.time) else None
        if hook is not None:
            hook.before_step(self, dt, S)
        vel = (self.u.data, self.v.data, self.w.data)
        # --- 1. predictor ---------------------------------------------------------------
        for c in range(3):
            lo, hi = self.bc.face_range[c]
            momentum_rhs(c, vel, eo, en, grid, nu=self.nu, lam_ratio=self.lam_ratio, scheme=self._scheme,
                         omega=self.omega, gravity=self.gravity, axis_point=self.axis_point,
                         face_range=(lo, hi), out=self._rhs[c])
        implicit = self.viscosity == "implicit" and self.nu > 0
        viscous_iters = 0
        zero = self._zero_face
        for c in range(3):
            lo, hi = self.bc.face_range[c]
            predictor_kernel(vel[c], en, self.p.data, self._rhs[c], S[c] if S is not None else zero[c],
                             K[c] if K is not None else zero[c], Up[c] if Up is not None else zero[c], dt, rho,
                             1.0 / grid.spacing[c], g, *_UNIT[c], lo, hi, not implicit, self._coef[c], self._ratio[c],
                             self._numer[c], self._den[c])
            if implicit:
                sl = self._upd_slice[c]
                val, it = self._implicit_viscous(c, sl, self._numer[c], self._den[c], eo, dt, (lo, hi))
                viscous_iters += it
                vel[c][sl] = val
        # a side with solved and prescribed boundary faces (Patched): the predictor updated the
        # whole face range; the prescribed faces get their value back and no pressure coupling
        self.bc.close_prescribed_faces(vel, self._coef, self._ratio)
        # the divergence below reads only the faces of the cells: the one face it needs that
        # the predictor did not write is face n of a periodic component (= face 0); the
        # halos are filled after the correction
        for c in range(3):
            self.bc.copy_periodic_faces(vel[c], c, g)
        # --- 2. pressure increment --------------------------------------------------------
        coefs = self._coef
        for c in range(3):
            self.bc.copy_periodic_faces(coefs[c], c, 0)
        # "mg": with drag the coefficients change at every step, so no comparison with the
        # last set-up's (it skips nothing and its copy costs memory traffic)
        self.psolver.set_coefficients(*coefs, **({"compare": K is None} if self.pressure_solver == "mg" else {}))
        nx, ny, nz = grid.shape
        dx, dy, dz = grid.spacing
        pressure_rhs_kernel(vel[0], vel[1], vel[2], en, eo, 1.0 / dx, 1.0 / dy, 1.0 / dz, dt, rho, g, self._b)
        # mass-balance stop ("mg"): after the correction the defect of a cell is
        # dt^2/rho |r_c| <= dt^2/rho ||r||_2 (r = b - A phi, unscaled), so
        # ||r||_2 <= defect_tol rho/dt^2 guarantees max defect <= defect_tol
        stop = {"atol": self.defect_tol * rho / (dt * dt)} if self.pressure_solver == "mg" else {}
        phi, sinfo = self.psolver.solve(self._b, x0=None if self.initial_guess == "zero" else self._phi,
                                        scale_x0=self.initial_guess == "scaled", **stop)
        self._phi = phi
        # --- 3. correction ----------------------------------------------------------------
        ci = grid.interior("ccc")
        phif = self._phif
        phif[ci] = phi
        self.bc.fill_pressure(phif, homogeneous=True)
        for c in range(3):
            lo, hi = self.bc.face_range[c]
            correction_kernel(vel[c], phif, self._ratio[c], dt / (rho * grid.spacing[c]), g, *_UNIT[c], lo, hi)
        self.p.data[ci] += phi
        self.bc.fill_pressure(self.p.data)
        self.bc.fill_velocity(*vel)
        # --- diagnostics ------------------------------------------------------------------
        # one pass: the mass defect, the local Courant number (NaN or inf if a velocity is:
        # the face sets are the same) and max |p| (finiteness)
        db = self._diag_buf
        defect, rate, pmax = step_diagnostics_kernel(vel[0], vel[1], vel[2], self.p.data, en, eo, 1.0 / dx, 1.0 / dy,
                                                     1.0 / dz, dt, g, nx, ny, nz, db, db.view(np.int64))
        self._last_div = float(defect)
        np.copyto(self._eps_prev, en)
        self.time += dt
        self.step_count += 1
        self._last_dt = dt
        if hook is not None:
            hook.after_step(self, dt, K, Up)
        cfl = dt * float(rate)
        finite = bool(np.isfinite(cfl) and np.isfinite(pmax))
        bad = "" if finite else self._first_nonfinite()
        ok, msg = True, ""
        if bad:
            ok, msg = False, bad
        elif self._visc_fail:
            ok, msg = False, self._visc_fail
        elif not sinfo.converged:
            ok = False
            msg = (f"pressure solver did not converge: relative residual {sinfo.residual:.3e} after "
                   f"{sinfo.iterations} iterations (tol {self.psolver.tol:.1e})")
        self.last_info = GasStepInfo(sinfo.iterations, sinfo.residual, cfl, self._last_div, ok, msg,
                                     sinfo.rebuilt, sinfo.compatibility, viscous_iters)
        return self.last_info

    def _implicit_viscous(self, c, sl, numer, den, eo, dt, face_range):
        """Solve ``den u* - dt L(u*) = numer - dt L(u^n)`` for component c on the updated
        faces (L: :func:`cfddem.gas.momentum.viscous_laplacian`, with the boundary halos as
        an affine function of u*).  The operator is symmetric positive definite."""
        grid = self.grid
        work, lout = self._work[c], self._lout[c]
        cn = 2.0 + self.lam_ratio
        kw = dict(nu=self.nu, cn=cn, face_range=face_range)
        vel = self.velocity[c].data
        viscous_laplacian(c, vel, eo, grid, out=lout, **kw)  # L(u^n), halos of u^n filled
        b = numer - dt * lout[sl]
        work[...] = 0.0
        self.bc.fill_component(work, c)
        viscous_laplacian(c, work, eo, grid, out=lout, **kw)
        lbc = lout[sl].copy()  # affine (boundary-value) part of L
        shape = lbc.shape
        b = (b + dt * lbc).ravel()

        def apply(x):
            work[sl] = x.reshape(shape)
            self.bc.fill_component(work, c)
            viscous_laplacian(c, work, eo, grid, out=lout, **kw)
            return (den * work[sl] - dt * (lout[sl] - lbc)).ravel()

        h = grid.spacing
        diag = (den + dt * self.nu * den * 2.0 * (cn / h[c] ** 2 + sum(1.0 / h[d] ** 2 for d in range(3) if d != c))).ravel()
        n = diag.size
        A = spla.LinearOperator((n, n), matvec=apply, dtype=float)
        M = spla.LinearOperator((n, n), matvec=lambda r: r / diag, dtype=float)
        count = [0]

        def cb(_):
            count[0] += 1

        x0 = (numer / den).ravel()
        x, info = spla.cg(A, b, x0=x0, rtol=self.viscous_tol, atol=0.0, maxiter=self.viscous_maxiter, M=M, callback=cb)
        if info != 0:
            self._visc_fail = f"implicit viscous solve of {_NAMES[c]} did not converge ({count[0]} iterations)"
        return x.reshape(shape), count[0]

    def _first_nonfinite(self) -> str:
        for name, f in (("u", self.u), ("v", self.v), ("w", self.w), ("p", self.p)):
            a = f.interior
            if np.isfinite(a.sum()):  # cheap test first (a finite sum has no NaN or inf terms)
                continue
            if not np.all(np.isfinite(a)):
                idx = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])
                pos = tuple(float(self.grid.coords(f.location, d, with_halo=False)[idx[d]]) for d in range(3))
                return (f"non-finite gas {name} = {a[idx]} at {f.location} index {idx} "
                        f"(x, y, z = {pos[0]:.4g}, {pos[1]:.4g}, {pos[2]:.4g}) at t = {self.time:.6g}")
        return ""

    # --- time-step limits -------------------------------------------------------------
    def _advective_rate(self) -> float:
        """max over cells of max(|u_W|,|u_E|)/dx + max(|v_S|,|v_N|)/dy + max(|w_B|,|w_T|)/dz,
        the local Courant number per unit time (:func:`~cfddem.gas.projection.local_advective_rate_kernel`;
        NaN if a velocity is NaN)."""
        dx, dy, dz = self.grid.spacing
        g = self.grid.halo
        nx, ny, nz = self.grid.shape
        return float(local_advective_rate_kernel(self.u.data, self.v.data, self.w.data, 1.0 / dx, 1.0 / dy, 1.0 / dz,
                                                 g, nx, ny, nz))

    def max_stable_dt(self) -> float:
        """Largest stable step of the explicit terms:

        * advection: ``cfl_max / max_cells (max(|u_W|,|u_E|)/dx + max(|v_S|,|v_N|)/dy +
          max(|w_B|,|w_T|)/dz)``, the local Courant number of each cell at most ``cfl_max``
          (0.5: the positivity bound of forward Euler with the van Leer limiter, whose
          limited slope at most doubles the upwind difference);
        * viscosity (explicit Euler only; none with ``viscosity="implicit"``): ``1 / (2 nu_e S)``, ``S = max_c [sum_d 1/h_d^2 +
          (1 + lam_ratio)/h_c^2]``, ``nu_e = nu max(eps)/min(eps)``;
        * Coriolis (explicit): ``0.05 / |Omega|`` (amplification ``sqrt(1 + (2|Omega|dt)^2)``
          per step stays below 1 + 5e-3).
        Drag is implicit and sets no limit.  Each limit separately: :meth:`stable_dt_limits`.
        """
        return float(min(self.stable_dt_limits().values()))

    def stable_dt_limits(self) -> dict:
        """The limits of :meth:`max_stable_dt` by name, in s: ``advective`` (at the current
        velocity), ``viscous`` (explicit viscosity only), ``coriolis``; inf where a term sets
        none (gas at rest, implicit or zero viscosity, no rotation)."""
        lims = {"advective": np.inf, "viscous": np.inf, "coriolis": np.inf}
        rate = self._advective_rate()
        if rate > 0:
            lims["advective"] = self.cfl_max / rate
        if self.nu > 0 and self.viscosity == "explicit":
            e = self.eps.interior
            nu_e = self.nu * float(e.max() / e.min())
            inv = [1.0 / h**2 for h in self.grid.spacing]
            S = max(sum(inv) + max(1.0 + self.lam_ratio, 0.0) * inv[c] for c in range(3))
            lims["viscous"] = 1.0 / (2.0 * nu_e * S)
        om = float(np.linalg.norm(self.omega))
        if om > 0:
            lims["coriolis"] = 0.05 / om
        return {k: float(v) for k, v in lims.items()}

    # --- output and diagnostics ---------------------------------------------------------
    def cell_centred_velocity(self) -> np.ndarray:
        """Velocity averaged from the faces to the cell centres, shape (nx, ny, nz, 3)."""
        out = np.empty(self.grid.shape + (3,))
        for c, f in enumerate(self.velocity):
            out[..., c] = interp_to_centre(f, c).interior  # (f[i] + f[i+1]) / 2
        return out

    def divergence_residual(self) -> float:
        """max |d(eps)/dt + div(eps_f u)| * dt of the last step (0 before the first step)."""
        return self._last_div

    # --- restart --------------------------------------------------------------------------
    def get_state(self) -> dict:
        """Evolving state for a bit-identical restart (arrays are copies)."""
        ref = self.psolver.reference_coefficients
        return {
            "u": self.u.data.copy(), "v": self.v.data.copy(), "w": self.w.data.copy(),
            "p": self.p.data.copy(), "eps": self.eps.data.copy(), "eps_prev": self._eps_prev.copy(),
            "phi": self._phi.copy(), "time": float(self.time), "step_count": int(self.step_count),
            "eps_set": bool(self._eps_set),
            "amg_reference_coefficients": None if ref is None else ref,
            "amg_reuse": self.psolver.reuse_state(),
        }

    def set_state(self, d: dict) -> None:
        for name, f in (("u", self.u), ("v", self.v), ("w", self.w), ("p", self.p), ("eps", self.eps)):
            a = np.asarray(d[name], dtype=float)
            if a.shape != f.data.shape:
                raise CaseError(f"gas.state.{name}", f"shape {a.shape}, expected {f.data.shape}")
            f.data[...] = a
        self._eps_prev = np.array(d["eps_prev"], dtype=float)
        self._phi = np.array(d["phi"], dtype=float)
        self.time = float(d["time"])
        self.step_count = int(d["step_count"])
        self._eps_set = bool(d.get("eps_set", True))
        ref = d.get("amg_reference_coefficients")
        if ref is not None:
            ref = np.asarray(ref, dtype=float)
            s = self.psolver._fshapes
            o = np.cumsum([0] + [int(np.prod(x)) for x in s])
            self.psolver.set_coefficients(*(ref[o[i]:o[i + 1]].reshape(s[i]) for i in range(3)))
            self.psolver.rebuild()
        if "amg_reuse" in d:
            self.psolver.set_reuse_state(d["amg_reuse"])
        self.fill_halos()
