"""Variable-coefficient pressure (Poisson) equation on the cell centres.

Solves ``A phi = b`` with ``A = -div(a grad .)`` discretised by finite volumes:

    (A phi)_c = sum_{faces f of c} a_f (phi_c - phi_nb(f)) / h_f^2

with ``a_f`` given on the faces (the solver passes ``a_f = eps_f^2/(eps_f + dt K/rho)``, which
is ``eps_f`` without drag).  Boundary faces: Neumann (no term) where the normal velocity is
prescribed, Dirichlet ``phi = 0`` on the boundary face (ghost ``-phi_c``, term ``2 a_f phi_c
/ h^2``) at pressure outlets, wrap-around at periodic sides.  ``A`` is symmetric positive
(semi-)definite.

Solver: preconditioned conjugate gradients (pyamg.krylov.cg) with a smoothed-aggregation
algebraic multigrid V-cycle (Vanek, Mandel & Brezina 1996; pyamg, Bell et al. 2022) as the
preconditioner.  The AMG hierarchy is built for the coefficients at one moment and reused
while the coefficients change by less than ``rebuild_threshold`` (max relative change): CG
with the old hierarchy as preconditioner still converges to the tolerance on the current
matrix, only in a few more iterations.  Without a Dirichlet face the system is singular
(constants are its null space): the right-hand side is projected onto the range (its mean
removed; the removed mean is reported as ``compatibility``), one cell is pinned by doubling
its diagonal entry (``A + a_00 e_0 e_0^T`` is positive definite and, for a compatible
right-hand side, has the singular system's solution with ``phi_0 = 0``), and the solution's
mean is then set to 0.

The matrix has a fixed CSR pattern built once; its values are refreshed by a compiled
loop.  ``tol`` is the relative residual ``||b - A phi|| <= tol ||b||``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyamg
import scipy.sparse as sp

from cfddem._jit import kernel

SIDES = ("x-", "x+", "y-", "y+", "z-", "z+")


@kernel
def _assemble(data, pos_diag, pos_off, fidx, ftype, coef, scale):
    """data[:] = A's values.  ftype: 0 neighbour, 1 Dirichlet boundary, 2 none."""
    data[:] = 0.0
    ns, nc = fidx.shape
    for s in range(ns):
        sc = scale[s]
        for c in range(nc):
            t = ftype[s, c]
            if t == 2:
                continue
            a = coef[fidx[s, c]] * sc
            if t == 0:
                data[pos_diag[c]] += a
                data[pos_off[s, c]] -= a
            else:
                data[pos_diag[c]] += 2.0 * a


@dataclass
class SolveInfo:
    iterations: int
    residual: float
    converged: bool
    rebuilt: bool
    compatibility: float


class PressureSolver:
    """``A = -div(a grad)`` on a grid's cells with the given pressure boundary types.

    Parameters: grid (StaggeredGrid), pressure_bc: dict side -> "neumann" | "dirichlet" |
    "periodic", tol, maxiter, rebuild_threshold.

    AMG hierarchy reuse: an AMG V-cycle built for an older matrix is still a symmetric positive
    definite preconditioner for CG on the current one; it only gets less effective.  So the
    hierarchy is rebuilt (a) when the coefficients changed by more than ``rebuild_threshold``
    (relative, max norm) since the last build, or (b) when CG needed more than
    ``rebuild_iteration_factor`` times (and at least 3 more than) the iterations of the first
    solve after the last build.  In a coupled run particles entering empty cells change the
    coefficients locally by O(1) every step, so (a) alone would rebuild at every gas step (the
    AMG set-up costs ~20 solves); set ``rebuild_threshold=inf`` to use (b) alone.
    """

    def __init__(self, grid, pressure_bc: dict, *, tol: float = 1e-8, maxiter: int = 200,
                 rebuild_threshold: float = 0.05, rebuild_iteration_factor: float = 1.5):
        self.grid = grid
        self.pressure_bc = dict(pressure_bc)
        self.tol = float(tol)
        self.maxiter = int(maxiter)
        self.rebuild_threshold = float(rebuild_threshold)
        self.rebuild_iteration_factor = float(rebuild_iteration_factor)
        self._base_iters = None  # iterations of the first solve after the last build
        self._slow = False  # the last solve needed too many iterations: rebuild next time
        self.singular = not any(v == "dirichlet" for v in self.pressure_bc.values())
        self._build_pattern()
        self._ml = None
        self._coef_ref = None
        self.n_rebuilds = 0

    # --- pattern ------------------------------------------------------------------------
    def _build_pattern(self):
        nx, ny, nz = self.grid.shape
        N = nx * ny * nz
        I, J, K = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
        I, J, K = I.ravel(), J.ravel(), K.ravel()
        cell = np.arange(N)
        n = (nx, ny, nz)
        # flat face index offsets: coefficient vector = [ax.ravel(), ay.ravel(), az.ravel()]
        fshapes = [(nx + 1, ny, nz), (nx, ny + 1, nz), (nx, ny, nz + 1)]
        foff = np.cumsum([0] + [int(np.prod(s)) for s in fshapes])
        self._fshapes = fshapes
        self._ncoef = int(foff[-1])
        fidx = np.zeros((6, N), dtype=np.int64)
        ftype = np.full((6, N), 2, dtype=np.int64)
        nbr = np.full((6, N), -1, dtype=np.int64)
        scale = np.zeros(6)
        for d in range(3):
            h = self.grid.spacing[d]
            for s, sgn in ((2 * d, -1), (2 * d + 1, 1)):
                scale[s] = 1.0 / h**2
                side = SIDES[s]
                fi = [I.copy(), J.copy(), K.copy()]
                if sgn > 0:
                    fi[d] = fi[d] + 1
                fidx[s] = foff[d] + np.ravel_multi_index(tuple(fi), fshapes[d])
                ni = [I.copy(), J.copy(), K.copy()]
                ni[d] = ni[d] + sgn
                inside = (ni[d] >= 0) & (ni[d] < n[d])
                kind = self.pressure_bc[side]
                if kind == "periodic":
                    ni[d] = ni[d] % n[d]
                    nb = np.ravel_multi_index(tuple(ni), (nx, ny, nz))
                    self_nb = nb == cell
                    ftype[s] = np.where(self_nb, 2, 0)
                    nbr[s] = np.where(self_nb, -1, nb)
                else:
                    nb = np.where(inside, np.ravel_multi_index(tuple(np.clip(x, 0, m - 1) for x, m in zip(ni, n)), (nx, ny, nz)), -1)
                    nbr[s] = nb
                    bt = 1 if kind == "dirichlet" else 2
                    ftype[s] = np.where(inside, 0, bt)
        rows = [cell]
        cols = [cell]
        for s in range(6):
            m = ftype[s] == 0
            rows.append(cell[m])
            cols.append(nbr[s][m])
        rows = np.concatenate(rows)
        cols = np.concatenate(cols)
        A = sp.csr_matrix((np.zeros(rows.size), (rows, cols)), shape=(N, N))
        A.sum_duplicates()
        A.sort_indices()
        indptr, indices = A.indptr, A.indices
        row_of = np.repeat(np.arange(N), np.diff(indptr))
        keys = row_of.astype(np.int64) * N + indices
        self._pos_diag = np.searchsorted(keys, cell.astype(np.int64) * N + cell)
        pos_off = np.zeros((6, N), dtype=np.int64)
        for s in range(6):
            m = ftype[s] == 0
            pos_off[s, m] = np.searchsorted(keys, cell[m].astype(np.int64) * N + nbr[s][m])
        self._pos_off = pos_off
        self._fidx = fidx
        self._ftype = ftype
        self._scale = scale
        self.A = sp.csr_matrix((np.zeros(indices.size), indices.copy(), indptr.copy()), shape=(N, N))
        self.N = N

    # --- coefficients -------------------------------------------------------------------
    def set_coefficients(self, ax: np.ndarray, ay: np.ndarray, az: np.ndarray) -> None:
        """Face coefficients a_f on the interior faces, shapes (nx+1,ny,nz), (nx,ny+1,nz), (nx,ny,nz+1)."""
        for a, s in zip((ax, ay, az), self._fshapes):
            if a.shape != s:
                raise ValueError(f"coefficient shape {a.shape}, expected {s}")
        coef = np.concatenate([np.ascontiguousarray(ax).ravel(), np.ascontiguousarray(ay).ravel(),
                               np.ascontiguousarray(az).ravel()])
        _assemble(self.A.data, self._pos_diag, self._pos_off, self._fidx, self._ftype, coef, self._scale)
        if self.singular:
            # pin cell 0: A + a00 e0 e0^T is positive definite; for a compatible right-hand
            # side (mean removed) its solution solves the singular system with phi_0 = 0
            self.A.data[self._pos_diag[0]] *= 2.0
        self._coef = coef

    def needs_rebuild(self) -> bool:
        if self._ml is None or self._slow:
            return True
        if not np.isfinite(self.rebuild_threshold):
            return False
        ref = self._coef_ref
        change = np.max(np.abs(self._coef - ref)) / max(np.max(np.abs(ref)), 1e-300)
        return change > self.rebuild_threshold

    def rebuild(self) -> None:
        """(Re)build the AMG hierarchy for the current matrix."""
        # forward Gauss-Seidel before and backward after the coarse-grid correction keeps the
        # V-cycle symmetric (a valid CG preconditioner) at half the cost of symmetric sweeps
        pre = ("gauss_seidel", {"sweep": "forward"})
        post = ("gauss_seidel", {"sweep": "backward"})
        # pyamg estimates spectral radii from a random start vector (numpy's global RNG):
        # seed it for the build so that the same matrix always gives the same hierarchy
        # (bit-identical restarts), and give the caller's RNG state back afterwards.
        rng_state = np.random.get_state()
        np.random.seed(20240531)
        try:
            self._ml = pyamg.smoothed_aggregation_solver(self.A.copy(), B=np.ones((self.N, 1)), max_coarse=500,
                                                         presmoother=pre, postsmoother=post)
        finally:
            np.random.set_state(rng_state)
        # smoothed aggregation returns block (BSR) coarse matrices of block size 1, whose
        # smoothing and products are 2-3x slower than the same matrices in CSR
        for lvl in self._ml.levels:
            lvl.A = lvl.A.tocsr()
            for name in ("P", "R"):
                if hasattr(lvl, name):
                    setattr(lvl, name, getattr(lvl, name).tocsr())
        self._M = self._ml.aspreconditioner(cycle="V")
        self._coef_ref = self._coef.copy()
        self._base_iters = None
        self._slow = False
        self.n_rebuilds += 1

    @property
    def reference_coefficients(self):
        return None if self._coef_ref is None else self._coef_ref.copy()

    def rebuild_from(self, coef_ref: np.ndarray) -> None:
        """Rebuild the hierarchy from stored reference coefficients (bit-identical restart)."""
        cur = self._coef
        s = self._fshapes
        o = np.cumsum([0] + [int(np.prod(x)) for x in s])
        self.set_coefficients(*(coef_ref[o[i]:o[i + 1]].reshape(s[i]) for i in range(3)))
        self.rebuild()
        parts = [cur[o[i]:o[i + 1]].reshape(s[i]) for i in range(3)]
        self.set_coefficients(*parts)

    # --- solve --------------------------------------------------------------------------
    def apply(self, phi: np.ndarray) -> np.ndarray:
        """A phi for phi of shape (nx, ny, nz)."""
        return (self.A @ phi.ravel()).reshape(self.grid.shape)

    def solve(self, b: np.ndarray, x0: np.ndarray | None = None, scale_x0: bool = False) -> tuple:
        """Solve A phi = b (b of shape (nx,ny,nz)); returns (phi, SolveInfo).  CG starts from
        x0 (zero if None), or with ``scale_x0`` from ``a x0``, ``a = x0.b / x0.A x0`` (the
        multiple of x0 closest to the solution in the A-norm; 0 if x0.A x0 is not positive)."""
        rebuilt = False
        if self.needs_rebuild():
            self.rebuild()
            rebuilt = True
        rhs = np.ascontiguousarray(b, dtype=np.float64).ravel().copy()
        compat = 0.0
        if self.singular:
            compat = float(rhs.mean())
            rhs -= compat
        bnorm = float(np.linalg.norm(rhs))
        x = np.zeros(self.N) if x0 is None else np.ascontiguousarray(x0, dtype=np.float64).ravel().copy()
        if scale_x0 and x0 is not None:
            xax = float(x @ (self.A @ x))
            a = float(x @ rhs) / xax if xax > 0.0 else 0.0
            x *= a if np.isfinite(a) else 0.0
        if bnorm == 0.0:
            return np.zeros(self.grid.shape), SolveInfo(0, 0.0, True, rebuilt, compat)
        res = []
        x, info = pyamg.krylov.cg(self.A, rhs, x0=x, tol=self.tol, maxiter=self.maxiter, M=self._M, residuals=res)
        r = float(np.linalg.norm(rhs - self.A @ x)) / bnorm
        if self.singular:
            x -= x.mean()
        converged = bool(np.isfinite(r) and r <= self.tol * 1.0001)
        if not np.all(np.isfinite(x)):
            converged = False
        its = max(len(res) - 1, 0)
        if self._base_iters is None:
            self._base_iters = its
        elif its > max(self.rebuild_iteration_factor * self._base_iters, self._base_iters + 3):
            self._slow = True
        return x.reshape(self.grid.shape), SolveInfo(its, r, converged, rebuilt, compat)

    def reuse_state(self) -> dict:
        """The rebuild-policy counters (part of a bit-identical restart)."""
        return {"base_iters": -1 if self._base_iters is None else int(self._base_iters), "slow": bool(self._slow)}

    def set_reuse_state(self, d: dict) -> None:
        b = int(d.get("base_iters", -1))
        self._base_iters = None if b < 0 else b
        self._slow = bool(d.get("slow", False))
