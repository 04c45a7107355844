"""Two-way momentum exchange between the gas solver and the particles (physics.md section 4).

:class:`CoupledGas` owns a :class:`cfddem.gas.GasSolver` and drives a
:class:`cfddem.particles.system.ParticleSystem`: the gas takes one step of ``dt_g = N dt``
every ``N = coupling_interval`` particle steps, and the particles receive the drag and
pressure forces as ``system.ext_force`` for the following N steps.

Scheme (one coupling step, at particle time t; superscript n+1 = the gas after its step)
----------------------------------------------------------------------------------------
1. Porosity ``eps_c = 1 - sum_a w_ac V_a / V_cell`` (:func:`cfddem.coupling.mapping.porosity`,
   trilinear, each side by its BC's ``particle_rule``: fold or wrap).  Cells below
   ``eps_min`` are counted and logged with their minimum and location; nothing is clipped
   unless ``eps_floor`` is set (then the clipped cells are logged and counted in the series).  A cell with ``eps <= 0`` and no floor stops the run
   with a message naming the cell.  ``gas.set_porosity(eps)``.
2. Per particle: porosity ``eps_a`` and gas velocity ``u_a`` interpolated with the same
   weights (each velocity component from its own face grid), ``Re_a = eps_a rho |u_a - v_a|
   d_a / mu``, ``F_a = closure(eps_a, Re_a)``, and the drag coefficient
   ``K_a = V_a beta_a / (1 - eps_a) = 3 pi mu d_a eps_a F_a`` [kg/s].

   * ``drag_treatment="implicit"``: ``K_eff = m_a (1 - exp(-dt_g K_a / m_a)) / dt_g``.  For a
     given gas velocity u this is the exact impulse of ``m dv/dt = K (u - v)`` over dt_g
     (``m dv = m (1 - exp(-dt_g K/m)) (u - v)``), so a particle approaches but never
     overshoots the gas velocity whatever its relaxation time ``m/K``.
   * ``"explicit"``: ``K_eff = K`` (forward Euler; unstable for ``dt_g > 2 m/K``).
3. Gas step with the drag implicit in the gas: ``drag_K = D(K_eff)/V_cell``,
   ``drag_Up = D(K_eff v_a)/D(K_eff)`` (0 where D(K_eff) = 0), D = per-component face
   deposition (:meth:`MappingPlan.deposit_faces`).  The gas momentum loses
   ``dt_g sum_f K_f (u_f^{n+1} - U_p,f) V_cell = dt_g sum_a K_eff,a (I(u^{n+1})_a - v_a)``
   (I = interpolation = D^T).
4. Particle drag impulse ``J_a = dt_g K_eff,a (I(u^{n+1})_a - v_a)``: by the transpose
   property the sum of the J_a is exactly (to round-off) what the gas lost in step 3.
5. Pressure force ``F^p_a = -V_a grad p``, conserving momentum exactly with the gas's
   ``-eps_f grad p`` (eps_f the gas's arithmetic face mean of the cell porosity, boundary
   halos zero-gradient), in two parts:

   a. *transpose part* at ``p^{n+1}`` (the pressure after the projection; the predictor's
      ``p^n`` and the correction's increment add up to it): the gas on face f receives
      ``-eps_f g_f V_cell``, g_f the face difference.  With ``eps_f = 1 - phi^avg_f``,
      ``phi^avg_f = (phi_{i-1} + phi_i)/2``, ``phi_i = sum_a w_ai V_a / V_cell``, the solid
      part ``sum_f phi^avg_f g_f V_cell = sum_a V_a I_c(G)_a`` with the *centre* field
      ``G_i = (g_i + g_{i+1})/2`` over the faces the momentum equation updates (a boundary
      cell whose halo copies it counts its outer updated face with weight 1).  The particles
      receive ``-V_a I_c(G^{n+1})_a`` (trilinear from the centres, the porosity's weights);
      gas plus particles then receive ``-V_cell sum_f g_f``, which telescopes to 0 on a
      periodic axis.  In the interior G is the central difference, exact for linear p; but
      in the cell next to a wall whose boundary face is not a gas unknown G is only half the
      inner face gradient, and a bed resting on the floor would lose half of its buoyancy
      there (measured: the bottom layer stayed on the distributor above U_mf).
   b. *boundary half-cells*: a cell next to a boundary face that is not a gas unknown (a
      wall or an inlet: the sides whose BC declares ``half_cell_source``, see
      :class:`cfddem.gas.BC`; not an outlet or a periodic side) has its outer half outside
      every gas momentum control volume, so 5a gives its particles only half the gradient (a bed
      on a distributor would lose half its buoyancy in the bottom cell, and its bottom layer
      stays on the floor above U_mf: measured).  The boundary half-cell is added to the
      first interior face's control volume: its particles receive ``-V_a w_a0 g_1/2``
      (``g_1`` the first interior face gradient at ``p^{n+1}``) and the gas on face 1 the
      explicit source ``(eps_0/2)(-g^n_1 + rho g_c)`` (its pressure force at ``p^n`` and its
      weight, so a hydrostatic rest state stays exact; the rotating-frame terms of the
      half-cell are left out), blended in over the first 5 % of solid in the cell so that
      particle-free wall cells keep the gas solver's own discretisation.  The boundary supplies these forces, as it supplies the
      pressure on the gas next to it; in a fluidised bed the pressure extrapolated to the
      distributor, ``p_0 - (h/2) g_1``, then carries the whole bed weight.

6. ``system.ext_force = J/dt_g + F^p``, constant over the next N particle steps (the
   velocity-Verlet kicks apply it for exactly N dt = dt_g).

The gas is thus one interval ahead of the particles: after a coupling step at particle time
t the gas sits at t + dt_g and the particles catch up during the interval.  The porosity
change enters the gas continuity equation through ``set_porosity`` (eps^{n+1} - eps^n)/dt_g.

What is conserved: the drag and pressure exchanges exactly (``last_exchange`` records both
sides; a cell clipped by ``eps_floor`` breaks part 5a there); the boundary half-cell forces
of 5b come from the walls and inlets (``particle_boundary_pressure_impulse``).  The gas solver's bounded advection form (see :mod:`cfddem.gas.momentum`) carries
a term ``u (eps^{n+1}_f - 2 eps^n_f + eps^{n-1}_f)`` (a second time difference of the
porosity) and the pressure solver's residual, so the *total* momentum of a closed periodic
box is conserved to that level (1e-12 relative when the particles barely move, see
tests/unit/test_exchange.py).

References: Kloss et al. (2012) Prog. Comput. Fluid Dyn. 12:140 (CFDEM semi-implicit
drag); Xiao & Sun (2011) Commun. Comput. Phys. 9:297 (implicit drag in CFD-DEM).
"""

from __future__ import annotations

import logging
import math
import time as _time
from dataclasses import dataclass

import numpy as np

from cfddem._jit import kernel, parallel_kernel, prange
from cfddem.coupling import drag as _drag
from cfddem.coupling.mapping import MappingPlan, sphere_volumes
from cfddem.errors import CaseError
from cfddem.gas import GasSolver, Inlet, NoSlip, Periodic, PressureOutlet, StaggeredGrid
from cfddem.gas.operators import c2f_grad_at, c2f_interp_at, f2c_interp_at, grad_to_face, interp_to_face

__all__ = ["CoupledGas", "CouplingStatus", "build_coupled_gas", "coupling_diagnostics", "column_gas"]

_LOC = ("fcc", "cfc", "ccf")
_UNIT = ((1, 0, 0), (0, 1, 0), (0, 0, 1))



# ---------------------------------------------------------------------------- grid kernels
@kernel(inline="always")
def _face_grad(p, hw, c, i, j, k, f, lo, hi, dx):
    """g_f = (p_I - p_{I-1})/h (:func:`cfddem.gas.operators.c2f_grad_at`) on face f of component
    c at the cross indices of cell (i, j, k) (halo width hw; only index c is replaced by f),
    0 outside the updated faces [lo, hi)."""
    if f < lo or f >= hi:
        return 0.0
    di, dj, dk = _unit(c)
    return c2f_grad_at(p, hw + (f if c == 0 else i), hw + (f if c == 1 else j), hw + (f if c == 2 else k),
                       di, dj, dk, dx)


@kernel(inline="always")
def _unit(c):
    """The unit vector of axis c as three integers."""
    return (1 if c == 0 else 0), (1 if c == 1 else 0), (1 if c == 2 else 0)


@kernel
def _pressure_layer(p, e, hw, spacing, flo, fhi, per, blo, bhi, G, Gb, i):
    """Layer i of :func:`_pressure_fields_kernel`: G[i], Gb[i] and the layer's solid sums
    (three components), in cell order."""
    nx = G.shape[0]
    ny = G.shape[1]
    nz = G.shape[2]
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for j in range(ny):
        for k in range(nz):
            for c in range(3):
                a = i if c == 0 else (j if c == 1 else k)
                n = nx if c == 0 else (ny if c == 1 else nz)
                lo = flo[c]
                hi = fhi[c]
                dx = spacing[c]
                g0 = _face_grad(p, hw, c, i, j, k, a, lo, hi, dx)
                if per[c] == 1 and a + 1 == n:
                    g1 = _face_grad(p, hw, c, i, j, k, 0, lo, hi, dx)
                else:
                    g1 = _face_grad(p, hw, c, i, j, k, a + 1, lo, hi, dx)
                val = 0.5 * (g0 + g1)
                if per[c] == 0:
                    if a == 0:
                        val += 0.5 * g0
                    if a == n - 1:
                        val += 0.5 * g1
                G[i, j, k, c] = val
                b = 0.0
                if blo[c] == 1 and a == 0:
                    b += 0.5 * _face_grad(p, hw, c, i, j, k, 1, lo, hi, dx)
                if bhi[c] == 1 and a == n - 1:
                    b += 0.5 * _face_grad(p, hw, c, i, j, k, n - 1, lo, hi, dx)
                Gb[i, j, k, c] = b
                # solid part over the faces: the low face of every cell, and face n of the last
                di, dj, dk = _unit(c)
                ii = hw + i
                jj = hw + j
                kk = hw + k
                sc = (1.0 - c2f_interp_at(e, ii, jj, kk, di, dj, dk)) * g0
                if a == n - 1:
                    ef = c2f_interp_at(e, ii + di, jj + dj, kk + dk, di, dj, dk)
                    sc += (1.0 - ef) * _face_grad(p, hw, c, i, j, k, n, lo, hi, dx)
                if c == 0:
                    s0 += sc
                elif c == 1:
                    s1 += sc
                else:
                    s2 += sc
    return s0, s1, s2


@parallel_kernel
def _pressure_fields_kernel(p, e, hw, spacing, flo, fhi, per, blo, bhi, G, Gb, part, solid):
    """From the halo-filled pressure ``p`` and porosity ``e`` (halo width hw): for each component
    c the centre field ``G[..., c]`` (step 5a: (g_i + g_{i+1})/2, face n = face 0 on a periodic
    axis, the outer faces counted fully on a wall axis), the boundary half-cell field
    ``Gb[..., c]`` (step 5b: g_1/2 in the first cell if ``blo[c]``, g_{n-1}/2 in the last if
    ``bhi[c]``, else 0) and ``solid[c] = sum_f (1 - eps_f) g_f`` over all faces (eps_f the
    arithmetic face mean of the halo-filled porosity).  The same operations, in the same
    order, as the numpy code of :meth:`CoupledGas._centre_from_faces` (bit-identical G, Gb);
    ``solid`` is summed per x-layer i in cell order into ``part[i]`` (nx, 3), the layers in
    parallel (each its own slot), then over the layers in order: the same sums for any
    thread count (round-off differences to ``np.sum``)."""
    nx = G.shape[0]
    for i in prange(nx):
        # (the prange index may be unsigned: mixed with signed indices it would type as float)
        s0, s1, s2 = _pressure_layer(p, e, hw, spacing, flo, fhi, per, blo, bhi, G, Gb, np.int64(i))
        part[i, 0] = s0
        part[i, 1] = s1
        part[i, 2] = s2
    for c in range(3):
        solid[c] = 0.0
    for i in range(nx):
        for c in range(3):
            solid[c] += part[i, c]
    return 0


@parallel_kernel
def _keff_kernel(F, eps_a, d, mass, c3, dtg, implicit, keff):
    """Drag coefficient per particle (step 2), each particle its own slot:
    ``K = c3 d eps_a F`` with ``c3 = 3 pi mu``; ``keff = -m expm1(-dt_g K/m)/dt_g`` if
    ``implicit`` is 1, else K (the numpy expressions of the step, evaluated in the same
    order)."""
    for p in prange(keff.shape[0]):
        K = c3 * d[p] * eps_a[p] * F[p]
        if implicit == 1:
            m = mass[p]
            keff[p] = -m * np.expm1(-dtg * K / m) / dtg
        else:
            keff[p] = K
    return 0


@kernel
def _drag_grid_kernel(pair, vc, K, Up):
    """Flat face arrays, ``pair[i] = (D(K_eff), D(K_eff v))``: K = D(K_eff)/vc,
    Up = D(K_eff v)/D(K_eff) where D(K_eff) > 0, else 0 (step 3)."""
    for i in range(pair.shape[0]):
        a = pair[i, 0]
        K[i] = a / vc
        Up[i] = pair[i, 1] / a if a > 0.0 else 0.0
    return 0


@kernel
def _gas_drag_sum(K, u, Up, c, lo, hi):
    """sum over the faces lo <= index_c < hi of K (u - Up) (the gas side of the drag exchange,
    per unit dt_g V_cell), summed in index order."""
    acc = 0.0
    for i in range(K.shape[0]):
        if c == 0 and (i < lo or i >= hi):
            continue
        for j in range(K.shape[1]):
            if c == 1 and (j < lo or j >= hi):
                continue
            for k in range(K.shape[2]):
                if c == 2 and (k < lo or k >= hi):
                    continue
                acc += K[i, j, k] * (u[i, j, k] - Up[i, j, k])
    return acc



@kernel
def _average_kernel(u, v, w, hw, dt, acc):
    """acc[..., c] += dt * (cell-centred velocity component c), the centre value being the
    mean of the two faces around the cell (``GasSolver.cell_centred_velocity``, same
    operations)."""
    for i in range(acc.shape[0]):
        for j in range(acc.shape[1]):
            for k in range(acc.shape[2]):
                a = hw + i
                b = hw + j
                c = hw + k
                acc[i, j, k, 0] += f2c_interp_at(u, a, b, c, 1, 0, 0) * dt
                acc[i, j, k, 1] += f2c_interp_at(v, a, b, c, 0, 1, 0) * dt
                acc[i, j, k, 2] += f2c_interp_at(w, a, b, c, 0, 0, 1) * dt
    return 0


@kernel
def _half_cell_source_kernel(p, e, hw, di, dj, dk, f, cell, lo, hi, h, rhog, half_solid, S):
    """S[face f along (di, dj, dk)] += (eps_b/2) s (-g_f + rho g_c) over the boundary layer
    (:meth:`CoupledGas._boundary_source`): eps_b the porosity of boundary cell ``cell`` beside
    the face, g_f = :func:`~cfddem.gas.operators.c2f_grad_at` of p on face f (0 unless
    lo <= f < hi), ``s = min(1, (1 - eps_b)/half_solid)``; S an interior face array."""
    n0, n1, n2 = S.shape
    i0, i1 = (f, f + 1) if di == 1 else (0, n0)
    j0, j1 = (f, f + 1) if dj == 1 else (0, n1)
    k0, k1 = (f, f + 1) if dk == 1 else (0, n2)
    for i in range(i0, i1):
        for j in range(j0, j1):
            for k in range(k0, k1):
                eb = e[hw + (cell if di == 1 else i), hw + (cell if dj == 1 else j), hw + (cell if dk == 1 else k)]
                g = c2f_grad_at(p, hw + i, hw + j, hw + k, di, dj, dk, h) if lo <= f < hi else 0.0
                blend = min(1.0, (1.0 - eb) / half_solid)
                S[i, j, k] += 0.5 * eb * blend * (-g + rhog)
    return 0


@dataclass
class CouplingStatus:
    """Failure of a coupling step (gas NaN, pressure solver, porosity): ``ok`` False and a
    one-sentence ``message`` naming the cell and the quantity."""

    ok: bool = False
    flag: str | None = "gas"
    index: int = -1
    value: float = float("nan")
    message: str = ""
    steps_done: int = 0


def _sl(d, s):
    out = [slice(None)] * 3
    out[d] = s
    return tuple(out)


def _layer(a, d, i):
    """The layer i along axis d of a 3-D array (a view over the other two axes in order)."""
    return a[_sl(d, i)]


class CoupledGas:
    """Gas solver plus the momentum exchange with a ParticleSystem (see module docstring).

    ``HALF_CELL_SOLID`` (0.05): solid fraction of a boundary cell above which its half-cell
    gas is fully added to the first face's control volume (step 5b).

    Parameters
    ----------
    system: the ParticleSystem (its ``ext_force`` is overwritten at every coupling step).
    grid: :class:`StaggeredGrid`; bcs: dict side -> BC (see :mod:`cfddem.gas.boundaries`).
    rho, mu: gas density and viscosity; closure: drag closure name (``drag.CLOSURES``).
    coupling_interval: N particle steps per gas step.
    drag_treatment: "implicit" or "explicit" (see module docstring).
    gravity, omega, axis_point: the gas's body force and frame rotation (the particles have
    their own, in the ParticleSystem).
    periodic: per axis, whether it is periodic (default: from the bcs).
    eps_min: porosity below which cells are counted (reported once, by :meth:`run_summary`);
    eps_floor: if set, the porosity handed to the gas (and used by the closures) is
    max(eps, eps_floor).
    superficial_inlets: {side: U} for :class:`Inlet` sides whose *superficial* velocity U
    is prescribed: the gas's inlet face velocity is the interstitial one, so at every
    coupling step it is reset to U / eps of the adjacent cell (the porous continuity flux
    through the face, eps_f u with the zero-gradient porosity halo, is then exactly U).
    A bed resting on a distributor needs this; a plain Inlet would feed eps U.
    log: a logger (default ``logging.getLogger("cfddem")``); gas_kw: passed to GasSolver
    (advection, tol, maxiter, ...).
    """

    HALF_CELL_SOLID = 0.05

    def __init__(self, system, grid: StaggeredGrid, bcs: dict, *, rho: float, mu: float,
                 closure: str = "beetstra", coupling_interval: int = 10, drag_treatment: str = "implicit",
                 gravity=(0.0, 0.0, 0.0), omega=(0.0, 0.0, 0.0), axis_point=(0.0, 0.0, 0.0),
                 periodic=None, log=None, eps_min: float = 0.3, eps_floor: float | None = None,
                 superficial_inlets: dict | None = None, cfl_stop: float = 1.0, divergence_stop: float = 1e-4,
                 drag_factor: float = 1.0, frozen: bool = False, **gas_kw):
        # blow-up guards (the run stops with a diagnosis): the explicit advection is unstable
        # above CFL 1; a mass-balance defect (max |d eps/dt + div(eps u)| dt) above
        # divergence_stop means continuity is no longer enforced
        self.cfl_stop = float(cfl_stop)
        self.divergence_stop = float(divergence_stop)
        if drag_treatment not in ("implicit", "explicit"):
            raise CaseError("gas.drag_treatment", f"'implicit' or 'explicit', got {drag_treatment!r}")
        if int(coupling_interval) < 1:
            raise CaseError("gas.coupling_interval", f"must be >= 1, got {coupling_interval}")
        if eps_floor is not None and not (0.0 < eps_floor < 1.0):
            raise CaseError("gas.eps_floor", f"must lie in (0, 1), got {eps_floor}")
        if not (drag_factor >= 0.0 and math.isfinite(drag_factor)):
            raise CaseError("gas.drag_factor", f"must be a finite number >= 0, got {drag_factor}")
        #: bracketing runs (#20): every drag coefficient times drag_factor; a frozen gas is not
        #: solved (its fields stay as set: one-way coupling, the particles feel drag and the
        #: pressure gradient of the held field, the gas feels nothing)
        self.drag_factor = float(drag_factor)
        self.frozen = bool(frozen)
        self._rest_p = None  # a frozen gas's pressure (hold_at_rest)
        self.system = system
        self.grid = grid
        self.gas = GasSolver(grid, rho=rho, mu=mu, bcs=bcs, gravity=gravity, omega=omega,
                             axis_point=axis_point, **gas_kw)
        bc_per = tuple(bool(p) for p in self.gas.bc.periodic)
        if periodic is not None and tuple(bool(p) for p in periodic) != bc_per:
            raise CaseError("gas.periodic", f"{tuple(periodic)} does not match the boundary conditions {bc_per}")
        self.periodic = bc_per
        self.rho = float(rho)
        self.mu = float(mu)
        self.closure = closure
        self._F = _drag.get_closure(closure)
        try:  # a named closure (or one of its functions) runs by its compiled twin
            self._cid = _drag.closure_id(closure)
        except CaseError:  # a user's own callable F(eps, re): called as it is
            self._cid = None
        self.N = int(coupling_interval)
        self.drag_treatment = drag_treatment
        self.eps_min = float(eps_min)
        self.eps_floor = eps_floor
        self.log = log if log is not None else logging.getLogger("cfddem")
        self.phase = 0
        self.n_couplings = 0
        #: an object with ``wants_gas(t)`` and ``add_gas(t, dt_g, pos, held, drag, pressure, keff,
        #: eps)`` (a :class:`cfddem.measure.budget.MomentumBudget`): given the per-particle drag and
        #: pressure force (n, 3) of every coupling step it wants, each applied for dt_g, and the
        #: drag coefficients (drag = keff (u - v)) and porosities at the particles (n,)
        self.force_sink = None
        self._last = {"gas_pressure_iterations": 0.0, "gas_pressure_residual": 0.0, "gas_cfl": 0.0,
                      "min_porosity": 1.0, "gas_max_divergence": 0.0, "drag_power": 0.0,
                      "n_low_porosity_cells": 0.0, "n_clipped_cells": 0.0, "max_drag_force": 0.0}
        # the gas steps of this run (not of a run resumed from): run_summary() logs them
        self._run_stats = {"steps": 0, "its_sum": 0, "its_max": 0, "res_max": 0.0, "defect_max": 0.0,
                           "cfl_max": 0.0, "low_steps": 0, "low_cells_max": 0, "low_min": math.inf,
                           "low_where": None}
        self.last_exchange: dict = {}
        self._ws: dict = {}  # MappingPlan work arrays, reused between coupling steps
        self._superficial: dict = {}
        for side, U in (superficial_inlets or {}).items():
            self.set_superficial_inlet(side, U)
        # time average of the cell-centred gas velocity (write_measurements), over gas steps
        # ending after average_start (build_coupled_gas: measurements.start_time)
        self.average_start = 0.0
        self._avg_sum = np.zeros(grid.shape + (3,))
        self._avg_time = 0.0
        # the boundary sides with a half-cell (step 5b): their BC's half_cell_source (walls,
        # inlets: the sides whose boundary face is not a gas unknown)
        self._bside = [tuple(bool(v) for v in pair) for pair in self.gas.bc.half_cell]
        self._has_boundary = [a or b for a, b in self._bside]
        # patched sides with a half-cell on some face cells only: (axis, lower) -> boolean
        # array over the side's face cells (tangential axes in increasing order) without one
        self._no_half = {}
        for c in range(3):
            for lower, side in ((True, "xyz"[c] + "-"), (False, "xyz"[c] + "+")):
                m = self.gas.bc.cell_mask(side, "half_cell_source", True)
                if isinstance(m, np.ndarray) and m.any() and not m.all():
                    self._no_half[(c, lower)] = ~m
        # sides whose particle rule is "leave": a particle whose centre lies beyond one takes
        # no part in the exchange (axis, lower, plane coordinate)
        self._leave = [(c, side[1] == "-", grid.origin[c] + (0.0 if side[1] == "-" else grid.lengths[c]))
                       for c in range(3) for side in ("xyz"[c] + "-", "xyz"[c] + "+")
                       if self.gas.bc.particle_rules[2 * c + (side[1] == "+")] == "leave"]
        self._g = tuple(float(v) for v in gravity)
        # parameters of _pressure_fields_kernel: spacing, updated face range, periodic, boundary sides
        fr = self.gas.bc.face_range
        self._gparams = (np.array([float(h) for h in grid.spacing]),
                         np.array([int(fr[c][0]) for c in range(3)], np.int64),
                         np.array([int(fr[c][1]) for c in range(3)], np.int64),
                         np.array([1 if self.gas.bc.periodic[c] else 0 for c in range(3)], np.int64),
                         np.array([1 if self._bside[c][0] else 0 for c in range(3)], np.int64),
                         np.array([1 if self._bside[c][1] else 0 for c in range(3)], np.int64))
        self._upd = []
        for c in range(3):
            lo, hi = self.gas.bc.face_range[c]
            m = np.zeros(grid.shape[c] + 1, bool)
            m[lo:hi] = True
            self._upd.append(m)

    # ------------------------------------------------------------------ properties
    @property
    def dt_gas(self) -> float:
        return self.N * float(self.system.dt)

    # ------------------------------------------------------------------ time loop
    def advance(self, n_steps: int, timings: dict | None = None):
        """Advance the particles by ``n_steps`` steps, stepping the gas at every multiple of
        the coupling interval (a phase counter carries over between calls).  Returns the
        particle StepStatus, or a :class:`CouplingStatus` (ok False) on a gas failure."""
        done = 0
        st = None
        n_steps = int(n_steps)
        while done < n_steps:
            if self.phase == 0:
                t0 = _time.perf_counter()
                fail = self.couple(timings)
                if timings is not None:
                    timings["coupling"] = timings.get("coupling", 0.0) + (_time.perf_counter() - t0
                                                                          - self._gas_wall)
                if fail is not None:
                    fail.steps_done = done
                    return fail
            k = min(self.N - self.phase, n_steps - done)
            st = self.system.step(k)
            if not st.ok:
                st.steps_done = done + st.steps_done
                return st
            self.phase = (self.phase + k) % self.N
            done += k
        if st is None:
            from cfddem.particles.system import StepStatus

            st = StepStatus(ok=True, steps_done=0)
        st.steps_done = done
        return st

    def couple(self, timings: dict | None = None):
        """One coupling step (module docstring, steps 1-6).  Returns None or a failure status."""
        sys_, gas, grid = self.system, self.gas, self.grid
        self._gas_wall = 0.0
        n = sys_.n
        pos = np.ascontiguousarray(sys_.pos)
        vel = np.ascontiguousarray(sys_.vel)  # read only here (ext_force is written)
        rad = np.ascontiguousarray(sys_.radius)
        mass = np.ascontiguousarray(sys_.mass)
        plan = MappingPlan(grid, pos, self.gas.bc, workspace=self._ws)  # the BCs' particle rules
        vol = sphere_volumes(rad, self._work("_vol", (n,)))
        gone = self._left_the_gas(pos) if self._leave and n else None
        if gone is not None:
            vol[gone] = 0.0  # no volume: no porosity, no pressure force (and no drag: below)
        # --- 1. porosity ------------------------------------------------------------------
        por = plan.porosity(rad, self.eps_min, volume=vol)
        eps = por.eps
        n_clip = 0
        if por.n_low:
            self._report_low(por)
        if self.eps_floor is not None:
            clip = eps < self.eps_floor
            n_clip = int(np.count_nonzero(clip))
            if n_clip:
                eps = np.where(clip, self.eps_floor, eps)
        elif por.n_negative or por.eps_min_found <= 0.0:
            return CouplingStatus(
                flag="porosity", value=por.eps_min_found,
                message=(f"porosity {por.eps_min_found:.3g} <= 0 in gas cell {por.where} at t = {sys_.time:.6g} s: "
                         f"more particle volume than the cell holds ({por.n_negative} cells); use larger gas "
                         "cells (about 3 particle diameters or more) or set an eps_floor"))
        gas.set_porosity(eps)
        self._update_inlets()
        # --- 2. drag coefficients ---------------------------------------------------------
        dtg = self.dt_gas
        vc = grid.cell_volume
        if n:
            d = 2.0 * rad
            # the closure in its own parallel pass over the particles (its compiled twin;
            # docs/coupling.md, "Fused kernels")
            eps_a, re = plan.interpolate_slip(eps, gas.u.interior, gas.v.interior, gas.w.interior, vel, d,
                                              self.rho, self.mu)
            if self._cid is not None:
                F = _drag.drag_values(self._cid, eps_a, re, self._work("_F", (n,)))
            else:
                F = np.ascontiguousarray(self._F(eps_a, re), dtype=np.float64)
            if self.drag_factor != 1.0:
                F *= self.drag_factor
            Keff = self._work("_Keff", (n,))
            _keff_kernel(F, eps_a, d, mass, 3.0 * np.pi * self.mu, dtg, 1 if self.drag_treatment == "implicit" else 0,
                         Keff)
            if gone is not None:
                Keff[gone] = 0.0
        if n and not self.frozen:
            pairs = plan.deposit_drag_pairs(Keff, vel)  # (D(K_eff), D(K_eff v_c)) per face grid
            drag_K = tuple(self._work("_dK" + loc, a.shape[:3]) for loc, a in zip(_LOC, pairs))
            drag_Up = tuple(self._work("_dUp" + loc, a.shape[:3]) for loc, a in zip(_LOC, pairs))
            for c in range(3):  # K = D(K_eff)/V_cell, Up = D(K_eff v)/D(K_eff) (0 where D(K_eff) = 0)
                _drag_grid_kernel(pairs[c].reshape(-1, 2), vc, drag_K[c].reshape(-1), drag_Up[c].reshape(-1))
        else:
            drag_K = drag_Up = None
        if self.frozen:
            return self._frozen_forces(plan, vel, Keff if n else None, vol, eps_a if n else None)
        # boundary half-cells (module docstring, step 5b), explicit at p^n
        source = self._boundary_source()
        # --- 3. gas step ------------------------------------------------------------------
        t0 = _time.perf_counter()
        t_gas = gas.time  # the start of the gas step (a gas budget integrates the steps it wants)
        info = gas.step(dtg, source=source, drag_K=drag_K, drag_Up=drag_Up)
        self._gas_wall = _time.perf_counter() - t0
        if timings is not None:
            timings["gas"] = timings.get("gas", 0.0) + self._gas_wall
        self._last.update(gas_pressure_iterations=float(info.pressure_iterations),
                          gas_pressure_residual=float(info.pressure_residual), gas_cfl=float(info.cfl),
                          min_porosity=float(por.eps_min_found), gas_max_divergence=float(info.max_divergence),
                          n_low_porosity_cells=float(por.n_low), n_clipped_cells=float(n_clip))
        st = self._run_stats
        st["steps"] += 1
        st["its_sum"] += int(info.pressure_iterations)
        st["its_max"] = max(st["its_max"], int(info.pressure_iterations))
        # max() with the new value first: a NaN (a failed step) is kept, not skipped
        st["res_max"] = max(float(info.pressure_residual), st["res_max"])
        st["defect_max"] = max(float(info.max_divergence), st["defect_max"])
        st["cfl_max"] = max(float(info.cfl), st["cfl_max"])
        if not info.ok:
            return CouplingStatus(flag="gas", message=f"gas step failed at t = {sys_.time:.6g} s: {info.message}")
        if info.cfl > self.cfl_stop:
            return CouplingStatus(
                flag="gas", message=f"gas CFL number {info.cfl:.3g} above {self.cfl_stop:g} at t = {sys_.time:.6g} s "
                f"(gas step {dtg:.3g} s, stable step {gas.max_stable_dt():.3g} s): the gas step is too large for "
                f"this flow; lower gas.coupling_interval (cfddem check recommends one)")
        if info.max_divergence > self.divergence_stop:
            return CouplingStatus(
                flag="gas", message=f"gas mass balance defect {info.max_divergence:.3g} above "
                f"{self.divergence_stop:g} at t = {sys_.time:.6g} s: the pressure solve no longer enforces "
                f"continuity (porosity changing too fast for the gas step; lower gas.coupling_interval)")
        self.n_couplings += 1
        # --- 4.-6. forces on the particles -------------------------------------------------
        if n:
            f, solid = self._apply_forces(plan, pos, vel, Keff, vol, eps_a)
            gb = gas.budget  # the gas's momentum budget: the particle side of the step it integrated
            if gb is not None and gb.wants(t_gas):
                gb.add_exchange(dtg, f["fd"], f["fp"], f["fb"])
            # both sides of the exchange (momentum received), for conservation checks: the
            # particle and gas entries of each pair must sum to zero
            gas_drag = np.empty(3)
            for c in range(3):
                lo, hi = gas.bc.face_range[c]
                u_c = np.ascontiguousarray(getattr(gas, "uvw"[c]).interior)
                gas_drag[c] = dtg * _gas_drag_sum(drag_K[c], u_c, drag_Up[c], c, lo, hi) * vc
            self.last_exchange = {"particle_drag_impulse": dtg * f["fd"],
                                  "gas_drag_impulse": -gas_drag,
                                  "particle_pressure_impulse": dtg * f["fp"],
                                  "gas_solid_pressure_impulse": dtg * vc * solid,
                                  "particle_boundary_pressure_impulse": dtg * f["fb"]}
        else:
            self._last["drag_power"] = 0.0
            self._last["max_drag_force"] = 0.0
        if gas.time > self.average_start + 1e-12 * dtg:
            _average_kernel(gas.u.data, gas.v.data, gas.w.data, int(grid.halo), dtg, self._avg_sum)
            self._avg_time += dtg
        if self.n_couplings % 1000 == 1 and gas.max_stable_dt() < dtg:  # (max_stable_dt costs 0.2 ms)
            self.log.warning("gas time step dt_g = %.3g s exceeds the gas's stable step %.3g s (CFL %.3g)",
                             dtg, gas.max_stable_dt(), info.cfl)
        return None

    def _frozen_forces(self, plan, vel, Keff, vol, eps_a):
        """A frozen gas (one-way coupling): the particles' drag and pressure forces from the
        held fields, nothing back to the gas, no gas step."""
        sys_, gas = self.system, self.gas
        self.n_couplings += 1
        gas.time += self.dt_gas
        if sys_.n:
            self._apply_forces(plan, np.ascontiguousarray(sys_.pos), vel, Keff, vol, eps_a)
        return None

    def _apply_forces(self, plan, pos, vel, Keff, vol, eps_a):
        """Steps 4-6 for the particles: ``system.ext_force = fd + fp + fb`` written directly
        (a contiguous view of its store); a momentum budget in its window (``force_sink``)
        also gets the per-particle split.  Returns (the apply_forces dict, the solid part of
        the pressure exchange)."""
        sys_, gas = self.system, self.gas
        G, Gb, solid = self._pressure_fields()
        sink = self.force_sink
        keep = sink is not None and sink.wants_gas(sys_.time)
        f = plan.apply_forces(gas.u.interior, gas.v.interior, gas.w.interior, vel, Keff, vol, G, Gb,
                              sys_.ext_force, boundary_used=self._has_boundary, store=keep)
        if keep:
            sink.add_gas(sys_.time, self.dt_gas, pos, sys_.held, f["fd_each"], f["fp_each"] + f["fb_each"], Keff,
                         eps_a)
        self._last["drag_power"] = f["power"]
        self._last["max_drag_force"] = f["max_magnitude"]
        return f, solid

    def _left_the_gas(self, pos):
        """Boolean mask of the particles whose centre lies beyond a side with particle rule
        "leave" (they left the gas domain: no volume, drag or pressure force), None if none."""
        out = np.zeros(pos.shape[0], bool)
        for c, lower, x in self._leave:
            out |= (pos[:, c] < x) if lower else (pos[:, c] > x)
        return out if out.any() else None

    def _work(self, key, shape):
        """A work array kept between coupling steps (reused when the shape matches; first
        touches of fresh arrays cost page faults every step)."""
        arr = self._ws.get(key)
        if arr is None or arr.shape != tuple(shape):
            arr = self._ws[key] = np.empty(shape)
        return arr

    def set_superficial_inlet(self, side: str, U: float) -> None:
        """Prescribe the superficial velocity U [m/s] (into the box) on an Inlet side."""
        if not isinstance(self.gas.bc.bcs.get(side), Inlet):
            raise CaseError("gas.bcs", f"side {side!r} is not an Inlet")
        self._superficial[side] = float(U)
        self._update_inlets()

    def _update_inlets(self) -> None:
        """Inlet face speed U / eps(adjacent cell) on each superficial inlet side (uses the
        halo layout of the porosity array; refreshes the BoundarySet's precomputed values)."""
        if not self._superficial:
            return
        bc, grid = self.gas.bc, self.grid
        h = grid.halo
        e = self.gas.eps.data
        for side, U in self._superficial.items():
            d = "xyz".index(side[0])
            idx = h if side[1] == "-" else h + grid.shape[d] - 1
            row = e[_sl(d, slice(idx, idx + 1))]
            speed = U / row

            def fn(x, y, z, _row=speed, _U=U):
                shape = np.broadcast(x, y, z).shape
                if shape == _row.shape:
                    return _row
                return np.full(shape, _U)  # other components' points: the normal speed is unused

            bc.bcs[side] = Inlet(speed=fn, tangential=bc.bcs[side].tangential)
        bc._precompute()
        self.gas.fill_halos()

    def _upd_mask(self, c):
        m = self._upd[c]
        shape = [1, 1, 1]
        shape[c] = m.size
        return m.reshape(shape)

    def _face_gradients(self):
        """g_f = (p_I - p_{I-1})/h (:func:`cfddem.gas.operators.grad_to_face` of the halo-filled p)
        on every face of each component, zero on faces that the momentum equation does not
        update."""
        return [self._interior_faces(grad_to_face(self.gas.p, c), c, masked=True) for c in range(3)]

    def _face_porosity(self):
        """The gas's face porosity eps_f = (eps_{I-1} + eps_I)/2 on every face
        (:func:`cfddem.gas.operators.interp_to_face` of the halo-filled eps)."""
        return [self._interior_faces(interp_to_face(self.gas.eps, c), c) for c in range(3)]

    def _interior_faces(self, f, c, masked=False):
        """The interior faces (0..n along c) of a component-c face Field, as a new array; with
        ``masked`` zero outside the faces the momentum equation updates."""
        out = np.array(f.interior)
        if masked:
            lo, hi = self.gas.bc.face_range[c]
            out[_sl(c, slice(0, lo))] = 0.0
            out[_sl(c, slice(hi, None))] = 0.0
        return out

    def centre_pressure_gradient(self):
        """The centre field G (module docstring, step 5) for each component, shape (nx,ny,nz):
        the transpose of the gas's face porosity weighting ``eps_f = (eps_{i-1} + eps_i)/2``."""
        return self._centre_from_faces(self._face_gradients())

    def _boundary_source(self):
        """Explicit gas source [N/m3] on the first updated face next to each boundary face that
        is not a gas unknown: the pressure force and weight of the gas in the boundary
        half-cell, ``S = (eps_b/2) s (-g^n_1 + rho g_c)`` (eps_b the boundary cell's porosity,
        g^n_1 the face gradient of the current pressure), blended in with the cell's solid
        fraction, ``s = min(1, (1 - eps_b)/HALF_CELL_SOLID)``, so that particle-free boundary
        cells keep the gas solver's own discretisation.  None if the box has no such side."""
        if not any(self._has_boundary):
            return None
        grid = self.grid
        p = self.gas.p.data
        e = self.gas.eps.data
        out = []
        for c in range(3):
            n = grid.shape[c]
            S = self._work("_S" + _LOC[c], grid.interior_shape(_LOC[c]))
            S.fill(0.0)
            lo, hi = self.gas.bc.face_range[c]
            for lower, on in zip((True, False), self._bside[c]):
                if on:
                    no_half = self._no_half.get((c, lower))
                    T = S
                    if no_half is not None:  # a patched side: only on its face cells with a half-cell
                        T = self._work("_T" + _LOC[c], S.shape)
                        T.fill(0.0)
                    _half_cell_source_kernel(p, e, int(grid.halo), *_UNIT[c], 1 if lower else n - 1, 0 if lower else n - 1,
                                             lo, hi, float(grid.spacing[c]), self.rho * self._g[c], self.HALF_CELL_SOLID, T)
                    if no_half is not None:
                        _layer(T, c, 1 if lower else n - 1)[no_half] = 0.0
                        S += T
            out.append(S)
        return tuple(out)

    def _pressure_fields(self):
        """``(G, Gb, solid)`` at the current pressure, one compiled pass over the cells
        (:func:`_pressure_fields_kernel`): G (nx, ny, nz, 3) the three centre fields of step 5a,
        Gb those of step 5b (zero for a component without a boundary side), solid (3,) the solid part
        ``sum_f (1 - eps_f) g_f`` of the gas's pressure exchange per component: of the gas's
        pressure impulse ``-dt_g sum_f eps_f g_f V_cell = -dt_g V_cell sum_f g_f + dt_g V_cell solid``
        over the updated faces, the first part telescopes to 0 on periodic axes, and the
        particles' share of step 5a is minus the second.  G and Gb live in work arrays that the
        next call overwrites."""
        gas, grid = self.gas, self.grid
        shape = tuple(grid.shape) + (3,)
        G = self._work("_G", shape)
        Gb = self._work("_Gb", shape)
        solid = np.empty(3)
        p = np.ascontiguousarray(gas.p.data, dtype=np.float64)
        e = np.ascontiguousarray(gas.eps.data, dtype=np.float64)
        part = self._work("_Gpart", (grid.shape[0], 3))
        _pressure_fields_kernel(p, e, int(grid.halo), *self._gparams, G, Gb, part, solid)
        for (c, lower), no_half in self._no_half.items():  # patched sides: no half-cell over the outlet part
            _layer(Gb[..., c], c, 0 if lower else grid.shape[c] - 1)[no_half] = 0.0
        return G, Gb, solid

    def _centre_from_faces(self, grads, boundary=False):
        """G_i = (g_i + g_{i+1})/2 (module docstring, step 5a); ``boundary``: instead the
        boundary half-cell part (step 5b): g_1/2 in the first cell next to a boundary face that
        is not a gas unknown (g_{n-1}/2 in the last), 0 elsewhere."""
        if boundary:
            out = []
            for c, g in enumerate(grads):
                n = self.grid.shape[c]
                G = np.zeros(self.grid.shape)
                lo, hi = self._bside[c]
                if lo:
                    G[_sl(c, 0)] += 0.5 * g[_sl(c, 1)]
                if hi:
                    G[_sl(c, n - 1)] += 0.5 * g[_sl(c, n - 1)]
                for (cc, lower), no_half in self._no_half.items():
                    if cc == c:
                        _layer(G, c, 0 if lower else n - 1)[no_half] = 0.0
                out.append(G)
            return out
        out = []
        for c, g in enumerate(grads):
            n = self.grid.shape[c]
            if self.periodic[c]:
                g = g.copy()
                g[_sl(c, n)] = g[_sl(c, 0)]  # face n is face 0
            G = 0.5 * (g[_sl(c, slice(0, n))] + g[_sl(c, slice(1, n + 1))])
            if not self.periodic[c]:  # zero-gradient porosity halo: outer faces count fully
                G[_sl(c, 0)] += 0.5 * g[_sl(c, 0)]
                G[_sl(c, n - 1)] += 0.5 * g[_sl(c, n)]
            out.append(G)
        return out

    def _report_low(self, por):
        """Count a gas step with cells below ``eps_min``: no log line per step (dense packing in
        single cells is expected, at a feed lattice or a pile against a wall), the run's counts
        go into the end-of-run summary (:meth:`run_summary`)."""
        st = self._run_stats
        st["low_steps"] += 1
        st["low_cells_max"] = max(st["low_cells_max"], int(por.n_low))
        if por.eps_min_found < st["low_min"]:
            st["low_min"] = float(por.eps_min_found)
            st["low_where"] = (tuple(int(i) for i in por.where), float(self.system.time))

    # ------------------------------------------------------------------ output
    def gas_momentum(self) -> np.ndarray:
        """rho sum_f eps_f u_f V_cell over the faces the momentum equation updates [kg m/s]."""
        gas, vc = self.gas, self.grid.cell_volume
        return np.array([self.rho * vc * float(np.sum(ef * f.interior * self._upd_mask(c)))
                         for c, (ef, f) in enumerate(zip(self._face_porosity(), (gas.u, gas.v, gas.w)))])

    def series_row(self) -> dict:
        row = dict(self._last)
        pg = self.gas_momentum()
        pp = self.system.momentum() if self.system.n else np.zeros(3)
        for i, ax in enumerate("xyz"):
            row[f"gas_momentum_{ax}"] = float(pg[i])
            row[f"particle_momentum_{ax}"] = float(pp[i])
        row["gas_time"] = float(self.gas.time)
        return row

    def vtk_fields(self) -> dict:
        g = self.grid
        return dict(origin=tuple(g.origin), spacing=tuple(g.spacing), shape=tuple(g.shape),
                    cell_data={"velocity": self.gas.cell_centred_velocity(),
                               "pressure": np.array(self.gas.p.interior),
                               "porosity": np.array(self.gas.eps.interior)})

    def mean_velocity(self) -> np.ndarray:
        """Time-averaged cell-centred gas velocity (nx, ny, nz, 3) over the gas steps ending
        after ``average_start`` (or since :meth:`reset_average`); the current field if none."""
        if self._avg_time <= 0:
            return self.gas.cell_centred_velocity()
        return self._avg_sum / self._avg_time

    def reset_average(self) -> None:
        self._avg_sum[:] = 0.0
        self._avg_time = 0.0

    def write_measurements(self, results_file) -> None:
        """``/measurements/gas``: time-averaged cell-centred velocity (nx, ny, nz, 3) over the
        coupling steps ending after ``average_start`` (the current field before that), its
        depth-mean ``top_view_velocity`` (nx, nz, 3) for the report, cell
        centre coordinates, and the averaging time."""
        g = self.grid
        mv = self.mean_velocity()
        results_file.write_measurements("gas", {
            "mean_velocity": mv, "top_view_velocity": mv.mean(axis=1),
            "x": g.centres(0), "y": g.centres(1), "z": g.centres(2),
        }, {"averaging_time": float(self._avg_time), "average_start": float(self.average_start),
            "closure": self.closure,
            "drag_treatment": self.drag_treatment, "coupling_interval": self.N})

    # ------------------------------------------------------------------ restart
    def get_state(self) -> dict:
        st = {k: v for k, v in self.gas.get_state().items() if v is not None}
        return {"gas": st, "phase": np.int64(self.phase), "n_couplings": np.int64(self.n_couplings),
                "ext_force": np.array(self.system.ext_force), "ext_ids": np.array(self.system.ids),
                "avg_sum": self._avg_sum.copy(), "avg_time": float(self._avg_time),
                "last": {k: float(v) for k, v in self._last.items()}}

    def hold_at_rest(self) -> None:
        """A frozen gas (``gas.coupling = "one_way_rest"``): the air at rest in the simulation's
        frame, on the boundary faces too (an inlet's or a moving lid's face values are not
        imposed), with the pressure it has now (the scene's initial, hydrostatic field), kept
        through checkpoints: a run branched from a developed flow with moving air holds the air
        at rest, not the flow of the checkpoint."""
        if self._rest_p is None:
            self._rest_p = self.gas.p.data.copy()
        for f in (self.gas.u, self.gas.v, self.gas.w):
            f.data[...] = 0.0
        self.gas.p.data[...] = self._rest_p

    def set_state(self, d: dict) -> None:
        gs = dict(d["gas"])
        gs.setdefault("amg_reference_coefficients", None)
        self.gas.set_state(gs)
        self.phase = int(d["phase"])
        self.n_couplings = int(d["n_couplings"])
        self._avg_sum[...] = np.asarray(d["avg_sum"], float)
        self._avg_time = float(d["avg_time"])
        self._last.update({k: float(v) for k, v in d.get("last", {}).items()})
        ids = np.asarray(d["ext_ids"], np.int64)
        f = np.asarray(d["ext_force"], float).reshape(-1, 3)
        cur = self.system.ids
        if ids.shape == cur.shape and np.array_equal(ids, cur):
            self.system.ext_force[:] = f
        else:
            order = np.argsort(ids)
            k = np.searchsorted(ids[order], cur)
            k = np.clip(k, 0, max(len(ids) - 1, 0))
            found = (len(ids) > 0) & (ids[order][k] == cur) if len(ids) else np.zeros(len(cur), bool)
            self.system.ext_force[:] = 0.0
            self.system.ext_force[found] = f[order][k[found]]
        if self.frozen:
            self.hold_at_rest()

    # ------------------------------------------------------------------ diagnostics
    def run_stats(self) -> dict:
        """The gas steps of this run: ``gas_steps``, ``gas_cg_iterations_mean`` and ``_max``,
        ``gas_pressure_residual_max`` (relative), ``gas_mass_defect_max``, ``gas_cfl_max``, and
        the porosity below ``eps_min``: ``gas_low_porosity_steps`` (gas steps with such cells),
        ``gas_low_porosity_cells_max`` (most such cells in one step), ``gas_low_porosity_min``
        (the lowest porosity in them, NaN if none) (the run stores them in results.h5's
        metadata, the comparison report shows the solver's)."""
        st = self._run_stats
        n = st["steps"]
        return {"gas_steps": n, "gas_cg_iterations_mean": st["its_sum"] / n if n else math.nan,
                "gas_cg_iterations_max": st["its_max"], "gas_pressure_residual_max": st["res_max"],
                "gas_mass_defect_max": st["defect_max"], "gas_cfl_max": st["cfl_max"],
                "gas_low_porosity_steps": st["low_steps"], "gas_low_porosity_cells_max": st["low_cells_max"],
                "gas_low_porosity_min": st["low_min"] if st["low_steps"] else math.nan}

    def run_summary(self) -> str | None:
        """One log line on the gas steps of this run (None before the first): their number,
        the pressure solve's CG iterations (mean, max) and largest relative residual against
        its tolerance, the largest mass-balance defect and the largest Courant number; and,
        when cells fell below ``eps_min``, in how many gas steps, how many cells at most and the
        lowest porosity with its cell and time (counted silently during the run)."""
        st = self.run_stats()
        if st["gas_steps"] == 0:
            return None
        gas = self.gas
        tol = getattr(gas.psolver, "tol", None)
        stop = "" if tol is None else f" (stops at {tol:.0e}"
        if stop and gas.pressure_solver == "mg" and gas.defect_tol > 0:
            stop += f" or once the defect is sure to be below {gas.defect_tol:.0e}"
        line = (f"gas: {st['gas_steps']} steps; pressure solve ({gas.pressure_solver}): CG iterations mean "
                f"{st['gas_cg_iterations_mean']:.2f}, max {st['gas_cg_iterations_max']}; relative residual at most "
                f"{st['gas_pressure_residual_max']:.2e}" + (stop + ")" if stop else "")
                + f"; mass-balance defect at most {st['gas_mass_defect_max']:.2e}; Courant number at most "
                f"{st['gas_cfl_max']:.3g}")
        if st["gas_low_porosity_steps"]:
            where, t = self._run_stats["low_where"]
            k = st["gas_low_porosity_cells_max"]
            line += (f"; porosity below {self.eps_min:g} in {st['gas_low_porosity_steps']} of the gas steps (at most "
                     f"{k} cell{'' if k == 1 else 's'} at once, lowest {st['gas_low_porosity_min']:.3g} in "
                     f"cell {where} at t = {t:.4g} s; expected where particles pack densely in single cells, "
                     "as at a feed lattice or a pile against a wall"
                     + (")" if self.eps_floor is None else f"; the gas used max(eps, {self.eps_floor:g}))"))
        return line

    def diagnostics(self) -> list[str]:
        s = self.system
        d = float(2 * s.radius.max()) if s.n else None
        rho_p = float(s.mass[0] / (4.0 / 3.0 * np.pi * s.radius[0] ** 3)) if s.n else None
        lines = _diag_lines(self.grid, d, rho_p, self.rho, self.mu, self.closure, float(s.dt), self.N,
                            self.gas.stable_dt_limits(), self.drag_treatment)
        lines.append(f"gas CFL of the last step: {self._last['gas_cfl']:.3g}; min porosity: "
                     f"{self._last['min_porosity']:.3g} ({int(self._last['n_low_porosity_cells'])} cells below "
                     f"{self.eps_min:g})")
        return lines


def _diag_lines(grid, d, rho_p, rho, mu, closure, dt, N, gas_stable_dt, treatment, u_scale=None):
    dtg = N * dt
    lines = []
    h = grid.spacing
    lines.append(f"gas grid {grid.shape[0]} x {grid.shape[1]} x {grid.shape[2]} cells of "
                 f"{h[0] * 1e3:.3g} x {h[1] * 1e3:.3g} x {h[2] * 1e3:.3g} mm; gas step dt_g = {N} x {dt:g} = {dtg:.3g} s "
                 f"(drag {treatment})")
    if d:
        vp = math.pi * d**3 / 6.0
        ratio = grid.cell_volume / vp
        hmin = min(h)
        lines.append(f"cell volume / particle volume = {ratio:.3g}; smallest cell side / d = {hmin / d:.3g}"
                     + (" (WARNING: below 3, noisy porosity)" if hmin / d < 3 else ""))
        tau0 = rho_p * d * d / (18.0 * mu)
        try:
            vt = _drag.terminal_velocity(rho_p, rho, d, mu, closure=closure)
            re_t = rho * vt * d / mu
            tau_t = float(_drag.relaxation_time(1.0, re_t, rho_p, d, mu, closure))
            tau_d = float(_drag.relaxation_time(0.4, 0.4 * re_t, rho_p, d, mu, closure))
        except CaseError:
            vt, re_t, tau_t, tau_d = float("nan"), float("nan"), tau0, tau0
        lines.append(f"particle relaxation time: Stokes {tau0:.3g} s, at the terminal velocity {vt:.3g} m/s "
                     f"(Re {re_t:.3g}) {tau_t:.3g} s, in a packed bed (eps 0.4) {tau_d:.3g} s; "
                     f"dt/tau = {dt / min(tau_t, tau_d):.3g}, dt_g/tau = {dtg / min(tau_t, tau_d):.3g}"
                     + (" (explicit drag unstable: dt_g > 2 tau)" if treatment == "explicit"
                        and dtg > 2 * min(tau_t, tau_d) else ""))
    # gas_stable_dt: GasSolver.stable_dt_limits(), each limit named
    label = {"advective": "advective at the present gas velocity", "viscous": "viscous (explicit)",
             "coriolis": "Coriolis"}
    named = ", ".join(f"{label.get(k, k)} {v:.3g} s" for k, v in gas_stable_dt.items() if math.isfinite(v))
    stable = f"gas stable step {min(gas_stable_dt.values()):.3g} s" + (f" ({named})" if named else " (no limit)")
    if u_scale:
        cfl = dtg * sum(u_scale / hh for hh in h)
        lines.append(f"gas CFL estimate at {u_scale:.3g} m/s: {cfl:.3g}; {stable}")
    else:
        lines.append(stable)
    return lines


# ---------------------------------------------------------------------------- a scene's gas
def build_coupled_gas(case, system, domain, log=None) -> CoupledGas:
    """The CoupledGas of a case with ``gas.enabled`` on the :class:`~cfddem.gas.domain.GasDomain`
    its scene declares (grid, a boundary condition per face, frame, initial fields), with the
    gas properties, closure, coupling interval and solver of the case's ``[gas]``."""
    gcfg = case.gas
    frozen = gcfg.coupling == "one_way_rest"
    cg = CoupledGas(system, domain.grid, domain.bcs, rho=gcfg.density, mu=gcfg.viscosity, closure=gcfg.drag,
                    coupling_interval=gcfg.coupling_interval, drag_treatment=gcfg.drag_treatment,
                    gravity=domain.gravity, omega=domain.omega, axis_point=domain.axis_point, log=log,
                    pressure_solver=gcfg.pressure_solver, tol=gcfg.pressure_tol, drag_factor=gcfg.drag_factor,
                    frozen=frozen)
    cg.average_start = float(case.measurements.start_time)
    if domain.velocity is not None and not frozen:
        cg.gas.set_velocity(domain.velocity)
    if domain.pressure is not None:
        cg.gas.set_pressure(domain.pressure)
    if frozen:
        cg.hold_at_rest()
    return cg


def coupling_diagnostics(case, domain, d: float | None) -> list[str]:
    """The coupling numbers of a case on its gas domain without running (for ``cfddem check``);
    ``d``: the largest particle diameter, None for a case without particles."""
    if not case.gas.enabled:
        return ["gas: off"]
    gcfg = case.gas
    gas = GasSolver(domain.grid, rho=gcfg.density, mu=gcfg.viscosity, bcs=domain.bcs, gravity=domain.gravity,
                    omega=domain.omega, axis_point=domain.axis_point)
    if domain.velocity is not None:
        gas.set_velocity(domain.velocity)
    lines = _diag_lines(domain.grid, d, case.particles.density, gcfg.density, gcfg.viscosity, gcfg.drag,
                        case.time.dt, gcfg.coupling_interval, gas.stable_dt_limits(), gcfg.drag_treatment,
                        domain.speed_scale)
    return lines + list(domain.notes)


# ---------------------------------------------------------------------------- test helper
def column_gas(system, *, lengths, cells, inlet_velocity, rho=1.2, mu=1.8e-5, gravity=(0.0, -9.81, 0.0),
               origin=(0.0, 0.0, 0.0), periodic_xz=True, **kw) -> CoupledGas:
    """A fluidisation column: gas fed from below through the whole y- side (a uniform
    superficial velocity inlet, i.e. an ideal distributor plate; the particles rest on their
    own floor wall, which the gas passes through), pressure outlet p = 0 on y+, x and z
    periodic (or no-slip walls).  ``inlet_velocity`` (superficial, m/s) can be changed later
    with ``cg.set_superficial_inlet("y-", U)``."""
    side = (Periodic(), Periodic()) if periodic_xz else (NoSlip(), NoSlip())
    bcs = {"x-": side[0], "x+": side[1], "z-": side[0], "z+": side[1],
           "y-": Inlet(speed=float(inlet_velocity)), "y+": PressureOutlet(p=0.0)}
    grid = StaggeredGrid(tuple(cells), tuple(lengths), tuple(origin), halo=2)
    cg = CoupledGas(system, grid, bcs, rho=rho, mu=mu, gravity=gravity,
                    superficial_inlets={"y-": float(inlet_velocity)}, **kw)
    cg.gas.set_velocity(lambda x, y, z: (0.0 * x, float(inlet_velocity) + 0.0 * x, 0.0 * x))
    return cg
