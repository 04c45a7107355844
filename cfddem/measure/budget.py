"""Momentum budget of the particles in bins along one axis (the chute's streamwise z).

For the particles whose centres lie in a bin, the momentum balance along the unit vector ``e``
of the axis over the averaging window is

    storage = gravity + walls + contacts + drag + pressure + coriolis + centrifugal + flux

with (each a sum over the bin's particles, component along e, force ON the particles, averaged
over the window):

* ``gravity``      m g
* ``walls``        the analytic walls' and meshes' contact forces, also per wall (``wall_<name>``)
* ``contacts``     particle-particle contact forces; pairs inside the bin cancel, so this is the
                   contact force across the bin's two faces (the contact stress), from the bins
                   up- and downstream
* ``drag``         the gas's drag on the particles
* ``pressure``     the gas's pressure-gradient force (incl. its boundary half-cell part)
* ``coriolis``     -2 m Omega x v;  ``centrifugal``  -m Omega x (Omega x r)
* ``flux``         the momentum the particles carry in and out through the bin faces: every
                   particle that changes bin from one step to the next takes its momentum m v_e
                   out of the old bin and into the new one (a particle that appears in a bin, e.g.
                   released by a feed, brings it in from outside)
* ``storage``      (P at the last sample - P at the first) / (t_last - t_first), P the bin's
                   momentum

and ``residual = sum of the eight terms - storage``: what does not close.

Every term is accumulated at every step (:meth:`MomentumBudget.accumulate`, a
``ParticleSystem.step_hook``): the forces with weight dt at each force evaluation, the flux at
each change of bin.  The velocity-Verlet update m (v_new - v_old) = dt F then makes the budget an
identity up to O(dt F) per bin change and at the window's ends (the force of a step is binned
where the particle is at its end, half a kick of a crossing particle lands in the neighbouring
bin): the residual is of order dt / (time a particle spends in a bin) of the terms, 1e-4 to
1e-3 in a chute, unless a force acts that the list misses (a feeder, a clump's internal
forces, particles removed inside a bin) or a term is wrong.  Between two measurement times the
accumulated terms form one row; the rows' block averages give the error bars (the scatter of
the window's averages, :func:`block_error`), the budget's rows give the mean.

Held particles (a sluice feed moving at its set velocity) are left out: no force acts on them.

The gas's forces are integrated exactly too: they are constant over each gas step, and the
coupling hands every step's per-particle drag and pressure force to :meth:`add_gas` (binned by
the particles' positions at the coupling step), so that ``drag`` and ``pressure`` are true time
averages.  (Sampling would not do: every layer a sluice inserts changes the porosity at once,
and the incompressible gas answers with a pressure pulse along the whole domain for one gas
step, much larger than the mean force.)

Cost: one pass over the particles per step (blocks over the threads) from the window's first measurement time on:
about 13 % of a particle step of the 16 rpm chute at one thread (docs/outputs.md).
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel, parallel_kernel, prange
from .stats import block_error

TERMS = ("gravity", "walls", "contacts", "drag", "pressure", "coriolis", "centrifugal", "flux")
#: the terms accumulated every step by :meth:`MomentumBudget.accumulate` (rows of the kernel's
#: accumulator; the gas's are integrated over every gas step by :meth:`MomentumBudget.add_gas`)
STEPPED = ("gravity", "centrifugal", "coriolis", "contacts", "walls", "external", "flux")
#: the particles whose slip against the gas is averaged, by the porosity at their centre
SLIP_CLASSES = ("bed", "surface", "dilute")
SLIP_EDGES = (0.6, 0.9)


@kernel
def _bin_of(z, edges):
    """The bin of ``z`` among ``edges`` (increasing), -1 outside [edges[0], edges[-1])."""
    nb = edges.shape[0] - 1
    if not (z >= edges[0] and z < edges[nb]):
        return -1
    lo, hi = 0, nb
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if edges[mid] <= z:
            lo = mid
        else:
            hi = mid
    return lo


#: particles per block of :func:`budget_step`: each block sums into its own accumulators in index
#: order and the blocks are added in block order, so the sums do not depend on the thread count
BUDGET_BLOCK = 4096


@kernel
def _budget_range(i0, i1, ids, pos, vel, mass, force, ext, held, wfw, nw, has_mesh, mstart, ms_mesh, ms_fw,
                  gravity, omega, axis_point, a, edges, prev, dt, init, acc, acc_wall, acc_mesh):
    """:func:`budget_step` for the particles [i0, i1) into the accumulators given."""
    for i in range(i0, i1):
        b = -1
        if held[i] != 1:
            b = _bin_of(pos[i, a], edges)
        pid = ids[i]
        pb = prev[pid]
        prev[pid] = b
        if init:
            continue
        m = mass[i]
        if pb != b:
            mv = m * vel[i, a]
            if pb >= 0:
                acc[6, pb] -= mv
            if b >= 0:
                acc[6, b] += mv
        if b < 0:
            continue
        rx = pos[i, 0] - axis_point[0]
        ry = pos[i, 1] - axis_point[1]
        rz = pos[i, 2] - axis_point[2]
        c0 = omega[1] * rz - omega[2] * ry
        c1 = omega[2] * rx - omega[0] * rz
        c2 = omega[0] * ry - omega[1] * rx
        v0, v1, v2 = vel[i, 0], vel[i, 1], vel[i, 2]
        if a == 0:
            oc = omega[1] * c2 - omega[2] * c1
            ov = omega[1] * v2 - omega[2] * v1
        elif a == 1:
            oc = omega[2] * c0 - omega[0] * c2
            ov = omega[2] * v0 - omega[0] * v2
        else:
            oc = omega[0] * c1 - omega[1] * c0
            ov = omega[0] * v1 - omega[1] * v0
        g = m * gravity[a]
        cen = -m * oc
        w = 0.0
        for k in range(nw):
            f = -wfw[i, k, a]
            acc_wall[k, b] += dt * f
            w += f
        if has_mesh and mstart[i + 1] > mstart[i]:
            for sl in range(ms_mesh.shape[1]):
                mk = ms_mesh[i, sl]
                if mk >= 0:
                    f = -ms_fw[i, sl, a]
                    acc_mesh[mk, b] += dt * f
                    w += f
        acc[0, b] += dt * g
        acc[1, b] += dt * cen
        acc[2, b] += dt * (-2.0 * m * ov)
        acc[3, b] += dt * (force[i, a] - g - cen - w)
        acc[4, b] += dt * w
        acc[5, b] += dt * ext[i, a]


@parallel_kernel
def budget_step(n, ids, pos, vel, mass, force, ext, held, wfw, nw, has_mesh, mstart, ms_mesh, ms_fw,
                gravity, omega, axis_point, a, edges, prev, dt, init, acc, acc_wall, acc_mesh, blk, bacc, bwall, bmesh):
    """One step of the budget (module doc): every free particle's forces along axis ``a``
    times ``dt`` added to its bin's rows of ``acc`` (rows in the order of :data:`STEPPED`:
    gravity, centrifugal, coriolis, contacts, walls, external; row 6 the flux), the walls' to
    ``acc_wall`` (wall, bin) and ``acc_mesh`` (mesh, bin); every particle whose bin differs
    from ``prev[id]`` (the bin at the last call, -1 outside or held) moves m v_a from the old
    bin's flux to the new one's.  ``init``: only record the bins.  Forces are those of the
    system's arrays (``force`` without the external and Coriolis forces, ``wfw`` the force on
    each analytic wall, ``ms_fw`` on each mesh slot).

    The particles go in blocks of ``blk`` over the threads, each block into its own slice of
    the work arrays ``bacc``, ``bwall``, ``bmesh`` (at least ceil(n / blk) blocks), which are
    then added in block order: the same sums for any thread count."""
    nblk = (n + blk - 1) // blk
    # (explicit loops: an array expression in a parallel kernel becomes a parallel loop of its
    # own, one thread launch each, which cost more than the whole pass)
    for q in range(nblk):
        _zero(bacc[q])
        _zero(bwall[q])
        _zero(bmesh[q])
    for q in prange(nblk):
        _budget_range(q * blk, min(n, (q + 1) * blk), ids, pos, vel, mass, force, ext, held, wfw, nw, has_mesh,
                      mstart, ms_mesh, ms_fw, gravity, omega, axis_point, a, edges, prev, dt, init, bacc[q],
                      bwall[q], bmesh[q])
    for q in range(nblk):
        _add(acc, bacc[q])
        _add(acc_wall, bwall[q])
        _add(acc_mesh, bmesh[q])


@kernel
def _zero(a):
    for r in range(a.shape[0]):
        for c in range(a.shape[1]):
            a[r, c] = 0.0


@kernel
def _add(a, b):
    for r in range(a.shape[0]):
        for c in range(a.shape[1]):
            a[r, c] += b[r, c]


@kernel
def add_gas_kernel(pos, held, drag, pressure, keff, eps, with_slip, a, edges, slip_edges, sums, tot, slip):
    """One gas step of :meth:`MomentumBudget.add_gas` in one serial pass: the free particles'
    drag and pressure forces along axis ``a`` summed per bin into ``sums`` (2, n_bins) and over
    all free particles into ``tot`` (2,); with ``with_slip``, the slip drag/keff of the binned
    particles with keff > 0 summed with their count per porosity class (``eps`` against
    ``slip_edges``: below the first, between, from the second on) into ``slip`` (3, 2)."""
    for i in range(pos.shape[0]):
        if held[i]:
            continue
        fd = drag[i, a]
        fp = pressure[i, a]
        tot[0] += fd
        tot[1] += fp
        b = _bin_of(pos[i, a], edges)
        if b < 0:
            continue
        sums[0, b] += fd
        sums[1, b] += fp
        if with_slip and keff[i] > 0.0:
            e = eps[i]
            j = 0 if e < slip_edges[0] else (1 if e < slip_edges[1] else 2)
            slip[j, 0] += fd / keff[i]
            slip[j, 1] += 1.0


class MomentumBudget:
    """Momentum budget of the particles in bins ``edges`` along ``axis`` (module doc).

    ``wall_names``: the names of the walls reported one by one (``wall_<name>``); every wall
    counts in ``walls``.  Call :meth:`sample` at each measurement time from ``start_time`` on:
    the first sample attaches :meth:`accumulate` to the system as its ``step_hook`` (or call
    :meth:`attach` first), and every step after it counts.
    """

    group = "momentum_budget"

    def __init__(self, edges, axis: int = 2, start_time: float = 0.0, wall_names=(), n_blocks: int = 10):
        self.edges = np.asarray(edges, float)
        if self.edges.ndim != 1 or len(self.edges) < 2 or np.any(np.diff(self.edges) <= 0):
            raise ValueError("budget bin edges must be increasing, at least two")
        self.axis = int(axis)
        self.start_time = float(start_time)
        self.wall_names = tuple(wall_names)
        self.n_blocks = int(n_blocks)
        self._rows: dict[str, list] = {}
        self._times: list[float] = []
        # every step's terms since the last sample (rows of STEPPED), per wall and per mesh
        self._step_acc = np.zeros((len(STEPPED), self.n_bins))
        self._wall_acc = np.zeros((0, self.n_bins))
        self._mesh_acc = np.zeros((0, self.n_bins))
        self._step_t = 0.0  # time accumulated since the last sample
        self._prev = np.full(0, -1, np.int64)  # the bin of each particle id at the last step (-1: none)
        # per-block work arrays of budget_step (grown as needed)
        self._blk_acc = np.zeros((0, len(STEPPED), self.n_bins))
        self._blk_wall = np.zeros((0, 0, self.n_bins))
        self._blk_mesh = np.zeros((0, 0, self.n_bins))
        # gas forces: impulse per bin since the last sample, and per-sample-interval means
        self._acc = {"drag": np.zeros(self.n_bins), "pressure": np.zeros(self.n_bins)}
        self._acc_all = np.zeros(2)  # impulse on every free particle, in the bins or not
        self._slip = np.zeros((len(SLIP_CLASSES), 2))  # time integrals of (sum of slips, count) per class
        self._acc_t = 0.0
        self._gas_t = 0.0  # all gas time added (the window's)
        self._gas_rows: dict[str, list] = {"drag": [], "pressure": [], "duration": []}

    def attach(self, system) -> "MomentumBudget":
        """Make :meth:`accumulate` the ``step_hook`` of ``system`` (a ParticleSystem)."""
        if system.step_hook is not None and system.step_hook != self.accumulate:
            raise RuntimeError("the particle system already has another step_hook")
        system.step_hook = self.accumulate
        return self

    def _grow(self, system) -> None:
        nid = int(system._next_id)
        if nid > len(self._prev):
            prev = np.full(max(nid, 2 * len(self._prev), 1024), -1, np.int64)
            prev[: len(self._prev)] = self._prev
            self._prev = prev
        if self._wall_acc.shape[0] != system.nw:
            self._wall_acc = np.zeros((system.nw, self.n_bins))
        if self._mesh_acc.shape[0] != system.nm:
            self._mesh_acc = np.zeros((system.nm, self.n_bins))

    def _step(self, system, init: bool) -> None:
        s = system
        self._grow(s)
        nm = s.nm > 0
        nblk = max(1, -(-s.n // BUDGET_BLOCK))
        if self._blk_acc.shape[0] < nblk or self._blk_wall.shape[1] != s.nw or self._blk_mesh.shape[1] != s.nm:
            nb = max(nblk, self._blk_acc.shape[0])
            self._blk_acc = np.zeros((nb, len(STEPPED), self.n_bins))
            self._blk_wall = np.zeros((nb, s.nw, self.n_bins))
            self._blk_mesh = np.zeros((nb, s.nm, self.n_bins))
        budget_step(s.n, s._ids, s._pos, s._vel, s._mass, s._force, s._ext_force, s._held, s._wfw, s.nw, nm,
                    s._mstart, s._ms_mesh, s._ms_fw, s.gravity, s.frame_omega, s.axis_point, self.axis,
                    self.edges, self._prev, s.dt, init, self._step_acc, self._wall_acc, self._mesh_acc,
                    BUDGET_BLOCK, self._blk_acc, self._blk_wall, self._blk_mesh)

    def accumulate(self, system) -> None:
        """One step's terms (the system's ``step_hook``; module doc); nothing before the first
        sample."""
        if not self._times:
            return
        self._step(system, False)
        self._step_t += system.dt

    @property
    def n_bins(self) -> int:
        return len(self.edges) - 1

    @property
    def n_samples(self) -> int:
        return len(self._times)

    def _bin_sum(self, b, values):
        """Sum of values (n,) per bin (b: bin index per particle, -1 outside)."""
        ok = b >= 0
        return np.bincount(b[ok], weights=values[ok], minlength=self.n_bins)

    def _bins(self, z, free):
        b = np.searchsorted(self.edges, z, side="right") - 1
        b[(b >= self.n_bins) | (z >= self.edges[-1]) | ~free] = -1
        return b

    def wants_gas(self, time: float) -> bool:
        """Whether the gas step starting at ``time`` lies in the averaging window."""
        return time >= self.start_time - 1e-12

    def add_gas(self, time: float, dt_gas: float, pos, held, drag, pressure, keff=None, eps=None) -> None:
        """One gas step's forces on the particles ((n, 3) each, applied from ``time`` for
        ``dt_gas``; ``held`` (n,) bool: not applied), binned by ``pos`` (module doc).  With the
        drag coefficients ``keff`` (n,) (drag = keff (u - v)) and the porosities ``eps`` (n,) at
        the particles, also the mean slip u - v along the axis of the particles in the bed
        (eps < 0.6), the surface layer (0.6 <= eps < 0.9) and dilute (eps >= 0.9) (:data:`SLIP_CLASSES`).
        One compiled serial pass (:func:`add_gas_kernel`)."""
        if not self.wants_gas(time):
            return
        pos = np.asarray(pos, float)
        n = pos.shape[0]
        with_slip = keff is not None and eps is not None and n > 0
        k = np.ascontiguousarray(keff, float) if with_slip else np.zeros(0)
        e = np.ascontiguousarray(eps, float) if with_slip else np.zeros(0)
        sums = np.zeros((2, self.n_bins))
        tot = np.zeros(2)
        slip = np.zeros((len(SLIP_CLASSES), 2))
        add_gas_kernel(pos, np.ascontiguousarray(held, np.bool_), np.asarray(drag, float), np.asarray(pressure, float),
                       k, e, with_slip, self.axis, self.edges, np.asarray(SLIP_EDGES, float), sums, tot, slip)
        self._acc["drag"] += dt_gas * sums[0]
        self._acc["pressure"] += dt_gas * sums[1]
        self._slip += dt_gas * slip
        self._acc_all += dt_gas * tot
        self._acc_t += dt_gas
        self._gas_t += dt_gas

    def sample(self, time: float, system, gas=None) -> bool:
        """Close the interval since the last sample: every step's terms (module doc) and the
        gas forces (``gas``: the CoupledGas feeding :meth:`add_gas`, or None: then the
        system's external forces form the row ``external``) averaged over it become one row;
        the bins' momenta at ``time`` are recorded.  The first sample starts the accounting
        (and attaches to ``system``).  Returns False before ``start_time``."""
        if time < self.start_time:
            return False
        first = not self._times
        if first:
            if system.step_hook is None:
                self.attach(system)
            self._step(system, True)
            self._acc = {"drag": np.zeros(self.n_bins), "pressure": np.zeros(self.n_bins)}
            self._acc_t = self._gas_t = 0.0
            self._acc_all[:] = 0.0
            self._slip[:] = 0.0
        else:
            if not self._step_t > 0.0:
                raise RuntimeError("MomentumBudget.sample: no step was accumulated since the last sample "
                                   "(attach the budget to the particle system: MomentumBudget.attach)")
            if gas is not None and self._acc_t > 0.0:
                for k in ("drag", "pressure"):
                    self._gas_rows[k].append(self._acc[k] / self._acc_t)
                    self._acc[k] = np.zeros(self.n_bins)
                self._gas_rows["duration"].append(self._acc_t)
                self._acc_t = 0.0
            T = self._step_t
            row = {k: self._step_acc[j] / T for j, k in enumerate(STEPPED) if k != "external" or gas is None}
            for names, acc in ((system.wall_labels(), self._wall_acc), (system.mesh_labels(), self._mesh_acc)):
                for k, name in enumerate(names):
                    if name in self.wall_names:
                        row[f"wall_{name}"] = acc[k] / T
            row["duration"] = np.full(self.n_bins, T)
            for k_, v in row.items():
                self._rows.setdefault(k_, []).append(v)
            self._step_acc[:] = 0.0
            self._wall_acc[:] = 0.0
            self._mesh_acc[:] = 0.0
            self._step_t = 0.0
        a = self.axis
        free = ~system.held
        b = self._bins(system.pos[:, a], free)
        self._rows.setdefault("momentum", []).append(self._bin_sum(b, system.mass * system.vel[:, a]))
        self._rows.setdefault("count", []).append(np.bincount(b[b >= 0], minlength=self.n_bins).astype(float))
        self._times.append(float(time))
        return True

    def results(self) -> dict:
        """Time averages and block errors per bin: ``z`` (bin centres), ``edges``, each term and
        ``<term>_err``, ``storage``, ``residual`` (and their errors), ``wall_<name>``, ``count``
        (particles per bin, mean over the samples), ``n_samples``, ``t_first``, ``t_last``,
        ``residual_relative`` (|sum of the residuals| / |sum of gravity|).  Forces in N along
        the axis."""
        out: dict = {"n_samples": np.int64(self.n_samples)}
        if self.n_samples < 2:
            return out
        e = self.edges
        out["z"] = 0.5 * (e[1:] + e[:-1])
        out["edges"] = e.copy()
        S = {k: np.array(v) for k, v in self._rows.items()}
        t = np.array(self._times)
        dur = S.pop("duration")[:, 0]
        P = S.pop("momentum")
        out["count"] = S.pop("count").mean(axis=0)
        rates = np.diff(P, axis=0) / dur[:, None]  # storage per interval
        resid_rows = -rates
        for k, v in S.items():  # the stepped terms and walls, one row per interval
            out[k] = (v * dur[:, None]).sum(axis=0) / dur.sum()
            out[f"{k}_err"] = block_error(v, self.n_blocks)
            if k in STEPPED:
                resid_rows = resid_rows + v
        gdur = np.array(self._gas_rows["duration"])
        aligned = len(gdur) == len(dur)
        for k in ("drag", "pressure"):
            if len(gdur):  # exact time averages of the applied gas forces (module doc)
                G = np.array(self._gas_rows[k])
                out[k] = (G * gdur[:, None]).sum(axis=0) / gdur.sum()
                out[f"{k}_err"] = block_error(G, self.n_blocks)
                if aligned:
                    resid_rows = resid_rows + G
            else:
                out[k] = np.zeros(self.n_bins)
                out[f"{k}_err"] = np.zeros(self.n_bins)
        out["storage"] = (P[-1] - P[0]) / (t[-1] - t[0])
        out["storage_err"] = block_error(rates, self.n_blocks)
        out["residual"] = sum(out[k] for k in TERMS) + out.get("external", 0.0) - out["storage"]
        out["residual_err"] = block_error(resid_rows, self.n_blocks) if (aligned or not len(gdur)) else \
            np.sqrt(sum(out[f"{k}_err"] ** 2 for k in TERMS) + out["storage_err"] ** 2)
        grav = float(np.sum(out["gravity"]))
        out["residual_relative"] = np.float64(abs(float(np.sum(out["residual"]))) / abs(grav) if grav else np.nan)
        out["t_first"] = np.float64(t[0])
        out["t_last"] = np.float64(t[-1])
        out["gas_time"] = np.float64(self._gas_t)
        # the gas's forces on all particles (not only those in the bins), time-averaged
        out["drag_all"] = np.float64(self._acc_all[0] / self._gas_t if self._gas_t else 0.0)
        out["pressure_all"] = np.float64(self._acc_all[1] / self._gas_t if self._gas_t else 0.0)
        for j, name in enumerate(SLIP_CLASSES):  # count-weighted time averages of the slip u - v
            s_, c_ = self._slip[j]
            out[f"slip_{name}"] = np.float64(s_ / c_ if c_ > 0 else np.nan)
            out[f"slip_{name}_count"] = np.float64(c_ / self._gas_t if self._gas_t else 0.0)
        return out

    def attrs(self) -> dict:
        return {"axis": "xyz"[self.axis], "n_blocks": self.n_blocks, "start_time": self.start_time,
                "terms": ",".join(TERMS), "flux": "exact: m v of every particle changing bin, every step",
                "units": "N (force on the particles in the bin, along the axis)"}

    def get_state(self) -> dict:
        nb = self.n_bins
        st = {"times": np.array(self._times), "acc_t": np.float64(self._acc_t),
              "acc/drag": self._acc["drag"].copy(), "acc/pressure": self._acc["pressure"].copy(),
              "gas/duration": np.array(self._gas_rows["duration"], float), "acc_all": self._acc_all.copy(),
              "gas_t": np.float64(self._gas_t), "slip": self._slip.copy()}
        for k in ("drag", "pressure"):
            st[f"gas/{k}"] = np.array(self._gas_rows[k], float).reshape(-1, nb)
        for k, v in self._rows.items():  # momentum and count: one row per sample; the rest per interval
            st[f"rows/{k}"] = np.array(v, float).reshape(-1, nb)
        st.update({"step/acc": self._step_acc.copy(), "step/wall": self._wall_acc.copy(),
                   "step/mesh": self._mesh_acc.copy(), "step/t": np.float64(self._step_t),
                   "step/prev": self._prev.copy()})
        return st

    def set_state(self, st: dict) -> None:
        from .chute import _flatten

        st = _flatten(st)
        if len(np.atleast_1d(st.get("times", []))) and "step/t" not in st:
            # a checkpoint of the sampled budget of earlier versions: its rows cannot be continued
            # by the stepped one; the window starts afresh at the next measurement time
            st = {}
        self._times = [float(x) for x in np.asarray(st.get("times", []), float)]
        self._rows = {k[5:]: [np.asarray(r, float) for r in np.asarray(v, float)]
                      for k, v in st.items() if k.startswith("rows/")}
        self._acc_t = float(st.get("acc_t", 0.0))
        self._acc_all = np.asarray(st.get("acc_all", np.zeros(2)), float).copy()
        self._gas_t = float(st.get("gas_t", 0.0))
        self._slip = np.asarray(st.get("slip", np.zeros((len(SLIP_CLASSES), 2))), float).reshape(-1, 2).copy()
        for k in ("drag", "pressure"):
            self._acc[k] = np.asarray(st.get(f"acc/{k}", np.zeros(self.n_bins)), float).copy()
            self._gas_rows[k] = [np.asarray(r, float) for r in np.asarray(st.get(f"gas/{k}", []), float)]
        self._gas_rows["duration"] = [float(x) for x in np.asarray(st.get("gas/duration", []), float)]
        nb = self.n_bins
        self._step_acc = np.asarray(st.get("step/acc", np.zeros((len(STEPPED), nb))), float).reshape(-1, nb).copy()
        self._wall_acc = np.asarray(st.get("step/wall", np.zeros((0, nb))), float).reshape(-1, nb).copy()
        self._mesh_acc = np.asarray(st.get("step/mesh", np.zeros((0, nb))), float).reshape(-1, nb).copy()
        self._step_t = float(st.get("step/t", 0.0))
        self._prev = np.asarray(st.get("step/prev", np.full(0, -1)), np.int64).copy()
