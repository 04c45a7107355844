"""FiPy as an independent oracle for the variable-coefficient pressure operator.

div(eps grad phi) = f on the same cells, eps a smooth field in [0.4, 1] at the centres,
Dirichlet phi = 0 on the x- side (our pressure-outlet treatment) and zero flux elsewhere.
FiPy: ``DiffusionTerm(coeff=eps.harmonicFaceValue) == f`` on a Grid3D.  Our
:class:`PressureSolver` is given the same harmonic face coefficients (cell value on
boundary faces), so the two discretisations coincide and the solutions must agree to the
linear solvers' tolerance.  With the solver's own arithmetic face mean the difference is a
discretisation error, O(h^2), checked too.
"""

import numpy as np
import pytest

from cfddem.gas import StaggeredGrid
from cfddem.gas.pressure import PressureSolver

fipy = pytest.importorskip("fipy")

SHAPE = (12, 10, 8)
LENGTHS = (0.12, 0.1, 0.08)


def fields(g):
    X, Y, Z = g.mesh("ccc")
    eps = 0.7 + 0.3 * np.sin(2 * np.pi * X / 0.12) * np.cos(np.pi * Y / 0.1) * np.cos(np.pi * Z / 0.16)
    f = 100.0 * np.cos(np.pi * X / 0.12) * (Y - 0.05) + 40.0 * Z
    return eps, f


def face_coefficients(eps, kind):
    out = []
    for d in range(3):
        e0 = np.take(eps, [0], axis=d)
        e1 = np.take(eps, [-1], axis=d)
        lo = np.take(eps, range(eps.shape[d] - 1), axis=d)
        hi = np.take(eps, range(1, eps.shape[d]), axis=d)
        mid = 2 * lo * hi / (lo + hi) if kind == "harmonic" else 0.5 * (lo + hi)
        out.append(np.concatenate([e0, mid, e1], axis=d))
    return out


def ours(eps, f, kind):
    g = StaggeredGrid(SHAPE, LENGTHS)
    pbc = {s: "neumann" for s in ("x-", "x+", "y-", "y+", "z-", "z+")}
    pbc["x-"] = "dirichlet"
    ps = PressureSolver(g, pbc, tol=1e-12, maxiter=500)
    ps.set_coefficients(*face_coefficients(eps, kind))
    phi, info = ps.solve(-f)  # A = -div(a grad)
    assert info.converged
    return phi


def fipy_solution(eps, f):
    dx, dy, dz = (L / n for L, n in zip(LENGTHS, SHAPE))
    mesh = fipy.Grid3D(dx=dx, dy=dy, dz=dz, nx=SHAPE[0], ny=SHAPE[1], nz=SHAPE[2])
    # FiPy orders cells with x fastest: a (nx, ny, nz) array in Fortran order
    e = fipy.CellVariable(mesh=mesh, value=eps.ravel(order="F"))
    src = fipy.CellVariable(mesh=mesh, value=f.ravel(order="F"))
    phi = fipy.CellVariable(mesh=mesh, value=0.0)
    phi.constrain(0.0, mesh.facesLeft)
    eq = fipy.DiffusionTerm(coeff=e.harmonicFaceValue) == src
    from fipy.solvers.scipy import LinearLUSolver

    eq.solve(var=phi, solver=LinearLUSolver())
    return np.asarray(phi.value).reshape(SHAPE, order="F")


def test_pressure_operator_matches_fipy():
    g = StaggeredGrid(SHAPE, LENGTHS)
    eps, f = fields(g)
    ref = fipy_solution(eps, f)
    scale = np.max(np.abs(ref))
    assert scale > 0
    same = ours(eps, f, "harmonic")
    err = np.max(np.abs(same - ref)) / scale
    print("harmonic faces: max relative difference", err)
    assert err < 1e-8
    arith = ours(eps, f, "arithmetic")
    err_a = np.max(np.abs(arith - ref)) / scale
    print("arithmetic faces: max relative difference", err_a)
    assert 1e-6 < err_a < 0.05
