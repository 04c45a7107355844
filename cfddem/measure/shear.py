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
    sel = (x >= lo - 1e-12 * abs(travel)) & (x <= hi + 1e-12 * abs(travel)) & np.isfinite(s) & np.isfinite(n)
    k = int(sel.sum())
    if k == 0:
        return {"mu": math.nan, "shear_force": math.nan, "normal_force": math.nan, "ratio_std": math.nan,
                "n_samples": 0, "window": (lo, hi)}
    ms, mn = float(s[sel].mean()), float(n[sel].mean())
    return {"mu": ms / mn if mn > 0 else math.nan, "shear_force": ms, "normal_force": mn,
            "ratio_std": float(np.std(s[sel] / n[sel])), "n_samples": k, "window": (lo, hi)}


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
