"""Blending analysis of a silo run with tracers (pure numpy/scipy functions; no engine imports).

Definitions (docs/blending.md "Blending analysis"; spec: shared blending.md §2).  Axes as in
:mod:`cfddem.measure.silo`: x across, y up, the outlet plane at ``y_outlet``.

- :func:`outflow_concentration`: c(t) per sampling interval from the outlet-crossing records
  (time, mass, tracer flag of every particle that crossed): mass fraction and number fraction of
  tracer; an interval without a crossing is NaN (no outflow), not 0.
- :func:`variance_reduction_ratio`: VRR = var(c_in) / var(c_out) over the intervals where both
  series are finite; :func:`vrr_by_recirculation`: the same in windows of one mean residence
  time (N_r = t / t_mean), with the batch input variance f (1 - f) (:func:`batch_input_variance`).
- :func:`rtd_from_residence_times`, :func:`rtd_from_pulse`, :func:`rtd_from_step`: the residence
  time distribution E(theta), F(theta), theta = t / t_mean, with its mean, variance, peak and
  first appearance (:func:`rtd_stats`).
- :func:`release_line`, :func:`release_area`, :func:`advect_tracers`, :func:`virtual_tracer_rtd`:
  the RTD from virtual tracers advected (RK4, bilinear interpolation) through a time-averaged
  velocity field; tracers that stop in stagnant bins are counted and excluded.
- :func:`convolve_rtd`: c_out = c_in * E, the outflow for any input (linear time-invariant silo).
- :func:`classify_flow_pattern`: "mass", "semi-mass" or "internal" from the averaged field and
  the flow-channel boundary (:func:`cfddem.measure.silo.channel_boundary`).
- :func:`by_recirculation`: a sampled series (bulk density) against N_r, with window means.
- :func:`blending_arrays`: the results-file tree of the contract (``/measurements/blending``,
  ``/measurements/rtd``, ``/measurements/flow_pattern``).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import cumulative_trapezoid, trapezoid
from scipy.interpolate import RegularGridInterpolator
from scipy.optimize import isotonic_regression

from .silo import channel_boundary

FLOW_PATTERNS = ("mass", "semi-mass", "internal")


# ----------------------------------------------------------------- outflow concentration
def outflow_concentration(t_cross, mass, tracer, dt: float, t_start: float = 0.0,
                          t_end: float | None = None) -> dict:
    """Tracer concentration of the outflow per sampling interval.

    ``t_cross``, ``mass``, ``tracer``: one entry per outlet crossing (time, particle mass,
    tracer flag: true/non-zero for a tracer particle).  Intervals
    [t_start + k dt, t_start + (k + 1) dt) cover [t_start, t_end] (t_end: the last crossing
    when not given; a crossing at exactly t_end goes into the last interval; crossings outside
    are ignored).  Returns ``time`` (interval centres), ``edges``, ``c_mass`` = (tracer mass) /
    (mass) and ``c_number`` = (tracer count) / (count) per interval (NaN where nothing crossed),
    ``count`` and ``mass`` (per interval)."""
    t = np.asarray(t_cross, float).ravel()
    m = np.asarray(mass, float).ravel()
    tr = np.asarray(tracer).ravel().astype(bool)
    if not (len(t) == len(m) == len(tr)):
        raise ValueError(f"crossing records of unequal length: time {len(t)}, mass {len(m)}, tracer {len(tr)}")
    if not dt > 0:
        raise ValueError(f"sampling interval dt must be > 0, got {dt}")
    if t_end is None:
        t_end = float(t.max()) if len(t) else t_start + dt
    n = max(1, int(math.ceil((t_end - t_start) / dt - 1e-9)))
    edges = t_start + dt * np.arange(n + 1)
    k = np.floor((t - t_start) / dt).astype(np.int64)
    k[(k == n) & (t <= t_end)] = n - 1
    ok = (k >= 0) & (k < n) & (t >= t_start)
    k, m, tr = k[ok], m[ok], tr[ok]
    count = np.bincount(k, minlength=n).astype(float)
    n_tr = np.bincount(k, weights=tr.astype(float), minlength=n)
    m_all = np.bincount(k, weights=m, minlength=n)
    m_tr = np.bincount(k, weights=m * tr, minlength=n)
    with np.errstate(invalid="ignore", divide="ignore"):
        c_mass = np.where(m_all > 0, m_tr / m_all, np.nan)
        c_number = np.where(count > 0, n_tr / count, np.nan)
    return {"time": 0.5 * (edges[:-1] + edges[1:]), "edges": edges, "c_mass": c_mass,
            "c_number": c_number, "count": count, "mass": m_all}


# ----------------------------------------------------------------- variance reduction
def block_concentration(time, mass_by_label, k: int, tracer: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Tracer mass fraction of the outflow in blocks of ``k`` record intervals: ``time`` (n,)
    interval ends, ``mass_by_label`` (n, labels) the mass of each label that crossed per
    interval.  Returns the blocks' mean time and their concentration (NaN where nothing crossed);
    a last incomplete block is left out.  With few bodies per interval the concentration of
    one interval is 0 or 1 more often than not: blocks give a series that can be differentiated
    (a step response) or read by eye."""
    t = np.asarray(time, float).ravel()
    M = np.asarray(mass_by_label, float).reshape(len(t), -1)
    k = max(1, int(k))
    nb = len(t) // k
    Mb = M[: nb * k].reshape(nb, k, -1).sum(axis=1)
    tot = Mb.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.where(tot > 0, Mb[:, tracer] / np.where(tot > 0, tot, 1.0), np.nan)
    return t[: nb * k].reshape(nb, k).mean(axis=1), c


def variance_reduction_ratio(c_in, c_out) -> float:
    """VRR = var(c_in) / var(c_out) (population variances, ddof 0) over the intervals where
    both series are finite: an interval without outflow (NaN) is left out of both, so the two
    variances are taken over the same intervals.  ``c_in`` may also be a scalar: the input
    variance itself (a batch, :func:`batch_input_variance`), then only c_out's NaN are
    dropped.  inf when var(c_out) = 0 (a perfect blend), NaN with fewer than 2 intervals."""
    co = np.asarray(c_out, float).ravel()
    if np.ndim(c_in) == 0:
        co = co[np.isfinite(co)]
        var_in = float(c_in)
    else:
        ci = np.asarray(c_in, float).ravel()
        if len(ci) != len(co):
            raise ValueError(f"c_in ({len(ci)}) and c_out ({len(co)}) must be on the same time base")
        ok = np.isfinite(ci) & np.isfinite(co)
        ci, co = ci[ok], co[ok]
        var_in = float(np.var(ci)) if len(ci) >= 2 else math.nan
    if len(co) < 2:
        return math.nan
    var_out = float(np.var(co))
    if var_out == 0.0:
        return math.inf if var_in > 0 else math.nan
    return var_in / var_out


def batch_input_variance(fraction: float) -> float:
    """Input variance of a batch of tracer volume fraction f = V_b / V_s: f (1 - f).

    The unblended reference is the silo's initial layering seen at the outlet without any
    mixing: the outflow is pure tracer (c = 1) while the batch passes and free of tracer (c = 0)
    otherwise, for a fraction f of the discharge, i.e. a two-valued series of mean f and
    variance f (1 - f), whatever the number of sub-layers (they change how often c switches,
    not its variance)."""
    f = float(fraction)
    if not 0.0 < f < 1.0:
        raise ValueError(f"batch fraction must lie in (0, 1), got {f}")
    return f * (1.0 - f)


def recirculation_windows(time, t_mean: float, t_start: float = 0.0) -> list[np.ndarray]:
    """Index masks of the complete windows [t_start + k t_mean, t_start + (k + 1) t_mean) that
    the sample times ``time`` cover (a window counts when the last sample reaches its end
    within half a sampling interval)."""
    t = np.asarray(time, float).ravel()
    if not t_mean > 0:
        raise ValueError(f"t_mean must be > 0, got {t_mean}")
    if len(t) == 0:
        return []
    half = 0.5 * float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    n = int(math.floor((t[-1] + half - t_start) / t_mean + 1e-9))
    return [(t >= t_start + k * t_mean) & (t < t_start + (k + 1) * t_mean) for k in range(max(n, 0))]


def vrr_by_recirculation(time, c_out, t_mean: float, c_in=None, batch_fraction: float | None = None,
                         t_start: float = 0.0, count=None) -> dict:
    """VRR in successive windows of one mean residence time: window k covers
    N_r = (t - t_start) / t_mean in [k, k + 1); reported at its end, ``n_r`` = k + 1.

    The input variance is var(c_in) over the same window (a continuous input: ``c_in`` on the
    same time base) or f (1 - f) for a batch (``batch_fraction`` f).  With ``count`` (particles
    per interval, from :func:`outflow_concentration`) also ``var_sampling``: the mean binomial
    counting variance c (1 - c) / n of the window, the part of var(c_out) that a finite number
    of particles per interval gives even for a perfect blend (a VRR near var_in / var_sampling
    is limited by counting, not by blending)."""
    if (c_in is None) == (batch_fraction is None):
        raise ValueError("give either c_in (continuous input) or batch_fraction (batch)")
    t = np.asarray(time, float).ravel()
    co = np.asarray(c_out, float).ravel()
    var_batch = batch_input_variance(batch_fraction) if batch_fraction is not None else None
    ci = None if c_in is None else np.asarray(c_in, float).ravel()
    cnt = None if count is None else np.asarray(count, float).ravel()
    rows = []
    for w in recirculation_windows(t, t_mean, t_start):
        if var_batch is not None:
            v = variance_reduction_ratio(var_batch, co[w])
            ok = np.isfinite(co[w])
            var_in = var_batch
        else:
            v = variance_reduction_ratio(ci[w], co[w])
            ok = np.isfinite(co[w]) & np.isfinite(ci[w])
            var_in = float(np.var(ci[w][ok])) if ok.sum() >= 2 else math.nan
        cw = co[w][ok]
        var_out = float(np.var(cw)) if len(cw) >= 2 else math.nan
        samp = math.nan
        if cnt is not None and len(cw):
            nw = cnt[w][ok]
            samp = float(np.mean(cw * (1.0 - cw) / np.maximum(nw, 1.0)))
        rows.append((v, var_in, var_out, samp, int(ok.sum())))
    arr = np.array(rows, float).reshape(-1, 5)
    return {"n_r": np.arange(1, len(arr) + 1, dtype=float), "vrr": arr[:, 0], "var_in": arr[:, 1],
            "var_out": arr[:, 2], "var_sampling": arr[:, 3], "n_intervals": arr[:, 4].astype(np.int64)}


def by_recirculation(time, values, t_mean: float, t_start: float = 0.0) -> dict:
    """A sampled series (e.g. the bulk density of the flowing material) against the number of
    recirculations: ``n_r`` = (t - t_start) / t_mean per sample with the ``values``, and the
    mean and standard deviation of the finite values in each complete window of one t_mean
    (``window_n_r`` = k + 1 at the window's end, ``window_mean``, ``window_std``)."""
    t = np.asarray(time, float).ravel()
    v = np.asarray(values, float).ravel()
    if len(t) != len(v):
        raise ValueError(f"time ({len(t)}) and values ({len(v)}) differ in length")
    means, stds = [], []
    for w in recirculation_windows(t, t_mean, t_start):
        x = v[w][np.isfinite(v[w])]
        means.append(float(x.mean()) if len(x) else math.nan)
        stds.append(float(x.std()) if len(x) else math.nan)
    return {"n_r": (t - t_start) / t_mean, "values": v, "window_n_r": np.arange(1, len(means) + 1, dtype=float),
            "window_mean": np.array(means), "window_std": np.array(stds)}


# ----------------------------------------------------------------- residence time distribution
def rtd_stats(theta, E, t_mean: float, t_d: float | None = None) -> dict:
    """Moments of an RTD given on a grid: ``mean`` = int theta E dtheta, ``variance`` =
    int (theta - mean)^2 E dtheta (trapezoid rule; E normalised by its integral ``norm``),
    ``peak`` = theta of the largest E, ``theta_s`` = the first theta with E > 0 (first
    appearance), ``t_s`` = theta_s t_mean, ``t_s_over_t_d`` = t_s / t_d (t_d, the total discharge
    time, defaults to t_mean: the time the fixed outflow takes to pass the silo content once)."""
    th = np.asarray(theta, float)
    e = np.asarray(E, float)
    norm = float(trapezoid(e, th))
    mean = float(trapezoid(th * e, th)) / norm if norm > 0 else math.nan
    var = float(trapezoid((th - mean) ** 2 * e, th)) / norm if norm > 0 else math.nan
    pos = np.nonzero(e > 0)[0]
    theta_s = float(th[pos[0]]) if len(pos) else math.nan
    return _stats(mean, var, float(th[int(np.argmax(e))]) if len(e) else math.nan, theta_s, t_mean, t_d, norm)


def _stats(mean, var, peak, theta_s, t_mean, t_d, norm) -> dict:
    t_d = t_mean if t_d is None else t_d
    return {"mean": mean, "variance": var, "peak": peak, "theta_s": theta_s, "t_s": theta_s * t_mean,
            "t_d": float(t_d), "t_s_over_t_d": theta_s * t_mean / t_d, "t_mean": float(t_mean), "norm": norm}


def rtd_from_residence_times(t_res, t_mean: float | None = None, weights=None, dtheta: float = 0.05,
                             theta_max: float | None = None, t_d: float | None = None) -> dict:
    """RTD from individual residence times (tracer particles of a pulse, virtual tracers).

    E(theta) is the weighted histogram density on bins of width ``dtheta`` from 0 to
    ``theta_max`` (default: one empty bin past the bin of the largest theta, so that F ends at 1),
    ``theta`` the bin centres, F the integral of E at the bin centres.  t_mean defaults to the
    weighted mean residence time.  The moments come from the samples themselves, not from the histogram: ``mean`` and
    ``variance`` of theta (weighted), ``theta_s`` = the smallest theta, ``peak`` = the weighted
    mean theta of the samples in the fullest bin (this one depends on ``dtheta``)."""
    t = np.asarray(t_res, float).ravel()
    w = np.ones_like(t) if weights is None else np.asarray(weights, float).ravel()
    if len(w) != len(t):
        raise ValueError(f"weights ({len(w)}) and residence times ({len(t)}) differ in length")
    ok = np.isfinite(t) & np.isfinite(w) & (w > 0)
    t, w = t[ok], w[ok]
    if not len(t):
        raise ValueError("no residence times with a positive weight")
    W = float(w.sum())
    if t_mean is None:
        t_mean = float(np.sum(w * t) / W)
    th = t / t_mean
    if theta_max is None:
        theta_max = (math.floor(th.max() / dtheta) + 2) * dtheta
    nb = max(1, int(round(theta_max / dtheta)))
    edges = dtheta * np.arange(nb + 1)
    h, _ = np.histogram(th, bins=edges, weights=w)
    E = h / (W * dtheta)
    F = np.cumsum(E) * dtheta - 0.5 * E * dtheta
    mean = float(np.sum(w * th) / W)
    var = float(np.sum(w * (th - mean) ** 2) / W)
    kb = int(np.argmax(E))
    inb = np.clip(np.searchsorted(edges, th, side="right") - 1, 0, nb - 1) == kb
    peak = float(np.sum(w[inb] * th[inb]) / np.sum(w[inb]))
    out = {"theta": 0.5 * (edges[:-1] + edges[1:]), "E": E, "F": F}
    out.update(_stats(mean, var, peak, float(th.min()), t_mean, t_d, float(E.sum() * dtheta)))
    return out


def _fill_gaps(time, c) -> np.ndarray:
    """NaN intervals (no outflow) filled by linear interpolation between their finite
    neighbours (the first and last finite values extended to the ends)."""
    c = np.asarray(c, float)
    ok = np.isfinite(c)
    if not ok.any():
        raise ValueError("the concentration series has no finite value")
    return np.interp(time, time[ok], c[ok]) if not ok.all() else c


def rtd_from_pulse(time, c, t_mean: float | None = None, t_inject: float = 0.0,
                   t_d: float | None = None) -> dict:
    """RTD from the outflow concentration after a tracer pulse injected at ``t_inject``:
    E(t) = c(t) / int c dt (valid for a constant outflow rate, which the feeder holds), theta =
    (t - t_inject) / t_mean, E(theta) = t_mean E(t), F the running trapezoid integral of E.
    NaN intervals are filled by linear interpolation; samples before t_inject are dropped.
    t_mean defaults to the first moment int t E dt of the record (the record must cover the
    whole pulse for that); given (silo content / outflow rate), ``mean`` != 1 shows dead
    volume (< 1) or a truncated record."""
    t = np.asarray(time, float).ravel() - t_inject
    keep = t >= 0
    t = t[keep]
    cc = _fill_gaps(t, np.asarray(c, float).ravel()[keep])
    area = float(trapezoid(cc, t))
    if not area > 0:
        raise ValueError("the pulse response integrates to zero: no tracer reached the outlet")
    Et = cc / area
    if t_mean is None:
        t_mean = float(trapezoid(t * Et, t))
    th = t / t_mean
    E = Et * t_mean
    out = {"theta": th, "E": E, "F": cumulative_trapezoid(E, th, initial=0.0)}
    out.update(rtd_stats(th, E, t_mean, t_d))
    return out


def rtd_from_step(time, c, c_step: float = 1.0, c_before: float = 0.0, t_mean: float | None = None,
                  t_inject: float = 0.0, t_d: float | None = None, monotone: bool = True) -> dict:
    """RTD from the outflow concentration after a step of the input from ``c_before`` to
    ``c_step`` at ``t_inject``: F(theta) = (c - c_before) / (c_step - c_before) (the normalised
    outflow concentration), E = dF/dtheta (``np.gradient``, second order), theta =
    (t - t_inject) / t_mean.  NaN intervals are filled by linear interpolation.  t_mean defaults
    to int (1 - F) dt from t_inject (where F = 0) over the record (the record must reach F = 1
    for that).  The moments are
    those of E (:func:`rtd_stats`).  ``monotone``: F is replaced by its least-squares
    non-decreasing fit in [0, 1] (``scipy.optimize.isotonic_regression``) before E is taken:
    a cumulative distribution cannot fall, and the counting noise of a particle-resolved
    response would otherwise give an E with negative lobes (whose clipping inflates it)."""
    if c_step == c_before:
        raise ValueError("a step needs c_step != c_before")
    t = np.asarray(time, float).ravel() - t_inject
    keep = t >= 0
    t = t[keep]
    F = (_fill_gaps(t, np.asarray(c, float).ravel()[keep]) - c_before) / (c_step - c_before)
    if monotone and len(F) > 1:
        F = np.clip(isotonic_regression(F).x, 0.0, 1.0)
    if t_mean is None:  # F = 0 at the injection itself (no residence time is zero)
        t0 = [0.0] if t[0] > 0 else []
        t_mean = float(trapezoid(1.0 - np.concatenate([t0, F]), np.concatenate([t0, t])))
    th = t / t_mean
    E = np.gradient(F, th)
    out = {"theta": th, "E": E, "F": F}
    out.update(rtd_stats(th, np.clip(E, 0.0, None), t_mean, t_d))
    return out


# ----------------------------------------------------------------- virtual tracers
def _cell_edges(c: np.ndarray) -> tuple[float, float, float]:
    d = float(c[1] - c[0]) if len(c) > 1 else 1.0
    return float(c[0] - 0.5 * d), float(c[-1] + 0.5 * d), d


def release_line(x, y_release: float, n: int) -> np.ndarray:
    """``n`` tracer start points (n, 2) evenly spread over a horizontal line at ``y_release``
    across the whole width of the bins (centres of n equal segments of [x_0 - dx/2, x_-1 + dx/2])."""
    x = np.asarray(x, float)
    lo, hi, _ = _cell_edges(x)
    xs = lo + (np.arange(n) + 0.5) * (hi - lo) / n
    return np.stack([xs, np.full(n, float(y_release))], axis=1)


def release_area(x, y, vx, vy, n: int, y_max: float | None = None) -> np.ndarray:
    """About ``n`` tracer start points (m, 2) evenly spread over the filled area: a k x k lattice
    in every bin that holds a velocity (finite vx and vy) and whose centre lies at or below
    ``y_max`` (the fill height: leaves out particles falling onto the heap), k = ceil(sqrt(n / bins))."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    filled = np.isfinite(np.asarray(vx, float)) & np.isfinite(np.asarray(vy, float))
    if y_max is not None:
        filled &= (y <= y_max)[:, None]
    jj, ii = np.nonzero(filled)
    if not len(jj):
        raise ValueError("no filled bin to release tracers in")
    _, _, dx = _cell_edges(x)
    _, _, dy = _cell_edges(y)
    k = max(1, int(math.ceil(math.sqrt(n / len(jj)))))
    off = (np.arange(k) + 0.5) / k - 0.5
    ox, oy = np.meshgrid(off * dx, off * dy)
    px = (x[ii][:, None] + ox.ravel()[None, :]).ravel()
    py = (y[jj][:, None] + oy.ravel()[None, :]).ravel()
    return np.stack([px, py], axis=1)


def advect_tracers(x, y, vx, vy, start, y_outlet: float, stagnant_speed: float | None = None,
                   dt: float | None = None, t_max: float | None = None, courant: float = 0.25) -> dict:
    """Advect virtual tracers through a time-averaged 2-D velocity field until they cross the
    outlet plane y = ``y_outlet`` downwards.

    ``x`` (nx,), ``y`` (ny,): bin centres (uniform); ``vx``, ``vy`` (ny, nx) the averaged velocity
    (NaN in bins never occupied: taken as 0, not moving).  The velocity between centres is
    bilinear (``RegularGridInterpolator``), beyond the outermost centres that of the outermost
    bins; positions are kept inside the bins' x range (the side walls).  Classical RK4 with a
    fixed step ``dt`` (default ``courant`` min(dx, dy) / the largest speed); the crossing time is
    interpolated linearly inside the step that crosses.

    A tracer whose interpolated speed is below ``stagnant_speed`` (default 1 % of the largest
    speed of the field), at release or on its way, is stuck in a stagnant zone: it stops there
    and is counted in ``n_stuck``.  One still moving at ``t_max`` (default
    2 (y_top - y_outlet) / stagnant_speed, twice the time to fall the field's height at the
    stagnant speed) is counted in ``n_late``.  Returns ``t_exit`` (NaN unless arrived), the
    masks ``arrived``, ``stuck``, ``late``, the counts, ``final`` positions and the settings."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if len(x) < 2 or len(y) < 2:
        raise ValueError("the velocity field needs at least 2 x 2 bins")
    ux = np.nan_to_num(np.asarray(vx, float), nan=0.0)
    uy = np.nan_to_num(np.asarray(vy, float), nan=0.0)
    if ux.shape != (len(y), len(x)) or uy.shape != ux.shape:
        raise ValueError(f"vx, vy must have shape (ny, nx) = ({len(y)}, {len(x)})")
    vmax = float(np.sqrt(ux ** 2 + uy ** 2).max())
    if not vmax > 0:
        raise ValueError("the velocity field is zero everywhere")
    if stagnant_speed is None:
        stagnant_speed = 0.01 * vmax
    xlo, xhi, dx = _cell_edges(x)
    _, ytop, dy = _cell_edges(y)
    if dt is None:
        dt = courant * min(dx, dy) / vmax
    if t_max is None:
        t_max = 2.0 * (ytop - y_outlet) / stagnant_speed
    interp = RegularGridInterpolator((y, x), np.stack([uy, ux], axis=-1), method="linear")
    lo = np.array([y[0], x[0]])
    hi = np.array([y[-1], x[-1]])

    def vel(p):  # p (m, 2) as (x, y) -> (m, 2) velocity (vx, vy)
        v = interp(np.clip(p[:, ::-1], lo, hi))
        return v[:, ::-1]

    p = np.array(start, float).reshape(-1, 2)
    n = len(p)
    t_exit = np.full(n, np.nan)
    arrived = p[:, 1] <= y_outlet
    t_exit[arrived] = 0.0
    stuck = ~arrived & (np.hypot(*vel(p).T) < stagnant_speed)
    active = ~arrived & ~stuck
    t = 0.0
    while active.any() and t < t_max:
        idx = np.nonzero(active)[0]
        q = p[idx]
        k1 = vel(q)
        k2 = vel(q + 0.5 * dt * k1)
        k3 = vel(q + 0.5 * dt * k2)
        k4 = vel(q + dt * k3)
        qn = q + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        qn[:, 0] = np.clip(qn[:, 0], xlo, xhi)
        out = qn[:, 1] <= y_outlet
        if out.any():
            f = (q[out, 1] - y_outlet) / np.maximum(q[out, 1] - qn[out, 1], 1e-300)
            t_exit[idx[out]] = t + f * dt
            arrived[idx[out]] = True
        slow = ~out & (np.hypot(*vel(qn).T) < stagnant_speed)
        stuck[idx[slow]] = True
        p[idx] = qn
        active[idx[out | slow]] = False
        t += dt
    late = active
    return {"t_exit": t_exit, "arrived": arrived, "stuck": stuck, "late": late, "final": p,
            "n_released": n, "n_arrived": int(arrived.sum()), "n_stuck": int(stuck.sum()),
            "n_late": int(late.sum()), "stagnant_speed": float(stagnant_speed), "dt": float(dt),
            "t_max": float(t_max)}


def virtual_tracer_rtd(x, y, vx, vy, start, y_outlet: float, t_mean: float | None = None,
                       weights="flux", dtheta: float = 0.05, t_d: float | None = None, **advect) -> dict:
    """RTD from virtual tracers: :func:`advect_tracers` from ``start`` (:func:`release_line` or
    :func:`release_area`), then :func:`rtd_from_residence_times` of the arrival times of the
    tracers that arrived (stuck and late tracers excluded, and counted).

    ``weights``: "flux" (default) weighs each tracer by the downward speed at its start point,
    so that a line release stands for the material crossing that line (a tracer pulse carried in
    by the flow): its arrival times give the RTD E used by :func:`convolve_rtd`.  "uniform"
    weighs all tracers alike: for an area release the arrival-time density is then that of the
    silo content present at t = 0 (the washout of a batch; for a steady vessel it is
    (1 - F(theta)) with theta in units of t_mean).  Or an array of weights."""
    start = np.array(start, float).reshape(-1, 2)
    adv = advect_tracers(x, y, vx, vy, start, y_outlet, **advect)
    if isinstance(weights, str):
        if weights == "flux":
            vyi = RegularGridInterpolator((np.asarray(y, float), np.asarray(x, float)),
                                          np.nan_to_num(np.asarray(vy, float), nan=0.0), method="linear")
            pts = np.clip(start[:, ::-1], [y[0], x[0]], [y[-1], x[-1]])
            w = np.clip(-vyi(pts), 0.0, None)
        elif weights == "uniform":
            w = np.ones(len(start))
        else:
            raise ValueError(f"weights must be 'flux', 'uniform' or an array, got {weights!r}")
    else:
        w = np.asarray(weights, float).ravel()
    a = adv["arrived"] & (w > 0)
    if not a.any():
        raise ValueError(f"no virtual tracer reached the outlet ({adv['n_stuck']} stuck, {adv['n_late']} late "
                         f"of {adv['n_released']})")
    out = rtd_from_residence_times(adv["t_exit"][a], t_mean, w[a], dtheta=dtheta, t_d=t_d)
    out.update({k: adv[k] for k in ("n_released", "n_arrived", "n_stuck", "n_late", "stagnant_speed", "dt")})
    out["t_exit"] = adv["t_exit"]
    out["stuck"] = adv["stuck"]
    return out


# ----------------------------------------------------------------- convolution
def convolve_rtd(time, c_in, theta, E, t_mean: float, c_before: float = 0.0) -> np.ndarray:
    """Outflow concentration predicted from the input and the RTD (the silo as a linear
    time-invariant system): c_out(t) = int_0^inf c_in(t - tau) E_t(tau) dtau with
    E_t(tau) = E(tau / t_mean) / t_mean.

    ``time``: uniform samples (step dt) of the input ``c_in`` (finite); before the first sample the
    input is ``c_before``.  E is interpolated linearly onto the lags tau_j = j dt (below the
    first given theta: E's first value; beyond the last: 0).  Then, with the trapezoid rule over
    the lags 0..t_k - t_0,
    c_out[k] = dt sum_j w_j c_in[k - j] E_t(tau_j) + c_before (1 - int_0^(t_k - t_0) E_t dtau),
    w_0 = w_k = 1/2, else 1 (the second term: the input before the record).  E should integrate
    to 1 over the given theta (a truncated E loses the missing tail)."""
    t = np.asarray(time, float).ravel()
    ci = np.asarray(c_in, float).ravel()
    if len(t) != len(ci) or len(t) < 2:
        raise ValueError("time and c_in need the same length, at least 2")
    if not np.isfinite(ci).all():
        raise ValueError("c_in must be finite (fill or drop the intervals without a value)")
    dt = float(t[1] - t[0])
    if not dt > 0 or not np.allclose(np.diff(t), dt, rtol=1e-6, atol=0.0):
        raise ValueError("convolve_rtd needs uniformly spaced times")
    th = np.asarray(theta, float).ravel()
    e = np.asarray(E, float).ravel()
    lag = np.arange(len(t)) * dt / t_mean
    Et = np.interp(lag, th, e, left=e[0], right=0.0) / t_mean
    n = len(t)
    full = np.convolve(ci, Et)[:n] * dt
    full -= 0.5 * dt * (ci * Et[0] + ci[0] * Et)
    full[0] = 0.0
    Ft = cumulative_trapezoid(Et, dx=dt, initial=0.0)
    return full + c_before * (1.0 - Ft)


# ----------------------------------------------------------------- flow pattern
def classify_flow_pattern(x, y, vy, fill_height: float | None = None, fraction: float = 0.05,
                          y_outlet_region: float = 0.0, xc: float | None = None,
                          wall_tolerance: float | None = None, semi_mass_max: float = 0.5) -> dict:
    """Flow pattern of a time-averaged field ``vy`` (ny, nx) on bin centres ``x``, ``y``.

    The flow-channel boundary of each row is where the downward speed falls to ``fraction`` of
    the centreline speed (:func:`cfddem.measure.silo.channel_boundary`).  Rows analysed: centres
    above ``y_outlet_region`` (the converging zone just above the outlet, left out) and at or
    below the fill height H (default: the top of the highest row whose bins are at least half
    filled).  A row's channel reaches the side walls when its boundary lies within
    ``wall_tolerance`` (default one bin width) of the outermost bin centres on both sides.

    The transition height h_t is the bottom of the lowest row from which every row up to H
    reaches the walls (NaN when the top row does not).  Classes:

    - "mass": every analysed row reaches the walls (the channel spans the full width at every
      height above the outlet region);
    - "semi-mass": h_t / H <= ``semi_mass_max`` (0.5): stagnant zones only in the lower part,
      at the bottom corners;
    - "internal": the channel is narrower than the silo up to the free surface (h_t NaN), or
      reaches the walls only above half the fill height.

    Returns ``pattern``, ``h_t``, ``h_t_over_H``, ``fill_height``, ``stagnant_fraction`` (the
    filled area of the analysed rows outside the channel, over the filled area of those rows),
    ``width_fraction`` (channel width / silo width per row, NaN outside the analysed rows) and
    the boundary (``x_left``, ``x_right``, ``centre_speed``)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    vy = np.asarray(vy, float)
    if vy.shape != (len(y), len(x)):
        raise ValueError(f"vy must have shape (ny, nx) = ({len(y)}, {len(x)})")
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction must lie in (0, 1), got {fraction}")
    xlo, xhi, dx = _cell_edges(x)
    _, _, dy = _cell_edges(y)
    filled = np.isfinite(vy)
    if fill_height is None:
        rows = np.nonzero(filled.mean(axis=1) >= 0.5)[0]
        if not len(rows):
            raise ValueError("no row of the field is at least half filled")
        fill_height = float(y[rows[-1]] + 0.5 * dy)
    xc = 0.5 * (xlo + xhi) if xc is None else float(xc)
    tol = dx if wall_tolerance is None else float(wall_tolerance)
    cb = channel_boundary(vy, x, xc, fraction)
    xl, xr = cb["x_left"], cb["x_right"]
    rows = np.nonzero((y > y_outlet_region) & (y <= fill_height))[0]
    if not len(rows):
        raise ValueError(f"no bin row between y_outlet_region = {y_outlet_region} and the fill height {fill_height}")
    with np.errstate(invalid="ignore"):
        spans = (xl <= x[0] + tol) & (xr >= x[-1] - tol)  # NaN (no centreline flow) -> False
    width = np.full(len(y), np.nan)
    width[rows] = (np.clip(xr[rows], xlo, xhi) - np.clip(xl[rows], xlo, xhi)) / (xhi - xlo)
    inside = (x[None, :] >= xl[:, None]) & (x[None, :] <= xr[:, None])  # False in NaN rows
    region = filled[rows]
    stagnant = float((region & ~inside[rows]).sum() / max(region.sum(), 1))
    sp = spans[rows]
    if sp.all():
        pattern, j0 = "mass", rows[0]
    elif not sp[-1]:
        pattern, j0 = "internal", None
    else:
        j0 = rows[np.nonzero(~sp)[0][-1] + 1]
        pattern = None
    h_t = math.nan if j0 is None else float(y[j0] - 0.5 * dy)
    if pattern is None:
        pattern = "semi-mass" if h_t / fill_height <= semi_mass_max else "internal"
    return {"pattern": pattern, "h_t": h_t, "h_t_over_H": h_t / fill_height, "fill_height": float(fill_height),
            "stagnant_fraction": stagnant, "width_fraction": width, "fraction": float(fraction),
            "x_left": xl, "x_right": xr, "centre_speed": cb["centre_speed"]}


# ----------------------------------------------------------------- results-file tree
def blending_arrays(time, concentration_out, vrr: float, rtd: dict | None = None, flow_pattern=None,
                    attrs: dict | None = None) -> dict:
    """The contract's measurements as the nested dict that
    ``ResultsFile.write_measurements(None, tree)`` writes under ``/measurements``:
    ``blending/time``, ``blending/concentration_out``, ``blending/vrr`` (scalar), with ``rtd``
    (a dict with ``theta``, ``E``, ``F``, e.g. from :func:`rtd_from_step`) ``rtd/theta``,
    ``rtd/E``, ``rtd/F``, and with ``flow_pattern`` (a class name or the dict of
    :func:`classify_flow_pattern`) ``flow_pattern``.  ``attrs`` (e.g. t_mean, the window) go on
    the ``blending`` group."""
    t = np.asarray(time, float).ravel()
    c = np.asarray(concentration_out, float).ravel()
    if len(t) != len(c):
        raise ValueError(f"time ({len(t)}) and concentration_out ({len(c)}) differ in length")
    tree: dict = {"blending": {"time": t, "concentration_out": c, "vrr": np.float64(vrr)}}
    if attrs:
        tree["blending"]["@attrs"] = dict(attrs)
    if rtd is not None:
        tree["rtd"] = {k: np.asarray(rtd[k], float) for k in ("theta", "E", "F")}
    if flow_pattern is not None:
        name = flow_pattern["pattern"] if isinstance(flow_pattern, dict) else str(flow_pattern)
        if name not in FLOW_PATTERNS:
            raise ValueError(f"flow_pattern must be one of {FLOW_PATTERNS}, got {name!r}")
        tree["flow_pattern"] = name
    return tree
