"""Momentum budget of the gas along one axis over the whole gas domain (issue #20, gas side).

The gas solver's momentum equation for the velocity component along the axis (``A``; the
chute's streamwise z) is summed over every control volume it updates (the faces of
:attr:`cfddem.gas.boundaries.BoundarySet.face_range`) and over every gas step of the
measurement window, term by term in the solver's own discretisation
(:mod:`cfddem.gas.momentum`, :mod:`cfddem.gas.projection`).  With ``eps_f`` the arithmetic
face porosity, ``V`` the cell volume and the step from n to n+1, the solver's update is exactly
(predictor plus correction, explicit viscosity)::

    rho eps_f^{n+1} (u^{n+1} - u^n) V / dt
        = rho V [ADV + VISC + eps_f^{n+1} (g + COR + CEN)] - eps_f^{n+1} grad p^{n+1} V + S V
          - K (u^{n+1} - U_p) V

and the gas momentum ``P = rho sum eps_f u V`` changes by the sum of this and
``rho u^n (eps_f^{n+1} - eps_f^n) V / dt``.  Summed over the control volumes, the advective
and viscous fluxes between neighbouring volumes cancel (the stencil's face values are the same
numbers seen from both sides), so what is left is, as forces on the gas in N along the axis:

* ``drag``: ``-sum K (u^{n+1} - U_p) V``, the reaction to the particles' drag (the exchange
  conserves it: minus the drag on all particles, held ones included, to round-off);
* ``pressure_particles``: ``sum (1 - eps_f) grad p V``, the reaction to the particles'
  pressure force (the exchange's transpose part; its boundary half-cell part is not a
  reaction, see ``source``);
* ``source``: the explicit source S the solver was given: in a coupled run the boundary
  half-cells' pressure force and weight (:mod:`cfddem.coupling.exchange`, step 5b);
* ``gravity``, ``coriolis``, ``centrifugal``: ``rho eps_f^{n+1} (...) V``;
* per side of the box (``x-``, ..., not periodic ones):
  ``flux_<side>`` the convective momentum flux through it (into the gas: positive),
  for the two sides normal to the axis ``pressure_<side>`` the pressure force
  (``+-p A`` summed over the side's cells) and ``viscous_<side>`` the normal viscous stress,
  for the four other sides ``shear_<side>`` the viscous shear stress;
* ``mass_imbalance``: ``rho sum u^n [div_CV(eps^n u^n) + (eps_f^{n+1} - eps_f^n)/dt] V``,
  the momentum the non-conservative advection form creates: u times the mass imbalance of the
  control volume between the step's advecting fluxes (at time n) and its porosity change.
  With steady porosity it is u times the continuity defect the pressure solve leaves (its
  tolerance); where the porosity changes it holds the lag of the fluxes by one step;
* ``storage``: ``(P_last - P_first) / window``;
* ``residual = sum of the terms - storage``: round-off (the terms are the solver's own
  numbers, regrouped; the budget does not rely on the pressure solve having converged, the
  ``mass_imbalance`` term carries its defect).

Where the planes lie: a side whose boundary face is prescribed (wall, inlet) bounds the
control volumes at the first cell centre (half a cell inside the box; the half cell between
lies outside every gas control volume, which is why the exchange adds its pressure force as
``source``), so ``pressure_z-`` is ``p`` of the first cell layer times the area and
``flux_z-`` the flux through that plane; a solved boundary face (an outlet) bounds them half a
cell outside the box (its halo values).  The wall shear of a no-slip wall is the solver's
``eps mu (u_P - u_ghost)/h`` at the wall itself.

Every gas step of the window is integrated (the hook :attr:`cfddem.gas.GasSolver.budget`
calls :meth:`GasBudget.before_step` and :meth:`GasBudget.after_step`); blocks for the error
bars end at :meth:`GasBudget.close_interval` (the Simulation calls it at each measurement
time).  Only with ``viscosity = "explicit"`` (the semi-implicit viscous solve changes the
update) and without a partly solved side normal to the axis.
"""

from __future__ import annotations

import numpy as np

from cfddem._jit import kernel
from cfddem.coupling.exchange import _gas_drag_sum
from cfddem.errors import CaseError
from cfddem.gas.boundaries import SIDES
from cfddem.gas.momentum import PERM, face_value
from cfddem.measure.stats import block_error

#: volume terms (forces on the gas, N, along the axis)
VOLUME = ("drag", "pressure_particles", "source", "gravity", "coriolis", "centrifugal", "mass_imbalance")
_LOC = ("fcc", "cfc", "ccf")
# slots of the kernels' accumulators
_B_GRAV, _B_COR, _B_CEN, _B_MASS, _B_P, _B_FLUX, _B_VISC = 0, 1, 2, 3, 4, 5, 11
_NB = 17
_A_PLO, _A_PHI, _A_SOLID, _A_P = 0, 1, 2, 3


@kernel
def _before_kernel(u, v, w, eo, en, dA, dB, dC, rdt, lam_ratio, scheme, oA, oB, oC, gA, XA, XB, XC, pA, pB, pC,
                   a0, a1, g, nB, nC, out):
    """Sums over the updated faces [a0, a1) (array indices along A) of the component along A,
    in the frame (A, B, C) of :data:`cfddem.gas.momentum.PERM` (arrays transposed to it, halos
    filled; u the component along A, v along B, w along C; eo, en the porosity at n and n+1),
    of the quantities of :func:`cfddem.gas.momentum.momentum_rhs_kernel`, the same operations:
    out[0] eps_f^{n+1} g_A, [1] eps_f^{n+1} COR, [2] eps_f^{n+1} CEN, [3] u_P (div_CV(F) +
    (eps_f^{n+1} - eps_f^n)/dt), [4] eps_f^n u_P (all per unit volume and rho), [5:11] the
    advective flux F q into the volumes through the sides A-, A+, B-, B+, C-, C+ (per unit
    area and rho), [11:17] the viscous stress on them (per unit area and mu), added to out."""
    rdx = 1.0 / dA
    rdy = 1.0 / dB
    rdz = 1.0 / dC
    om2 = oA * oA + oB * oB + oC * oC
    for a in range(a0, a1):
        rA = XA[a] - pA
        for b in range(g, g + nB):
            rB = XB[b] - pB
            for c in range(g, g + nC):
                rC = XC[c] - pC
                uP = u[a, b, c]
                uE = u[a + 1, b, c]
                uW = u[a - 1, b, c]
                eW = eo[a - 1, b, c]
                eE = eo[a, b, c]
                mP = 0.5 * (eW + eE) * uP
                mE = 0.5 * (eE + eo[a + 1, b, c]) * uE
                mW = 0.5 * (eo[a - 2, b, c] + eW) * uW
                Fe = 0.5 * (mP + mE)
                Fw = 0.5 * (mW + mP)
                uN = u[a, b + 1, c]
                uS = u[a, b - 1, c]
                vWn = v[a - 1, b + 1, c]
                vPn = v[a, b + 1, c]
                vWs = v[a - 1, b, c]
                vPs = v[a, b, c]
                eWn = eo[a - 1, b + 1, c]
                ePn = eo[a, b + 1, c]
                eWs = eo[a - 1, b - 1, c]
                ePs = eo[a, b - 1, c]
                Fn = 0.25 * ((eW + eWn) * vWn + (eE + ePn) * vPn)
                Fs = 0.25 * ((eWs + eW) * vWs + (ePs + eE) * vPs)
                uT = u[a, b, c + 1]
                uB_ = u[a, b, c - 1]
                wWt = w[a - 1, b, c + 1]
                wPt = w[a, b, c + 1]
                wWb = w[a - 1, b, c]
                wPb = w[a, b, c]
                eWt = eo[a - 1, b, c + 1]
                ePt = eo[a, b, c + 1]
                eWb = eo[a - 1, b, c - 1]
                ePb = eo[a, b, c - 1]
                Ft = 0.25 * ((eW + eWt) * wWt + (eE + ePt) * wPt)
                Fb = 0.25 * ((eWb + eW) * wWb + (ePb + eE) * wPb)
                efo = 0.5 * (eW + eE)
                efn = 0.5 * (en[a - 1, b, c] + en[a, b, c])
                div = (Fe - Fw) * rdx + (Fn - Fs) * rdy + (Ft - Fb) * rdz
                out[3] += uP * (div + (efn - efo) * rdt)
                out[4] += efo * uP
                out[0] += efn * gA
                vf = 0.25 * (vWs + vWn + vPs + vPn)
                wf = 0.25 * (wWb + wWt + wPb + wPt)
                out[1] += efn * (-2.0 * (oB * wf - oC * vf))
                out[2] += efn * (om2 * rA - oA * (oA * rA + oB * rB + oC * rC))
                # the sides: fluxes and stresses on the control-volume faces that lie on them
                if a == a0:
                    qw = face_value(u[a - 2, b, c], uW, uP, uE, Fw, scheme)
                    dudx_w = (uP - uW) * rdx
                    div_w = dudx_w + (vWn - vWs) * rdy + (wWt - wWb) * rdz
                    out[5] += Fw * qw
                    out[11] -= eW * (2.0 * dudx_w + lam_ratio * div_w)
                if a == a1 - 1:
                    qe = face_value(uW, uP, uE, u[a + 2, b, c], Fe, scheme)
                    dudx_e = (uE - uP) * rdx
                    div_e = dudx_e + (vPn - vPs) * rdy + (wPt - wPb) * rdz
                    out[6] -= Fe * qe
                    out[12] += eE * (2.0 * dudx_e + lam_ratio * div_e)
                if b == g:
                    qs = face_value(u[a, b - 2, c], uS, uP, uN, Fs, scheme)
                    out[7] += Fs * qs
                    out[13] -= 0.25 * (eWs + ePs + eW + eE) * ((uP - uS) * rdy + (vPs - vWs) * rdx)
                if b == g + nB - 1:
                    qn = face_value(uS, uP, uN, u[a, b + 2, c], Fn, scheme)
                    out[8] -= Fn * qn
                    out[14] += 0.25 * (eW + eE + eWn + ePn) * ((uN - uP) * rdy + (vPn - vWn) * rdx)
                if c == g:
                    qb = face_value(u[a, b, c - 2], uB_, uP, uT, Fb, scheme)
                    out[9] += Fb * qb
                    out[15] -= 0.25 * (eWb + ePb + eW + eE) * ((uP - uB_) * rdz + (wPb - wWb) * rdx)
                if c == g + nC - 1:
                    qt = face_value(uB_, uP, uT, u[a, b, c + 2], Ft, scheme)
                    out[10] -= Ft * qt
                    out[16] += 0.25 * (eW + eE + eWt + ePt) * ((uT - uP) * rdz + (wPt - wWt) * rdx)
    return 0


@kernel
def _after_kernel(u, p, en, rdA, a0, a1, g, nB, nC, out):
    """After the step (frame and arrays as :func:`_before_kernel`; p the halo-filled pressure
    p^{n+1}), added to out: ``-sum (p_a - p_{a-1})`` over the updated faces [a0, a1) telescopes
    to ``p_{a0-1} - p_{a1-1}``, the cells just below the first and the last face: out[0] the sum
    of the first over the cross-section, out[1] minus that of the second; out[2]
    ``sum (1 - eps_f^{n+1}) (p_a - p_{a-1})/h_A`` (the solid part); out[3]
    ``sum eps_f^{n+1} u^{n+1}``."""
    for b in range(g, g + nB):
        for c in range(g, g + nC):
            out[0] += p[a0 - 1, b, c]
            out[1] -= p[a1 - 1, b, c]
    for a in range(a0, a1):
        for b in range(g, g + nB):
            for c in range(g, g + nC):
                ef = 0.5 * (en[a - 1, b, c] + en[a, b, c])
                out[2] += (1.0 - ef) * ((p[a, b, c] - p[a - 1, b, c]) * rdA)
                out[3] += ef * u[a, b, c]
    return 0


class GasBudget:
    """Time-integrated momentum budget of the gas along ``axis`` over the whole domain of
    ``solver`` (a :class:`cfddem.gas.GasSolver`), over the gas steps that start at or after
    ``start_time`` (module docstring).  ``side_names``: optional labels of the sides
    (``{"y-": "floor", ...}``) for the attributes and the report.  :meth:`attach` hooks it into
    the solver."""

    group = "gas_budget"

    def __init__(self, solver, axis: int = 2, start_time: float = 0.0, side_names: dict | None = None,
                 n_blocks: int = 10):
        if solver.viscosity == "implicit" and solver.nu > 0:
            raise CaseError("gas.viscosity", "the gas momentum budget needs 'explicit' viscosity (the semi-implicit "
                            "viscous solve changes the update it sums)")
        self.axis = int(axis)
        if self.axis not in (0, 1, 2):
            raise CaseError("gas_budget.axis", f"0, 1 or 2, got {axis!r}")
        ends = ("xyz"[self.axis] + "-", "xyz"[self.axis] + "+")
        bad = [s for s in solver.bc.patched_sides if s in ends]
        if bad:
            raise CaseError("gas_budget.axis", f"side {bad[0]} is partly solved (a patched outlet): its control "
                            "volumes do not end on one plane; no budget along this axis")
        self.solver = solver
        self.start_time = float(start_time)
        self.side_names = dict(side_names or {})
        self.n_blocks = int(n_blocks)
        A, B, C = PERM[self.axis]
        self._perm = (A, B, C)
        # the sides in the kernel's slot order A-, A+, B-, B+, C-, C+, and each one's terms
        self._sides = [SIDES[2 * d + k] for d in (A, B, C) for k in (0, 1)]
        per = solver.bc.periodic
        self.terms = list(VOLUME)
        for s, d in zip(self._sides, (A, A, B, B, C, C)):
            if per[d]:
                continue
            self.terms += [f"pressure_{s}", f"flux_{s}", f"viscous_{s}"] if d == A else [f"flux_{s}", f"shear_{s}"]
        self._zero_interval()
        self._rows: list = []  # per closed interval: (duration, impulses (len terms), P at its end)
        self._p_first = None  # gas momentum at the start of the window's first step
        self._p_last = None
        self._t_first = None
        self._t_last = None
        self._n_steps = 0
        self._exchange = np.zeros(3)  # the particle side's impulse: drag, pressure, boundary pressure
        self._step_acc = None
        self._buf_b = np.zeros(_NB)
        self._buf_a = np.zeros(4)

    def attach(self) -> "GasBudget":
        self.solver.budget = self
        return self

    # ------------------------------------------------------------------ the step hook
    def wants(self, time: float) -> bool:
        """Whether the gas step starting at ``time`` lies in the window."""
        return time >= self.start_time - 1e-12

    def _frame(self, arr):
        return np.transpose(arr, self._perm)

    def before_step(self, solver, dt: float, source) -> None:
        """At the start of a step of the window (halos filled, porosity n and n+1 set): the terms
        evaluated at time n, and the given explicit source S (interior face arrays or None)."""
        A, B, C = self._perm
        grid, gh = solver.grid, solver.grid.halo
        vel = (solver.u.data, solver.v.data, solver.w.data)
        lo, hi = solver.bc.face_range[A]
        h = grid.spacing
        co = [grid.coords(_LOC[A], d, with_halo=True) for d in (A, B, C)]
        om, gv, ap = solver.omega, solver.gravity, solver.axis_point
        buf = self._buf_b
        buf[:] = 0.0
        _before_kernel(self._frame(vel[A]), self._frame(vel[B]), self._frame(vel[C]), self._frame(solver._eps_prev),
                       self._frame(solver.eps.data), h[A], h[B], h[C], 1.0 / dt, solver.lam_ratio, solver._scheme,
                       float(om[A]), float(om[B]), float(om[C]), float(gv[A]), co[0], co[1], co[2],
                       float(ap[A]), float(ap[B]), float(ap[C]), gh + lo, gh + hi, gh, grid.shape[B], grid.shape[C],
                       buf)
        vc, rho, mu = grid.cell_volume, solver.rho, solver.mu
        t = dict.fromkeys(self.terms, 0.0)
        t["gravity"] = rho * vc * buf[_B_GRAV]
        t["coriolis"] = rho * vc * buf[_B_COR]
        t["centrifugal"] = rho * vc * buf[_B_CEN]
        t["mass_imbalance"] = rho * vc * buf[_B_MASS]
        area = {A: h[B] * h[C], B: h[A] * h[C], C: h[A] * h[B]}
        for k, (s, d) in enumerate(zip(self._sides, (A, A, B, B, C, C))):
            if f"flux_{s}" in t:
                t[f"flux_{s}"] = rho * area[d] * buf[_B_FLUX + k]
                t[("viscous_" if d == A else "shear_") + s] = mu * area[d] * buf[_B_VISC + k]
        if source is not None:
            sl = [slice(None)] * 3
            sl[A] = slice(lo, hi)
            t["source"] = vc * float(np.asarray(source[A])[tuple(sl)].sum())
        if self._p_first is None:
            self._p_first = rho * vc * buf[_B_P]
            self._t_first = float(solver.time)
        self._step_acc = t

    def after_step(self, solver, dt: float, drag_K, drag_Up) -> None:
        """At the end of the same step (u^{n+1}, p^{n+1}, halos filled): pressure, drag and the
        gas momentum; adds the step's impulses to the open interval."""
        A, B, C = self._perm
        grid, gh = solver.grid, solver.grid.halo
        lo, hi = solver.bc.face_range[A]
        vel = (solver.u.data, solver.v.data, solver.w.data)
        buf = self._buf_a
        buf[:] = 0.0
        _after_kernel(self._frame(vel[A]), self._frame(solver.p.data), self._frame(solver.eps.data),
                      1.0 / grid.spacing[A], gh + lo, gh + hi, gh, grid.shape[B], grid.shape[C], buf)
        h, vc, rho = grid.spacing, grid.cell_volume, solver.rho
        t = self._step_acc
        self._step_acc = None
        ends = self._sides[0], self._sides[1]
        if f"pressure_{ends[0]}" in t:
            t[f"pressure_{ends[0]}"] = h[B] * h[C] * buf[_A_PLO]
            t[f"pressure_{ends[1]}"] = h[B] * h[C] * buf[_A_PHI]
        t["pressure_particles"] = vc * buf[_A_SOLID]
        if drag_K is not None:
            uA = np.ascontiguousarray(solver.velocity[A].interior)
            t["drag"] = -vc * _gas_drag_sum(drag_K[A], uA, drag_Up[A], A, lo, hi)
        for i, k in enumerate(self.terms):
            self._acc[i] += dt * t[k]
        self._acc_t += dt
        self._p_last = rho * vc * buf[_A_P]
        self._t_last = float(solver.time)
        self._n_steps += 1

    def add_exchange(self, dt_gas: float, fd, fp, fb) -> None:
        """The particle side of the exchange of the step just integrated (sums over all
        particles, held ones included, of the drag, the pressure force's transpose part and its
        boundary half-cell part, (3,) each): kept for the check against ``drag``."""
        a = self.axis
        self._exchange += dt_gas * np.array([fd[a], fp[a], fb[a]], float)

    def close_interval(self) -> None:
        """End the open block of steps (for the error bars); nothing if it is empty."""
        if self._acc_t > 0.0:
            self._rows.append((self._acc_t, self._acc.copy(), self._p_last))
            self._zero_interval()

    def _zero_interval(self):
        self._acc = np.zeros(len(self.terms))
        self._acc_t = 0.0

    # ------------------------------------------------------------------ results
    @property
    def n_steps(self) -> int:
        return self._n_steps

    def results(self) -> dict:
        """Time averages over the window (forces on the gas along the axis, N): every term, its
        block error ``<term>_err``, ``storage``, ``residual``, ``residual_relative`` (|residual|
        / the largest |term|), ``particle_drag``, ``particle_pressure``,
        ``particle_boundary_pressure`` (the particle side of the exchange, all particles),
        ``momentum_first`` / ``momentum_last`` (kg m/s), ``t_first``, ``t_last``, ``duration``
        (s), ``n_steps``."""
        out: dict = {"n_steps": np.int64(self._n_steps)}
        rows = list(self._rows)
        if self._acc_t > 0.0:
            rows.append((self._acc_t, self._acc.copy(), self._p_last))
        if not rows:
            return out
        dur = np.array([r[0] for r in rows])
        imp = np.array([r[1] for r in rows])
        T = float(dur.sum())
        mean = imp.sum(axis=0) / T
        pe = np.array([self._p_first] + [r[2] for r in rows])
        st_rows = np.diff(pe) / dur
        per = imp / dur[:, None]
        for i, k in enumerate(self.terms):
            out[k] = np.float64(mean[i])
            out[f"{k}_err"] = np.float64(block_error(per[:, i], self.n_blocks))
        storage = (self._p_last - self._p_first) / T
        out["storage"] = np.float64(storage)
        out["storage_err"] = np.float64(block_error(st_rows, self.n_blocks))
        total = float(mean.sum())
        out["sum_of_terms"] = np.float64(total)
        out["residual"] = np.float64(total - storage)
        scale = max(float(np.max(np.abs(mean))), abs(storage))
        out["residual_relative"] = np.float64(abs(total - storage) / scale if scale > 0 else 0.0)
        out["particle_drag"] = np.float64(self._exchange[0] / T)
        out["particle_pressure"] = np.float64(self._exchange[1] / T)
        out["particle_boundary_pressure"] = np.float64(self._exchange[2] / T)
        out["momentum_first"] = np.float64(self._p_first)
        out["momentum_last"] = np.float64(self._p_last)
        out["t_first"] = np.float64(self._t_first)
        out["t_last"] = np.float64(self._t_last + 0.0)
        out["duration"] = np.float64(T)
        return out

    def attrs(self) -> dict:
        names = {s: self.side_names.get(s, s) for s in SIDES}
        return {"axis": "xyz"[self.axis], "start_time": self.start_time, "n_blocks": self.n_blocks,
                "terms": ",".join(self.terms), "side_names": ",".join(f"{s}={n}" for s, n in names.items()),
                "units": "N (time-averaged force on the gas along the axis); momentum_* kg m/s; t_*, duration s"}

    # ------------------------------------------------------------------ restart
    def get_state(self) -> dict:
        n = len(self.terms)
        return {"acc": self._acc.copy(), "acc_t": np.float64(self._acc_t),
                "rows/duration": np.array([r[0] for r in self._rows], float),
                "rows/impulse": np.array([r[1] for r in self._rows], float).reshape(-1, n),
                "rows/momentum": np.array([r[2] for r in self._rows], float),
                "p_first": np.float64(np.nan if self._p_first is None else self._p_first),
                "p_last": np.float64(np.nan if self._p_last is None else self._p_last),
                "t_first": np.float64(np.nan if self._t_first is None else self._t_first),
                "t_last": np.float64(np.nan if self._t_last is None else self._t_last),
                "n_steps": np.int64(self._n_steps), "exchange": self._exchange.copy()}

    def set_state(self, st: dict) -> None:
        from .chute import _flatten

        st = _flatten(st)

        def opt(k):
            v = float(st.get(k, np.nan))
            return None if np.isnan(v) else v

        n = len(self.terms)
        self._acc = np.asarray(st.get("acc", np.zeros(n)), float).copy()
        if self._acc.shape != (n,):
            raise CaseError("checkpoint.gas_budget", f"{self._acc.shape[0]} terms in the checkpoint, {n} here")
        self._acc_t = float(st.get("acc_t", 0.0))
        dur = np.asarray(st.get("rows/duration", []), float)
        imp = np.asarray(st.get("rows/impulse", np.zeros((0, n))), float).reshape(-1, n)
        mom = np.asarray(st.get("rows/momentum", []), float)
        self._rows = [(float(d), i.copy(), float(m)) for d, i, m in zip(dur, imp, mom)]
        self._p_first, self._p_last = opt("p_first"), opt("p_last")
        self._t_first, self._t_last = opt("t_first"), opt("t_last")
        self._n_steps = int(st.get("n_steps", 0))
        self._exchange = np.asarray(st.get("exchange", np.zeros(3)), float).copy()
