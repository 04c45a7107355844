"""The flat-bottom silo blender (``geometry.type = "silo_blender"``; case sections ``[silo]`` and
``[blender]``): the planar silo of :mod:`cfddem.scenes.silo` recirculating its contents through a
vertical channel below the outlet (the blending thesis, chapter 6; ``/work/shared/blending.md``
§2; docs/blending.md, "The flat-bottom silo blender").

Geometry (axes as the silo: x across, y up, z depth; outlet plane y = 0):

- the silo's walls, fill (lattice or pour), settling and gate logic unchanged (``[silo]`` keys);
- a **channel** below the slot: the slot's lip walls continued down to y = -L
  (L = ``blender.channel_length``), so the channel is the slot's width by the full depth; the
  gate closes its bottom during the fill (the channel fills with the silo);
- a **feeder zone** in the channel (``blender.feeder_range``, default its lower half): from the
  gate opening on, every body whose centre (a clump: its centre of mass) lies in it has its
  vertical velocity set to -V_out (``blender.outflow_velocity``) at the end of every step
  (:meth:`cfddem.particles.system.ParticleSystem.add_velocity_zone`);
- **recirculation**: the vertical axis is periodic from y = -L (the channel bottom) to the top
  y_t: a body leaving the channel bottom re-enters at y_t at the same x and z and falls onto
  the heap.  Nothing is removed: the particle count and mass are conserved exactly.  y_t is
  ``silo.height`` when set, else the top of the fill (lattice top, or the pour layers' top)
  plus ``blender.free_height``; a case that leaves less than ``free_height`` empty above the
  fill is refused.

Fill colouring (``blender.input = "batch"``), at the gate opening (the fill has settled): the
bodies above the outlet plane (the silo contents) are ordered by height; their cumulative mass
divided by the contents' mass M is a coordinate q in [0, 1]; with n = ``blender.sublayers`` and
f = ``blender.batch_fraction`` the k-th tracer sub-layer is q in [(k + 1/2)/n - f/(2n),
(k + 1/2)/n + f/(2n)), k = 0..n-1 (equal-mass strata, each with its tracer layer of mass f M/n
in its middle: "evenly spread" by mass, which at uniform bulk density is evenly by height).  A
body is tracer (label 1) when the midpoint of its own mass interval lies in a sub-layer, else
bulk (label 0); the labelled fraction is f within n body masses.  Bodies in the channel are bulk.

Continuous mode (``input = "step"`` or ``"sinusoid"``): the fill is all bulk; every body that
re-enters at the top is relabelled tracer with probability c_in(t) (t since the gate opening;
step: 0 before ``input_step_time``, 1 after; sinusoid: mean + amplitude sin(2 pi t / period)),
drawn from a generator seeded with (particles.seed, sample index): reproducible and identical
after a restart.

Outflow records, every ``blender.sample_interval`` from the gate opening: each body's height
(clumps: centre of mass) is compared with its height at the previous sample (matched by particle
or body id).  A body that went from y >= 0 to y < 0 crossed the outlet plane downwards (+1); one
that went from y < 0 to y >= 0 without wrapping, upwards (-1); one whose height jumped up by more
than half the periodic length wrapped round (re-entered at the top).  Per interval: the net mass
and count crossing per label (0, 1), the tracer mass fraction of that outflow (NaN when nothing
crossed), the re-entering stream's tracer mass fraction, c_in, and the mean downward velocity of
the bodies in the channel between the feeder's top and the outlet plane, and the mass per unit
height of the bodies in the feeder zone (the stream's velocity by continuity is the mass flow
rate over its mean: ``outflow_velocity``).  The crossing mass and
the member spheres also feed the run counters ``mass_out`` / ``count_out`` (here: what passed the
outlet, nothing removed), so the silo's flow-rate fit, discharge records and clog detection work
unchanged.  The bulk density of the silo contents (the silo's box below the free surface) every
``blender.density_interval``.

Derived: mean residence time t_mean = M / (steady mass flow rate) with M the mass above the
outlet plane at the gate opening and the rate the silo's fit (:func:`cfddem.measure.silo.fit_mass_flow`
over ``silo.fit_range`` of the cumulative outflow); at constant bulk density it equals the silo
volume over the volumetric flow rate.  N_r = (t - t_gate) / t_mean.

Stored in results.h5 under ``/measurements/blending`` (time, concentration_out, mass_by_label,
count_by_label, concentration_in, concentration_reentry, channel_velocity, n_recirculations,
t_mean, density_time, bulk_density, the fill colouring) beside the silo's ``/measurements/silo``.

The thesis's lower filling friction (mu_pp 0.15 during the fill, the calibrated values from the
gate opening) is the silo's ``fill_friction`` key.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import CaseError
from ..schema import Key
from ..schema import positive as _pos
from .silo import SILO_KEYS, SiloGeometry, SiloScene, check_silo_case, silo_walls

LABELS = (0, 1)  # bulk, tracer

BLENDER_KEYS = {
    "channel_length": _pos(0.08, "m", "length L of the vertical channel below the slot (the slot's lips continued "
                           "down to y = -L; the gate closes its bottom during the fill; the periodic vertical axis "
                           "starts there)"),
    "feeder_range": Key("floats", [0.0, 0.0], "m", "feeder zone: [y_lo, y_hi] in the channel (-L <= y_lo < y_hi "
                        "<= 0) where the bodies' vertical velocity is set to -outflow_velocity every step from the "
                        "gate opening ([0, 0]: the lower half, [-L, -L/2])", length=2),
    "outflow_velocity": _pos(0.4, "m/s", "V_out: the downward velocity the feeder holds"),
    "free_height": _pos(0.03, "m", "empty height required between the top of the fill (lattice top, or the top of "
                        "the pour layers) and the top of the periodic domain, where recirculated bodies re-enter "
                        "(the top is silo.height, or the fill top + free_height when silo.height = 0)"),
    "input": Key("str", "batch", "-", "'batch': the settled fill is coloured in layers (batch_fraction, "
                 "sublayers) and recirculated; 'step' / 'sinusoid': continuous mode, the fill is bulk and the "
                 "re-entering bodies become tracer with probability c_in(t)", choices=("batch", "step", "sinusoid")),
    "batch_fraction": Key("float", 0.25, "-", "batch: tracer mass fraction of the silo contents (above the outlet "
                          "plane at the gate opening)", lo=0.0, hi=1.0, lo_open=True, hi_open=True),
    "sublayers": Key("int", 1, "-", "batch: number of tracer sub-layers, centred in equal-mass strata of the fill",
                     lo=1),
    "input_step_time": Key("float", 0.5, "s", "step: c_in = 0 before, 1 from this time after the gate opening",
                           lo=0.0),
    "input_mean": Key("float", 0.5, "-", "sinusoid: mean of c_in", lo=0.0, hi=1.0),
    "input_amplitude": Key("float", 0.5, "-", "sinusoid: amplitude of c_in (mean +- amplitude within [0, 1])",
                           lo=0.0, hi=0.5),
    "input_period": _pos(1.0, "s", "sinusoid: period of c_in"),
    "sample_interval": _pos(0.005, "s", "interval of the outflow records (mass and count per label crossing the "
                            "outlet plane)"),
    "density_interval": _pos(0.1, "s", "interval of the bulk-density record of the silo contents"),
}


class BlenderGeometry:
    """The blender's derived dimensions from a resolved case dict ``r``: channel length L, feeder
    range (y_lo, y_hi), fill top, domain top y_t, the periodic vertical range (-L, y_t), and
    ``silo``: the ``[silo]`` values the silo walls and geometry are built from (lip = L, the
    side walls up to y_t)."""

    def __init__(self, r: dict):
        s, b, p = r["silo"], r["blender"], r["particles"]
        d = p["diameter"]
        args = (d, p["seed"], p["clump"], p["density"], p["clump_spheres"])
        base = SiloGeometry(s, *args)
        self.L = float(b["channel_length"])
        self.fill_top = base.pour_y + 0.5 * base.d_site if base.pour else base.lattice_top
        self.free_height = float(b["free_height"])
        self.top = float(s["height"] or (self.fill_top + self.free_height))
        lo, hi = (float(v) for v in b["feeder_range"])
        self.feeder = (-self.L, -0.5 * self.L) if lo == 0.0 and hi == 0.0 else (lo, hi)
        self.silo = dict(s, lip=self.L, removal_depth=self.L + 0.5 * d, height=self.top)
        self.g = SiloGeometry(self.silo, *args)
        self.d_site = base.d_site

    @property
    def periodic(self) -> tuple:
        return (None, (-self.L, self.top), None)


def check_blender_case(r: dict) -> None:
    """Consistency of a blender case (:meth:`BlenderScene.check`), after the silo's checks."""
    s, b = r["silo"], r["blender"]
    for k, why in (("lip", "the blender's channel (blender.channel_length) continues the slot's lips"),
                   ("removal_depth", "nothing is removed: bodies recirculate")):
        if s[k]:
            raise CaseError(f"silo.{k}", f"leave it 0 in a blender: {why}")
    if s["walls"] != "analytic":
        raise CaseError("silo.walls", "the blender builds its own container and channel ('analytic')")
    if s["depth_boundary"] != "walls":
        raise CaseError("silo.depth_boundary", "the blender is periodic in y (recirculation) and keeps its front and "
                                               "back walls ('walls')")
    geo = BlenderGeometry(r)
    L, ds = geo.L, geo.d_site
    if L < 2 * ds:
        raise CaseError("blender.channel_length", f"{L:g} m is shorter than two particles (2 x {ds:.4g} m)")
    lo, hi = geo.feeder
    if not (-L <= lo < hi <= 0.0):
        raise CaseError("blender.feeder_range", f"[{lo:g}, {hi:g}] m is not a range inside the channel (y from "
                                                f"{-L:g} to 0 m, y_lo < y_hi)")
    if geo.free_height < 2 * ds:
        raise CaseError("blender.free_height", f"{geo.free_height:g} m leaves no room for re-entering bodies: at "
                                               f"least two particles ({2 * ds:.4g} m)")
    if s["height"] and s["height"] - geo.fill_top < geo.free_height:
        raise CaseError("silo.height", f"{s['height']:g} m leaves {s['height'] - geo.fill_top:.4g} m above the top "
                                       f"of the fill ({geo.fill_top:.4g} m): recirculation needs blender.free_height "
                                       f"= {geo.free_height:g} m empty (raise it or set 0: automatic)")
    if b["input"] == "sinusoid" and not (0.0 <= b["input_mean"] - b["input_amplitude"]
                                         and b["input_mean"] + b["input_amplitude"] <= 1.0):
        raise CaseError("blender.input_amplitude", f"c_in = {b['input_mean']:g} +- {b['input_amplitude']:g} leaves "
                                                   "[0, 1]")


def colour_layers(y, mass, fraction: float, sublayers: int) -> np.ndarray:
    """The batch fill colouring (module doc): bool per body, True for tracer, from the bodies'
    heights ``y`` and masses (ties in height broken by order)."""
    y = np.asarray(y, float)
    m = np.asarray(mass, float)
    order = np.argsort(y, kind="stable")
    cum = np.cumsum(m[order])
    q = (cum - 0.5 * m[order]) / cum[-1] if len(cum) else cum
    n = int(sublayers)
    k = np.clip(np.floor(q * n), 0, n - 1)  # the stratum of each body
    tracer_sorted = np.abs(q - (k + 0.5) / n) < 0.5 * fraction / n
    out = np.zeros(len(y), bool)
    out[order] = tracer_sorted
    return out


def input_concentration(b: dict, t: float) -> float:
    """c_in at ``t`` after the gate opening (NaN in batch mode)."""
    if b["input"] == "step":
        return 1.0 if t >= b["input_step_time"] else 0.0
    if b["input"] == "sinusoid":
        return b["input_mean"] + b["input_amplitude"] * math.sin(2.0 * math.pi * t / b["input_period"])
    return math.nan


class BlenderScene(SiloScene):
    """The silo scene with the channel, feeder, periodic recirculation, fill colouring and outflow
    records of the blender (module doc)."""

    DOC = "'silo_blender': the planar silo of [silo] recirculating through the channel and feeder of [blender]"
    EXAMPLE = "blender_small"
    SCHEMA = {"silo": SILO_KEYS, "blender": BLENDER_KEYS}
    HAS_GAS = False

    # ------------------------------------------------------------------ from the case alone
    @classmethod
    def check(cls, r: dict, case_dir) -> None:
        check_silo_case(r)
        check_blender_case(r)

    @classmethod
    def wall_specs(cls, case) -> list:
        return silo_walls(case, silo=BlenderGeometry(case.resolved).silo)

    @classmethod
    def periodic(cls, case) -> tuple:
        return BlenderGeometry(case.resolved).periodic

    @classmethod
    def speed_scale(cls, case) -> float:
        """A body falling freely from the top of the domain to the channel bottom."""
        geo = BlenderGeometry(case.resolved)
        return math.sqrt(2.0 * case.gravity.g * (geo.top + geo.L))

    @classmethod
    def gas_domain(cls, case):
        return None

    @classmethod
    def describe(cls, case) -> list[str]:
        geo = BlenderGeometry(case.resolved)
        b = case.resolved["blender"]
        n = case.silo.n_particles
        what = "bodies (clumps)" if case.particles.clump != "none" else "spheres"
        return [f"blender: {n} {what}; channel {geo.g.b * 1e3:.4g} x {geo.g.L * 1e3:.4g} mm, {geo.L * 1e3:.4g} mm "
                f"long; feeder y {geo.feeder[0] * 1e3:.4g}..{geo.feeder[1] * 1e3:.4g} mm at V_out = "
                f"{b['outflow_velocity']:g} m/s; periodic y {-geo.L:.4g}..{geo.top:.4g} m (fill top "
                f"{geo.fill_top:.4g} m, {geo.top - geo.fill_top:.4g} m free above it); input '{b['input']}'"
                + (f", batch {b['batch_fraction']:g} in {b['sublayers']} sub-layer(s)" if b["input"] == "batch"
                   else "")]

    @classmethod
    def plots(cls, results_h5, out_dir) -> list:
        """The silo's plots and the outflow concentration against N_r."""
        from ..io.results import read_measurements

        out = super().plots(results_h5, out_dir)
        name = "blender_concentration.png"
        m = read_measurements(results_h5).get("blending")
        if m is None or not len(np.asarray(m["time"])):
            return out + [(name, None, "no outflow record (the gate never opened)")]
        return out + [(name, plot_concentration(m, out_dir), "")]

    # ------------------------------------------------------------------ during a run
    def __init__(self, sim):
        super().__init__(sim)
        from ..measure.silo import VelocityField

        self.geo = BlenderGeometry(self.case.resolved)
        self.b = self.case.resolved["blender"]
        self.s = self.geo.silo
        self.g = self.geo.g
        self.field = VelocityField(0.0, self.g.W, -self.geo.L, self.geo.top, self.s["field_cell"] or 2 * self.g.d)
        self.k_sample = 0
        self.prev_key = np.zeros(0, np.int64)
        self.prev_y = np.zeros(0)
        self.rec: dict[str, list] = {k: [] for k in ("time", "mass", "count", "c_in", "c_re", "v_ch", "lam")}
        self.dens_t: list[float] = []
        self.dens: list[float] = []
        self.colour = {"content_mass": math.nan, "inventory_mass": math.nan, "tracer_mass": 0.0,
                       "inventory_tracer_mass": 0.0, "content_bodies": 0, "layer_bottom": np.zeros(0),
                       "layer_top": np.zeros(0)}

    def _units(self) -> dict:
        """Every body (free sphere or clump) sorted by key (sphere id, or -1 - clump body id): its
        x, height, vertical velocity (clumps: of the centre of mass), mass, label, spheres."""
        sys_ = self.sim.system
        free = np.flatnonzero(sys_.body < 0)
        pos, vel = sys_.pos, sys_.vel
        parts = [(sys_.ids[free], pos[free, 0], pos[free, 1], vel[free, 1], sys_.mass[free], sys_.label[free],
                  np.ones(len(free), np.int64))]
        c = sys_.clumps
        if c is not None and c.nb:
            first = c.members[c.start[:-1]]
            parts.append((-1 - c.bid, c.com[:, 0], c.com[:, 1], c.vel[:, 1], c.mass, sys_.label[first],
                          np.diff(c.start)))
        cols = [np.concatenate(a) for a in zip(*parts)]
        order = np.argsort(cols[0], kind="stable")
        return dict(zip(("key", "x", "y", "vy", "m", "label", "spheres"), (a[order] for a in cols)))

    def _relabel(self, keys, value: int) -> None:
        """Give the bodies with these keys the label ``value``."""
        sys_ = self.sim.system
        if not len(keys):
            return
        mask = np.isin(sys_.ids, keys) & (sys_.body < 0)
        c = sys_.clumps
        if c is not None and c.nb:
            hit = np.isin(-1 - c.bid, keys)
            mask |= (sys_.body >= 0) & hit[np.maximum(sys_.body, 0)]
        sys_.set_label(mask, int(value))

    def _feeder(self) -> None:
        g, (lo, hi) = self.g, self.geo.feeder
        e = g.d_site
        self.sim.system.add_velocity_zone((g.xc - 0.5 * g.b - e, lo, -e), (g.xc + 0.5 * g.b + e, hi, g.L + e), 1,
                                          -self.b["outflow_velocity"])

    def _open_gate(self, t: float, ke: float) -> None:
        super()._open_gate(t, ke)
        u = self._units()
        above = u["y"] >= 0.0
        M = float(u["m"][above].sum())
        self.colour.update(content_mass=M, inventory_mass=float(u["m"].sum()), content_bodies=int(above.sum()))
        if self.b["input"] == "batch" and above.any():
            f, n = self.b["batch_fraction"], self.b["sublayers"]
            tr = colour_layers(u["y"][above], u["m"][above], f, n)
            self._relabel(u["key"][above][tr], 1)
            ys = np.sort(u["y"][above])
            cum = np.cumsum(u["m"][above][np.argsort(u["y"][above], kind="stable")]) / M
            qs = (np.arange(n) + 0.5) / n
            self.colour.update(tracer_mass=float(u["m"][above][tr].sum()),
                               inventory_tracer_mass=float(u["m"][above][tr].sum()),
                               layer_bottom=np.interp(qs - 0.5 * f / n, cum, ys),
                               layer_top=np.interp(qs + 0.5 * f / n, cum, ys))
            self.sim.log.info("blender: %d of %d bodies above the outlet labelled tracer (%.4g of the contents' mass "
                              "%.4g kg; requested %g in %d sub-layer(s))", int(tr.sum()), int(above.sum()),
                              self.colour["tracer_mass"] / M, M, f, n)
        self._feeder()
        room = self.geo.top - self.fill["fill_height"]
        if room < self.geo.free_height:
            self.sim.log.warning("blender: only %.4g m between the settled fill (%.4g m) and the top of the domain",
                                 room, self.fill["fill_height"])
        u = self._units()
        self.prev_key, self.prev_y = u["key"], u["y"]
        self.k_sample = 1
        self._density(t)

    def _next_sample(self) -> float:
        return self.gate_open_time + self.k_sample * self.b["sample_interval"]

    def next_time(self, t: float) -> float:
        nt = super().next_time(t)
        return min(nt, self._next_sample()) if self.gate_open else nt

    def exit_plane(self):
        return None  # nothing leaves: the bodies recirculate through the periodic channel

    def after_steps(self) -> None:
        t = self.sim.system.time
        if self.gate_open and t >= self._next_sample() - 0.5 * self.sim.dt:
            self._sample(t)
            while self._next_sample() <= t + 0.5 * self.sim.dt:
                self.k_sample += 1
        super().after_steps()

    def _sample(self, t: float) -> None:
        u = self._units()
        j = np.clip(np.searchsorted(self.prev_key, u["key"]), 0, max(len(self.prev_key) - 1, 0))
        known = (self.prev_key[j] == u["key"]) if len(self.prev_key) else np.zeros(len(u["key"]), bool)
        y0 = np.where(known, self.prev_y[j] if len(self.prev_y) else 0.0, u["y"])
        y1 = u["y"]
        half = 0.5 * (self.geo.top + self.geo.L)
        wrap_up = known & (y1 - y0 > half)
        wrap = wrap_up | (known & (y0 - y1 > half))
        sign = (known & ~wrap & (y0 >= 0.0) & (y1 < 0.0)).astype(float) - (known & ~wrap & (y0 < 0.0) & (y1 >= 0.0))
        mass = np.array([float(np.sum(sign * u["m"] * (u["label"] == k))) for k in LABELS])
        count = np.array([int(np.sum(sign * (u["label"] == k))) for k in LABELS], np.int64)
        c = self.sim.counters
        c["mass_out"] += float(np.sum(sign * u["m"]))
        c["count_out"] += int(np.sum(sign * u["spheres"]))
        self.bodies_out += int(np.sum(sign))
        if np.any(sign > 0):
            self.last_out_time = t
        re = wrap_up
        c_in = input_concentration(self.b, t - self.gate_open_time)
        tracer = u["label"][re] == 1
        if self.b["input"] != "batch" and re.any():
            rng = np.random.default_rng([int(self.case.particles.seed), 0xB1E, self.k_sample])
            tracer = rng.random(int(re.sum())) < c_in
            self._relabel(u["key"][re][tracer], 1)
            self._relabel(u["key"][re][~tracer], 0)
        m_re = float(u["m"][re].sum())
        c_re = float(u["m"][re][tracer].sum()) / m_re if m_re > 0 else math.nan
        g = self.g
        ch = (y1 < 0.0) & (y1 >= self.geo.feeder[1]) & (np.abs(u["x"] - g.xc) < 0.5 * g.b)
        r = self.rec
        r["time"].append(t)
        r["mass"].append(mass)
        r["count"].append(count)
        r["c_in"].append(c_in)
        r["c_re"].append(c_re)
        r["v_ch"].append(float(-np.mean(u["vy"][ch])) if ch.any() else math.nan)
        lo, hi = self.geo.feeder
        zone = (y1 >= lo) & (y1 < hi) & (np.abs(u["x"] - g.xc) < 0.5 * g.b + g.d_site)
        r["lam"].append(float(u["m"][zone].sum()) / (hi - lo))
        self.prev_key, self.prev_y = u["key"], y1
        k_d = max(1, int(round(self.b["density_interval"] / self.b["sample_interval"])))
        if self.k_sample % k_d == 0:
            self._density(t)

    def _density(self, t: float) -> None:
        """Bulk density of the silo contents in columns 2 d wide, each from 3 d above the bottom
        to 3 d below its own highest centre, 3 d from the side walls
        (:func:`cfddem.measure.silo.column_bulk_density`: a crater over the slot is left out, not
        counted as empty volume); the spheres at most 3 d above the fill height at the gate
        opening (not the falling re-entering stream)."""
        from ..measure.silo import column_bulk_density

        sys_ = self.sim.system
        d, g = self.g.d, self.g
        keep = (sys_.pos[:, 1] <= self.fill["fill_height"] + 3 * d) & (sys_.pos[:, 1] >= 0.0)
        rho, _ = column_bulk_density(sys_.pos[keep], sys_.mass[keep], 3 * d, g.W - 3 * d, 2 * d,
                                     g.y_fill + 3 * d, g.L, 3 * d)
        self.dens_t.append(t)
        self.dens.append(rho)

    def series(self) -> dict:
        """The silo's columns (``discharged_*``: what passed the outlet plane) and the tracer mass present."""
        out = super().series()
        out["tracer_mass_present"] = float(np.sum(self.sim.system.mass[self.sim.system.label == 1]))
        return out

    def records(self) -> dict:
        """The outflow records as arrays, with t_mean and N_r from the current flow-rate fit."""
        r = self.rec
        n = len(r["time"])
        t = np.array(r["time"], float)
        mass = np.array(r["mass"], float).reshape(n, len(LABELS))
        count = np.array(r["count"], np.int64).reshape(n, len(LABELS))
        tot = mass.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            conc = np.where(tot > 0, mass[:, 1] / np.where(tot > 0, tot, 1.0), np.nan)
        rate = self.flow_fit()["rate"]
        t_mean = self.colour["content_mass"] / rate if rate > 0 else math.nan
        return {"time": t, "concentration_out": conc, "mass_by_label": mass, "count_by_label": count,
                "concentration_in": np.array(r["c_in"], float), "concentration_reentry": np.array(r["c_re"], float),
                "channel_velocity": np.array(r["v_ch"], float), "feeder_line_density": np.array(r["lam"], float),
                "outflow_velocity": rate / float(np.mean(r["lam"])) if n and rate > 0 else math.nan,
                "t_mean": t_mean, "mass_flow_rate": rate,
                "n_recirculations": (t - self.gate_open_time) / t_mean,
                "density_time": np.array(self.dens_t, float), "bulk_density": np.array(self.dens, float)}

    def measurements(self):
        group, arrays, attrs = super().measurements()
        b, col = self.b, self.colour
        rec = self.records()
        rec.update({"gate_open_time": self.gate_open_time, "content_mass": col["content_mass"],
                    "inventory_mass": col["inventory_mass"], "tracer_mass": col["tracer_mass"],
                    "tracer_fraction": col["tracer_mass"] / col["content_mass"] if col["content_mass"] > 0
                    else math.nan,
                    "tracer_fraction_inventory": col["inventory_tracer_mass"] / col["inventory_mass"]
                    if col["inventory_mass"] > 0 else math.nan,
                    "content_bodies": np.int64(col["content_bodies"]), "layer_bottom": col["layer_bottom"],
                    "layer_top": col["layer_top"]})
        rec["@attrs"] = {
            "labels": "columns of mass_by_label / count_by_label: label 0 (bulk), 1 (tracer)",
            "crossing": "net mass and bodies crossing the outlet plane y = 0 downwards in each interval ending at "
                        "time (clumps by their centre of mass); concentration_out = tracer mass fraction (NaN: "
                        "nothing crossed)",
            "outflow_velocity": "mass_flow_rate / mean feeder_line_density (mass of the bodies whose centres lie in "
                                "the feeder zone per unit height): the stream's velocity by continuity",
            "t_mean": "content_mass / mass_flow_rate (the silo's fit of the cumulative outflow); "
                      "n_recirculations = (time - gate_open_time) / t_mean",
            "input": b["input"], "batch_fraction": b["batch_fraction"], "sublayers": b["sublayers"],
            "V_out": b["outflow_velocity"], "channel_length": self.geo.L,
            "feeder_range": np.array(self.geo.feeder), "periodic_y": np.array([-self.geo.L, self.geo.top]),
            "sample_interval": b["sample_interval"],
        }
        arrays["blending"] = rec
        arrays["mass_flow_rate"] = rec["mass_flow_rate"]
        arrays.update(self.analysis(rec, arrays["silo"]))
        return group, arrays, attrs

    def analysis(self, rec: dict, silo: dict) -> dict:
        """The blending measures of :mod:`cfddem.measure.blending` on the records: VRR over the
        analysed window (from the gate opening to now) and per recirculation, the flow pattern
        and the RTD.  VRR: var(c_in)/var(c_out) in continuous mode, f (1 - f)/var(c_out) for a
        batch of tracer fraction f.  RTD: from the outflow's step response with ``input =
        "step"`` (the particle-resolved RTD), and from virtual tracers released over the filled
        area of the time-averaged velocity field (``/measurements/rtd_virtual``; the
        ``/measurements/rtd`` of the other modes).  Quantities that the records cannot give yet
        (no outflow, no recirculation, no field) are left out, never filled in."""
        from ..measure import blending as bl

        b, out = self.b, {}
        t, c_out = rec["time"], rec["concentration_out"]
        t_mean = rec["t_mean"]
        count = rec["count_by_label"].sum(axis=1) if len(t) else np.zeros(0)
        batch = b["input"] == "batch"
        f = rec["tracer_fraction"]
        if batch and not 0.0 < f < 1.0:
            c_in = None
        else:
            c_in = bl.batch_input_variance(f) if batch else rec["concentration_in"]
        vrr = bl.variance_reduction_ratio(c_in, c_out) if c_in is not None and len(t) >= 2 else math.nan
        rec["vrr"] = vrr
        rec.setdefault("@attrs", {})["vrr"] = (
            "var(c_in) / var(c_out) over the records from the gate opening to the end: "
            + ("c_in a batch of tracer fraction f, var f (1 - f)" if batch else "c_in the re-entry input c_in(t)"))
        if math.isfinite(t_mean) and t_mean > 0 and c_in is not None and len(t) >= 2:
            by = bl.vrr_by_recirculation(t, c_out, t_mean, c_in=None if batch else c_in,
                                         batch_fraction=f if batch else None, t_start=self.gate_open_time,
                                         count=count)
            if len(by["n_r"]):
                rec["vrr_recirculations"] = by["n_r"]
                rec["vrr_by_recirculation"] = by["vrr"]
                rec["vrr_sampling_limit"] = np.where(by["var_sampling"] > 0,
                                                     by["var_in"] / np.where(by["var_sampling"] > 0,
                                                                             by["var_sampling"], 1.0), np.nan)
        fld = silo["field"]
        have_field = int(np.asarray(fld["n_samples"])) > 0 and np.isfinite(np.asarray(fld["vy"], float)).any()
        fill_h = self.fill["fill_height"]
        if have_field:
            x, y, vx, vy = (np.asarray(fld[k], float) for k in ("x", "y", "vx", "vy"))
            try:
                fp = bl.classify_flow_pattern(x, y, vy, fill_height=fill_h if math.isfinite(fill_h) else None)
                out["flow_pattern"] = fp["pattern"]
                out["flow_pattern_details"] = {k: fp[k] for k in ("h_t", "h_t_over_H", "fill_height",
                                                                  "stagnant_fraction", "width_fraction")}
            except ValueError as exc:
                self.sim.log.info("blender: no flow-pattern class yet (%s)", exc)
            if math.isfinite(t_mean) and t_mean > 0:
                try:
                    start = bl.release_area(x, y, vx, vy, 2000, y_max=fill_h if math.isfinite(fill_h) else None)
                    start = start[start[:, 1] > 0.0]
                    v = bl.virtual_tracer_rtd(x, y, vx, vy, start, 0.0, t_mean=t_mean)
                    out["rtd_virtual"] = {k: v[k] for k in ("theta", "E", "F", "mean", "variance", "peak", "theta_s",
                                                            "n_released", "n_arrived", "n_stuck", "n_late")}
                    out["rtd_virtual"]["@attrs"] = {
                        "method": "virtual tracers released over the filled area of the time-averaged velocity "
                                  "field (flux-weighted), advected to the outlet plane; theta = t / t_mean"}
                except ValueError as exc:
                    self.sim.log.info("blender: no virtual-tracer RTD (%s)", exc)
        if b["input"] == "step" and math.isfinite(t_mean) and t_mean > 0 and len(t) >= 2:
            t_inj = self.gate_open_time + b["input_step_time"]
            # blocks of about t_mean / 20: a few bodies per record interval make c_out 0 or 1, whose
            # derivative is noise; F from the blocks is smooth enough to differentiate
            k = max(1, int(round(0.05 * t_mean / b["sample_interval"])))
            tb, cb = bl.block_concentration(t, rec["mass_by_label"], k)
            if np.isfinite(cb[tb > t_inj]).sum() >= 3:
                st = bl.rtd_from_step(tb, cb, t_mean=t_mean, t_inject=t_inj)
                out["rtd"] = {k: st[k] for k in ("theta", "E", "F", "mean", "variance", "peak", "theta_s")}
                out["rtd"]["source"] = "step response of the outflow (particle-resolved)"
        elif "rtd_virtual" in out:
            out["rtd"] = {k: out["rtd_virtual"][k] for k in ("theta", "E", "F", "mean", "variance", "peak",
                                                            "theta_s")}
            out["rtd"]["source"] = "virtual tracers in the time-averaged velocity field"
        if "rtd" in out:
            out["rtd"]["first_appearance"] = out["rtd"]["theta_s"]
        return out

    def get_state(self) -> dict:
        st = super().get_state()
        r = self.rec
        n = len(r["time"])
        st["blender"] = {
            "k_sample": np.int64(self.k_sample), "prev_key": self.prev_key.copy(), "prev_y": self.prev_y.copy(),
            "time": np.array(r["time"], float), "mass": np.array(r["mass"], float).reshape(n, len(LABELS)),
            "count": np.array(r["count"], np.int64).reshape(n, len(LABELS)), "c_in": np.array(r["c_in"], float),
            "c_re": np.array(r["c_re"], float), "v_ch": np.array(r["v_ch"], float), "lam": np.array(r["lam"], float),
            "dens_t": np.array(self.dens_t, float), "dens": np.array(self.dens, float),
            "colour": {k: (np.asarray(v) if isinstance(v, np.ndarray) else float(v)) for k, v in self.colour.items()},
        }
        return st

    def set_state(self, d: dict) -> None:
        super().set_state(d)
        b = d["blender"]
        self.k_sample = int(b["k_sample"])
        self.prev_key = np.asarray(b["prev_key"], np.int64).ravel().copy()
        self.prev_y = np.asarray(b["prev_y"], float).ravel().copy()
        self.rec = {"time": [float(x) for x in np.asarray(b["time"]).ravel()],
                    "mass": list(np.asarray(b["mass"], float).reshape(-1, len(LABELS))),
                    "count": list(np.asarray(b["count"], np.int64).reshape(-1, len(LABELS))),
                    "c_in": [float(x) for x in np.asarray(b["c_in"]).ravel()],
                    "c_re": [float(x) for x in np.asarray(b["c_re"]).ravel()],
                    "v_ch": [float(x) for x in np.asarray(b["v_ch"]).ravel()],
                    "lam": [float(x) for x in np.asarray(b["lam"]).ravel()]}
        self.dens_t = [float(x) for x in np.asarray(b["dens_t"]).ravel()]
        self.dens = [float(x) for x in np.asarray(b["dens"]).ravel()]
        for k, v in b["colour"].items():
            self.colour[k] = np.asarray(v, float).ravel() if k.startswith("layer") else float(v)
        if self.gate_open:
            self._feeder()  # zones are configuration, not state


def plot_concentration(m: dict, out_dir):
    """``blender_concentration.png``: the outflow tracer concentration (and c_in) against N_r."""
    from pathlib import Path

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    nr = np.asarray(m["n_recirculations"], float)
    x, xl = (nr, "number of recirculations N_r") if np.isfinite(nr).any() else (np.asarray(m["time"]), "time [s]")
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(x, m["concentration_out"], ".", ms=2, label="outflow c_out")
    cin = np.asarray(m["concentration_in"], float)
    if np.isfinite(cin).any():
        ax.plot(x, cin, "-", lw=1, label="input c_in")
    if np.isfinite(float(m["tracer_fraction_inventory"])):
        ax.axhline(float(m["tracer_fraction_inventory"]), color="k", lw=0.8, ls="--", label="mean of the contents")
    ax.set_xlabel(xl)
    ax.set_ylabel("tracer mass fraction")
    ax.set_ylim(-0.05, 1.05)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    p = out / "blender_concentration.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p
