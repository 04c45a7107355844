"""Coarse graining: continuum fields (density, velocity, stress) from particles and contacts.

The method of Goldhirsch (Granular Matter 12, 2010), Weinhart, Thornton, Luding & Bokhove
(Granular Matter 14, 2012) and Labra, Ooi & Sun (the Gaussian kernel of the silo studies):
with a kernel W(r) of unit integral and the particles' (bodies') centres x_p, masses m_p and
velocities v_p,

    density          rho(r)   = sum_p m_p W(r - x_p)
    momentum         p(r)     = sum_p m_p v_p W(r - x_p),       velocity V = p / rho
    solid fraction   phi(r)   = sum_p V_p W(r - x_p)             (V_p the solid volume)
    kinetic stress   s_k(r)   = -sum_p m_p v'_p (x) v'_p W(r - x_p),  v'_p = v_p - V(r)
    contact stress   s_c(r)   = sum over contact forces f acting on a body with centre X at the
                                contact point c of  f (x) (c - X) int_0^1 W(r - X - s (c - X)) ds

The contact term is the line integral along the branch vector.  For a contact between two
bodies i and j (f on i, -f on j, both at c) the two half-branches X_i -> c -> X_j add up to
Weinhart's -f_ij (x) r_ij int W along the line from x_i to x_j (r_ij = x_i - x_j) when c lies
on that line (spheres); for clumps the members' contact points are off the line between the
bodies' centres and the path through c is the right one.  A wall (or mesh) contact has one
half-branch, from the particle's centre to the contact point on the wall.  The stress is the
Cauchy stress, tension positive, as in the momentum balance
d(rho V)/dt + div(rho V V) = div(s_k + s_c) + rho g: a column at rest has s_yy = -rho_b g (H - y);
the vertical *pressure* of silo mechanics is -s_yy.

Clumps are coarse-grained as rigid bodies: the body's mass sits at its centre of mass with the
body's velocity, and the contact branches start at the centre of mass (forces between members
of one clump do not exist).  Free spheres are bodies of their own.

The kernel: a Gaussian of standard deviation ``width`` w, truncated per axis at
``cutoff`` x w (a box, which keeps it a product of three one-dimensional kernels) and
normalised *on the grid*: for a point x, the weights along each axis are
g_j = exp(-(c_j - x)^2 / 2 w^2) over the cell centres c_j within the cutoff, divided by
h sum_j g_j.  The discrete sum of W times the cell volume is therefore 1 to round-off for every
point, whatever its position relative to the cells: the mass deposited is the mass, the
momentum the momentum, and the integral of the contact stress of a contact is exactly its
virial -f_ij (x) r_ij (the line integral is a composite two-point Gauss-Legendre rule with
sub-segments no longer than w / 2; each quadrature point carries a normalised kernel).

Edges of the grid (``edges``): on an axis where the system is periodic and the grid spans the
period exactly, the kernel wraps around and nothing is lost.  On other axes the part of a
kernel beyond the grid is dropped ("open"): cells within ``cutoff`` x w of such an edge receive
less than their share (in a uniform medium that fills the grid to its edge, the density in the
edge cell is about half the bulk; the field ``coverage`` is the fraction of a kernel centred at
each cell that lies inside the grid), and particles outside the grid but within the cutoff
contribute to it.  ``edges="correct"`` divides every field by ``coverage`` (the boundary
normalisation of a kernel estimate: unbiased for a medium that fills the grid up to its edges,
e.g. walls at the grid edges; the totals are then no longer conserved in those cells).

All loops are serial compiled kernels (the scatter onto the grid would race in parallel), so
the fields do not depend on the thread count.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cfddem._jit import kernel
from cfddem.errors import CaseError
from cfddem.particles.walls import wall_contact_s

EDGES = ("open", "correct")


# --------------------------------------------------------------------------------- kernels
@kernel(inline="always")
def _axis_weights(x, lo, h, n, wrap, inv2w2, cut, w, idx):
    """One axis of the kernel at coordinate x: the cells with centres within ``cut`` of x.
    Writes their weights (per unit length, normalised so that h sum = 1) to ``w`` and their
    cell indices to ``idx`` (-1 outside a non-wrapping grid); returns their count."""
    j0 = int(math.ceil((x - cut - lo) / h - 0.5))
    j1 = int(math.floor((x + cut - lo) / h - 0.5))
    cnt = j1 - j0 + 1
    s = 0.0
    for k in range(cnt):
        j = j0 + k
        d = lo + (j + 0.5) * h - x
        g = math.exp(-d * d * inv2w2)
        s += g
        w[k] = g
        if wrap:
            idx[k] = ((j % n) + n) % n
        elif j >= 0 and j < n:
            idx[k] = j
        else:
            idx[k] = -1
    inv = 1.0 / (s * h)
    for k in range(cnt):
        w[k] *= inv
    return cnt


@kernel(inline="always")
def _scatter(x, y, z, scale, vals, lo, h, nc, wrap, inv2w2, cut, wx, ix, wy, iy, wz, iz, out):
    """out[i, j, k, :] += scale * W(cell - (x, y, z)) * vals for the cells of the kernel."""
    lx = _axis_weights(x, lo[0], h[0], nc[0], wrap[0], inv2w2, cut, wx, ix)
    ly = _axis_weights(y, lo[1], h[1], nc[1], wrap[1], inv2w2, cut, wy, iy)
    lz = _axis_weights(z, lo[2], h[2], nc[2], wrap[2], inv2w2, cut, wz, iz)
    nv = len(vals)
    for a in range(lx):
        i = ix[a]
        if i < 0:
            continue
        for b in range(ly):
            j = iy[b]
            if j < 0:
                continue
            wab = scale * wx[a] * wy[b]
            for c in range(lz):
                k = iz[c]
                if k < 0:
                    continue
                W = wab * wz[c]
                for r in range(nv):
                    out[i, j, k, r] += W * vals[r]


@kernel
def deposit_points(npt, P, m, v, vol, lo, h, nc, wrap, inv2w2, cut, wx, ix, wy, iy, wz, iz, vals, out):
    """Add each point's mass, solid volume, momentum (3) and m v (x) v (xx, xy, xz, yy, yz, zz),
    times the kernel, to out (nx, ny, nz, 11); ``vals`` (11,) scratch."""
    for p in range(npt):
        mp = m[p]
        vals[0] = mp
        vals[1] = vol[p]
        r = 5
        for a in range(3):
            vals[2 + a] = mp * v[p, a]
            for b in range(a, 3):
                vals[r] = mp * v[p, a] * v[p, b]
                r += 1
        _scatter(P[p, 0], P[p, 1], P[p, 2], 1.0, vals, lo, h, nc, wrap, inv2w2, cut, wx, ix, wy, iy, wz, iz, out)
    return 0


@kernel
def deposit_branches(ns, X, B, F, width, lo, h, nc, wrap, inv2w2, cut, wx, ix, wy, iy, wz, iz, vals, out):
    """Add F[s] (x) B[s] times the line integral of the kernel along the segment X[s] ->
    X[s] + B[s] to out (nx, ny, nz, 9) (row-major 3 x 3).  Composite two-point Gauss-Legendre
    rule with ceil(2 |B| / width) sub-segments; ``vals`` (9,) scratch."""
    for s in range(ns):
        bl = math.sqrt(B[s, 0] * B[s, 0] + B[s, 1] * B[s, 1] + B[s, 2] * B[s, 2])
        nsub = max(1, int(math.ceil(2.0 * bl / width)))
        for r in range(3):
            for e in range(3):
                vals[3 * r + e] = F[s, r] * B[s, e]
        for q in range(2 * nsub):
            # nodes 1/2 -+ 1/(2 sqrt 3) of each sub-segment
            t = ((q // 2) + 0.5 + (0.28867513459481287 if q % 2 else -0.28867513459481287)) / nsub
            _scatter(X[s, 0] + t * B[s, 0], X[s, 1] + t * B[s, 1], X[s, 2] + t * B[s, 2], 0.5 / nsub, vals,
                     lo, h, nc, wrap, inv2w2, cut, wx, ix, wy, iy, wz, iz, out)
    return 0


@kernel
def axis_coverage(lo, h, n, wrap, inv2w2, cut, w, idx, out):
    """out[i]: the fraction of a one-dimensional kernel centred at cell centre i that falls
    on the grid's cells."""
    for i in range(n):
        cnt = _axis_weights(lo + (i + 0.5) * h, lo, h, n, wrap, inv2w2, cut, w, idx)
        s = 0.0
        for k in range(cnt):
            if idx[k] >= 0:
                s += w[k]
        out[i] = s * h
    return 0


@kernel
def wall_contact_points(nc, ci, cw, pos, radius, wgeom, q):
    """q[k]: the contact point on analytic wall cw[k] of particle ci[k] (as the force kernel
    computes it)."""
    for k in range(nc):
        i = ci[k]
        w = cw[k]
        ov, nx, ny, nz, qx, qy, qz = wall_contact_s(
            wgeom[w, 0], wgeom[w, 1], wgeom[w, 2], wgeom[w, 3], wgeom[w, 4], wgeom[w, 5], wgeom[w, 6],
            wgeom[w, 7], wgeom[w, 8], wgeom[w, 9], wgeom[w, 10], wgeom[w, 11], wgeom[w, 12],
            wgeom[w, 13], wgeom[w, 14], pos[i, 0], pos[i, 1], pos[i, 2], radius[i])
        q[k, 0] = qx
        q[k, 1] = qy
        q[k, 2] = qz
    return 0


# --------------------------------------------------------------------------------- fields
@dataclass
class CoarseFields:
    """Cell-centred fields on a regular grid of ``shape`` cells from ``lo`` to ``hi``.

    density (kg/m3 of solid mass per volume: the bulk density), solid_fraction, momentum
    (kg/m2/s, 3), velocity (m/s, 3; momentum / density, 0 where the density is 0),
    kinetic_stress and contact_stress (Pa, (3, 3), Cauchy, tension positive; [a, b] = the a
    component of the force on a face of normal b), coverage (the fraction of a kernel centred at
    the cell inside the grid), and the totals of what went in (``totals``: mass and momentum
    of the bodies, sum of -f (x) r over the contacts, counts)."""

    lo: np.ndarray
    hi: np.ndarray
    shape: tuple
    width: float
    cutoff: float
    edges: str
    time: float
    density: np.ndarray
    solid_fraction: np.ndarray
    momentum: np.ndarray
    velocity: np.ndarray
    kinetic_stress: np.ndarray
    contact_stress: np.ndarray
    coverage: np.ndarray
    totals: dict = field(default_factory=dict)

    @property
    def spacing(self) -> np.ndarray:
        return (self.hi - self.lo) / np.asarray(self.shape)

    @property
    def cell_volume(self) -> float:
        return float(np.prod(self.spacing))

    @property
    def stress(self) -> np.ndarray:
        """Total stress: kinetic + contact (Pa, tension positive)."""
        return self.kinetic_stress + self.contact_stress

    def centres(self, axis: int) -> np.ndarray:
        """Cell-centre coordinates along ``axis``."""
        h = self.spacing[axis]
        return self.lo[axis] + (np.arange(self.shape[axis]) + 0.5) * h

    def profile(self, values, axis: int) -> np.ndarray:
        """Mean of a field over the two other axes (a cross-section average) against ``axis``:
        shape (n_axis, ...)."""
        a = np.moveaxis(np.asarray(values), axis, 0)
        return a.reshape(a.shape[0], -1, *a.shape[3:]).mean(axis=1)

    def arrays(self) -> dict:
        return {"density": self.density, "solid_fraction": self.solid_fraction, "momentum": self.momentum,
                "velocity": self.velocity, "kinetic_stress": self.kinetic_stress,
                "contact_stress": self.contact_stress, "stress": self.stress, "coverage": self.coverage}

    def write_h5(self, path) -> None:
        """HDF5: one dataset per field (cells x, y, z first; tensors [..., a, b]), the cell
        centres ``x``, ``y``, ``z`` and the parameters as attributes."""
        import h5py

        with h5py.File(path, "w") as f:
            for k, v in self.arrays().items():
                f.create_dataset(k, data=v, compression="gzip")
            for a, name in enumerate("xyz"):
                f.create_dataset(name, data=self.centres(a))
            f.attrs.update(lo=self.lo, hi=self.hi, shape=np.asarray(self.shape), spacing=self.spacing,
                           width=self.width, cutoff=self.cutoff, edges=self.edges, time=self.time,
                           stress_sign="Cauchy, tension positive")
            for k, v in self.totals.items():
                f.attrs["total_" + k] = v

    def write_vtu(self, path):
        """ParaView grid: scalars, vectors and the nine stress components of each tensor
        (``stress_xx`` ...)."""
        from cfddem.io.vtk import write_grid_vtu

        data = {}
        for k, v in self.arrays().items():
            if v.ndim == 5:
                for a, ca in enumerate("xyz"):
                    for b, cb in enumerate("xyz"):
                        data[f"{k}_{ca}{cb}"] = v[..., a, b]
            else:
                data[k] = v
        return write_grid_vtu(path, self.lo, self.spacing, self.shape, data)


# --------------------------------------------------------------------------------- gathering
def _min_image(d, plen):
    """Minimum image of differences d (.., 3) for the periodic lengths plen (0: not periodic)."""
    out = np.array(d, float)
    for a in range(3):
        if plen[a] > 0:
            out[..., a] -= plen[a] * np.round(out[..., a] / plen[a])
    return out


def _forces_now(system) -> None:
    """Make the contact forces those of the current positions (after an insertion or a restart
    they are re-evaluated, which re-sorts the particles: call before reading any array)."""
    if system._pending_m2 >= 0.0:
        raise CaseError("state", "the positions are one drift ahead of the forces (a step() that "
                        "stopped on a bad flag): coarse graining needs a state between steps")
    if system._forces_stale or system._need_rebuild:
        st = system._refresh()
        if st is not None:
            raise CaseError("state", st.message)


def bodies(system, solid_density: float | None = None) -> dict:
    """The mass carriers: free spheres and clump bodies (centre, mass, velocity, solid volume),
    and each particle's body centre (``centre_of``, (n, 3))."""
    _forces_now(system)
    n = system.n
    body = system.body
    free = body < 0
    pos = system.pos
    centre_of = pos.copy()
    P, m, v = [pos[free]], [system.mass[free]], [system.vel[free]]
    if solid_density is not None:
        vol = [system.mass[free] / solid_density]
    else:
        vol = [4.0 / 3.0 * np.pi * system.radius[free] ** 3]
    if system.clumps is not None and system.clumps.nb > 0:
        c = system.clumps
        if solid_density is None:
            raise CaseError("solid_density", "needed for the solid fraction of clumps (their spheres overlap)")
        centre_of[~free] = c.com[body[~free]]
        P.append(c.com)
        m.append(c.mass)
        v.append(c.vel)
        vol.append(c.mass / solid_density)
    del n
    return dict(P=np.concatenate(P), m=np.concatenate(m), v=np.concatenate(v), vol=np.concatenate(vol),
                centre_of=centre_of)


def contact_branches(system, centre_of=None) -> dict:
    """Every contact force on a body with its half-branch: start X (the body's centre), branch
    B (contact point - X, minimum image) and force F on the body, (k, 3) each, for the pair
    contacts (two entries each; their forces evaluated at the current state,
    :meth:`~cfddem.particles.ParticleSystem.pair_forces`), the analytic walls and the mesh walls
    (as at the last force evaluation).  Also ``virial``: sum of F (x) B, i.e. the integral of the contact stress."""
    _forces_now(system)
    n = system.n
    plen = system._plen
    pos = system.pos
    rad = system.radius
    if centre_of is None:
        centre_of = bodies(system, solid_density=1.0)["centre_of"]
    X, B, F = [], [], []
    # pairs: pf[k] is the force on pi[k] from pj[k]; n from pi to pj
    pairs = system.pair_forces()
    pi, pj, pf = pairs["pi"], pairs["pj"], pairs["force"]
    d = _min_image(pos[pj] - pos[pi], plen)
    dist = np.sqrt(np.sum(d * d, axis=1))
    rs = rad[pi] + rad[pj]
    on = dist < rs
    pi, pj, pf, d, dist, rs = pi[on], pj[on], pf[on], d[on], dist[on], rs[on]
    nvec = d / dist[:, None]
    # contact point relative to particle a: the middle of the overlap along the normal
    ca = nvec * (rad[pi] - 0.5 * (rs - dist))[:, None]
    off_a = _min_image(pos[pi] - centre_of[pi], plen)
    off_b = _min_image(pos[pj] - centre_of[pj], plen)
    X += [centre_of[pi], centre_of[pj]]
    B += [off_a + ca, off_b + ca - d]
    F += [pf, -pf]
    # analytic walls: force on the particle -wfw, at the contact point on the wall
    if system.nw:
        ci, cw = np.nonzero(system._won[:n] == 1)
        q = np.empty((len(ci), 3))
        if len(ci):
            wall_contact_points(len(ci), ci.astype(np.int64), cw.astype(np.int64), system._pos,
                                system._radius, system._wgeom, q)
        X.append(centre_of[ci])
        B.append(_min_image(q - centre_of[ci], plen))
        F.append(-system._wfw[ci, cw])
    # mesh walls: force on the particle -ms_fw at the slot's contact point ms_q
    if system.nm:
        has = system._mstart[1: n + 1] > system._mstart[:n]
        ci, cs = np.nonzero((system._ms_mesh[:n] >= 0) & has[:, None])
        X.append(centre_of[ci])
        B.append(_min_image(system._ms_q[ci, cs] - centre_of[ci], plen))
        F.append(-system._ms_fw[ci, cs])
    X = np.ascontiguousarray(np.concatenate(X).reshape(-1, 3))
    B = np.ascontiguousarray(np.concatenate(B).reshape(-1, 3))
    F = np.ascontiguousarray(np.concatenate(F).reshape(-1, 3))
    return dict(X=X, B=B, F=F, virial=np.einsum("ka,kb->ab", F, B), n_pairs=int(on.sum()))


# --------------------------------------------------------------------------------- the API
def grid_shape(lo, hi, spacing) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Validated (lo, hi, shape): shape = the whole number of cells nearest (hi - lo) / spacing
    (at least 1); the spacing used is (hi - lo) / shape."""
    lo = np.asarray(lo, float).reshape(3)
    hi = np.asarray(hi, float).reshape(3)
    sp = np.broadcast_to(np.asarray(spacing, float), (3,))
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
        raise CaseError("lo/hi", f"need finite lo < hi on every axis, got lo={lo.tolist()}, hi={hi.tolist()}")
    if not np.all(sp > 0):
        raise CaseError("spacing", f"must be positive, got {sp.tolist()}")
    shape = tuple(int(max(1, round(x))) for x in (hi - lo) / sp)
    return lo, hi, shape


def coarse_grain(system, lo, hi, spacing, width: float, *, cutoff: float = 3.0, edges: str = "open",
                 solid_density: float | None = None) -> CoarseFields:
    """Coarse-grained fields of ``system`` (a :class:`cfddem.particles.ParticleSystem`) at its
    current state on the grid [lo, hi] (m, 3 values each) of cells of about ``spacing`` (m,
    scalar or 3 values), with a Gaussian kernel of standard deviation ``width`` (m) truncated at
    ``cutoff`` widths; ``edges``: "open" or "correct" (module docstring); ``solid_density``
    (kg/m3) gives the solid volume m / rho_s of each body (needed with clumps; without it a
    sphere's volume is 4/3 pi R^3)."""
    lo, hi, shape = grid_shape(lo, hi, spacing)
    h = (hi - lo) / np.asarray(shape)
    if not (width > 0 and math.isfinite(width)):
        raise CaseError("width", f"must be positive, got {width}")
    if not (cutoff > 0 and math.isfinite(cutoff)):
        raise CaseError("cutoff", f"must be positive, got {cutoff}")
    cut = cutoff * width
    if 2.0 * cut < h.max():
        raise CaseError("width", f"the kernel (cutoff x width = {cut:g} m) must reach at least half a cell "
                        f"({0.5 * h.max():g} m): raise the width or refine the grid")
    if edges not in EDGES:
        raise CaseError("edges", f"one of {EDGES}, got {edges!r}")
    if solid_density is not None and not solid_density > 0:
        raise CaseError("solid_density", f"must be positive, got {solid_density}")
    # periodic axes: the kernel wraps where the grid spans the period; elsewhere the bodies are
    # taken at their image nearest the grid's centre
    plen = system._plen
    wrap = np.zeros(3, np.int64)
    shift_axes = []
    for a in range(3):
        if plen[a] > 0:
            if abs(lo[a] - system._plo[a]) <= 1e-9 * plen[a] and abs(hi[a] - lo[a] - plen[a]) <= 1e-9 * plen[a]:
                wrap[a] = 1
            else:
                shift_axes.append(a)
    bd = bodies(system, solid_density)
    br = contact_branches(system, bd["centre_of"])
    P, X = bd["P"].copy(), br["X"].copy()
    gc = 0.5 * (lo + hi)
    for a in shift_axes:
        for A in (P, X):
            A[:, a] = gc[a] + (A[:, a] - gc[a]) - plen[a] * np.round((A[:, a] - gc[a]) / plen[a])
    nc = np.asarray(shape, np.int64)
    L = int(math.floor(2.0 * cut / h.min())) + 2
    scratch = [np.empty(L) if k % 2 == 0 else np.empty(L, np.int64) for k in range(6)]
    inv2w2 = 1.0 / (2.0 * width * width)
    pts = np.zeros(shape + (11,))
    deposit_points(len(P), np.ascontiguousarray(P), np.ascontiguousarray(bd["m"]), np.ascontiguousarray(bd["v"]),
                   np.ascontiguousarray(bd["vol"]), lo, h, nc, wrap, inv2w2, cut, *scratch, np.zeros(11), pts)
    sig = np.zeros(shape + (9,))
    deposit_branches(len(X), X, br["B"], br["F"], float(width), lo, h, nc, wrap, inv2w2, cut, *scratch,
                     np.zeros(9), sig)
    sig = sig.reshape(shape + (3, 3))
    rho, phi, mom = (np.ascontiguousarray(pts[..., k]) for k in (0, 1, slice(2, 5)))
    mvv = np.zeros(shape + (3, 3))
    r = 5
    for a in range(3):  # m v v was filled on and above the diagonal
        for b in range(a, 3):
            mvv[..., a, b] = mvv[..., b, a] = pts[..., r]
            r += 1
    cov = np.ones(shape)
    for a in range(3):
        c1 = np.empty(shape[a])
        axis_coverage(lo[a], h[a], shape[a], wrap[a], inv2w2, cut, scratch[0], scratch[1], c1)
        cov *= c1.reshape([-1 if b == a else 1 for b in range(3)])
    if edges == "correct":
        inv = 1.0 / cov
        rho, phi = rho * inv, phi * inv
        mom = mom * inv[..., None]
        mvv = mvv * inv[..., None, None]
        sig = sig * inv[..., None, None]
    safe = np.where(rho > 0, rho, 1.0)
    vel = np.where((rho > 0)[..., None], mom / safe[..., None], 0.0)
    kin = -(mvv - rho[..., None, None] * vel[..., :, None] * vel[..., None, :])
    totals = dict(mass=float(bd["m"].sum()), momentum=np.sum(bd["m"][:, None] * bd["v"], axis=0),
                  virial=br["virial"], contacts=len(br["X"]), pair_contacts=br["n_pairs"], bodies=len(P))
    return CoarseFields(lo=lo, hi=hi, shape=shape, width=float(width), cutoff=float(cutoff), edges=edges,
                        time=float(system.time), density=rho, solid_fraction=phi, momentum=mom, velocity=vel,
                        kinetic_stress=kin, contact_stress=sig, coverage=cov, totals=totals)


# --------------------------------------------------------------------------------- Janssen
def lateral_pressure_ratio(bulk_friction: float) -> float:
    """Rankine's active ratio K = (1 - sin phi) / (1 + sin phi) with tan phi = ``bulk_friction``."""
    s = math.sin(math.atan(bulk_friction))
    return (1.0 - s) / (1.0 + s)


def janssen_length(W: float, T: float, K: float, mu_side: float, mu_front: float) -> float:
    """Janssen's z_c = W T / (2 K (mu_side T + mu_front W)) of a W x T rectangular silo
    (:func:`janssen`); infinite for frictionless walls (no wall carries weight)."""
    grip = mu_side * T + mu_front * W
    return W * T / (2.0 * K * grip) if grip > 0 else math.inf


def janssen(z, H: float, gamma: float, W: float, T: float, K: float, mu_side: float, mu_front: float):
    """Janssen's vertical stress (Pa, compression positive) at heights ``z`` in a W x T
    rectangular silo filled to H with material of weight density ``gamma`` (N/m3):
    sigma_v = gamma z_c (1 - exp(-(H - z) / z_c)), z_c = W T / (2 K (mu_side T + mu_front W))
    (:func:`janssen_length`), mu_side the friction of the two walls of width T (normal along W),
    mu_front of the two of width W (normal along T); 0 above H.  Frictionless walls: the
    hydrostatic limit gamma (H - z)."""
    z = np.asarray(z, float)
    zc = janssen_length(W, T, K, mu_side, mu_front)
    if not math.isfinite(zc):
        return np.where(z < H, gamma * (H - z), 0.0)
    return np.where(z < H, gamma * zc * (1.0 - np.exp(-(H - z) / zc)), 0.0)


# --------------------------------------------------------------------------------- runs
def load_run_state(src, case_dir=None):
    """The particle system of a run at a checkpoint: ``src`` a run folder (its newest valid
    checkpoint) or a checkpoint file (``RUN/checkpoints/ckpt_*.h5``).  The case is the run's
    ``case.resolved.toml`` (``case_dir``: the original case folder instead, when the case
    refers to files by relative paths, e.g. mesh walls).  Returns (system, case, checkpoint
    path); the system is rebuilt as ``cfddem run --resume`` does, so its pair forces are those
    of the saved state."""
    from pathlib import Path

    from cfddem.config import load_case
    from cfddem.io.checkpoint import latest_checkpoint, read_checkpoint
    from cfddem.simulation import Simulation

    src = Path(src)
    if src.is_dir():
        found = latest_checkpoint(src / "checkpoints" if (src / "checkpoints").is_dir() else src)
        if found is None:
            raise CaseError("RUN_DIR_OR_CHECKPOINT", f"no valid checkpoint in {src} (set checkpoint.interval "
                            "or checkpoint.every_steps in the run's case)")
        path, state = found
        run = src if (src / "checkpoints").is_dir() else src.parent
    elif src.is_file():
        try:
            state = read_checkpoint(src)
        except (OSError, KeyError, ValueError) as e:
            raise CaseError("RUN_DIR_OR_CHECKPOINT", f"{src}: not a readable checkpoint ({e})") from None
        path = src
        run = src.parent.parent if src.parent.name == "checkpoints" else src.parent
    else:
        raise CaseError("RUN_DIR_OR_CHECKPOINT", f"not found: {src}")
    if case_dir is not None:
        case = load_case(case_dir)
    else:
        resolved = run / "case.resolved.toml"
        if not resolved.is_file():
            raise CaseError("--case", f"no case.resolved.toml in {run}: give the case folder with --case")
        case = load_case(resolved)
    sim = Simulation(case, out_dir=run, echo=False, progress=False)
    sim.build()
    sim.system.set_state(state["system"])
    return sim.system, case, path


def vertical_axis(gravity) -> tuple[int, float]:
    """(axis, sign): the axis along gravity and +1 if 'up' (against gravity) is its positive
    direction."""
    g = np.asarray(gravity, float)
    if not np.any(g):
        raise CaseError("gravity", "no gravity: the vertical axis is undefined")
    a = int(np.argmax(np.abs(g)))
    return a, (1.0 if g[a] < 0 else -1.0)


def default_grid(system, width: float, cutoff: float):
    """The bodies' extent (centres +- radius) widened by the kernel's cutoff on every axis (so
    that no kernel is cut), or the period on periodic axes."""
    lo = np.min(system.pos - system.radius[:, None], axis=0) - cutoff * width
    hi = np.max(system.pos + system.radius[:, None], axis=0) + cutoff * width
    for a in range(3):
        if system._plen[a] > 0:
            lo[a], hi[a] = system._plo[a], system._plo[a] + system._plen[a]
    return lo, hi


def vertical_profile(fields: CoarseFields, system, up_axis: int, up: float, base: float | None = None) -> dict:
    """Cross-section averages against height: the integral over the horizontal cells divided by
    the bodies' horizontal extent W x T (centres +- radius; the period on periodic axes), so
    that a grid wider than the bed loses nothing.  Returns height (up from the lowest body
    surface), density, vertical pressure -sigma_vv (Pa, compression positive), ``lateral``: the
    two horizontal normal pressures -sigma_aa (the same average) along the first and second
    horizontal axes, W, T (the extents along those axes), the axes, the bed's bulk density rho_b (mean density over the
    middle half of the bed) and the equivalent flat fill height H = M / (rho_b W T).  ``base``:
    the level heights are measured from (up times the coordinate; default the lowest body
    surface), e.g. a silo's floor below which bodies rest in the outlet."""
    hz = [a for a in range(3) if a != up_axis]
    ext = []
    for a in hz:
        if system._plen[a] > 0:
            ext.append(float(system._plen[a]))
        else:
            ext.append(float(np.max(system.pos[:, a] + system.radius) - np.min(system.pos[:, a] - system.radius)))
    W, T = ext
    area_cell = float(np.prod([fields.spacing[a] for a in hz]))
    dens = np.moveaxis(fields.density, up_axis, 0).reshape(fields.shape[up_axis], -1).sum(axis=1)
    svv = np.moveaxis(fields.stress[..., up_axis, up_axis], up_axis, 0).reshape(fields.shape[up_axis], -1).sum(axis=1)
    dens *= area_cell / (W * T)
    pv = -svv * area_cell / (W * T)
    ph = [-np.moveaxis(fields.stress[..., a, a], up_axis, 0).reshape(fields.shape[up_axis], -1).sum(axis=1)
          * area_cell / (W * T) for a in hz]
    z = fields.centres(up_axis)
    if base is None:
        base = np.min(up * system.pos[:, up_axis] - system.radius)
    h = up * z - base
    order = np.argsort(h)
    h, dens, pv = h[order], dens[order], pv[order]
    ph = [q[order] for q in ph]
    M = fields.totals["mass"]
    bed = dens > 0.5 * dens.max()
    H0 = float(h[bed].max()) if bed.any() else 0.0
    mid = bed & (h > 0.25 * H0) & (h < 0.75 * H0)
    rho_b = float(dens[mid].mean()) if mid.any() else float("nan")
    return dict(height=h, density=dens, pressure=pv, lateral=ph, W=W, T=T, axes=hz, rho_b=rho_b,
                H=M / (rho_b * W * T))


def plot_vertical_stress(prof: dict, path, janssen_curve=None, title: str = "") -> None:
    """PNG: the cross-section averaged vertical pressure against height, with the hydrostatic
    line rho_b g (H - h) and Janssen's curve when given ((height, pressure, label))."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 5))
    h = prof["height"]
    ax.plot(prof["pressure"], 1e3 * h, "k-", lw=1.8, label="coarse-grained DEM")
    top = h.max()
    if math.isfinite(prof["H"]):  # no bed (fewer particles than a layer): no bulk density
        hh = np.linspace(0.0, prof["H"], 100)
        ax.plot(prof["rho_b"] * prof["g"] * (prof["H"] - hh), 1e3 * hh, "b:", label="hydrostatic rho_b g (H - h)")
        top = max(top, prof["H"])
    if janssen_curve is not None:
        ax.plot(janssen_curve[1], 1e3 * janssen_curve[0], "r--", label=janssen_curve[2])
    ax.set_xlabel("vertical pressure -sigma_vv (Pa), cross-section average")
    ax.set_ylabel("height above the floor (mm)")
    ax.set_xlim(left=0.0)
    ax.set_ylim(0.0, 1e3 * top)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def coarse_grain_run(src, out=None, *, spacing=None, width: float | None = None, cutoff: float = 3.0,
                     edges: str = "open", lo=None, hi=None, case_dir=None, janssen_walls=None,
                     K: float | None = None) -> dict:
    """Coarse-grain a run at a checkpoint (:func:`load_run_state`) and write ``out`` (default:
    RUN/coarse): ``coarse.h5`` (:meth:`CoarseFields.write_h5`), ``coarse.vtu`` (ParaView),
    ``vertical_profile.csv`` and ``vertical_stress.png`` (:func:`vertical_profile`; Janssen's
    curve with ``janssen_walls`` = (mu_side, mu_front) and the lateral pressure ratio ``K``).
    Defaults: ``width`` 3 mean particle radii (the thesis's kernel), ``spacing`` = width, the
    grid :func:`default_grid`.  Returns a summary dict (files, numbers)."""
    from pathlib import Path

    system, case, ckpt = load_run_state(src, case_dir)
    if system.n == 0:
        raise CaseError("RUN_DIR_OR_CHECKPOINT", f"{ckpt}: holds no particles")
    if width is None:
        width = 3.0 * float(system.radius.mean())
    if spacing is None:
        spacing = width
    dlo, dhi = default_grid(system, width, cutoff)
    lo = dlo if lo is None else lo
    hi = dhi if hi is None else hi
    if janssen_walls is not None and K is None:
        raise CaseError("--janssen", "needs the lateral pressure ratio: --K, --phi or --bulk-friction")
    fields = coarse_grain(system, lo, hi, spacing, width, cutoff=cutoff, edges=edges,
                          solid_density=case.particles.density)
    out = Path(out) if out is not None else Path(ckpt).parent.parent / "coarse"
    out.mkdir(parents=True, exist_ok=True)
    fields.write_h5(out / "coarse.h5")
    fields.write_vtu(out / "coarse.vtu")
    files = [out / "coarse.h5", out / "coarse.vtu"]
    summary = dict(checkpoint=str(ckpt), time=fields.time, shape=fields.shape, spacing=fields.spacing.tolist(),
                   width=width, cutoff=cutoff, edges=edges, mass=fields.totals["mass"],
                   mass_on_grid=float(fields.density.sum() * fields.cell_volume))
    axis, up = vertical_axis(system.gravity)
    prof = vertical_profile(fields, system, axis, up)
    prof["g"] = float(np.linalg.norm(system.gravity))
    cols = [prof["height"], prof["density"], prof["pressure"]]
    head = "height_m,density_kg_m3,vertical_pressure_Pa"
    curve = None
    summary.update(rho_b=prof["rho_b"], H=prof["H"], W=prof["W"], T=prof["T"])
    if janssen_walls is not None:
        mu_s, mu_f = (float(x) for x in janssen_walls)
        jz = janssen(prof["height"], prof["H"], prof["rho_b"] * prof["g"], prof["W"], prof["T"], K, mu_s, mu_f)
        hh = np.linspace(0.0, prof["H"], 100)
        curve = (hh, janssen(hh, prof["H"], prof["rho_b"] * prof["g"], prof["W"], prof["T"], K, mu_s, mu_f),
                 f"Janssen K = {K:.3g}, mu_side = {mu_s:g}, mu_front = {mu_f:g}")
        cols.append(jz)
        head += ",janssen_Pa"
        zc = janssen_length(prof["W"], prof["T"], K, mu_s, mu_f)
        summary.update(K=K, mu_side=mu_s, mu_front=mu_f, z_c=zc)
        floor = (prof["height"] > 0.1 * prof["H"]) & (prof["height"] < 0.2 * prof["H"])
        if floor.any():
            summary["pressure_low"] = float(prof["pressure"][floor].mean())
            summary["janssen_low"] = float(jz[floor].mean())
    np.savetxt(out / "vertical_profile.csv", np.column_stack(cols), delimiter=",", header=head, comments="")
    files.append(out / "vertical_profile.csv")
    plot_vertical_stress(prof, out / "vertical_stress.png", curve,
                         title=f"{case.name}, t = {fields.time:.3g} s, width {1e3 * width:.2g} mm")
    files.append(out / "vertical_stress.png")
    summary["files"] = [str(f) for f in files]
    return summary
