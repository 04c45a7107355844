"""What the air does at the outlet of a silo with gas (issue #20): forces on the particles near
the slot against their weight, and the air's volume flow through the outlet plane against the
particles'.

Regions: for each radius R of ``radii`` (m), the particles whose centres lie in the half-disc
(x - xc)^2 + y^2 < R^2, y >= 0, over the full depth (xc the slot's centre, y = 0 the outlet
plane; particles below it have left the gas and feel no air).  Per region, along y (up
positive):

* ``drag``, ``pressure``: the air's drag and pressure-gradient force on those particles
  (the pressure force with its boundary half-cell part), integrated exactly over every gas step
  (the coupling hands each step's per-particle forces to :meth:`OutletBudget.add_gas`, as to
  the particles' momentum budget, :mod:`cfddem.measure.budget`), divided by the time;
* ``weight``: the particles' weight m g (positive), sampled at the block ends;
* ``count``: how many particles, sampled likewise.

Air volume flows (m^3/s, up positive, integrated over every gas step from the solver's own face
fluxes eps_f v A, eps_f the face porosity of the porous continuity equation):

* ``q_slot``: through the outlet plane y = 0 (only the slot's faces are open): positive when
  the air is drawn up into the silo through the slot, negative when it leaves with the beads;
* ``q_top``: through the open top (positive: out of the silo);
* ``air_volume``: sum of eps V over the gas cells at each block end.  The porous continuity
  equation makes ``q_slot - q_top`` the rate of change of the air volume, which grows by the
  volume of the particles leaving through the outlet plane.

The scene closes a block at each of its velocity-field sampling times; :meth:`window` averages
the blocks that lie inside a time window (the flow-rate fit's), weighting by duration.
"""

from __future__ import annotations

import math

import numpy as np

#: per-block columns, (n_blocks, n_radii) each
REGION_TERMS = ("drag", "pressure", "weight", "count")
#: per-block columns, (n_blocks,) each
FLOWS = ("q_slot", "q_top", "air_volume")


class OutletBudget:
    """Forces on the particles in half-discs around the slot and the air's volume flows
    (module doc).  ``xc``: the slot's centre (m); ``radii`` (m); ``g`` (m/s^2); ``air``: a
    callable returning (q_slot, q_top, air_volume) of the gas's current state, or None."""

    def __init__(self, xc: float, radii, g: float, air=None):
        self.xc = float(xc)
        self.radii = np.asarray(radii, float).ravel()
        if self.radii.size == 0 or np.any(self.radii <= 0):
            raise ValueError("outlet budget radii must be positive, at least one")
        self.g = float(g)
        self.air = air
        self.start_time = math.inf  # set when the gate opens
        self._t0 = math.nan  # start of the open block
        self._zero()
        self.rows: dict[str, list] = {k: [] for k in ("t_start", "t_end", "duration") + REGION_TERMS + FLOWS}

    def _zero(self):
        nr = len(self.radii)
        self._imp = np.zeros((2, nr))  # drag, pressure impulses
        self._q = np.zeros(2)  # slot, top volumes
        self._t_gas = 0.0
        self._w = np.zeros((2, nr))  # weight, count sums over samples
        self._ns = 0

    def regions(self, pos) -> np.ndarray:
        """(n_radii, n) bool: the particles in each half-disc."""
        pos = np.asarray(pos, float)
        r2 = (pos[:, 0] - self.xc) ** 2 + pos[:, 1] ** 2
        return (r2[None, :] < self.radii[:, None] ** 2) & (pos[:, 1] >= 0.0)[None, :]

    def open(self, t: float) -> None:
        """Start integrating at ``t`` (the gate opening)."""
        self.start_time = float(t)
        self._t0 = float(t)

    # the coupling's force sink (cfddem.coupling.exchange, Coupling.force_sink)
    def wants_gas(self, time: float) -> bool:
        return time >= self.start_time - 1e-12

    def add_gas(self, time: float, dt_gas: float, pos, held, drag, pressure, keff=None, eps=None) -> None:
        """One gas step's per-particle forces ((n, 3) each, applied for ``dt_gas``)."""
        if not self.wants_gas(time):
            return
        m = self.regions(pos) & ~np.asarray(held, bool)[None, :]
        self._imp[0] += dt_gas * (m @ np.asarray(drag, float)[:, 1])
        self._imp[1] += dt_gas * (m @ np.asarray(pressure, float)[:, 1])
        if self.air is not None:
            qs, qt, _ = self.air()
            self._q += dt_gas * np.array([qs, qt])
        self._t_gas += dt_gas

    def sample(self, pos, mass) -> None:
        """The weight and count of the particles in each region now."""
        m = self.regions(pos)
        self._w[0] += m @ (np.asarray(mass, float) * self.g)
        self._w[1] += m.sum(axis=1)
        self._ns += 1

    def close_block(self, t: float) -> None:
        """End the open block at ``t`` (nothing if no gas step and no sample fell in it)."""
        if self._t_gas <= 0.0 and self._ns == 0:
            return
        T = self._t_gas
        nan = np.full(len(self.radii), np.nan)
        row = {"t_start": self._t0, "t_end": float(t), "duration": T,
               "drag": self._imp[0] / T if T > 0 else nan, "pressure": self._imp[1] / T if T > 0 else nan,
               "weight": self._w[0] / self._ns if self._ns else nan, "count": self._w[1] / self._ns if self._ns else nan,
               "q_slot": self._q[0] / T if T > 0 else math.nan, "q_top": self._q[1] / T if T > 0 else math.nan,
               "air_volume": self.air()[2] if self.air is not None else math.nan}
        for k, v in row.items():
            self.rows[k].append(v)
        self._t0 = float(t)
        self._zero()

    def arrays(self) -> dict:
        nr = len(self.radii)
        out = {}
        for k, v in self.rows.items():
            shape = (0, nr) if k in REGION_TERMS else (0,)
            out[k] = np.array(v, float) if v else np.zeros(shape)
        return out

    def window(self, t_lo: float, t_hi: float) -> dict:
        """Duration-weighted means over the blocks inside [t_lo, t_hi] (the region terms
        (n_radii,) and q_slot, q_top), ``air_force_ratio`` = (drag + pressure) / weight,
        ``n_blocks`` and the time covered."""
        a = self.arrays()
        nr = len(self.radii)
        tol = 1e-9 * max(abs(t_hi), 1.0)
        sel = (a["t_start"] >= t_lo - tol) & (a["t_end"] <= t_hi + tol) & (a["duration"] > 0)
        out: dict = {"n_blocks": np.int64(sel.sum()), "duration": float(a["duration"][sel].sum())}
        if not sel.any():
            for k in REGION_TERMS + ("air_force_ratio",):
                out[k] = np.full(nr, np.nan)
            out["q_slot"] = out["q_top"] = math.nan
            return out
        w = a["duration"][sel]
        for k in REGION_TERMS:
            out[k] = (w[:, None] * a[k][sel]).sum(axis=0) / w.sum()
        for k in ("q_slot", "q_top"):
            out[k] = float((w * a[k][sel]).sum() / w.sum())
        with np.errstate(invalid="ignore", divide="ignore"):
            out["air_force_ratio"] = (out["drag"] + out["pressure"]) / out["weight"]
        return out

    # restart
    def get_state(self) -> dict:
        st = {f"rows/{k}": v for k, v in self.arrays().items()}
        st.update(imp=self._imp.copy(), q=self._q.copy(), t_gas=np.float64(self._t_gas), w=self._w.copy(),
                  ns=np.int64(self._ns), start_time=np.float64(self.start_time), t0=np.float64(self._t0))
        return st

    def set_state(self, st: dict) -> None:
        from .chute import _flatten

        st = _flatten(st)
        self._imp = np.asarray(st["imp"], float).copy()
        self._q = np.asarray(st["q"], float).copy()
        self._t_gas = float(st["t_gas"])
        self._w = np.asarray(st["w"], float).copy()
        self._ns = int(st["ns"])
        self.start_time = float(st["start_time"])
        self._t0 = float(st["t0"])
        for k in self.rows:
            v = np.asarray(st[f"rows/{k}"], float)
            self.rows[k] = [r.copy() if v.ndim > 1 else float(r) for r in v]
