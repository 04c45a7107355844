"""The internals of the multi-flow blender (blending.md §3) in the planar silo scene: a blending
tube on the centre line and a cone-in-cone insert in the hopper (case keys ``[silo]`` ``insert``,
``tube``, ... below; docs/blender-multiflow.md).

Axes as in :mod:`cfddem.scenes.silo`: x across (side walls x = 0 and x = W), y up (outlet plane
y = 0), z through the depth.  The hopper walls are the planes from the slot edges x = W/2 +- b/2
at ``hopper_angle_deg`` a to the horizontal, i.e. theta = 90 deg - a from the vertical; they meet
at the apex (W/2, y_A), y_A = -(b/2) tan a, below the outlet, and reach the side walls at the
transition y_h = (W - b)/2 tan a, at the distance R_t = (W/2) / sin theta from the apex.

Every internal is a **closed thin body**: a quadrilateral in the x-y plane extruded through the
full depth, each of its four sides a one-sided bounded rectangle facing out (``<body>_outer``,
``_inner`` (towards the centre line), ``_top``, ``_bottom``), so a particle meets a face, an edge
or a corner from any side, like the container's walls.  Bodies: ``tube_left`` / ``tube_right``
and ``insert_left`` / ``insert_right``.  Their contact parameters are ``[silo.internals]`` (unset
keys: ``contact.particle_wall``).

- **Blending tube** (``tube = true``): two vertical walls of thickness t, clear width w
  (``tube_width``, 0: the outlet width b) between their inner faces, from the insert's outlet
  level y_o (``insert_outlet_level`` times y_h) up to y_h + ``tube_inlet`` W (blending.md: 15 % of
  the width above the transition).
- **Insert** (``insert`` = "diverging" | "straight" | "converging"): one inclined plate of
  thickness t on each side, between the hopper wall and the tube, dividing each side into an
  exterior channel (hopper wall to plate) and an interior channel (plate to the tube's outer
  face; to the centre line without a tube).  Channel cross-sections ("areas": widths times the
  depth): at the **inlet** along the arc of radius R_t centred on the apex (the arc through the
  transition, on which the plate's upper corners lie: the cross-section of radial hopper flow);
  at the **outlet** horizontal, at y = y_o, where the plate's lower side and the tube's end lie.
  With E_i, I_i the plate's outer and inner upper corners (angles psi_E > psi_I from the
  vertical, seen from the apex), E_o, I_o its lower corners, c the half-width of the tube's outer
  faces (w/2 + t; 0 without a tube), X the distance from the centre line::

      A_e = R_t (theta - psi_E) / (X_wall(y_o) - X(E_o)),   X_wall(y) = (y - y_A) tan theta
      A_i = R_t (psi_I - asin(c / R_t)) / (X(I_o) - c)

  (thesis Table 7.1: diverging 0.5 / 2.6, straight 1 / 1.72, converging 2 / 1.18; A_r = A_e / A_i).
  The plate's two long faces are parallel, t apart.  Given y_o the plate has two unknowns
  (psi_E and X(E_o)); A_e gives X(E_o) from psi_E, and A_i(psi_E) = target is solved by bracketing
  on a fine grid of psi_E and ``scipy.optimize.brentq`` (the root with the widest narrowest
  channel when there are several).  "straight" (A_i = 1) is then a nearly vertical plate.

Checks (one-line :class:`~cfddem.errors.CaseError` naming the key): an insert needs a hopper; a
tube no wider than the outlet; no plate with the table's ratios between the hopper wall and the
tube at that outlet level, or a channel narrower than 3 particle (bounding) diameters:
``silo.insert`` says which; internals that reach above the silo's side walls.

``python -m cfddem.scenes.silo_internals CASE --draw OUT.png`` draws the silo with each insert
(one panel per insert, axes in mm) and prints every dimension.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import CaseError
from ..schema import Key, wall_override
from ..schema import nonneg as _nonneg
from ..schema import number as _f

#: thesis Table 7.1: (A_i, A_e, A_r), A_r = A_e / A_i
INSERT_RATIOS = {"diverging": (0.5, 2.6, 5.2), "straight": (1.0, 1.72, 1.72), "converging": (2.0, 1.18, 0.59)}
BODIES = ("insert_left", "insert_right", "tube_left", "tube_right")
FACES = ("outer", "top", "inner", "bottom")
WALL_NAMES = tuple(f"{b}_{f}" for b in BODIES for f in FACES)
#: the contact group of the internals (``[silo.internals]``)
GROUP = "internals"
#: narrowest channel allowed, in particle (bounding) diameters
MIN_CHANNEL = 3.0

KEYS = {
    "insert": Key("str", "none", "-", "multi-flow blender insert in the hopper (docs/blender-multiflow.md): 'none', "
                  "or a cone-in-cone insert built from thesis Table 7.1's area ratios A_i / A_e: 'diverging' "
                  "(0.5 / 2.6), 'straight' (1 / 1.72), 'converging' (2 / 1.18); needs a hopper",
                  choices=("none",) + tuple(INSERT_RATIOS)),
    "tube": Key("bool", False, "-", "blending tube on the centre line: two vertical walls from the insert's outlet "
                "level up to tube_inlet x width above the hopper transition"),
    "tube_width": _nonneg(0.0, "m", "clear width of the blending tube (0: silo.outlet_width; at most that)"),
    "tube_inlet": _nonneg(0.15, "-", "height of the tube's inlet (its top) above the hopper transition, as a "
                          "fraction of silo.width"),
    "insert_outlet_level": _f(0.8, "-", "height y_o of the insert's outlet (and the tube's outlet) as a fraction "
                              "of the hopper height", lo=0.0, hi=1.0, lo_open=True, hi_open=True),
    "insert_thickness": _nonneg(0.0, "m", "thickness of the insert plates and the tube walls (0: "
                                "particles.diameter)"),
    "centreline_heights": Key("floats", [0.1, 0.4, 0.7], "m", "with internals: heights above the outlet where the "
                              "steady centreline speed is reported (/measurements/silo/centreline; NaN above the "
                              "field); default the thesis's 100, 400 and 700 mm", lo=0.0),
    GROUP: wall_override("insert plates and blending tube"),
}


class Internals:
    """The blender internals of one silo (module doc): ``bodies`` {name: (4, 2) corners in x-y,
    counter-clockwise, with ``faces`` {name: the four face names, edge k from corner k to k + 1}},
    ``y_o`` (insert and tube outlet level), ``top`` (highest point), ``solution`` (the insert's
    solved channel widths)."""

    def __init__(self, W: float, b: float, angle: float, insert: str = "none", tube: bool = False,
                 tube_width: float = 0.0, tube_inlet: float = 0.15, level: float = 0.8, t: float = 0.003,
                 d_site: float = 0.0):
        self.W, self.b, self.t, self.insert, self.tube = W, b, t, insert, tube
        self.theta = 0.5 * math.pi - angle
        self.xc = 0.5 * W
        self.y_A = -0.5 * b * math.tan(angle) if angle > 0 else -math.inf
        self.y_h = 0.5 * (W - b) * math.tan(angle) if angle > 0 else 0.0
        self.R_t = 0.5 * W / math.sin(self.theta) if angle > 0 else math.inf
        self.y_o = level * self.y_h
        self.w = tube_width or b
        self.c = 0.5 * self.w + t if tube else 0.0
        self.y_tube = self.y_h + tube_inlet * W
        self.d_site = d_site
        self.bodies: dict[str, np.ndarray] = {}
        self.solution: dict = {}
        if tube:
            for side, s in (("left", -1.0), ("right", 1.0)):
                X = np.array([self.c, self.c, 0.5 * self.w, 0.5 * self.w])  # outer bottom, outer top, inner top, inner bottom
                Y = np.array([self.y_o, self.y_tube, self.y_tube, self.y_o])
                self.bodies[f"tube_{side}"] = self._xy(X, Y, s)
        if insert != "none":
            sol = self._solve(*INSERT_RATIOS[insert][:2])
            self.solution = sol
            for side, s in (("left", -1.0), ("right", 1.0)):
                X = np.array([sol["Eo"][0], sol["Ei"][0], sol["Ii"][0], sol["Io"][0]])
                Y = np.array([sol["Eo"][1], sol["Ei"][1], sol["Ii"][1], sol["Io"][1]]) + self.y_A
                self.bodies[f"insert_{side}"] = self._xy(X, Y, s)
        self.top = max((float(p[:, 1].max()) for p in self.bodies.values()), default=-math.inf)

    @classmethod
    def from_silo(cls, silo: dict, d: float, d_site: float) -> "Internals | None":
        """The internals of a resolved ``[silo]`` section (None when it has none, or when the dict
        lacks the internals' keys)."""
        if silo.get("insert", "none") == "none" and not silo.get("tube", False):
            return None
        return cls(silo["width"], silo["outlet_width"], math.radians(silo["hopper_angle_deg"]), silo["insert"],
                   silo["tube"], silo["tube_width"], silo["tube_inlet"], silo["insert_outlet_level"],
                   silo["insert_thickness"] or d, d_site)

    def _xy(self, X, Y, side: float) -> np.ndarray:
        """Corners from (distance from the centre line X, height y) on one side; the corner order
        (outer bottom, outer top, inner top, inner bottom: edges outer, top, inner, bottom) is
        counter-clockwise on the right side and reversed (keeping the face names) on the left."""
        return np.stack([self.xc + side * np.asarray(X), np.asarray(Y)], axis=1)

    def faces(self, body: str) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """The four sides of a body: (face name, start corner, end corner)."""
        P = self.bodies[body]
        return [(f"{body}_{FACES[k]}", P[k], P[(k + 1) % 4]) for k in range(4)]

    # ------------------------------------------------------------------ insert
    def _plate(self, psi_E: float, A_e: float) -> dict | None:
        """The left plate (in X = distance from the centre line, Y = height above the apex) whose
        outer upper corner lies on the arc R_t at psi_E, for the exterior ratio A_e."""
        R, th, t, c = self.R_t, self.theta, self.t, self.c
        Yo = self.y_o - self.y_A
        Ei = R * np.array([math.sin(psi_E), math.cos(psi_E)])
        ext_in = R * (th - psi_E)
        ext_out = ext_in / A_e
        Eo = np.array([Yo * math.tan(th) - ext_out, Yo])
        D = Ei - Eo
        D /= np.linalg.norm(D)
        n = np.array([-D[1], D[0]])
        if n[0] > 0:
            n = -n  # towards the centre line
        P = Ei + t * n
        pd, q = float(P @ D), float(P @ P) - R * R
        disc = pd * pd - q
        if disc < 0 or D[1] <= 0:
            return None
        s = min((-pd + math.sqrt(disc), -pd - math.sqrt(disc)), key=abs)
        Ii = P + s * D
        Io = P + (Yo - P[1]) / D[1] * D
        psi_I = math.atan2(Ii[0], Ii[1])
        int_in = R * (psi_I - math.asin(c / R))
        int_out = Io[0] - c
        if not (int_in > 0 and int_out > 0 and ext_out > 0 and psi_I < psi_E and Ii[1] > Yo):
            return None
        return {"Ei": Ei, "Eo": Eo, "Ii": Ii, "Io": Io, "psi_E": psi_E, "psi_I": psi_I, "exterior_in": ext_in,
                "exterior_out": ext_out, "interior_in": int_in, "interior_out": int_out}

    def _solve(self, A_i: float, A_e: float) -> dict:
        from scipy.optimize import brentq

        lo, hi = math.asin(self.c / self.R_t), self.theta
        grid = np.linspace(lo, hi, 4001)[1:-1]

        def f(p):
            pl = self._plate(p, A_e)
            return math.nan if pl is None else pl["interior_in"] / pl["interior_out"] - A_i

        vals = np.array([f(p) for p in grid])
        roots = []
        for k in range(len(grid) - 1):
            a, b = vals[k], vals[k + 1]
            if np.isfinite(a) and np.isfinite(b) and a * b <= 0:
                roots.append(grid[k] if a == 0 else brentq(f, grid[k], grid[k + 1], xtol=1e-15, rtol=4 * np.finfo(float).eps))
        plates = [self._plate(p, A_e) for p in roots]
        plates = [p for p in plates if p is not None]
        if not plates:
            raise CaseError("silo.insert", f"no {self.insert} insert (A_i = {A_i:g}, A_e = {A_e:g}) fits between the "
                                           f"hopper wall and the {'tube' if self.tube else 'centre line'} with its "
                                           f"outlet at y_o = {self.y_o:.4g} m: change silo.insert_outlet_level")

        def narrowest(p):
            return min(p["exterior_in"], p["exterior_out"], p["interior_in"], p["interior_out"])

        best = max(plates, key=narrowest)
        if self.d_site and narrowest(best) < MIN_CHANNEL * self.d_site:
            raise CaseError("silo.insert", f"the {self.insert} insert does not fit: its narrowest channel is "
                                           f"{narrowest(best) * 1e3:.3g} mm, less than {MIN_CHANNEL:g} particle "
                                           f"diameters ({MIN_CHANNEL * self.d_site * 1e3:.3g} mm); change "
                                           "silo.insert_outlet_level or the particle size")
        return best

    # ------------------------------------------------------------------ measures
    def channel_widths(self) -> dict:
        """The insert's channel cross-section widths (m) recomputed from the corners: exterior and
        interior, inlet (arc R_t) and outlet (horizontal at y_o); their ratios A_i, A_e."""
        P = self.bodies["insert_right"]
        X = P[:, 0] - self.xc
        Y = P[:, 1] - self.y_A
        psi = np.arctan2(X, Y)
        Xw = (self.y_o - self.y_A) * math.tan(self.theta)
        out = {"exterior_in": self.R_t * (self.theta - psi[1]), "exterior_out": Xw - X[0],
               "interior_in": self.R_t * (psi[2] - math.asin(self.c / self.R_t)), "interior_out": X[3] - self.c}
        out["A_i"] = out["interior_in"] / out["interior_out"]
        out["A_e"] = out["exterior_in"] / out["exterior_out"]
        return out

    def channels(self, y: float) -> dict[str, list[tuple[float, float]]]:
        """The channels' clear x intervals at height y (between y_o and the lowest top of the
        internals): with an insert 'exterior', 'interior' (each the left and the right one) and,
        with a tube, 'tube'; a tube alone: 'annulus' (hopper wall to tube) and 'tube'."""
        xc = self.xc
        Xw = min((y - self.y_A) * math.tan(self.theta), 0.5 * self.W)
        out: dict[str, list] = {}
        if self.insert != "none":
            P = self.bodies["insert_right"]

            def at(a, b):  # X of the line through corners a, b at height y
                return P[a, 0] - xc + (y - P[a, 1]) * (P[b, 0] - P[a, 0]) / (P[b, 1] - P[a, 1])

            Xe, Xi = at(0, 1), at(3, 2)
            spans = {"exterior": (Xe, Xw), "interior": (self.c, Xi)}
        else:
            spans = {"annulus": (self.c, Xw)}
        for k, (a, b) in spans.items():
            out[k] = [(xc - b, xc - a), (xc + a, xc + b)]
        if self.tube:
            out["tube"] = [(xc - 0.5 * self.w, xc + 0.5 * self.w)]
        return out

    # ------------------------------------------------------------------ walls
    def rectangles(self, L: float, e: float):
        """(name, centre, normal, in-plane axis, half-length, half-depth) of every face: the
        rectangles span the depth (extended e past the front and back walls)."""
        out = []
        for body, P in self.bodies.items():
            area = 0.5 * np.sum(P[:, 0] * np.roll(P[:, 1], -1) - np.roll(P[:, 0], -1) * P[:, 1])
            sgn = 1.0 if area > 0 else -1.0  # counter-clockwise: the outward normal is (dy, -dx)
            for name, a, b in self.faces(body):
                d = b - a
                ln = float(np.hypot(*d))
                u = np.array([d[0], d[1], 0.0]) / ln
                n = sgn * np.array([u[1], -u[0], 0.0])
                out.append((name, np.array([0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * L]), n, u, 0.5 * ln,
                            0.5 * L + e))
        return out

    def describe(self) -> list[str]:
        """Every dimension, one line each (mm), for ``cfddem check`` and the docs."""
        mm = 1e3
        lines = [f"hopper: theta = {math.degrees(self.theta):.4g} deg from the vertical, apex y_A = {self.y_A * mm:.2f} "
                 f"mm, transition y_h = {self.y_h * mm:.2f} mm, arc radius R_t = {self.R_t * mm:.2f} mm; internals "
                 f"thickness t = {self.t * mm:.3g} mm, outlet level y_o = {self.y_o * mm:.2f} mm"]
        if self.tube:
            lines.append(f"tube: clear width {self.w * mm:.2f} mm (outer {2 * self.c * mm:.2f} mm), from y = "
                         f"{self.y_o * mm:.2f} to {self.y_tube * mm:.2f} mm ({(self.y_tube - self.y_h) * mm:.2f} mm "
                         "above the transition)")
        if self.insert != "none":
            P = self.bodies["insert_right"]
            cw = self.channel_widths()
            s = self.solution
            incl = math.degrees(math.atan2(P[1, 0] - P[0, 0], P[1, 1] - P[0, 1]))
            lines.append(f"{self.insert} insert (right plate; the left one mirrored): outer face ({P[0, 0] * mm:.2f}, "
                         f"{P[0, 1] * mm:.2f}) -> ({P[1, 0] * mm:.2f}, {P[1, 1] * mm:.2f}) mm, inner face "
                         f"({P[3, 0] * mm:.2f}, {P[3, 1] * mm:.2f}) -> ({P[2, 0] * mm:.2f}, {P[2, 1] * mm:.2f}) mm, "
                         f"{incl:.2f} deg from the vertical (+: leaning out at the top), upper corners at "
                         f"{math.degrees(s['psi_E']):.3f} / {math.degrees(s['psi_I']):.3f} deg on the arc")
            lines.append(f"channels: exterior {cw['exterior_in'] * mm:.2f} -> {cw['exterior_out'] * mm:.2f} mm (A_e = "
                         f"{cw['A_e']:.6g}), interior {cw['interior_in'] * mm:.2f} -> {cw['interior_out'] * mm:.2f} mm "
                         f"(A_i = {cw['A_i']:.6g}), A_r = A_e / A_i = {cw['A_e'] / cw['A_i']:.4g}")
        return lines


def check_internals(r: dict, d: float, d_site: float, H: float | None = None) -> "Internals | None":
    """The consistency checks of the internals' keys (module doc); returns the internals."""
    from ..particles.contact import check_contact_values

    s = r["silo"]
    check_contact_values(f"silo.{GROUP}", s[GROUP])
    if s["insert"] == "none" and not s["tube"]:
        return None
    if s["hopper_angle_deg"] <= 0:
        key = "silo.insert" if s["insert"] != "none" else "silo.tube"
        raise CaseError(key, "the blender's internals need a hopper (silo.hopper_angle_deg > 0)")
    if s["tube"] and s["tube_width"] > s["outlet_width"]:
        raise CaseError("silo.tube_width", f"{s['tube_width']:g} m is wider than the outlet "
                                           f"(silo.outlet_width = {s['outlet_width']:g} m)")
    t = s["insert_thickness"] or d
    if s["tube"] and 0.5 * s["width"] < 0.5 * (s["tube_width"] or s["outlet_width"]) + t + MIN_CHANNEL * d_site:
        raise CaseError("silo.tube_width", "the tube leaves no room beside it in the silo")
    g = Internals.from_silo(s, d, d_site)
    if H is not None and g.top > H:
        raise CaseError("silo.height", f"{H:g} m is below the top of the internals ({g.top:.4g} m)")
    return g


def describe_fill(case, phi: float = 0.6) -> list[str]:
    """``cfddem check`` lines of a silo with internals: their dimensions (:meth:`Internals.describe`)
    and the fill: the number of bodies and the height above the outlet that their volume fills
    at the solid fraction ``phi`` (the silo's cross-section less the internals')."""
    from ..particles.clumps import shape_from_case
    from .silo import SiloGeometry

    s = case.resolved["silo"]
    p = case.particles
    geo = SiloGeometry(s, p.diameter, p.seed, p.clump, p.density, p.clump_spheres)
    if geo.internals is None:
        return []
    shape = shape_from_case(p.clump, p.diameter, p.density, p.clump_spheres)
    v = math.pi / 6 * p.diameter ** 3 if shape is None else shape.mass / p.density
    y = np.linspace(0.0, max(geo.H, geo.y_h), 20001)
    width = np.minimum(geo.b + 2 * y / math.tan(geo.angle), geo.W)
    for P in geo.internals.bodies.values():  # less the internals' own width at each height
        xs = [np.interp(y, *sorted_edge(P[k], P[(k + 1) % 4]), left=np.nan, right=np.nan) for k in range(4)]
        xs = np.array(xs)
        ok = np.isfinite(xs)
        span = np.where(ok, xs, -np.inf).max(axis=0) - np.where(ok, xs, np.inf).min(axis=0)
        width -= np.where(ok.sum(axis=0) >= 2, span, 0.0)
    vol = np.concatenate([[0.0], np.cumsum(0.5 * (width[1:] + width[:-1]) * np.diff(y))]) * geo.L
    n = s["n_particles"]
    h = float(np.interp(n * v / phi, vol, y))
    what = "spheres" if shape is None else f"{p.clump} clumps of {len(shape.radii)} spheres"
    return [f"blender {line}" for line in geo.internals.describe()] + [
        f"fill: {n:,} {what}; at a solid fraction of {phi:g} they fill to about {h * 1e3:.0f} mm above the outlet"]


def sorted_edge(a, b):
    """(y, x) of a segment's end points with y increasing (for np.interp of x at heights y)."""
    return ([a[1], b[1]], [a[0], b[0]]) if a[1] <= b[1] else ([b[1], a[1]], [b[0], a[0]])


class ChannelProbe:
    """The blender's steady measurements: a :class:`~cfddem.measure.silo.VelocityField` sampled
    (at the scene's field times) only while the discharged mass lies between the ``fit_range``
    fractions of the mass in the silo at the gate opening (the steady window); at the end the
    mean v_y per channel at the insert outlet relative to the cross-sectional mean
    (:func:`~cfddem.measure.silo.channel_velocities`) and the centreline speeds at the given
    heights (:func:`~cfddem.measure.silo.centreline_speeds`)."""

    def __init__(self, internals: "Internals | None", xc: float, x0, x1, y0, y1, cell, window, heights):
        from ..measure.silo import VelocityField

        self.g = internals
        self.xc = xc
        self.field = VelocityField(x0, x1, y0, y1, cell)
        self.window = tuple(window)
        self.heights = np.asarray(heights, float)
        self.m_fill = math.nan
        self.t_window = [math.nan, math.nan]

    def open(self, m_fill: float) -> None:
        self.m_fill = float(m_fill)

    def sample(self, t: float, pos, vel, mass_out: float) -> None:
        lo, hi = self.window
        if not (lo * self.m_fill <= mass_out <= hi * self.m_fill):
            return
        if not math.isfinite(self.t_window[0]):
            self.t_window[0] = t
        self.t_window[1] = t
        self.field.sample(pos, vel)

    def measurements(self) -> dict:
        from ..measure.silo import centreline_speeds, channel_velocities

        f = self.field
        out = {"window_time": np.array(self.t_window), "window_mass_fraction": np.array(self.window),
               "n_samples": f.n_samples,
               "centreline": {"height": self.heights, "speed": centreline_speeds(f, self.xc, self.heights)}}
        if self.g is not None:
            j = min(int(math.ceil((self.g.y_o - f.y0) / f.dy - 1e-9)), f.ny - 1)  # first row above y_o
            y = float(f.y[j])
            ch = channel_velocities(f, j, self.g.channels(y))
            out["channels"] = {**ch, "y": y, "y_outlet": self.g.y_o,
                               "@attrs": {"relative": "channel mean v_y / cross-sectional mean v_y (the row of "
                                                      "cells just above the insert outlet, steady window)"}}
        return out

    def get_state(self) -> dict:
        return {"field": self.field.get_state(), "m_fill": self.m_fill, "t_window": np.array(self.t_window)}

    def set_state(self, d: dict) -> None:
        self.field.set_state(d["field"])
        self.m_fill = float(d["m_fill"])
        self.t_window = [float(x) for x in np.asarray(d["t_window"]).ravel()]


# ---------------------------------------------------------------------- drawing
def draw(case, out_png, inserts=tuple(INSERT_RATIOS)) -> list[list[str]]:
    """One panel per insert (x-y, mm): the silo's walls, the internals (filled), the arc through
    the transition and the channel names; returns each panel's :meth:`Internals.describe`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..config import load_case
    from .silo import SiloGeometry, silo_walls

    fig, axes = plt.subplots(1, len(inserts), figsize=(4.2 * len(inserts), 7.5), squeeze=False)
    texts = []
    for ax, ins in zip(axes[0], inserts):
        c = load_case(case.path, overrides={**case.overrides, "silo.insert": ins, "silo.tube": True})
        p = c.particles
        geo = SiloGeometry(c.resolved["silo"], p.diameter, p.seed, p.clump, p.density, p.clump_spheres)
        g = geo.internals
        mm = 1e3
        for w in silo_walls(c, container=True):
            if abs(w.normal[2]) > 0.5 or w.name.startswith(("insert", "tube")):
                continue
            a = w.point - w.half_extents[0] * w.u_axis
            b = w.point + w.half_extents[0] * w.u_axis
            ax.plot([a[0] * mm, b[0] * mm], [a[1] * mm, b[1] * mm], color="k", lw=1.5)
        for P in g.bodies.values():
            ax.fill(P[:, 0] * mm, P[:, 1] * mm, color="tab:blue", alpha=0.8, lw=0.5, ec="navy")
        ph = np.linspace(-g.theta, g.theta, 200)
        ax.plot((g.xc + g.R_t * np.sin(ph)) * mm, (g.y_A + g.R_t * np.cos(ph)) * mm, ls=":", color="grey", lw=1)
        ax.axhline(g.y_h * mm, color="grey", lw=0.5, ls="--")
        ax.axhline(g.y_o * mm, color="grey", lw=0.5, ls="--")
        y_mid = g.y_o + 0.3 * (float(g.bodies["insert_right"][1:3, 1].min()) - g.y_o)
        for name, spans in g.channels(y_mid).items():
            for a, b in spans[1:] if len(spans) > 1 else spans:
                ax.text(0.5 * (a + b) * mm, y_mid * mm, name, rotation=90, ha="center", va="center", fontsize=8)
        ax.set_title(f"{ins}: A_i = {INSERT_RATIOS[ins][0]:g}, A_e = {INSERT_RATIOS[ins][1]:g}", fontsize=10)
        ax.set_aspect("equal")
        ax.set_xlim(-0.05 * geo.W * mm, 1.05 * geo.W * mm)
        ax.set_ylim(-geo.lip * mm - 5, (g.top + 0.35 * geo.W) * mm)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y above the outlet (mm)")
        texts.append(g.describe())
    fig.tight_layout()
    fig.savefig(out_png, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return texts


def main(argv=None) -> int:
    """``python -m cfddem.scenes.silo_internals CASE --draw OUT.png [--set K=V]...``"""
    import argparse
    import sys

    from .silo import load_silo_case

    ap = argparse.ArgumentParser(prog="python -m cfddem.scenes.silo_internals",
                                 description="draw the multi-flow blender's three inserts and print their dimensions")
    ap.add_argument("case", help="a silo case with a hopper (its folder or case.toml)")
    ap.add_argument("--draw", metavar="OUT.png", required=True)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    args = ap.parse_args(argv)
    try:
        texts = draw(load_silo_case(args.case, args.overrides), args.draw)
    except CaseError as e:
        print(f"cfddem: error: {e}", file=sys.stderr)
        return 2
    for ins, lines in zip(INSERT_RATIOS, texts):
        print(f"## {ins}")
        print("\n".join(lines))
    print(f"# wrote {args.draw}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
