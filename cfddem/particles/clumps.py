"""Rigid clumps: rigid bodies made of (possibly overlapping) spheres (physics.md §1.4).

Multi-sphere pellets and the lid of the Jenike shear cell.  The member spheres stay ordinary
particles of the :class:`~cfddem.particles.system.ParticleSystem`: their pair and wall contacts
are computed sphere by sphere by the usual kernels (pairs of two members of the same clump are
dropped from the neighbour list, :func:`drop_intra_pairs`).  The clump kernels then sum the
member forces and torques onto the body and integrate the body:

    F_B = sum_m (F_m + F_ext,m - m_m g - F_cf,m) + F_ext,B + M g + F_cf(r_com)
    T_B = sum_m [ s_m x (F_m + F_ext,m - m_m g - F_cf,m) + T_m + T_ext,m ] + T_ext,B - Omega x (I_lab Omega)

with s_m = R(q) b_m the member's offset from the centre of mass (b_m in the body frame), F_m,
T_m the member's contact + wall + gravity + centrifugal force and contact torque of the last
evaluation.  The members' own gravity and centrifugal forces are replaced by the body's (M g and
-M Omega x (Omega x (r_com - r_axis)) acting at the centre of mass), so the body force is exact
whatever mass share the members carry; -Omega x (I_lab Omega) is the exact centrifugal torque
about the centre of mass of a rigid body (int rho s x (-Omega x (Omega x s)) dV with
S = int rho s s^T dV and I = tr(S) 1 - S).

Integration (per body, one step dt, h = dt/2):

    v  <- K_h(v; F_B/M)                 (Boris half kick with the Coriolis rotation, as free spheres)
    L  <- K_h(L; T_B)                   (lab-frame angular momentum; the frame's Coriolis term is
                                         taken as dL/dt = -Omega x L, exact for a sphere - the same
                                         approximation the free spheres use, see integrate.py)
    q, L_body <- NO_SQUISH free rotor   (Miller, Eleftheriou, Pattnaik, Ndirango, Newns & Martyna,
                                         J. Chem. Phys. 116, 8649 (2002)): body-frame momentum
                                         pi = R^T L, exact rotations about the principal axes
                                         1 (h/2), 2 (h/2), 3 (dt), 2 (h/2), 1 (h/2): symplectic,
                                         time reversible, q stays unit to round-off
    r_com <- r_com + dt v                (wrapped into periodic boxes, as free spheres)
    members: r_m = r_com + R(q) b_m,  v_m = v + w x s_m,  w_m = w = R diag(1/I) R^T L
    ... forces at t + dt ...
    v <- K_h(v; F_B/M),  L <- K_h(L; T_B),  members' v_m, w_m

Velocity constraint: a body can have components of its centre-of-mass velocity held at a set
value (``vfix``/``vset``; the shear-cell lid moves horizontally with the shear ring).  After each
half kick those components are reset; the force the constraint exerts on the body is recorded as
``cforce = -F_B`` (for those components; 0 for the others) at each closing kick.

Mass and inertia of a union of spheres (:func:`union_mass_properties`): spheres that overlap no
other sphere of the clump are integrated exactly; the others on a grid of cubic cells of side
h = r_min / ``cells_per_radius`` (cell-centre rule, a cell belongs to the first sphere that
contains it, so overlaps are counted once).  Accuracy (tests/verification/test_clumps.py): the
volume and centre of mass of two overlapping spheres to 5e-4 relative with the default 24 cells
per radius (each sphere's owned part is scaled by its exact / gridded whole-sphere volume).  The user may give the mass and the principal moments instead.

Summation order is fixed (members of a body in the order of their particle ids, bodies are
independent in the prange loop), so results are bit-identical for any number of threads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cfddem._jit import kernel, parallel_kernel, prange
from cfddem.errors import CaseError
from cfddem.particles._twin import serial_twin
from cfddem.particles.integrate import _half_kick
from cfddem.particles.neighbours import _wrap

# ----------------------------------------------------------------------------------- helpers


@kernel(inline="always")
def _qmat(q0, q1, q2, q3):
    """Rotation matrix R(q) (body -> lab) of the unit quaternion q = (q0, q1, q2, q3)."""
    r00 = q0 * q0 + q1 * q1 - q2 * q2 - q3 * q3
    r01 = 2.0 * (q1 * q2 - q0 * q3)
    r02 = 2.0 * (q1 * q3 + q0 * q2)
    r10 = 2.0 * (q1 * q2 + q0 * q3)
    r11 = q0 * q0 - q1 * q1 + q2 * q2 - q3 * q3
    r12 = 2.0 * (q2 * q3 - q0 * q1)
    r20 = 2.0 * (q1 * q3 - q0 * q2)
    r21 = 2.0 * (q2 * q3 + q0 * q1)
    r22 = q0 * q0 - q1 * q1 - q2 * q2 + q3 * q3
    return r00, r01, r02, r10, r11, r12, r20, r21, r22


@kernel(inline="always")
def _rotor(k, dt, I0, I1, I2, p0, p1, p2, q0, q1, q2, q3):
    """Exact free rotation about principal axis k for time dt (one NO_SQUISH sub-step):
    phi = dt p_k / I_k; q <- q (x) (cos phi/2, sin phi/2 e_k); p <- Rot_k(-phi) p."""
    if k == 0:
        phi = dt * p0 / I0
    elif k == 1:
        phi = dt * p1 / I1
    else:
        phi = dt * p2 / I2
    c = math.cos(0.5 * phi)
    s = math.sin(0.5 * phi)
    cp = math.cos(phi)
    sp = math.sin(phi)
    if k == 0:
        n0 = q0 * c - q1 * s
        n1 = q1 * c + q0 * s
        n2 = q2 * c + q3 * s
        n3 = q3 * c - q2 * s
        a, b = p1, p2
        p1 = cp * a + sp * b
        p2 = -sp * a + cp * b
    elif k == 1:
        n0 = q0 * c - q2 * s
        n1 = q1 * c - q3 * s
        n2 = q2 * c + q0 * s
        n3 = q3 * c + q1 * s
        a, b = p2, p0
        p2 = cp * a + sp * b
        p0 = -sp * a + cp * b
    else:
        n0 = q0 * c - q3 * s
        n1 = q1 * c + q2 * s
        n2 = q2 * c - q1 * s
        n3 = q3 * c + q0 * s
        a, b = p0, p1
        p0 = cp * a + sp * b
        p1 = -sp * a + cp * b
    return p0, p1, p2, n0, n1, n2, n3


@kernel(inline="always")
def _half(vx, vy, vz, ax, ay, az, h, rotating, R):
    """:func:`cfddem.particles.integrate._half_kick` (v += h a, Boris frame rotation R in the
    middle) with R given as a matrix."""
    return _half_kick(vx, vy, vz, ax, ay, az, h, rotating, R[0, 0], R[0, 1], R[0, 2], R[1, 0], R[1, 1],
                      R[1, 2], R[2, 0], R[2, 1], R[2, 2])


@kernel(inline="always")
def _kick_body(vel, vfix, vset, b, ax, ay, az, h, rotating, Rv):
    """Half kick of body b's velocity, then its held components (``vfix``) set to ``vset``."""
    vx, vy, vz = _half(vel[b, 0], vel[b, 1], vel[b, 2], ax, ay, az, h, rotating, Rv)
    if vfix[b, 0] != 0.0:
        vx = vset[b, 0]
    if vfix[b, 1] != 0.0:
        vy = vset[b, 1]
    if vfix[b, 2] != 0.0:
        vz = vset[b, 2]
    vel[b, 0] = vx
    vel[b, 1] = vy
    vel[b, 2] = vz


@kernel(inline="always")
def _write_members(b, start, members, com, vel, L, quat, inert, pos, pvel, pomg, boff, plen, plo,
                   ref, write_pos):
    """Members of body b from the body state; returns max |r_m - r_ref|^2 (0 if not write_pos)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = _qmat(quat[b, 0], quat[b, 1], quat[b, 2], quat[b, 3])
    # w = R diag(1/I) R^T L
    px = r00 * L[b, 0] + r10 * L[b, 1] + r20 * L[b, 2]
    py = r01 * L[b, 0] + r11 * L[b, 1] + r21 * L[b, 2]
    pz = r02 * L[b, 0] + r12 * L[b, 1] + r22 * L[b, 2]
    px /= inert[b, 0]
    py /= inert[b, 1]
    pz /= inert[b, 2]
    wx = r00 * px + r01 * py + r02 * pz
    wy = r10 * px + r11 * py + r12 * pz
    wz = r20 * px + r21 * py + r22 * pz
    m2 = 0.0
    for s in range(start[b], start[b + 1]):
        i = members[s]
        sx = r00 * boff[i, 0] + r01 * boff[i, 1] + r02 * boff[i, 2]
        sy = r10 * boff[i, 0] + r11 * boff[i, 1] + r12 * boff[i, 2]
        sz = r20 * boff[i, 0] + r21 * boff[i, 1] + r22 * boff[i, 2]
        if write_pos:
            x = _wrap(com[b, 0] + sx, plo[0], plen[0])
            y = _wrap(com[b, 1] + sy, plo[1], plen[1])
            z = _wrap(com[b, 2] + sz, plo[2], plen[2])
            pos[i, 0] = x
            pos[i, 1] = y
            pos[i, 2] = z
            dx = x - ref[i, 0]
            dy = y - ref[i, 1]
            dz = z - ref[i, 2]
            if plen[0] > 0.0:
                dx -= plen[0] * round(dx / plen[0])
            if plen[1] > 0.0:
                dy -= plen[1] * round(dy / plen[1])
            if plen[2] > 0.0:
                dz -= plen[2] * round(dz / plen[2])
            m2 = max(m2, dx * dx + dy * dy + dz * dz)
        pvel[i, 0] = vel[b, 0] + wy * sz - wz * sy
        pvel[i, 1] = vel[b, 1] + wz * sx - wx * sz
        pvel[i, 2] = vel[b, 2] + wx * sy - wy * sx
        pomg[i, 0] = wx
        pomg[i, 1] = wy
        pomg[i, 2] = wz
    return m2


# ----------------------------------------------------------------------------------- kernels


@parallel_kernel
def clump_open(nb, start, members, com, vel, L, quat, mass, inert, bforce, btorque, bext_f,
               bext_t, vfix, vset, wfix, dt, rotating, Rv, Rw, pos, pvel, pomg, boff, plen, plo, ref):
    """Opening half kick, NO_SQUISH rotation and drift of every body; writes the members'
    positions, velocities and spins.  Bodies with ``wfix[b, 0] != 0`` do not rotate (their
    angular momentum stays 0).  Returns max |r_m - r_ref|^2 over the members."""
    h = 0.5 * dt
    m2 = 0.0
    for b in prange(nb):
        im = 1.0 / mass[b]
        _kick_body(vel, vfix, vset, b, (bforce[b, 0] + bext_f[b, 0]) * im, (bforce[b, 1] + bext_f[b, 1]) * im,
                   (bforce[b, 2] + bext_f[b, 2]) * im, h, rotating, Rv)
        lx, ly, lz = _half(L[b, 0], L[b, 1], L[b, 2], btorque[b, 0] + bext_t[b, 0],
                           btorque[b, 1] + bext_t[b, 1], btorque[b, 2] + bext_t[b, 2], h, rotating, Rw)
        if wfix[b, 0] != 0.0:  # rotation locked: no spin, the rotor below is the identity
            lx = 0.0
            ly = 0.0
            lz = 0.0
        # free rotor in the body frame: pi = R^T L
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = _qmat(quat[b, 0], quat[b, 1], quat[b, 2], quat[b, 3])
        p0 = r00 * lx + r10 * ly + r20 * lz
        p1 = r01 * lx + r11 * ly + r21 * lz
        p2 = r02 * lx + r12 * ly + r22 * lz
        q0 = quat[b, 0]
        q1 = quat[b, 1]
        q2 = quat[b, 2]
        q3 = quat[b, 3]
        I0 = inert[b, 0]
        I1 = inert[b, 1]
        I2 = inert[b, 2]
        p0, p1, p2, q0, q1, q2, q3 = _rotor(0, h, I0, I1, I2, p0, p1, p2, q0, q1, q2, q3)
        p0, p1, p2, q0, q1, q2, q3 = _rotor(1, h, I0, I1, I2, p0, p1, p2, q0, q1, q2, q3)
        p0, p1, p2, q0, q1, q2, q3 = _rotor(2, dt, I0, I1, I2, p0, p1, p2, q0, q1, q2, q3)
        p0, p1, p2, q0, q1, q2, q3 = _rotor(1, h, I0, I1, I2, p0, p1, p2, q0, q1, q2, q3)
        p0, p1, p2, q0, q1, q2, q3 = _rotor(0, h, I0, I1, I2, p0, p1, p2, q0, q1, q2, q3)
        qn = 1.0 / math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
        quat[b, 0] = q0 * qn
        quat[b, 1] = q1 * qn
        quat[b, 2] = q2 * qn
        quat[b, 3] = q3 * qn
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = _qmat(quat[b, 0], quat[b, 1], quat[b, 2], quat[b, 3])
        L[b, 0] = r00 * p0 + r01 * p1 + r02 * p2
        L[b, 1] = r10 * p0 + r11 * p1 + r12 * p2
        L[b, 2] = r20 * p0 + r21 * p1 + r22 * p2
        # the centre of mass is wrapped into periodic boxes like a free sphere's centre (velocity
        # zones and measurements test it against boxes)
        com[b, 0] = _wrap(com[b, 0] + dt * vel[b, 0], plo[0], plen[0])
        com[b, 1] = _wrap(com[b, 1] + dt * vel[b, 1], plo[1], plen[1])
        com[b, 2] = _wrap(com[b, 2] + dt * vel[b, 2], plo[2], plen[2])
        d2 = _write_members(b, start, members, com, vel, L, quat, inert, pos, pvel, pomg, boff,
                            plen, plo, ref, True)
        m2 = max(m2, d2)
    return m2


@parallel_kernel
def clump_close(nb, start, members, com, vel, L, quat, mass, inert, bforce, btorque, bext_f,
                bext_t, vfix, vset, wfix, cforce, dt, kick, rotating, Rv, Rw, pos, pvel, pomg, boff,
                pforce, ptorque, pmass, pext_f, pext_t, has_ext, gx, gy, gz, omx, omy, omz, cax,
                cay, caz, plen, plo):
    """Sum the members' forces and torques onto each body (fixed member order) and, if ``kick``,
    do the closing half kick and write the members' velocities and spins.  Returns the number of
    bodies with a non-finite state."""
    h = 0.5 * dt
    o2 = omx * omx + omy * omy + omz * omz
    bad = 0
    for b in prange(nb):
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = _qmat(quat[b, 0], quat[b, 1], quat[b, 2], quat[b, 3])
        fx = 0.0
        fy = 0.0
        fz = 0.0
        tx = 0.0
        ty = 0.0
        tz = 0.0
        for s in range(start[b], start[b + 1]):
            i = members[s]
            m = pmass[i]
            ax = pforce[i, 0] - m * gx
            ay = pforce[i, 1] - m * gy
            az = pforce[i, 2] - m * gz
            ttx = ptorque[i, 0]
            tty = ptorque[i, 1]
            ttz = ptorque[i, 2]
            if rotating:
                px = pos[i, 0] - cax
                py = pos[i, 1] - cay
                pz = pos[i, 2] - caz
                op = omx * px + omy * py + omz * pz
                ax -= m * (o2 * px - op * omx)
                ay -= m * (o2 * py - op * omy)
                az -= m * (o2 * pz - op * omz)
            if has_ext:
                ax += pext_f[i, 0]
                ay += pext_f[i, 1]
                az += pext_f[i, 2]
                ttx += pext_t[i, 0]
                tty += pext_t[i, 1]
                ttz += pext_t[i, 2]
            sx = r00 * boff[i, 0] + r01 * boff[i, 1] + r02 * boff[i, 2]
            sy = r10 * boff[i, 0] + r11 * boff[i, 1] + r12 * boff[i, 2]
            sz = r20 * boff[i, 0] + r21 * boff[i, 1] + r22 * boff[i, 2]
            fx += ax
            fy += ay
            fz += az
            tx += sy * az - sz * ay + ttx
            ty += sz * ax - sx * az + tty
            tz += sx * ay - sy * ax + ttz
        M = mass[b]
        fx += M * gx
        fy += M * gy
        fz += M * gz
        if rotating:
            px = com[b, 0] - cax
            py = com[b, 1] - cay
            pz = com[b, 2] - caz
            op = omx * px + omy * py + omz * pz
            fx += M * (o2 * px - op * omx)
            fy += M * (o2 * py - op * omy)
            fz += M * (o2 * pz - op * omz)
            # -Omega x (I_lab Omega), I_lab = R diag(I) R^T
            bx = r00 * omx + r10 * omy + r20 * omz
            by = r01 * omx + r11 * omy + r21 * omz
            bz = r02 * omx + r12 * omy + r22 * omz
            bx *= inert[b, 0]
            by *= inert[b, 1]
            bz *= inert[b, 2]
            ix = r00 * bx + r01 * by + r02 * bz
            iy = r10 * bx + r11 * by + r12 * bz
            iz = r20 * bx + r21 * by + r22 * bz
            tx -= omy * iz - omz * iy
            ty -= omz * ix - omx * iz
            tz -= omx * iy - omy * ix
        bforce[b, 0] = fx
        bforce[b, 1] = fy
        bforce[b, 2] = fz
        btorque[b, 0] = tx
        btorque[b, 1] = ty
        btorque[b, 2] = tz
        ftx = fx + bext_f[b, 0]
        fty = fy + bext_f[b, 1]
        ftz = fz + bext_f[b, 2]
        cforce[b, 0] = -ftx if vfix[b, 0] != 0.0 else 0.0
        cforce[b, 1] = -fty if vfix[b, 1] != 0.0 else 0.0
        cforce[b, 2] = -ftz if vfix[b, 2] != 0.0 else 0.0
        if kick:
            im = 1.0 / M
            _kick_body(vel, vfix, vset, b, ftx * im, fty * im, ftz * im, h, rotating, Rv)
            lx, ly, lz = _half(L[b, 0], L[b, 1], L[b, 2], tx + bext_t[b, 0], ty + bext_t[b, 1],
                               tz + bext_t[b, 2], h, rotating, Rw)
            if wfix[b, 0] != 0.0:
                lx = 0.0
                ly = 0.0
                lz = 0.0
            L[b, 0] = lx
            L[b, 1] = ly
            L[b, 2] = lz
        _write_members(b, start, members, com, vel, L, quat, inert, pos, pvel, pomg, boff, plen,
                       plo, pos, False)
        t = vel[b, 0] + vel[b, 1] + vel[b, 2] + L[b, 0] + L[b, 1] + L[b, 2] + com[b, 0] + com[b, 1] + com[b, 2]
        if not (t - t == 0.0):
            bad += 1
    return bad


@kernel
def drop_intra_pairs(n, first_start, pi, pj, body):
    """Remove (in place, keeping the order) the neighbour pairs of two members of the same
    clump; updates the CSR ``first_start``; returns the new number of pairs."""
    w = 0
    lo = first_start[0]
    for i in range(n):
        hi = first_start[i + 1]
        for k in range(lo, hi):
            a = pi[k]
            b = pj[k]
            if body[a] >= 0 and body[a] == body[b]:
                continue
            pi[w] = a
            pj[w] = b
            w += 1
        first_start[i + 1] = w
        lo = hi
    first_start[0] = 0
    return w


clump_open_s = serial_twin(clump_open)
clump_close_s = serial_twin(clump_close)


# ----------------------------------------------------------------------------------- mass properties


@kernel
def _grid_moments(centres, radii, flags, h, out):
    """Cell-centre integration of the union of spheres with flags != 0 (the ones overlapping
    another sphere): a cell belongs to the first sphere containing it.  out[k] = (volume,
    first moments (3), second moments xx, yy, zz, xy, xz, yz) of the part owned by sphere k;
    out[k, 10] the gridded volume of the whole sphere k (for the volume correction)."""
    k_n = len(radii)
    for k in range(k_n):
        if flags[k] == 0:
            continue
        cx, cy, cz, r = centres[k, 0], centres[k, 1], centres[k, 2], radii[k]
        nc = int(math.ceil(r / h))
        dv = h * h * h
        for a in range(-nc, nc):
            x = cx + (a + 0.5) * h
            for bb in range(-nc, nc):
                y = cy + (bb + 0.5) * h
                for c in range(-nc, nc):
                    z = cz + (c + 0.5) * h
                    if (x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2 > r * r:
                        continue
                    out[k, 10] += dv
                    owned = True
                    for j in range(k):
                        if (x - centres[j, 0]) ** 2 + (y - centres[j, 1]) ** 2 + (z - centres[j, 2]) ** 2 <= radii[j] ** 2:
                            owned = False
                            break
                    if not owned:
                        continue
                    out[k, 0] += dv
                    out[k, 1] += dv * x
                    out[k, 2] += dv * y
                    out[k, 3] += dv * z
                    out[k, 4] += dv * x * x
                    out[k, 5] += dv * y * y
                    out[k, 6] += dv * z * z
                    out[k, 7] += dv * x * y
                    out[k, 8] += dv * x * z
                    out[k, 9] += dv * y * z


def union_mass_properties(centres, radii, density, cells_per_radius: int = 24):
    """Mass properties of the union of spheres (see module docstring).

    Returns (M, com (3,), I_com (3, 3), member_mass (k,)): the member masses are the parts of the
    union each sphere owns (they sum to M)."""
    c = np.ascontiguousarray(np.atleast_2d(np.asarray(centres, float)))
    r = np.ascontiguousarray(np.broadcast_to(np.asarray(radii, float), (len(c),)))
    k = len(c)
    d = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=2)
    ov = (d < (r[:, None] + r[None, :]) * (1 - 1e-12)) & ~np.eye(k, dtype=bool)
    flags = ov.any(axis=1).astype(np.int64)
    mom = np.zeros((k, 11))
    if flags.any():
        h = float(r[flags > 0].min()) / cells_per_radius
        _grid_moments(c, r, flags, h, mom)
        # per-sphere correction: scale by exact / gridded volume of the whole sphere
        for i in np.flatnonzero(flags):
            mom[i, :10] *= (4.0 / 3.0 * math.pi * r[i] ** 3) / mom[i, 10]
    mom = mom[:, :10]
    for i in np.flatnonzero(flags == 0):  # exact sphere
        v = 4.0 / 3.0 * math.pi * r[i] ** 3
        s2 = v * r[i] ** 2 / 5.0
        x, y, z = c[i]
        mom[i] = (v, v * x, v * y, v * z, v * x * x + s2, v * y * y + s2, v * z * z + s2,
                  v * x * y, v * x * z, v * y * z)
    mom = mom * density
    tot = mom.sum(axis=0)
    M = tot[0]
    com = tot[1:4] / M
    S = np.array([[tot[4], tot[7], tot[8]], [tot[7], tot[5], tot[9]], [tot[8], tot[9], tot[6]]])
    S = S - M * np.outer(com, com)
    I = np.trace(S) * np.eye(3) - S
    return float(M), com, I, mom[:, 0].copy()


def quat_from_matrix(R) -> np.ndarray:
    """Unit quaternion (q0, q1, q2, q3) of a proper rotation matrix (Shepperd's method)."""
    R = np.asarray(R, float)
    t = np.trace(R)
    if t > 0:
        s = 2.0 * math.sqrt(1.0 + t)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
        q = [0.0] * 4
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    q = np.array(q)
    return q / np.linalg.norm(q)


def matrix_from_quat(q) -> np.ndarray:
    return np.array(_qmat(*[float(x) for x in q])).reshape(3, 3)


@dataclass
class ClumpShape:
    """A rigid shape: member spheres in the principal body frame (centre of mass at 0).

    ``offsets`` (k, 3), ``radii`` (k,), ``member_mass`` (k,) (sum = ``mass``), ``inertia`` (3,)
    principal moments, ``frame`` (3, 3): the principal axes (columns) in the frame the shape was
    given in (``to_given = frame``), ``com_given``: the centre of mass in that frame."""

    offsets: np.ndarray
    radii: np.ndarray
    member_mass: np.ndarray
    mass: float
    inertia: np.ndarray
    frame: np.ndarray
    com_given: np.ndarray
    name: str = "clump"

    @classmethod
    def from_spheres(cls, centres, radii, density, *, mass=None, inertia=None,
                     cells_per_radius: int = 24, name: str = "clump") -> "ClumpShape":
        """Shape from sphere centres/radii given in any frame.  ``mass`` and ``inertia`` (3x3
        tensor about the centre of mass, in the given frame) override the computed ones."""
        c = np.atleast_2d(np.asarray(centres, float))
        k = len(c)
        if c.shape != (k, 3) or k == 0:
            raise CaseError("clump", f"sphere centres need shape (k, 3), got {c.shape}")
        r = np.broadcast_to(np.asarray(radii, float), (k,)).copy()
        if not np.all(r > 0) or not density > 0:
            raise CaseError("clump", "radii and density must be positive")
        M, com, I, mm = union_mass_properties(c, r, density, cells_per_radius)
        if mass is not None:
            mm = mm * (float(mass) / M)
            M = float(mass)
        if inertia is not None:
            I = np.asarray(inertia, float).reshape(3, 3)
        w, Q = np.linalg.eigh(0.5 * (I + I.T))
        if np.linalg.det(Q) < 0:
            Q[:, 2] = -Q[:, 2]
        if not np.all(w > 0):
            raise CaseError("clump", f"inertia tensor must be positive definite, got {w}")
        off = (c - com) @ Q
        return cls(off, r, mm, M, w, Q, com, name)

    def orientation_identity(self) -> np.ndarray:
        """Quaternion that puts the shape back in the orientation it was given in."""
        return quat_from_matrix(self.frame)


def pellet(n: int, diameter: float, density: float) -> ClumpShape:
    """Preset pellets of spheres of ``diameter`` d: n = 2: two spheres with centres d/2 apart
    (a peanut, length 1.5 d); n = 4: four spheres at the corners of a regular tetrahedron of
    edge d/2.  Shape names ``pellet2`` / ``pellet4``."""
    r = 0.5 * diameter
    if n == 2:
        c = np.array([[-0.25 * diameter, 0, 0], [0.25 * diameter, 0, 0]])
    elif n == 4:
        a = 0.5 * diameter
        c = a / math.sqrt(8.0) * np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    else:
        raise CaseError("particles.clump", f"pellets of {n} spheres are not defined (2 or 4)")
    return ClumpShape.from_spheres(c, r, density, name=f"pellet{n}")


CLUMP_SHAPES = ("none", "pellet2", "pellet4", "template")


def spheres_per_body(name: str, spheres=()) -> int:
    """Spheres per inserted body of the clump shape ``name`` (1 for plain spheres; a template:
    its rows)."""
    if name == "template":
        return max(1, len(spheres))
    return {"none": 1, "pellet2": 2, "pellet4": 4}.get(name, 4)


def check_template(spheres, key: str = "particles.clump_spheres") -> np.ndarray:
    """A clump template's rows [x, y, z, r] (units of the diameter d) as a (k, 4) array, or a
    one-line :class:`CaseError` naming ``key``: rows of four finite numbers, positive radii, no
    sphere inside another, and every sphere overlapping or touching the others (one rigid body,
    not disjoint spheres)."""
    rows = np.asarray(spheres, float) if len(spheres) else np.zeros((0, 4))
    if rows.ndim != 2 or rows.shape[1] != 4:
        raise CaseError(key, "expected rows [x, y, z, r] (four numbers each, units of particles.diameter)")
    if not len(rows):
        raise CaseError(key, "a clump template needs at least one sphere")
    if not np.all(np.isfinite(rows)):
        raise CaseError(key, "every entry must be a finite number")
    bad = np.flatnonzero(rows[:, 3] <= 0)
    if len(bad):
        raise CaseError(f"{key}[{bad[0]}]", f"radius {rows[bad[0], 3]:g} must be positive")
    c, r = rows[:, :3], rows[:, 3]
    dist = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=2)
    k = len(rows)
    for i in range(k):
        for j in range(k):
            if i != j and dist[i, j] + r[i] <= r[j] and (r[i] < r[j] or i > j):
                raise CaseError(f"{key}[{i}]", f"lies inside sphere {j}: it adds nothing to the shape")
    # connected: overlapping or touching spheres form one body
    touch = dist <= (r[:, None] + r[None, :]) * (1.0 + 1e-9)
    seen = {0}
    todo = [0]
    while todo:
        i = todo.pop()
        for j in np.flatnonzero(touch[i]):
            if int(j) not in seen:
                seen.add(int(j))
                todo.append(int(j))
    if len(seen) < k:
        lone = min(set(range(k)) - seen)
        raise CaseError(f"{key}[{lone}]", "does not touch the other spheres: a clump is one rigid body of "
                                          "overlapping or touching spheres")
    return rows


def shape_from_case(name: str, diameter: float, density: float, spheres=()) -> ClumpShape | None:
    """The clump shape of ``particles.clump`` (None for plain spheres); ``spheres``: the rows of
    ``particles.clump_spheres`` for a template."""
    if name == "none":
        return None
    if name == "pellet2":
        return pellet(2, diameter, density)
    if name == "pellet4":
        return pellet(4, diameter, density)
    if name == "template":
        rows = check_template(spheres)
        return ClumpShape.from_spheres(rows[:, :3] * diameter, rows[:, 3] * diameter, density, name="template")
    raise CaseError("particles.clump", f"unknown clump shape {name!r} (one of {CLUMP_SHAPES})")


def particle_shape(p) -> ClumpShape | None:
    """The clump shape of a case's resolved ``[particles]`` (a dict or a config Section)."""
    g = p.get if isinstance(p, dict) else (lambda k, _p=p: getattr(_p, k))
    return shape_from_case(g("clump"), g("diameter"), g("density"), g("clump_spheres"))


# ----------------------------------------------------------------------------------- body store

_BODY_ARRAYS = dict(com=3, vel=3, L=3, quat=4, inert=3, force=3, torque=3, ext_force=3,
                    ext_torque=3, vfix=3, vset=3, cforce=3, wfix=1)


class ClumpSet:
    """Per-body state of the clumps of a ParticleSystem (arrays of length ``nb``; ``mass`` (nb,),
    ``bid`` stable body ids) and the CSR of members (``start``, ``members``: particle indices in
    id order)."""

    def __init__(self):
        self.nb = 0
        self.next_bid = 0
        self._cap = 0
        self._alloc(8)
        self.start = np.zeros(1, np.int64)
        self.members = np.zeros(0, np.int64)

    def _alloc(self, cap):
        for k, w in _BODY_ARRAYS.items():
            a = np.zeros((cap, w))
            o = getattr(self, "_" + k, None)
            if o is not None:
                a[: self.nb] = o[: self.nb]
            setattr(self, "_" + k, a)
        for k, dt in (("mass", float), ("bid", np.int64)):
            a = np.ones(cap, dt)
            o = getattr(self, "_" + k, None)
            if o is not None:
                a[: self.nb] = o[: self.nb]
            setattr(self, "_" + k, a)
        self._cap = cap

    def __getattr__(self, k):
        if k in _BODY_ARRAYS or k in ("mass", "bid"):
            return self.__dict__["_" + k][: self.nb]
        raise AttributeError(k)

    def add(self, m, mass, inert, com, vel, L, quat) -> np.ndarray:
        if self.nb + m > self._cap:
            self._alloc(max(2 * (self.nb + m), 8))
        s = slice(self.nb, self.nb + m)
        for k in _BODY_ARRAYS:
            getattr(self, "_" + k)[s] = 0.0
        self._mass[s] = mass
        self._inert[s] = inert
        self._com[s] = com
        self._vel[s] = vel
        self._L[s] = L
        self._quat[s] = quat
        bid = np.arange(self.next_bid, self.next_bid + m, dtype=np.int64)
        self._bid[s] = bid
        self.next_bid += m
        self.nb += m
        return bid

    def keep(self, keep_mask) -> np.ndarray:
        """Keep bodies where keep_mask; returns the map old index -> new index (-1: removed)."""
        idx = np.flatnonzero(keep_mask)
        newidx = np.full(self.nb, -1, np.int64)
        newidx[idx] = np.arange(len(idx))
        for k in list(_BODY_ARRAYS) + ["mass", "bid"]:
            a = getattr(self, "_" + k)
            a[: len(idx)] = a[idx]
        self.nb = len(idx)
        return newidx

    def rebuild_csr(self, body, ids):
        """Members of each body in the order of their particle ids."""
        n = len(body)
        order = np.lexsort((ids, body))
        sel = order[body[order] >= 0]
        self.members = np.ascontiguousarray(sel.astype(np.int64))
        counts = np.bincount(body[sel], minlength=self.nb) if len(sel) else np.zeros(self.nb, np.int64)
        self.start = np.zeros(self.nb + 1, np.int64)
        np.cumsum(counts, out=self.start[1:])
        del n

    def get_state(self) -> dict:
        st = {"c_nb": self.nb, "c_next_bid": self.next_bid}
        for k in list(_BODY_ARRAYS) + ["mass", "bid"]:
            st["c_" + k] = getattr(self, "_" + k)[: self.nb].copy()
        return st

    def set_state(self, st) -> None:
        nb = int(st["c_nb"])
        self.nb = 0
        self._alloc(max(nb, 8))
        self.nb = nb
        for k in list(_BODY_ARRAYS) + ["mass", "bid"]:
            if k == "wfix" and "c_wfix" not in st:  # written before rotation locking: all free
                getattr(self, "_" + k)[:nb] = 0.0
                continue
            a = np.asarray(st["c_" + k])
            getattr(self, "_" + k)[:nb] = a.reshape(getattr(self, "_" + k)[:nb].shape)
        self.next_bid = int(st["c_next_bid"])

    def kinetic_energy(self) -> float:
        """sum 1/2 M |v|^2 + 1/2 L . w over bodies (lab frame of the simulation)."""
        e = 0.0
        for b in range(self.nb):
            R = matrix_from_quat(self.quat[b])
            p = R.T @ self.L[b]
            e += 0.5 * self.mass[b] * float(self.vel[b] @ self.vel[b]) + 0.5 * float(np.sum(p * p / self.inert[b]))
        return e

    def omega(self) -> np.ndarray:
        out = np.zeros((self.nb, 3))
        for b in range(self.nb):
            R = matrix_from_quat(self.quat[b])
            out[b] = R @ ((R.T @ self.L[b]) / self.inert[b])
        return out
