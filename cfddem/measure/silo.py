"""Silo discharge measurements (pure functions and one accumulator; no engine imports).

Axes of the silo scene: x across the silo (0..width), y up (the outlet plane at y = 0), z through
the depth (front wall z = 0, back wall z = depth).

- :func:`fit_mass_flow`: the steady mass flow rate W as the slope of a least-squares line through
  the discharged mass m(t) between two fractions (default 20 % and 80 %) of the final discharged
  mass; the rms residual of the fit is returned with the window.
- :func:`bulk_density`: rho_b = (sum of the masses of the particles whose centres lie in a box) /
  (box volume).  For a box much larger than a particle this is the bulk density without bias (a
  sphere is counted whole or not at all, which averages out over the box faces).
- :class:`VelocityField`: time average of the particle velocity on an x-y grid (depth-averaged):
  per cell sum(v) / (number of particle samples), i.e. the average over the particles present.
- :func:`channel_boundary`: for each row of the averaged field, the x on each side of the
  centreline where the downward speed -v_y first falls below ``fraction`` x the centreline speed
  (linear interpolation between cell centres).
- :func:`beverloo_rate` / :func:`fit_beverloo`: the Beverloo law for a slot (planar silo)
  W = C rho_b sqrt(g) L (b - k d)^(3/2) (Beverloo, Leniger & van de Velde, Chem. Eng. Sci. 15
  (1961) 260; slot form e.g. Nedderman, "Statics and kinematics of granular materials", 1992,
  §10), fitted for C and k by non-linear least squares (scipy.optimize.curve_fit).
"""

from __future__ import annotations

import math

import numpy as np


def fit_mass_flow(t, m, lo: float = 0.2, hi: float = 0.8) -> dict:
    """Linear fit m = W t + c over the samples with lo M <= m <= hi M, M = m[-1] (the final
    discharged mass).  Returns rate W (kg/s; NaN when fewer than 3 samples fall in the window),
    intercept c, the window (t_lo, t_hi, m_lo, m_hi), the rms residual (kg), the residual
    relative to the mass range of the window, and the number of samples used."""
    t = np.asarray(t, float)
    m = np.asarray(m, float)
    out = {"rate": math.nan, "intercept": math.nan, "t_lo": math.nan, "t_hi": math.nan,
           "m_lo": lo * (m[-1] if len(m) else 0.0), "m_hi": hi * (m[-1] if len(m) else 0.0),
           "residual_rms": math.nan, "residual_rel": math.nan, "n_points": 0}
    if len(m) < 3 or not m[-1] > 0:
        return out
    M = m[-1]
    sel = (m >= lo * M) & (m <= hi * M)
    n = int(sel.sum())
    out["n_points"] = n
    if n < 3:
        return out
    ts, ms = t[sel], m[sel]
    if np.ptp(ts) <= 0:
        return out
    A = np.stack([ts, np.ones_like(ts)], axis=1)
    (w, c), *_ = np.linalg.lstsq(A, ms, rcond=None)
    res = ms - (w * ts + c)
    rms = float(np.sqrt(np.mean(res ** 2)))
    out.update(rate=float(w), intercept=float(c), t_lo=float(ts[0]), t_hi=float(ts[-1]), residual_rms=rms,
               residual_rel=rms / max(float(np.ptp(ms)), 1e-300))
    return out


def bulk_density(pos, mass, box_lo, box_hi) -> tuple[float, int]:
    """(mass of the particles whose centres are inside [box_lo, box_hi]) / box volume, and
    their number."""
    pos = np.asarray(pos, float).reshape(-1, 3)
    lo = np.asarray(box_lo, float)
    hi = np.asarray(box_hi, float)
    vol = float(np.prod(hi - lo))
    if not vol > 0:
        return math.nan, 0
    inside = np.all((pos >= lo) & (pos < hi), axis=1)
    return float(np.asarray(mass, float)[inside].sum()) / vol, int(inside.sum())


def _bin_tops(pos, x0: float, x1: float, bin_width: float):
    """Per x bin of [x0, x1) (width about ``bin_width``): the highest particle centre (-inf in an
    empty bin), with each particle's bin index and whether it lies in the range."""
    nb = max(1, int((x1 - x0) / bin_width))
    k = np.floor((pos[:, 0] - x0) / (x1 - x0) * nb).astype(np.int64)
    ok = (k >= 0) & (k < nb)
    top = np.full(nb, -np.inf)
    np.maximum.at(top, k[ok], pos[ok, 1])
    return top, k, ok


def surface_height(pos, x0: float, x1: float, bin_width: float) -> float:
    """Height of the free surface: the median over x bins of [x0, x1) of the highest particle
    centre in each (non-empty) bin; NaN without particles."""
    pos = np.asarray(pos, float).reshape(-1, 3)
    if not len(pos):
        return math.nan
    top, _, _ = _bin_tops(pos, x0, x1, bin_width)
    top = top[np.isfinite(top)]
    return float(np.median(top)) if len(top) else math.nan


def column_bulk_density(pos, mass, x0: float, x1: float, bin_width: float, y0: float, depth: float,
                        margin: float) -> tuple[float, int]:
    """Bulk density of a heap with an uneven surface (a crater over the outlet, heaps in the
    corners): the x range [x0, x1) in bins of ``bin_width``; in each bin the column from
    ``y0`` to ``margin`` below that bin's own highest centre; (mass of the centres in the
    columns) / (their volume, ``depth`` deep).  Returns (kg/m3, particles counted); NaN where no
    column is taller than zero."""
    pos = np.asarray(pos, float).reshape(-1, 3)
    m = np.asarray(mass, float).ravel()
    top, k, ok = _bin_tops(pos, x0, x1, bin_width)
    w = (x1 - x0) / len(top)
    hi = top - margin
    h = np.clip(hi - y0, 0.0, None)
    h[~np.isfinite(h)] = 0.0
    vol = float(h.sum() * w * depth)
    if vol <= 0.0:
        return math.nan, 0
    kk = np.where(ok, k, 0)
    inside = ok & (pos[:, 1] >= y0) & (pos[:, 1] < hi[kk])
    return float(m[inside].sum()) / vol, int(inside.sum())


class VelocityField:
    """Time-averaged, depth-averaged particle velocity on an x-y grid of ``nx`` x ``ny`` cells
    over [x0, x1) x [y0, y1): per cell the sums of v_x, v_y and the number of particle samples.
    ``mean()`` is sum / count (NaN in cells never occupied)."""

    def __init__(self, x0: float, x1: float, y0: float, y1: float, cell: float):
        self.x0, self.y0 = float(x0), float(y0)
        self.nx = max(1, int(round((x1 - x0) / cell)))
        self.ny = max(1, int(round((y1 - y0) / cell)))
        self.dx = (x1 - x0) / self.nx
        self.dy = (y1 - y0) / self.ny
        self.sum_vx = np.zeros((self.ny, self.nx))
        self.sum_vy = np.zeros((self.ny, self.nx))
        self.count = np.zeros((self.ny, self.nx))
        self.n_samples = 0

    @property
    def x(self) -> np.ndarray:
        return self.x0 + (np.arange(self.nx) + 0.5) * self.dx

    @property
    def y(self) -> np.ndarray:
        return self.y0 + (np.arange(self.ny) + 0.5) * self.dy

    def sample(self, pos, vel) -> None:
        pos = np.asarray(pos, float).reshape(-1, 3)
        vel = np.asarray(vel, float).reshape(-1, 3)
        i = np.floor((pos[:, 0] - self.x0) / self.dx).astype(np.int64)
        j = np.floor((pos[:, 1] - self.y0) / self.dy).astype(np.int64)
        ok = (i >= 0) & (i < self.nx) & (j >= 0) & (j < self.ny)
        flat = j[ok] * self.nx + i[ok]
        size = self.nx * self.ny
        self.count += np.bincount(flat, minlength=size).reshape(self.ny, self.nx)
        self.sum_vx += np.bincount(flat, weights=vel[ok, 0], minlength=size).reshape(self.ny, self.nx)
        self.sum_vy += np.bincount(flat, weights=vel[ok, 1], minlength=size).reshape(self.ny, self.nx)
        self.n_samples += 1

    def mean(self) -> tuple[np.ndarray, np.ndarray]:
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.sum_vx / self.count, self.sum_vy / self.count

    def get_state(self) -> dict:
        return {"sum_vx": self.sum_vx.copy(), "sum_vy": self.sum_vy.copy(), "count": self.count.copy(),
                "n_samples": np.int64(self.n_samples)}

    def set_state(self, d: dict) -> None:
        self.sum_vx[...] = d["sum_vx"]
        self.sum_vy[...] = d["sum_vy"]
        self.count[...] = d["count"]
        self.n_samples = int(d["n_samples"])


def channel_boundary(vy_mean, x, xc: float, fraction: float = 0.1) -> dict:
    """Flow-channel boundary of an averaged field ``vy_mean`` (ny, nx) on cell centres ``x``.

    Per row: the centreline speed s_c = -v_y interpolated at ``xc``; walking outwards from the
    centre, the first x where s = -v_y < fraction s_c (linear interpolation between the two
    cells that bracket the crossing; an empty cell counts as s = 0).  Rows where s_c <= 0 or is
    undefined give NaN; a side where the speed never falls below the threshold gives the
    outermost cell centre.  Returns arrays ``centre_speed``, ``x_left``, ``x_right``."""
    vy = np.asarray(vy_mean, float)
    x = np.asarray(x, float)
    ny, nx = vy.shape
    s = np.where(np.isfinite(vy), -vy, 0.0)
    sc = np.full(ny, np.nan)
    xl = np.full(ny, np.nan)
    xr = np.full(ny, np.nan)
    ic = int(np.clip(np.searchsorted(x, xc), 1, nx - 1)) if nx > 1 else 0
    for j in range(ny):
        if not np.isfinite(vy[j]).any():
            continue
        c = float(np.interp(xc, x, s[j])) if nx > 1 else float(s[j, 0])
        if not c > 0:
            continue
        sc[j] = c
        thr = fraction * c
        # right: cells from the first centre at or right of xc
        prev_x, prev_s = xc, c
        xr[j] = x[-1]
        for i in range(ic, nx):
            if s[j, i] < thr:
                f = (prev_s - thr) / (prev_s - s[j, i]) if prev_s != s[j, i] else 0.0
                xr[j] = prev_x + f * (x[i] - prev_x)
                break
            prev_x, prev_s = x[i], s[j, i]
        prev_x, prev_s = xc, c
        xl[j] = x[0]
        for i in range(ic - 1, -1, -1):
            if s[j, i] < thr:
                f = (prev_s - thr) / (prev_s - s[j, i]) if prev_s != s[j, i] else 0.0
                xl[j] = prev_x + f * (x[i] - prev_x)
                break
            prev_x, prev_s = x[i], s[j, i]
    return {"centre_speed": sc, "x_left": xl, "x_right": xr}


def beverloo_rate(b, C: float, k: float, rho_b: float, L: float, d: float, g: float = 9.81):
    """W = C rho_b sqrt(g) L (b - k d)^(3/2) for a slot of width b and length L (0 where b <= k d)."""
    b = np.asarray(b, float)
    return C * rho_b * math.sqrt(g) * L * np.clip(b - k * d, 0.0, None) ** 1.5


def fit_beverloo(b, W, rho_b: float, L: float, d: float, g: float = 9.81) -> dict:
    """Least-squares fit of C and k in W = C rho_b sqrt(g) L (b - k d)^(3/2).

    Started from the exact two-parameter solution of the linearised form
    W^(2/3) = (C rho_b sqrt(g) L)^(2/3) (b - k d) (a straight line in b), then refined by
    ``scipy.optimize.curve_fit`` on W itself.  Returns C, k, their standard errors and the rms
    relative residual."""
    from scipy.optimize import curve_fit

    b = np.asarray(b, float)
    W = np.asarray(W, float)
    ok = np.isfinite(W) & (W > 0)
    b, W = b[ok], W[ok]
    if len(b) < 2:
        raise ValueError("the Beverloo fit needs at least two outlet widths with a positive flow rate")
    A = rho_b * math.sqrt(g) * L
    slope, icpt = np.polyfit(b, W ** (2.0 / 3.0), 1)
    C0 = max(slope, 1e-12) ** 1.5 / A
    k0 = -icpt / max(slope, 1e-12) / d
    if len(b) == 2:
        C, k, sC, sk = C0, k0, math.nan, math.nan
    else:
        def f(bb, C, k):
            return beverloo_rate(bb, C, k, rho_b, L, d, g)

        kmax = (b.min() / d) * (1 - 1e-9)
        p0 = (C0, min(k0, 0.99 * kmax))
        popt, pcov = curve_fit(f, b, W, p0=p0, bounds=([0.0, -10.0], [np.inf, kmax]), maxfev=20000)
        C, k = float(popt[0]), float(popt[1])
        err = np.sqrt(np.diag(pcov)) if np.all(np.isfinite(pcov)) else (math.nan, math.nan)
        sC, sk = float(err[0]), float(err[1])
    rel = (beverloo_rate(b, C, k, rho_b, L, d, g) - W) / W
    return {"C": float(C), "k": float(k), "C_err": sC, "k_err": sk,
            "rms_rel_residual": float(np.sqrt(np.mean(rel ** 2)))}


def channel_velocities(field: VelocityField, row: int, channels: dict) -> dict:
    """Mean v_y of each channel in row ``row`` of a time-averaged :class:`VelocityField`:
    ``channels`` {name: [(x_lo, x_hi), ...]} (a channel may be several intervals, e.g. the left
    and right exterior channels); a cell belongs to a channel when its centre lies strictly
    inside one of its intervals.  Per channel the particle-weighted mean sum(v_y) / count over its
    cells; the cross-sectional mean the same over the cells of all channels; ``relative`` =
    channel mean / cross-sectional mean (NaN where no particle was sampled).  Returns
    {name: {"mean_vy", "relative", "cells", "count"}, "cross_section_mean_vy": ...}."""
    x = field.x
    tot_v = tot_n = 0.0
    out: dict = {}
    for name, spans in channels.items():
        sel = np.zeros(field.nx, bool)
        for a, b in spans:
            sel |= (x > a) & (x < b)
        v = float(field.sum_vy[row, sel].sum())
        n = float(field.count[row, sel].sum())
        tot_v += v
        tot_n += n
        out[name] = {"mean_vy": v / n if n > 0 else math.nan, "cells": int(sel.sum()), "count": n}
    mean = tot_v / tot_n if tot_n > 0 else math.nan
    for name in channels:
        out[name]["relative"] = out[name]["mean_vy"] / mean if mean != 0 else math.nan
    out["cross_section_mean_vy"] = mean
    return out


def centreline_speeds(field: VelocityField, xc: float, heights) -> np.ndarray:
    """Downward centreline speed -v_y of a time-averaged field at each height: the per-row
    centreline speed of :func:`channel_boundary` interpolated linearly between row centres (NaN
    outside the field or where a row has no downward flow)."""
    heights = np.asarray(heights, float)
    if not heights.size:
        return np.zeros(0)
    cs = channel_boundary(field.mean()[1], field.x, xc)["centre_speed"]
    return np.interp(heights, field.y, cs, left=math.nan, right=math.nan)


# ----------------------------------------------------------------------------- chapter-5 profiles
def rows_at_heights(y, values, heights) -> np.ndarray:
    """The rows of a field ``values`` (ny, nx) on row centres ``y`` at each of ``heights``, by
    linear interpolation in y between the two rows around each height (NaN where either of them
    is NaN in that column, or the height lies outside the row centres).  Returns (n_heights, nx)."""
    y = np.asarray(y, float)
    v = np.asarray(values, float)
    h = np.atleast_1d(np.asarray(heights, float))
    out = np.full((len(h), v.shape[1]), np.nan)
    for k, z in enumerate(h):
        if not (y[0] <= z <= y[-1]) or len(y) < 2:
            continue
        j = int(min(np.searchsorted(y, z, side="right") - 1, len(y) - 2))
        f = (z - y[j]) / (y[j + 1] - y[j])
        out[k] = v[j] if f == 0.0 else v[j + 1] if f == 1.0 else (1.0 - f) * v[j] + f * v[j + 1]
    return out


def kinematic_profile(x, v0: float, B: float, z: float):
    """The kinematic model's downward speed v(x) = v0 exp(-x^2 / (4 B z)) at the distance x
    from the centreline, height z above the outlet (Nedderman & Tuzun 1979)."""
    return v0 * np.exp(-np.asarray(x, float) ** 2 / (4.0 * B * z))


def fit_kinematic_B(x, speed, z: float, xc: float, max_rel_err: float = 0.5, min_points: int = 4,
                    min_drop: float = 0.25) -> dict:
    """Fit v(x) = v0 exp(-(x - xc)^2 / (4 B z)) to a downward-speed profile ``speed`` (m/s,
    positive down) across the width at height ``z`` (m above the outlet) by
    ``scipy.optimize.curve_fit`` (parameters v0 and B, m).  Returns B, B_err (one standard
    error), v0, v0_err, the number of points and ``reason``: "" for a meaningful fit, otherwise
    why B is NaN: fewer than ``min_points`` finite points, no downward flow on the centreline
    (largest speed <= 0), z <= 0, the fit failed, its relative error exceeds ``max_rel_err`` (a
    profile too noisy to fix a width), or the fitted curve falls by less than ``min_drop`` of v0
    between the centre and the farthest point (a profile too flat: e.g. plug flow across the
    whole silo, where any large B fits)."""
    from scipy.optimize import curve_fit

    x = np.asarray(x, float) - xc
    s = np.asarray(speed, float)
    ok = np.isfinite(x) & np.isfinite(s)
    x, s = x[ok], s[ok]
    out = {"B": math.nan, "B_err": math.nan, "v0": math.nan, "v0_err": math.nan, "n_points": int(len(x)),
           "reason": ""}
    if len(x) < min_points:
        out["reason"] = f"{len(x)} points (fewer than {min_points})"
        return out
    if not z > 0:
        out["reason"] = f"height {z:g} m is not above the outlet"
        return out
    v0 = float(s[np.argmin(np.abs(x))])
    if not s.max() > 0 or not v0 > 0:
        out["reason"] = "no downward flow at the centreline"
        return out
    # start: the width where the profile falls to half its centre value, w_half^2 = 4 B z ln 2
    above = np.abs(x[s >= 0.5 * v0])
    w_half = max(float(above.max()) if len(above) else 0.0, float(np.min(np.abs(np.diff(np.sort(x))))) or 1e-3)
    B0 = w_half ** 2 / (4.0 * z * math.log(2.0))
    try:
        popt, pcov = curve_fit(lambda xx, a, b: kinematic_profile(xx, a, b, z), x, s, p0=(v0, B0),
                               bounds=([0.0, 1e-12], [np.inf, np.inf]), maxfev=20000)
    except (RuntimeError, ValueError) as e:
        out["reason"] = f"fit failed ({e})"
        return out
    err = np.sqrt(np.diag(pcov)) if np.all(np.isfinite(pcov)) else np.array([math.nan, math.nan])
    out.update(v0=float(popt[0]), v0_err=float(err[0]))
    drop = 1.0 - math.exp(-float(np.max(x ** 2)) / (4.0 * popt[1] * z))
    if drop < min_drop:
        out["reason"] = (f"the fitted profile falls by only {drop:.0%} across the width (below {min_drop:.0%}): "
                         f"too flat to fix B (B = {popt[1]:.3g} m)")
        return out
    if not (np.isfinite(err[1]) and err[1] <= max_rel_err * popt[1]):
        out["reason"] = (f"relative error of B {err[1] / popt[1]:.2g} above {max_rel_err:g} (B = {popt[1]:.3g} m)"
                         if np.isfinite(err[1]) else "no error estimate (singular fit)")
        return out
    out.update(B=float(popt[1]), B_err=float(err[1]))
    return out


def centreline_velocity(pos, vel, xc: float, heights, half_x: float, half_y: float) -> np.ndarray:
    """Instantaneous mean vertical velocity v_y (m/s, up positive) of the particles whose
    centres lie within ``half_x`` of the centreline x = ``xc`` and within ``half_y`` of each of
    ``heights`` (full depth); NaN where no centre lies in the box."""
    pos = np.asarray(pos, float).reshape(-1, 3)
    vel = np.asarray(vel, float).reshape(-1, 3)
    h = np.atleast_1d(np.asarray(heights, float))
    near = np.abs(pos[:, 0] - xc) < half_x
    out = np.full(len(h), np.nan)
    for k, z in enumerate(h):
        sel = near & (np.abs(pos[:, 1] - z) < half_y)
        if sel.any():
            out[k] = float(vel[sel, 1].mean())
    return out


def bed_top(field: VelocityField, share: float = 0.25) -> float:
    """Top of the highest row of a time-averaged field in which every cell holds at least
    ``share`` of the median particle-sample count of the occupied cells (NaN when none): the
    bed that stayed in place over the averaging window, without the rows of the free surface
    that the particles left during it (there the cells at the walls or over the crater are
    empty part of the time and a channel boundary would be found in the empty cells)."""
    c = field.count
    occ = c[c > 0]
    if not occ.size:
        return math.nan
    full = np.nonzero((c >= share * float(np.median(occ))).all(axis=1))[0]
    return float(field.y[full[-1]] + 0.5 * field.dy) if len(full) else math.nan


def profile_measurements(field_all: VelocityField, field_front: VelocityField, xc: float, heights,
                         fraction: float = 0.1) -> dict:
    """The chapter-5 profile measurements of two time-averaged fields over the same grid (the
    depth average and the layer at the front wall): at each height (m above the outlet) the
    vertical velocity across the width (:func:`rows_at_heights` of v_y), the kinematic model's B
    fitted to the downward speed (:func:`fit_kinematic_B`, NaN where not meaningful, with the
    reason), the flow-channel boundary and width there (:func:`channel_boundary` of the depth
    average at ``fraction`` of the centreline speed), and the flow pattern of the depth-averaged
    field (:func:`cfddem.measure.blending.classify_flow_pattern` at the same fraction, over the
    rows up to :func:`bed_top`; "" when it cannot classify, e.g. no sample)."""
    from .blending import classify_flow_pattern

    h = np.asarray(heights, float)
    x, y = field_all.x, field_all.y
    out: dict = {"x": x, "y": y, "heights": h, "n_samples": np.int64(field_all.n_samples)}
    reasons = []
    for name, fld in (("depth", field_all), ("front", field_front)):
        vy = fld.mean()[1]
        prof = rows_at_heights(y, vy, h)
        fits = [fit_kinematic_B(x, -prof[k], float(z), xc) for k, z in enumerate(h)]
        out[name] = {"vy_field": vy, "count": fld.count, "vy": prof,
                     "B": np.array([f["B"] for f in fits]), "B_err": np.array([f["B_err"] for f in fits]),
                     "v0": np.array([f["v0"] for f in fits])}
        reasons += [f"{name} {z * 1e3:g} mm: {f['reason']}" for z, f in zip(h, fits) if f["reason"]]
    vy = field_all.mean()[1]
    cb = channel_boundary(vy, x, xc, fraction)
    xl = rows_at_heights(y, cb["x_left"][:, None], h)[:, 0]
    xr = rows_at_heights(y, cb["x_right"][:, None], h)[:, 0]
    out["channel"] = {"x_left": xl, "x_right": xr, "width": xr - xl, "fraction": float(fraction)}
    pattern, details = "", {}
    H = bed_top(field_all)
    if field_all.n_samples and np.isfinite(vy).any() and math.isfinite(H):
        try:
            fp = classify_flow_pattern(x, y, vy, fill_height=H, fraction=fraction, xc=xc)
            pattern = fp["pattern"]
            details = {k: fp[k] for k in ("h_t", "h_t_over_H", "fill_height", "stagnant_fraction")}
        except ValueError as e:
            reasons.append(f"flow pattern: {e}")
    out["flow_pattern"] = pattern
    out["flow_pattern_details"] = details
    out["@attrs"] = {"B_notes": "; ".join(reasons) or "every fit meaningful",
                     "B": "v(x) = v0 exp(-(x - xc)^2 / (4 B z)), z = height above the outlet (m), B in m; "
                          "NaN where the fit is not meaningful (B_notes)",
                     "vy": "time-averaged vertical velocity (m/s, up positive) across the width at each height"}
    return out
