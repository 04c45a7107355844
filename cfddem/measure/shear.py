"""Shear-cell measurements: bulk (or wall) friction from the shear-force series, the inertial
number of the shear, the lid of glued spheres.

Bulk friction (physics.md §6): with S(x) the shear force (the horizontal force the particles
exert against the moving upper part, ring + lid) at shear displacement x, N the normal force on
the lid and W the weight of the particles above the shear plane,

    mu_bulk = <S> / <N + W>

where <.> is the mean over the samples with x in the steady window [f_lo X, f_hi X] of the total
travel X (default the second half: the peak of a dense sample lies in the first half).
"""

from __future__ import annotations

import math

import numpy as np


def bulk_friction(displacement, shear_force, normal_force, travel: float,
                  window=(0.5, 1.0)) -> dict:
    """``mu`` = mean(shear_force) / mean(normal_force) over the samples with displacement in
    [window[0] travel, window[1] travel]; ``normal_force`` includes the weight above the shear
    plane (the caller adds it).  Also returns the window, the means, the standard deviation of
    the per-sample ratio and the number of samples (mu = nan when there are none)."""
    x = np.asarray(displacement, float).ravel()
    s = np.asarray(shear_force, float).ravel()
    n = np.asarray(normal_force, float).ravel()
    if not (len(x) == len(s) == len(n)):
        raise ValueError("displacement, shear_force and normal_force need the same length")
    lo, hi = float(window[0]) * travel, float(window[1]) * travel
    sel = _in_window(x, s, n, lo, hi, travel)
    k = int(sel.sum())
    if k == 0:
        return {"mu": math.nan, "shear_force": math.nan, "normal_force": math.nan, "ratio_std": math.nan,
                "n_samples": 0, "window": (lo, hi)}
    ms, mn = float(s[sel].mean()), float(n[sel].mean())
    return {"mu": ms / mn if mn > 0 else math.nan, "shear_force": ms, "normal_force": mn,
            "ratio_std": float(np.std(s[sel] / n[sel])), "n_samples": k, "window": (lo, hi)}


def _in_window(x, s, n, lo: float, hi: float, scale: float) -> np.ndarray:
    """The samples with displacement in [lo, hi] (round-off 1e-12 ``scale`` allowed) and finite
    forces."""
    tol = 1e-12 * abs(scale)
    return (x >= lo - tol) & (x <= hi + tol) & np.isfinite(s) & np.isfinite(n)


def window_rise(displacement, shear_force, normal_force, window) -> float:
    """How much the ratio shear_force / normal_force still changes across the steady window
    ``window`` = (lo, hi) (m, as :func:`bulk_friction` returns it): (ratio of the means over the
    window's second half of samples - over its first half) / ratio over the whole window.  Near
    0 at a steady state; NaN with fewer than 4 samples."""
    x = np.asarray(displacement, float).ravel()
    s = np.asarray(shear_force, float).ravel()
    n = np.asarray(normal_force, float).ravel()
    lo, hi = (float(w) for w in np.asarray(window, float)[:2])
    sel = np.flatnonzero(_in_window(x, s, n, lo, hi, hi))
    if len(sel) < 4:
        return math.nan
    s, n = s[sel], n[sel]
    k = len(sel) // 2
    whole = s.mean() / n.mean()
    return float((s[k:].mean() / n[k:].mean() - s[:k].mean() / n[:k].mean()) / whole)


def inertial_number(speed: float, diameter: float, pressure: float, density: float,
                    band_diameters: float = 10.0) -> float:
    """I = gamma_dot d / sqrt(p / rho_p) with gamma_dot = speed / (band_diameters d) (a shear
    band ~10 particle diameters thick, GDR MiDi 2004).  Quasi-static: I << 1e-3."""
    gd = speed / (band_diameters * diameter)
    return gd * diameter / math.sqrt(pressure / density)


def lid_disc(radius: float, sphere_radius: float) -> np.ndarray:
    """Centres (k, 3) in the x-z plane (y = 0) of a hexagonal disc of touching spheres of
    ``sphere_radius`` whose outline stays inside ``radius`` (centres within radius - r)."""
    a = 2.0 * sphere_radius
    rc = radius - sphere_radius
    if rc < 0:
        raise ValueError("lid radius smaller than one sphere")
    nz = int(rc / (a * math.sqrt(3) / 2)) + 1
    nx = int(rc / a) + 2
    pts = []
    for j in range(-nz, nz + 1):
        z = j * a * math.sqrt(3) / 2
        off = 0.5 * a if j % 2 else 0.0
        for i in range(-nx, nx + 1):
            x = i * a + off
            if x * x + z * z <= rc * rc * (1 + 1e-12):
                pts.append((x, 0.0, z))
    return np.array(pts, float)


def slab_solid_fraction(y, volume, y_lo: float, y_hi: float, area: float) -> float:
    """Solid fraction of a horizontal slab y_lo < y < y_hi of a cell of cross-section ``area``
    (m^2): the solid volume of the units (spheres, or clumps at their centre of mass) whose
    centre lies in it, over the slab's volume.  Counting whole units by their centres is exact
    on average for a uniform packing (what crosses the slab's faces inward balances what crosses
    outward); keep the slab a few diameters clear of the floor and the free surface, where the
    packing is not uniform.  NaN for an empty or inverted slab."""
    y = np.asarray(y, float)
    v = np.asarray(volume, float)
    if not y_hi > y_lo or area <= 0.0:
        return math.nan
    sel = (y > y_lo) & (y < y_hi)
    return float(np.sum(v[sel])) / (area * (y_hi - y_lo))
