"""Momentum budget of the particles in bins along one axis (the chute's streamwise z).

For the particles whose centres lie in a bin, the time-averaged momentum balance along the
unit vector ``e`` of the axis is

    d<P>/dt = gravity + walls + contacts + drag + pressure + coriolis + centrifugal + flux

with (each a sum over the bin's particles, component along e, force ON the particles):

* ``gravity``      m g
* ``walls``        the analytic walls' and meshes' contact forces, also per wall (``wall_<name>``)
* ``contacts``     particle-particle contact forces; pairs inside the bin cancel, so this is the
                   contact force across the bin's two faces (the contact stress), from the bins
                   up- and downstream
* ``drag``         the gas's drag on the particles
* ``pressure``     the gas's pressure-gradient force (incl. its boundary half-cell part)
* ``coriolis``     -2 m Omega x v;  ``centrifugal``  -m Omega x (Omega x r)
* ``flux``         the momentum the particles carry in and out through the bin faces:
                   K(z_lo) - K(z_hi), K(z) = <sum_i m v_e^2 delta(z - z_i)> the kinetic momentum
                   flux through the plane z, estimated by a top-hat of width ``slab`` centred
                   on the plane: K = sum over |z_i - z| < slab/2 of m v_e^2 / slab
* ``storage``      d<P>/dt, (P at the last sample - P at the first) / (t_last - t_first)

and ``residual = sum of the eight terms - storage``: what does not close (the sampling
error of a finite window, the top-hat flux estimate, a term this list misses).  Forces are
sampled at the measurement times; the time average of sampled forces is an unbiased
estimate of the time-averaged force (the samples of a chaotic flow are what they are: the
error bars come from block averages, :func:`block_error`).

Held particles (a sluice feed moving at its set velocity) are left out: no force acts on them.

The gas's forces are not sampled but integrated exactly: they are constant over each gas step,
and the coupling hands every step's per-particle drag and pressure force to :meth:`add_gas`
(binned by the particles' positions at the coupling step), so that ``drag`` and ``pressure``
are true time averages.  Sampling would not do: every layer a sluice inserts changes the
porosity at once, and the incompressible gas answers with a pressure pulse along the whole
domain for one gas step, much larger than the mean force (and of both signs, as the gas
speeds up and slows down again); samples 10 ms apart catch such pulses at random.
"""

from __future__ import annotations

import numpy as np

from .stats import block_error

TERMS = ("gravity", "walls", "contacts", "drag", "pressure", "coriolis", "centrifugal", "flux")
#: the terms sampled at the measurement times (the gas's are integrated over every gas step)
SAMPLED = ("gravity", "walls", "contacts", "coriolis", "centrifugal", "flux")
#: the particles whose slip against the gas is averaged, by the porosity at their centre
SLIP_CLASSES = ("bed", "surface", "dilute")
SLIP_EDGES = (0.6, 0.9)


class MomentumBudget:
    """Sampled momentum budget of the particles in bins ``edges`` along ``axis`` (module doc).

    ``wall_names``: the names of the walls reported one by one (``wall_<name>``); every wall
    counts in ``walls``.  ``slab``: the width of the top-hat for the kinetic flux (default the
    smallest bin width).  Call :meth:`sample` at each measurement time from ``start_time`` on.
    """

    group = "momentum_budget"

    def __init__(self, edges, axis: int = 2, start_time: float = 0.0, wall_names=(), slab: float | None = None,
                 n_blocks: int = 10):
        self.edges = np.asarray(edges, float)
        if self.edges.ndim != 1 or len(self.edges) < 2 or np.any(np.diff(self.edges) <= 0):
            raise ValueError("budget bin edges must be increasing, at least two")
        self.axis = int(axis)
        self.start_time = float(start_time)
        self.wall_names = tuple(wall_names)
        self.slab = float(slab) if slab is not None else float(np.min(np.diff(self.edges)))
        self.n_blocks = int(n_blocks)
        self._rows: dict[str, list] = {}
        self._times: list[float] = []
        # gas forces: impulse per bin since the last sample, and per-sample-interval means
        self._acc = {"drag": np.zeros(self.n_bins), "pressure": np.zeros(self.n_bins)}
        self._acc_all = np.zeros(2)  # impulse on every free particle, in the bins or not
        self._slip = np.zeros((len(SLIP_CLASSES), 2))  # time integrals of (sum of slips, count) per class
        self._acc_t = 0.0
        self._gas_t = 0.0  # all gas time added (the window's)
        self._gas_rows: dict[str, list] = {"drag": [], "pressure": [], "duration": []}

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
        (eps < 0.6), the surface layer (0.6 <= eps < 0.9) and dilute (eps >= 0.9) (:data:`SLIP_CLASSES`)."""
        if not self.wants_gas(time):
            return
        a = self.axis
        b = self._bins(np.asarray(pos)[:, a], ~np.asarray(held, bool))
        if keff is not None and eps is not None and len(b):
            k = np.asarray(keff, float)
            ok = (k > 0) & (b >= 0)
            slip = np.zeros(len(k))
            slip[ok] = np.asarray(drag)[ok, a] / k[ok]
            cls = np.digitize(np.asarray(eps, float), SLIP_EDGES)
            for j in range(len(SLIP_CLASSES)):
                sel = ok & (cls == j)
                self._slip[j] += dt_gas * np.array([slip[sel].sum(), sel.sum()])
        self._acc["drag"] += dt_gas * self._bin_sum(b, np.asarray(drag)[:, a])
        self._acc["pressure"] += dt_gas * self._bin_sum(b, np.asarray(pressure)[:, a])
        free = ~np.asarray(held, bool)
        self._acc_all += dt_gas * np.array([np.asarray(drag)[free, a].sum(), np.asarray(pressure)[free, a].sum()])
        self._acc_t += dt_gas
        self._gas_t += dt_gas

    def sample(self, time: float, system, gas=None) -> bool:
        """Add one sample of every particle term (module doc) from ``system`` (a ParticleSystem
        after a step), and close the gas forces' interval since the last sample (``gas``: the
        CoupledGas feeding :meth:`add_gas`, or None).  Returns False before ``start_time``."""
        if time < self.start_time:
            return False
        if gas is not None and self._acc_t > 0.0:
            for k in ("drag", "pressure"):
                self._gas_rows[k].append(self._acc[k] / self._acc_t)
                self._acc[k] = np.zeros(self.n_bins)
            self._gas_rows["duration"].append(self._acc_t)
            self._acc_t = 0.0
        a = self.axis
        fb = system.force_breakdown()
        pos, vel, mass = system.pos, system.vel, system.mass
        free = ~fb["held"]
        z = pos[:, a]
        b = self._bins(z, free)
        row = {}
        row["gravity"] = self._bin_sum(b, fb["gravity"][:, a])
        row["centrifugal"] = self._bin_sum(b, fb["centrifugal"][:, a])
        row["coriolis"] = self._bin_sum(b, fb["coriolis"][:, a])
        row["contacts"] = self._bin_sum(b, fb["contacts"][:, a])
        walls = np.zeros(self.n_bins)
        for name, f in list(fb["walls"].items()) + list(fb["meshes"].items()):
            s = self._bin_sum(b, f[:, a])
            walls += s
            if name in self.wall_names:
                row[f"wall_{name}"] = s
        row["walls"] = walls
        if gas is None:  # other external forces (a user's ext_force), sampled
            row["external"] = self._bin_sum(b, fb["external"][:, a])
        # kinetic flux through every bin face: top-hat of width slab centred on the face
        mv2 = mass * vel[:, a] ** 2
        K = np.empty(len(self.edges))
        h = 0.5 * self.slab
        zs = np.sort(z[free])
        csum = np.concatenate([[0.0], np.cumsum(mv2[free][np.argsort(z[free])])])
        lo = np.searchsorted(zs, self.edges - h, side="left")
        hi = np.searchsorted(zs, self.edges + h, side="left")
        K[:] = (csum[hi] - csum[lo]) / self.slab
        row["flux"] = K[:-1] - K[1:]
        row["momentum"] = self._bin_sum(b, mass * vel[:, a])
        row["count"] = np.bincount(b[b >= 0], minlength=self.n_bins).astype(float)
        for k_, v in row.items():
            self._rows.setdefault(k_, []).append(v)
        self._times.append(float(time))
        return True

    def results(self) -> dict:
        """Time averages and block errors per bin: ``z`` (bin centres), ``edges``, each term and
        ``<term>_err``, ``storage``, ``residual`` (and its error), ``wall_<name>``, ``count``
        (particles per bin), ``n_samples``, ``t_first``, ``t_last``.  Forces in N along the axis."""
        out: dict = {"n_samples": np.int64(self.n_samples)}
        if not self.n_samples:
            return out
        e = self.edges
        out["z"] = 0.5 * (e[1:] + e[:-1])
        out["edges"] = e.copy()
        S = {k: np.array(v) for k, v in self._rows.items()}
        t = np.array(self._times)
        span = t[-1] - t[0]
        storage = (S["momentum"][-1] - S["momentum"][0]) / span if span > 0 else np.zeros(self.n_bins)
        for k, v in S.items():
            if k == "momentum":
                continue
            out[k] = v.mean(axis=0)
            if k != "count":
                out[f"{k}_err"] = block_error(v, self.n_blocks)
        dur = np.array(self._gas_rows["duration"])
        for k in ("drag", "pressure"):
            if len(dur):  # exact time averages of the applied gas forces (module doc)
                G = np.array(self._gas_rows[k])
                out[k] = (G * dur[:, None]).sum(axis=0) / dur.sum()
                out[f"{k}_err"] = block_error(G, self.n_blocks)
            else:
                out[k] = np.zeros(self.n_bins)
                out[f"{k}_err"] = np.zeros(self.n_bins)
        sampled = sum(S[k] for k in SAMPLED) + (S["external"] if "external" in S else 0.0)
        out["residual"] = sum(out[k] for k in TERMS) + out.get("external", 0.0) - storage
        err2 = block_error(sampled, self.n_blocks) ** 2 + out["drag_err"] ** 2 + out["pressure_err"] ** 2
        out["residual_err"] = np.sqrt(err2)
        out["storage"] = storage
        # its error: the scatter of the same difference over the blocks of the window
        nb = min(self.n_blocks, len(t) // 2)
        if nb >= 2:
            blocks = np.array_split(np.arange(len(t)), nb)  # the blocks of block_error
            rates = np.array([(S["momentum"][b[-1]] - S["momentum"][b[0]]) / (t[b[-1]] - t[b[0]])
                              for b in blocks if t[b[-1]] > t[b[0]]])
            out["storage_err"] = rates.std(axis=0, ddof=1) / np.sqrt(len(rates)) if len(rates) >= 2 \
                else np.full(self.n_bins, np.nan)
        else:
            out["storage_err"] = np.full(self.n_bins, np.nan)
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
        return {"axis": "xyz"[self.axis], "slab": self.slab, "n_blocks": self.n_blocks,
                "start_time": self.start_time, "terms": ",".join(TERMS),
                "units": "N (force on the particles in the bin, along the axis)"}

    def get_state(self) -> dict:
        nb = self.n_bins
        st = {"times": np.array(self._times), "acc_t": np.float64(self._acc_t),
              "acc/drag": self._acc["drag"].copy(), "acc/pressure": self._acc["pressure"].copy(),
              "gas/duration": np.array(self._gas_rows["duration"], float), "acc_all": self._acc_all.copy(),
              "gas_t": np.float64(self._gas_t), "slip": self._slip.copy()}
        for k in ("drag", "pressure"):
            st[f"gas/{k}"] = np.array(self._gas_rows[k], float).reshape(-1, nb)
        for k, v in self._rows.items():
            st[f"rows/{k}"] = np.array(v).reshape(len(self._times), nb)
        return st

    def set_state(self, st: dict) -> None:
        from .chute import _flatten

        st = _flatten(st)
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
