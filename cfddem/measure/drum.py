"""Rotating-drum measurements (pure functions; no engine imports).

Axes of the drum scene: the drum axis along z through the origin, gravity along -y, x
horizontal.  A positive rotation rate turns the drum counter-clockwise seen from +z: the wall at
the bottom moves towards +x and lifts the bed on the +x side, so the free surface rises towards
+x.  Angles are reported for the direction of rotation (positive for either sign of the rpm).

- :func:`surface_profile`: the free surface in the cross-section (all particles projected onto
  the x-y plane): in each column of width ``dx`` the highest particle centre of the connected
  bed, i.e. walking up the column's sorted centres, the last one before the first vertical gap
  larger than ``gap`` (particles thrown above the bed, as in cascading and cataracting, are not
  the surface).  Columns whose surface point lies within ``wall_clearance`` of the drum wall are
  dropped (the surface bends there into the wall's boundary layer).
- :func:`fit_surface`: least-squares line y = a + b x through the profile points whose x lies in
  the middle ``fraction`` of the profile's x range: the dynamic angle of repose
  atan(b) (sign(rpm)), and the S-shape of the surface: the rms and largest distance of the
  profile points from the line (over the whole profile) and the cubic coefficient of a cubic fit
  along the line, both relative to the drum radius.
- :func:`block_average`: the mean of a series over its sampling window and the standard error
  from ``n_blocks`` block means (the blocks absorb the correlation between successive samples).
- :func:`froude`: Fr = w^2 R / g.
- :func:`mellmann_regimes`: the regimes whose Froude-number range (Mellmann, Powder Technology
  118 (2001) 251-270, table of the transverse-motion forms) contains Fr: slumping
  1e-5 < Fr < 1e-3, rolling 1e-4 < Fr < 1e-2, cascading 1e-3 < Fr < 0.1, cataracting
  0.1 < Fr < 1, centrifuging Fr >= 1 (the ranges overlap: the filling degree and the wall
  friction decide inside an overlap; slipping depends on the wall friction, not on Fr).
- :func:`classify_run`: the regime the run shows (definitions of this code, docs/drum.md):
  ``slumping`` when the angle's sample-to-sample standard deviation exceeds ``slump_std_deg``
  (intermittent avalanches); otherwise ``cataracting`` when more than ``airborne_fraction`` of
  the particles are detached above the surface; otherwise ``cascading`` when the surface is
  S-shaped (the time-averaged cubic coefficient of :func:`fit_surface` above
  ``s_shape_threshold`` in magnitude: single profiles are noisy by about a particle radius, the
  average is not), else ``rolling``.
"""

from __future__ import annotations

import math

import numpy as np

from .stats import block_error

#: Mellmann (2001): Froude-number ranges of the forms of transverse motion (lo, hi), Fr = w^2 R / g
MELLMANN_RANGES = {
    "slumping": (1e-5, 1e-3),
    "rolling": (1e-4, 1e-2),
    "cascading": (1e-3, 1e-1),
    "cataracting": (1e-1, 1.0),
    "centrifuging": (1.0, math.inf),
}


def froude(rpm: float, radius: float, g: float = 9.81) -> float:
    """Fr = w^2 R / g with w = 2 pi rpm / 60."""
    w = 2.0 * math.pi * rpm / 60.0
    return w * w * radius / g


def mellmann_regimes(fr: float) -> list[str]:
    """The regimes of :data:`MELLMANN_RANGES` whose range contains ``fr`` (lo < Fr < hi; the
    centrifuging range includes Fr = 1); empty below 1e-5 (slipping or at rest)."""
    out = []
    for name, (lo, hi) in MELLMANN_RANGES.items():
        if lo < fr < hi or (name == "centrifuging" and fr >= lo):
            out.append(name)
    return out


def surface_profile(pos, radius: float, dx: float, gap: float, wall_clearance: float = 0.0):
    """(x, y, n_detached): the free-surface points of the cross-section (module docstring), one
    per column of width ``dx`` across [-radius, radius] holding at least one particle, and the
    number of particles above the first gap of their column (detached from the bed)."""
    pos = np.asarray(pos, float).reshape(-1, 3)
    if not len(pos):
        return np.zeros(0), np.zeros(0), 0
    nb = max(1, int(math.ceil(2.0 * radius / dx)))
    col = np.clip(np.floor((pos[:, 0] + radius) / dx).astype(np.int64), 0, nb - 1)
    order = np.lexsort((pos[:, 1], col))
    c, y = col[order], pos[order, 1]
    starts = np.flatnonzero(np.r_[True, c[1:] != c[:-1]])
    ends = np.r_[starts[1:], len(c)]
    xs, ys = [], []
    detached = 0
    for s, e in zip(starts, ends):
        yy = y[s:e]
        jumps = np.flatnonzero(np.diff(yy) > gap)
        top = jumps[0] if len(jumps) else e - s - 1
        detached += e - s - 1 - top
        xc = -radius + (c[s] + 0.5) * dx
        if math.hypot(xc, yy[top]) <= radius - wall_clearance:
            xs.append(xc)
            ys.append(yy[top])
    return np.array(xs), np.array(ys), int(detached)


def fit_surface(x, y, radius: float, fraction: float = 0.6, sign: float = 1.0) -> dict:
    """Line and S-shape of a surface profile (module docstring): ``angle_deg`` (NaN with fewer
    than 3 points in the fit), ``slope``, ``intercept``, ``rms_dev`` and ``max_dev`` (distances
    from the line over the whole profile, / radius), ``cubic`` (the cubic coefficient of
    y' = c0 + c1 s + c2 s^2 + c3 s^3 along the line, s and y' in units of the radius: 0 for a
    straight surface), ``n_fit``."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    out = {"angle_deg": math.nan, "slope": math.nan, "intercept": math.nan, "rms_dev": math.nan,
           "max_dev": math.nan, "cubic": math.nan, "n_fit": 0}
    if len(x) < 3:
        return out
    mid = 0.5 * (x.min() + x.max())
    half = 0.5 * fraction * (x.max() - x.min())
    sel = np.abs(x - mid) <= half + 1e-12 * radius
    out["n_fit"] = int(sel.sum())
    if sel.sum() < 3:
        return out
    b, a = np.polyfit(x[sel], y[sel], 1)
    c, s_ = 1.0 / math.sqrt(1.0 + b * b), b / math.sqrt(1.0 + b * b)
    # coordinates along (s) and across (h) the fitted line, in units of the radius
    s = ((x - mid) * c + (y - (a + b * mid)) * s_) / radius
    h = (-(x - mid) * s_ + (y - (a + b * mid)) * c) / radius
    out.update(angle_deg=math.degrees(math.atan(b)) * (1.0 if sign >= 0 else -1.0), slope=float(b),
               intercept=float(a), rms_dev=float(np.sqrt(np.mean(h * h))), max_dev=float(np.max(np.abs(h))))
    if len(x) >= 5:
        out["cubic"] = float(np.polyfit(s, h, 3)[0]) * (1.0 if sign >= 0 else -1.0)
    return out


def block_average(v, n_blocks: int = 5) -> tuple[float, float]:
    """(mean, standard error) of the finite values of ``v``: the error from ``n_blocks``
    consecutive block means, std(block means, ddof=1) / sqrt(n_blocks); NaN error with fewer
    samples than blocks (mean NaN without samples)."""
    v = np.asarray(v, float)
    v = v[np.isfinite(v)]
    if not len(v):
        return math.nan, math.nan
    if len(v) < n_blocks or n_blocks < 2:
        return float(np.mean(v)), math.nan
    return float(np.mean(v)), float(block_error(v, n_blocks))


def classify_run(angle_std_deg: float, s_shape: float, airborne: float, *, slump_std_deg: float = 2.0,
                 s_shape_threshold: float = 0.1, airborne_fraction: float = 0.02) -> str:
    """The regime the run shows (module docstring); ``"unknown"`` without samples (NaN)."""
    if not (math.isfinite(angle_std_deg) and math.isfinite(s_shape) and math.isfinite(airborne)):
        return "unknown"
    if angle_std_deg > slump_std_deg:
        return "slumping"
    if airborne > airborne_fraction:
        return "cataracting"
    return "cascading" if abs(s_shape) > s_shape_threshold else "rolling"
