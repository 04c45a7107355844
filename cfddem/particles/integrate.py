"""Time integration and the per-step force kernels.

Integrator: velocity Verlet in kick-drift-kick form (as LIGGGHTS ``fix nve/sphere``), for
translation and rotation:

    v_{n+1/2} = K_{dt/2}(v_n; F_n)          w_{n+1/2} = K_{dt/2}(w_n; T_n)
    r_{n+1}   = r_n + dt v_{n+1/2}
    F_{n+1}, T_{n+1} from r_{n+1}, v_{n+1/2}, w_{n+1/2}
    v_{n+1}   = K_{dt/2}(v_{n+1/2}; F_{n+1})  w_{n+1} = K_{dt/2}(w_{n+1/2}; T_{n+1})

Rotating frame (physics.md §3): the centrifugal force -m Omega x (Omega x (r - r_axis)) depends
on position only and is part of F.  The velocity-dependent terms are integrated inside each
half kick K_h exactly as a rotation, Boris style:

    v- = v + (h/2) F/m;   v+ = Rot(Omega_hat, -2|Omega| h) v-;   v_new = v+ + (h/2) F/m

(exact for dv/dt = -2 Omega x v; the kick is a symmetric second-order approximation of the flow
of dv/dt = F/m - 2 Omega x v, so Strang composition keeps the scheme second order and
time-reversible).  Likewise w is rotated by angle -|Omega| h for T = -I Omega x w.

Kernels per step: the opening kick and drift (:func:`kick_drift`, or fused into the previous
step's :func:`body_kick`), the neighbour rebuild when needed, :func:`pair_forces` (one pass over
the half list, slabs of cells in three colours: each particle's sums in an order that does not
depend on the threads), :func:`wall_forces` (the particles near a wall only) and
:func:`body_kick` (gravity, centrifugal force, the closing half kick).
"""

from __future__ import annotations

import math

import numpy as np

from cfddem._jit import kernel, parallel_kernel, prange
from cfddem.particles._twin import serial_twin
from cfddem.particles.contact import (P_1, P_2, P_3, P_4, P_MODEL, P_MU, P_MUR, pair_law,
                                      rolling_torque_limited, spring_energy, wall_contact_force)
from cfddem.particles.neighbours import _min_image, _wrap
from cfddem.particles.walls import wall_contact, wall_contact_s, wall_shift


def rotation_matrix(axis_vec, angle_per_unit: float, h: float) -> np.ndarray:
    """Rotation by angle ``-angle_per_unit * |axis_vec| * h`` about ``axis_vec`` (Rodrigues)."""
    a = np.asarray(axis_vec, float)
    w = float(np.linalg.norm(a))
    if w == 0.0:
        return np.eye(3)
    k = a / w
    th = -angle_per_unit * w * h
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * (K @ K)


@kernel(inline="always")
def _half_kick(vx, vy, vz, ax, ay, az, h, rotating, r00, r01, r02, r10, r11, r12, r20, r21, r22):
    vx += 0.5 * h * ax
    vy += 0.5 * h * ay
    vz += 0.5 * h * az
    if rotating:
        ux = r00 * vx + r01 * vy + r02 * vz
        uy = r10 * vx + r11 * vy + r12 * vz
        uz = r20 * vx + r21 * vy + r22 * vz
        vx, vy, vz = ux, uy, uz
    vx += 0.5 * h * ax
    vy += 0.5 * h * ay
    vz += 0.5 * h * az
    return vx, vy, vz


@kernel(inline="always")
def _past_slack(slack, i, wgeom, dx, dy, dz):
    """True if the displacement d may have brought particle i within reach of a standing wall
    it is not a candidate of (its margins ``slack[i]``, walls.wall_candidates).

    The nearest wall's shift is computed for every particle (wall 0 stands in where there is
    none: pack_walls gives wgeom a row even without walls) and the two tests are combined
    bitwise, without early returns or short-circuits: their branches made the kick loop ~30 %
    slower (27-31 against 22-25 ns per particle, the 30k chute, one thread)."""
    s2 = slack[i, 1]
    w = int(slack[i, 2])
    shift = wall_shift(wgeom, max(w, 0), dx, dy, dz)
    # (both False for a non-finite d: the force pass reports that particle)
    return (dx * dx + dy * dy + dz * dz >= s2 * s2) | ((w >= 0) & (shift >= slack[i, 0]))


@parallel_kernel
def kick_drift(n, pos, vel, omg, force, torque, mass, inertia, ext_f, ext_t, has_ext, dt, rotating,
               Rv, Rw, periodic_len, plo, ref, held, dux, duy, duz, B, slack, wgeom):
    """Opening half kick and drift; wraps periodic axes; returns the displacements since the
    last rebuild d = r - r_ref as (max |d|^2, max |d - u|^2, the number of particles that may
    have come within reach of a standing wall they are not a candidate of), with
    u = (dux, duy, duz) + B r_ref the bed's estimated displacement field (3 x 3 ``B``) and
    ``slack`` their margins (:func:`cfddem.particles.walls.wall_candidates`): the rebuild test,
    :meth:`cfddem.particles.ParticleSystem._expired`.
    Held particles (``held[i] == 1``: a feed moving at a set velocity) keep their velocity and
    spin: no kick, only the drift; ``held[i] == 2``: the spin is locked (particles.rotation =
    'locked'), the velocity is kicked."""
    h = 0.5 * dt
    rv00 = Rv[0, 0]
    rv01 = Rv[0, 1]
    rv02 = Rv[0, 2]
    rv10 = Rv[1, 0]
    rv11 = Rv[1, 1]
    rv12 = Rv[1, 2]
    rv20 = Rv[2, 0]
    rv21 = Rv[2, 1]
    rv22 = Rv[2, 2]
    rw00 = Rw[0, 0]
    rw01 = Rw[0, 1]
    rw02 = Rw[0, 2]
    rw10 = Rw[1, 0]
    rw11 = Rw[1, 1]
    rw12 = Rw[1, 2]
    rw20 = Rw[2, 0]
    rw21 = Rw[2, 1]
    rw22 = Rw[2, 2]
    b00 = B[0, 0]
    b01 = B[0, 1]
    b02 = B[0, 2]
    b10 = B[1, 0]
    b11 = B[1, 1]
    b12 = B[1, 2]
    b20 = B[2, 0]
    b21 = B[2, 1]
    b22 = B[2, 2]
    m2 = 0.0
    r2 = 0.0
    ws = 0
    for i in prange(n):
        im = 1.0 / mass[i]
        ii = 1.0 / inertia[i]
        efx = 0.0
        efy = 0.0
        efz = 0.0
        etx = 0.0
        ety = 0.0
        etz = 0.0
        if has_ext:
            efx = ext_f[i, 0]
            efy = ext_f[i, 1]
            efz = ext_f[i, 2]
            etx = ext_t[i, 0]
            ety = ext_t[i, 1]
            etz = ext_t[i, 2]
        vx = vel[i, 0]
        vy = vel[i, 1]
        vz = vel[i, 2]
        wx = omg[i, 0]
        wy = omg[i, 1]
        wz = omg[i, 2]
        hv = held[i]
        if hv != 1:
            vx, vy, vz = _half_kick(vx, vy, vz,
                                    (force[i, 0] + efx) * im, (force[i, 1] + efy) * im,
                                    (force[i, 2] + efz) * im, h, rotating,
                                    rv00, rv01, rv02, rv10, rv11, rv12, rv20, rv21, rv22)
        if hv == 0:
            wx, wy, wz = _half_kick(wx, wy, wz,
                                    (torque[i, 0] + etx) * ii, (torque[i, 1] + ety) * ii,
                                    (torque[i, 2] + etz) * ii, h, rotating,
                                    rw00, rw01, rw02, rw10, rw11, rw12, rw20, rw21, rw22)
        vel[i, 0] = vx
        vel[i, 1] = vy
        vel[i, 2] = vz
        omg[i, 0] = wx
        omg[i, 1] = wy
        omg[i, 2] = wz
        x = pos[i, 0] + dt * vx
        y = pos[i, 1] + dt * vy
        z = pos[i, 2] + dt * vz
        x = _wrap(x, plo[0], periodic_len[0])
        y = _wrap(y, plo[1], periodic_len[1])
        z = _wrap(z, plo[2], periodic_len[2])
        pos[i, 0] = x
        pos[i, 1] = y
        pos[i, 2] = z
        dx = _min_image(x - ref[i, 0], periodic_len[0])
        dy = _min_image(y - ref[i, 1], periodic_len[1])
        dz = _min_image(z - ref[i, 2], periodic_len[2])
        m2 = max(m2, dx * dx + dy * dy + dz * dz)
        qx = dx - dux - (b00 * ref[i, 0] + b01 * ref[i, 1] + b02 * ref[i, 2])
        qy = dy - duy - (b10 * ref[i, 0] + b11 * ref[i, 1] + b12 * ref[i, 2])
        qz = dz - duz - (b20 * ref[i, 0] + b21 * ref[i, 1] + b22 * ref[i, 2])
        r2 = max(r2, qx * qx + qy * qy + qz * qz)
        ws += _past_slack(slack, i, wgeom, dx, dy, dz)
    return m2, r2, ws


@parallel_kernel
def pair_forces(n, nslab, slab_start, slab_ov, first_start, pj, pos, vel, omg, radius, mass,
                inertia, params, periodic_len, hist, force, torque, store, pf, pr, dt, dt_hist):
    """The contact forces of all pairs, summed into ``force`` and ``torque`` (zeroed first) in
    one pass over the half list: each pair's force is added to its first particle a (summed
    over a's pairs, which are contiguous in the list, then added once) and subtracted from its
    second particle b (Newton's third law exactly).  The torques are R_a n x F_t + T_r on a and
    R_b n x F_t - T_r on b (T_r the rolling torque, only when mu_r > 0).  Updates the
    tangential history (zero when not touching).

    Threads: the particles' slabs (:func:`cfddem.particles.neighbours.slab_starts`) are run in
    three colours, s = 0, 3, 6, ... in parallel, then 1, 4, ..., then 2, 5, ...; a pair joins
    particles of the same or neighbouring slabs, so two slabs of one colour never write the
    same particle.  Each particle's forces are summed in an order fixed by the slabs alone:
    the result is the same, bit for bit, for any number of threads.

    ``store``: also write each pair's (force on a, n x F_t) to ``pf[k]`` and its rolling torque
    on a to ``pr[k]`` (zero when not touching), for measurements that need the forces pair by
    pair (:meth:`cfddem.particles.ParticleSystem.pair_forces`).

    Each slab's largest overlap ratio d_n / min(R_a, R_b) goes to ``slab_ov[s]``; returns their
    maximum."""
    mur = params[0, P_MUR]
    model = params[0, P_MODEL]
    p1 = params[0, P_1]
    p2 = params[0, P_2]
    p3 = params[0, P_3]
    p4 = params[0, P_4]
    mu = params[0, P_MU]
    pl0 = periodic_len[0]
    pl1 = periodic_len[1]
    pl2 = periodic_len[2]
    # Zeroing (no loop of its own: each parallel loop costs a thread wake-up, 45-65 us on
    # these machines).  A pair writes its second particle in the same or the next slab, and
    # slab 0 also in the last one (periodic major axis).  So the last slab is zeroed here, and
    # in the first colour each slab s = 3q zeroes its group s .. s + 2 (but the last slab)
    # before its own pairs: no other slab of that colour writes into the group.
    for i in range(slab_start[nslab - 1], slab_start[nslab]):
        force[i, 0] = 0.0
        force[i, 1] = 0.0
        force[i, 2] = 0.0
        torque[i, 0] = 0.0
        torque[i, 1] = 0.0
        torque[i, 2] = 0.0
    for colour in range(3):
        nq = (nslab - colour + 2) // 3
        for q in prange(nq):
            sl = colour + 3 * q
            if colour == 0:
                for i in range(slab_start[sl], slab_start[min(sl + 3, nslab - 1)]):
                    force[i, 0] = 0.0
                    force[i, 1] = 0.0
                    force[i, 2] = 0.0
                    torque[i, 0] = 0.0
                    torque[i, 1] = 0.0
                    torque[i, 2] = 0.0
            ovs = 0.0
            for a in range(slab_start[sl], slab_start[sl + 1]):
                xa = pos[a, 0]
                ya = pos[a, 1]
                za = pos[a, 2]
                ra = radius[a]
                ma = mass[a]
                vax = vel[a, 0]
                vay = vel[a, 1]
                vaz = vel[a, 2]
                wax = omg[a, 0]
                way = omg[a, 1]
                waz = omg[a, 2]
                fax = 0.0
                fay = 0.0
                faz = 0.0
                tax = 0.0
                tay = 0.0
                taz = 0.0
                for k in range(first_start[a], first_start[a + 1]):
                    b = pj[k]
                    dx = _min_image(pos[b, 0] - xa, pl0)
                    dy = _min_image(pos[b, 1] - ya, pl1)
                    dz = _min_image(pos[b, 2] - za, pl2)
                    rb = radius[b]
                    rs = ra + rb
                    d2 = dx * dx + dy * dy + dz * dz
                    if d2 >= rs * rs:
                        hist[k, 0] = 0.0
                        hist[k, 1] = 0.0
                        hist[k, 2] = 0.0
                        if store:
                            for c in range(6):
                                pf[k, c] = 0.0
                            for c in range(3):
                                pr[k, c] = 0.0
                        continue
                    d = math.sqrt(d2)
                    nx = dx / d
                    ny = dy / d
                    nz = dz / d
                    dn = rs - d
                    mb = mass[b]
                    meff = ma * mb / (ma + mb)
                    sx = ra * wax + rb * omg[b, 0]
                    sy = ra * way + rb * omg[b, 1]
                    sz = ra * waz + rb * omg[b, 2]
                    vx = vax - vel[b, 0] + sy * nz - sz * ny
                    vy = vay - vel[b, 1] + sz * nx - sx * nz
                    vz = vaz - vel[b, 2] + sx * ny - sy * nx
                    fx, fy, fz, tx, ty, tz, hx, hy, hz, fnabs = pair_law(
                        model, p1, p2, p3, p4, mu, meff, ra * rb / rs, dn, nx, ny, nz, vx, vy, vz,
                        hist[k, 0], hist[k, 1], hist[k, 2], dt_hist)
                    hist[k, 0] = hx
                    hist[k, 1] = hy
                    hist[k, 2] = hz
                    # n x F_t
                    cx = ny * tz - nz * ty
                    cy = nz * tx - nx * tz
                    cz = nx * ty - ny * tx
                    fax += fx
                    fay += fy
                    faz += fz
                    tax += ra * cx
                    tay += ra * cy
                    taz += ra * cz
                    force[b, 0] -= fx
                    force[b, 1] -= fy
                    force[b, 2] -= fz
                    torque[b, 0] += rb * cx
                    torque[b, 1] += rb * cy
                    torque[b, 2] += rb * cz
                    rx = 0.0
                    ry = 0.0
                    rz = 0.0
                    if mur > 0.0:
                        rx, ry, rz = rolling_torque_limited(
                            mur, ra * rb / rs, fnabs, wax - omg[b, 0], way - omg[b, 1],
                            waz - omg[b, 2], 1.0 / inertia[a] + 1.0 / inertia[b], dt)
                        tax += rx
                        tay += ry
                        taz += rz
                        torque[b, 0] -= rx
                        torque[b, 1] -= ry
                        torque[b, 2] -= rz
                    if store:
                        pf[k, 0] = fx
                        pf[k, 1] = fy
                        pf[k, 2] = fz
                        pf[k, 3] = cx
                        pf[k, 4] = cy
                        pf[k, 5] = cz
                        pr[k, 0] = rx
                        pr[k, 1] = ry
                        pr[k, 2] = rz
                    ovs = max(ovs, dn / min(ra, rb))
                force[a, 0] += fax
                force[a, 1] += fay
                force[a, 2] += faz
                torque[a, 0] += tax
                torque[a, 1] += tay
                torque[a, 2] += taz
            slab_ov[sl] = ovs
    ovmax = 0.0
    for sl in range(nslab):
        ovmax = max(ovmax, slab_ov[sl])
    return ovmax


@kernel(inline="always")
def _rolling_step(tmax, inert, dt, pwx, pwy, pwz):
    """Rolling torque of one wall contact with limit ``tmax`` = mu_r R |F_n| on a particle whose
    spin predicted without it is pw: -I pw/dt if that is within the limit (the spin stops), else
    -tmax pw/|pw|; zero if pw = 0.  Returns (torque (3), the predicted spin with it (3))."""
    pw = math.sqrt(pwx * pwx + pwy * pwy + pwz * pwz)
    if pw == 0.0:
        return 0.0, 0.0, 0.0, pwx, pwy, pwz
    tstop = inert * pw / dt
    if tstop <= tmax:
        s = -inert / dt
    else:
        s = -tmax / pw
    rx = s * pwx
    ry = s * pwy
    rz = s * pwz
    return rx, ry, rz, pwx + dt * rx / inert, pwy + dt * ry / inert, pwz + dt * rz / inert


@parallel_kernel
def wall_forces(nl, plist, pos, vel, omg, force, torque, radius, mass, inertia, ext_t, has_ext,
                wgeom, wref, wpar, nw, wmask, maxf, whist, won, wfw, wtw, wfn,
                has_mesh, mstart, K, ms_mesh, ms_fn, ms_tw, mpar, mf, mt, dt, dt_hist):
    """Add the walls' contacts to ``force`` and ``torque`` of the ``nl`` particles ``plist``
    (those within reach of a wall since the last rebuild, or with candidate mesh triangles),
    after :func:`pair_forces`.  Each visits the analytic walls of its bits in ``wmask`` (every
    wall from ``maxf`` on) and adds the mesh walls' sums ``mf[i]``, ``mt[i]``
    (:func:`cfddem.particles.mesh.mesh_forces`) where it has candidate triangles.  A pass of its
    own over those particles only: the same code inside the loop over all particles (the pair
    pass, or the kick) cost that loop more than this pass costs.

    Back of a wall: a wall contact that would *start* (the particle was not touching that wall
    at the previous evaluation, ``won[i, w] == 0``) with an overlap above the radius, i.e. with
    the centre behind the face of a plane, rectangle or annulus, is not a contact: the sphere
    reached the one-sided wall from its back (from outside the region the walls enclose, e.g.
    over the rim of a ring).  Without this rule the contact switched on at an overlap up to 2 r
    and threw the particle out in one step.  The particle is marked behind that wall
    (``won[i, w] = 2``; 1 = in contact, 0 = neither) and gets no contact from it until its
    overlap ends.  Each such start is counted; the largest ``i * nw + w + 1`` among them names
    one (particle row i, wall w) for the diagnosis.

    Wall rolling friction is applied last, when all other torques on the particle are known:
    with w' = w + dt (T + T_ext)/I the spin predicted without it, the rolling torque of a wall
    contact is T_r = -I w'/dt if |I w'/dt| <= mu_r R |F_n| (the spin stops exactly: static
    rolling resistance) else -mu_r R |F_n| w'/|w'|.  It never reverses the spin within the
    step.  Analytic walls first, then the mesh slots (``ms_mesh``, |F_n| ``ms_fn``, parameters
    ``mpar``), in order.

    Returns (the largest wall overlap ratio, the count of back-of-wall events, their largest
    key i * nw + w + 1 or 0)."""
    ovmax = 0.0
    nback = 0
    kback = 0
    for q in prange(nl):
        i = plist[q]
        r = radius[i]
        inert = inertia[i]
        x = pos[i, 0]
        y = pos[i, 1]
        z = pos[i, 2]
        m = mass[i]
        vx = vel[i, 0]
        vy = vel[i, 1]
        vz = vel[i, 2]
        wx = omg[i, 0]
        wy = omg[i, 1]
        wz = omg[i, 2]
        mk = wmask[i]
        anyroll = False
        fx = 0.0
        fy = 0.0
        fz = 0.0
        tx = 0.0
        ty = 0.0
        tz = 0.0
        for w in range(nw):
            if w < maxf and (mk >> w) & 1 == 0:
                continue  # not within reach since the last rebuild (walls.wall_candidates)
            ov, nx, ny, nz, qx, qy, qz = wall_contact_s(
                wgeom[w, 0], wgeom[w, 1], wgeom[w, 2], wgeom[w, 3], wgeom[w, 4], wgeom[w, 5],
                wgeom[w, 6], wgeom[w, 7], wgeom[w, 8], wgeom[w, 9], wgeom[w, 10], wgeom[w, 11],
                wgeom[w, 12], wgeom[w, 13], wgeom[w, 14], x, y, z, r)
            wo = won[i, w]
            if ov > 0.0 and (wo == 2 or (wo == 0 and ov > r)):
                # behind the wall (docstring): no contact until the overlap ends; counted once
                if wo == 0:
                    nback += 1
                    kback = max(kback, i * nw + w + 1)
                    won[i, w] = 2
            elif ov > 0.0:
                # surface velocity: v + spin n x (q - p) (spin about the wall's own axis)
                wvx = wgeom[w, 16]
                wvy = wgeom[w, 17]
                wvz = wgeom[w, 18]
                spin = wgeom[w, 19]
                if spin != 0.0:
                    lx = qx - wgeom[w, 1]
                    ly = qy - wgeom[w, 2]
                    lz = qz - wgeom[w, 3]
                    wvx += spin * (wgeom[w, 5] * lz - wgeom[w, 6] * ly)
                    wvy += spin * (wgeom[w, 6] * lx - wgeom[w, 4] * lz)
                    wvz += spin * (wgeom[w, 4] * ly - wgeom[w, 5] * lx)
                cfx, cfy, cfz, ptx, pty, ptz, hx, hy, hz, fnabs, twx, twy, twz = wall_contact_force(
                    wpar[w, P_MODEL], wpar[w, P_1], wpar[w, P_2], wpar[w, P_3], wpar[w, P_4],
                    wpar[w, P_MU], m, r, ov, nx, ny, nz, qx, qy, qz, vx, vy, vz, wx, wy, wz, wvx, wvy, wvz,
                    whist[i, w, 0], whist[i, w, 1], whist[i, w, 2], wref[w, 0], wref[w, 1], wref[w, 2], dt_hist)
                whist[i, w, 0] = hx
                whist[i, w, 1] = hy
                whist[i, w, 2] = hz
                fx += cfx
                fy += cfy
                fz += cfz
                tx += ptx
                ty += pty
                tz += ptz
                won[i, w] = 1
                wfn[i, w] = fnabs
                wfw[i, w, 0] = -cfx
                wfw[i, w, 1] = -cfy
                wfw[i, w, 2] = -cfz
                wtw[i, w, 0] = twx
                wtw[i, w, 1] = twy
                wtw[i, w, 2] = twz
                ovmax = max(ovmax, ov / r)
                if wpar[w, P_MUR] > 0.0:
                    anyroll = True
            elif wo != 0:
                won[i, w] = 0
                wfn[i, w] = 0.0
                for c in range(3):
                    whist[i, w, c] = 0.0
                    wfw[i, w, c] = 0.0
                    wtw[i, w, c] = 0.0
        if has_mesh and mstart[i] < mstart[i + 1]:
            fx += mf[i, 0]
            fy += mf[i, 1]
            fz += mf[i, 2]
            tx += mt[i, 0]
            ty += mt[i, 1]
            tz += mt[i, 2]
        # the pair contacts' sums first, then the walls (one order for every thread count)
        fx = force[i, 0] + fx
        fy = force[i, 1] + fy
        fz = force[i, 2] + fz
        tx = torque[i, 0] + tx
        ty = torque[i, 1] + ty
        tz = torque[i, 2] + tz
        if has_mesh and mstart[i] < mstart[i + 1]:
            for s in range(K):
                if ms_mesh[i, s] >= 0 and mpar[ms_mesh[i, s], P_MUR] > 0.0:
                    anyroll = True
        if anyroll:
            etx = 0.0
            ety = 0.0
            etz = 0.0
            if has_ext:
                etx = ext_t[i, 0]
                ety = ext_t[i, 1]
                etz = ext_t[i, 2]
            pwx = wx + dt * (tx + etx) / inert
            pwy = wy + dt * (ty + ety) / inert
            pwz = wz + dt * (tz + etz) / inert
            for w in range(nw):
                mur = wpar[w, P_MUR]
                if won[i, w] != 1 or mur == 0.0:
                    continue
                rx, ry, rz, pwx, pwy, pwz = _rolling_step(mur * r * wfn[i, w], inert, dt, pwx, pwy, pwz)
                tx += rx
                ty += ry
                tz += rz
                wtw[i, w, 0] -= rx
                wtw[i, w, 1] -= ry
                wtw[i, w, 2] -= rz
            if has_mesh and mstart[i] < mstart[i + 1]:
                for s in range(K):
                    mm = ms_mesh[i, s]
                    if mm < 0:
                        continue
                    mur = mpar[mm, P_MUR]
                    if mur == 0.0:
                        continue
                    rx, ry, rz, pwx, pwy, pwz = _rolling_step(mur * r * ms_fn[i, s], inert, dt, pwx, pwy, pwz)
                    tx += rx
                    ty += ry
                    tz += rz
                    ms_tw[i, s, 0] -= rx
                    ms_tw[i, s, 1] -= ry
                    ms_tw[i, s, 2] -= rz
        force[i, 0] = fx
        force[i, 1] = fy
        force[i, 2] = fz
        torque[i, 0] = tx
        torque[i, 1] = ty
        torque[i, 2] = tz
    return ovmax, nback, kback


@parallel_kernel
def body_kick(n, pos, vel, omg, force, torque, mass, inertia, ext_f, ext_t, has_ext, gx, gy, gz, omx, omy, omz, cax, cay, caz,
              dt, kick, rotating, Rv, Rw, drift_next, periodic_len, plo, ref, held, dux, duy, duz, B, slack, wgeom):
    """Add gravity and the centrifugal force -m Omega x (Omega x (r - r_axis)) to the contact
    forces in ``force`` (:func:`pair_forces`, :func:`wall_forces`), and (if ``kick``) do the
    closing half kick.

    With ``drift_next`` the opening half kick and the drift of the *next* step follow at once
    (the same operations as :func:`kick_drift`, so results do not depend on the fusion; it
    saves one pass over the particles and one kernel launch per step).

    Returns (count of particles with non-finite position/velocity/spin, then after the fused
    drift (zeros without it) the displacements' maxima of :func:`kick_drift`).
    """
    h = 0.5 * dt
    rv00 = Rv[0, 0]
    rv01 = Rv[0, 1]
    rv02 = Rv[0, 2]
    rv10 = Rv[1, 0]
    rv11 = Rv[1, 1]
    rv12 = Rv[1, 2]
    rv20 = Rv[2, 0]
    rv21 = Rv[2, 1]
    rv22 = Rv[2, 2]
    rw00 = Rw[0, 0]
    rw01 = Rw[0, 1]
    rw02 = Rw[0, 2]
    rw10 = Rw[1, 0]
    rw11 = Rw[1, 1]
    rw12 = Rw[1, 2]
    rw20 = Rw[2, 0]
    rw21 = Rw[2, 1]
    rw22 = Rw[2, 2]
    bad = 0
    b00 = B[0, 0]
    b01 = B[0, 1]
    b02 = B[0, 2]
    b10 = B[1, 0]
    b11 = B[1, 1]
    b12 = B[1, 2]
    b20 = B[2, 0]
    b21 = B[2, 1]
    b22 = B[2, 2]
    m2 = 0.0
    r2 = 0.0
    ws = 0
    for i in prange(n):
        efx = 0.0
        efy = 0.0
        efz = 0.0
        etx = 0.0
        ety = 0.0
        etz = 0.0
        if has_ext:
            efx = ext_f[i, 0]
            efy = ext_f[i, 1]
            efz = ext_f[i, 2]
            etx = ext_t[i, 0]
            ety = ext_t[i, 1]
            etz = ext_t[i, 2]
        x = pos[i, 0]
        y = pos[i, 1]
        z = pos[i, 2]
        m = mass[i]
        im = 1.0 / m
        ii = 1.0 / inertia[i]
        vx = vel[i, 0]
        vy = vel[i, 1]
        vz = vel[i, 2]
        wx = omg[i, 0]
        wy = omg[i, 1]
        wz = omg[i, 2]
        fx = force[i, 0] + m * gx
        fy = force[i, 1] + m * gy
        fz = force[i, 2] + m * gz
        tx = torque[i, 0]
        ty = torque[i, 1]
        tz = torque[i, 2]
        if rotating:
            px = x - cax
            py = y - cay
            pz = z - caz
            o2 = omx * omx + omy * omy + omz * omz
            op = omx * px + omy * py + omz * pz
            fx += m * (o2 * px - op * omx)
            fy += m * (o2 * py - op * omy)
            fz += m * (o2 * pz - op * omz)
        force[i, 0] = fx
        force[i, 1] = fy
        force[i, 2] = fz
        hv = held[i]
        if kick and hv != 1:
            vx, vy, vz = _half_kick(vx, vy, vz, (fx + efx) * im, (fy + efy) * im,
                                    (fz + efz) * im, h, rotating,
                                    rv00, rv01, rv02, rv10, rv11, rv12, rv20, rv21, rv22)
            if hv == 0:
                wx, wy, wz = _half_kick(wx, wy, wz, (tx + etx) * ii, (ty + ety) * ii,
                                        (tz + etz) * ii, h, rotating,
                                        rw00, rw01, rw02, rw10, rw11, rw12, rw20, rw21, rw22)
            vel[i, 0] = vx
            vel[i, 1] = vy
            vel[i, 2] = vz
            omg[i, 0] = wx
            omg[i, 1] = wy
            omg[i, 2] = wz
        # one test for all nine: a NaN or inf anywhere makes (t - t) NaN
        tsum = x + y + z + vx + vy + vz + wx + wy + wz
        if not (tsum - tsum == 0.0):
            bad += 1
        if drift_next:
            ux, uy, uz = vx, vy, vz
            sx2, sy2, sz2 = wx, wy, wz
            if hv != 1:
                ux, uy, uz = _half_kick(vx, vy, vz, (fx + efx) * im, (fy + efy) * im,
                                        (fz + efz) * im, h, rotating,
                                        rv00, rv01, rv02, rv10, rv11, rv12, rv20, rv21, rv22)
            if hv == 0:
                sx2, sy2, sz2 = _half_kick(wx, wy, wz, (tx + etx) * ii, (ty + ety) * ii,
                                           (tz + etz) * ii, h, rotating,
                                           rw00, rw01, rw02, rw10, rw11, rw12, rw20, rw21, rw22)
            vel[i, 0] = ux
            vel[i, 1] = uy
            vel[i, 2] = uz
            omg[i, 0] = sx2
            omg[i, 1] = sy2
            omg[i, 2] = sz2
            xn = x + dt * ux
            yn = y + dt * uy
            zn = z + dt * uz
            xn = _wrap(xn, plo[0], periodic_len[0])
            yn = _wrap(yn, plo[1], periodic_len[1])
            zn = _wrap(zn, plo[2], periodic_len[2])
            pos[i, 0] = xn
            pos[i, 1] = yn
            pos[i, 2] = zn
            # read back from memory: keeps the reduction variable's definition chain short
            # (numba's parfor reduction analysis fails on the long += chains of fx otherwise)
            ex = _min_image(pos[i, 0] - ref[i, 0], periodic_len[0])
            ey = _min_image(pos[i, 1] - ref[i, 1], periodic_len[1])
            ez = _min_image(pos[i, 2] - ref[i, 2], periodic_len[2])
            m2 = max(m2, ex * ex + ey * ey + ez * ez)
            qx = ex - dux - (b00 * ref[i, 0] + b01 * ref[i, 1] + b02 * ref[i, 2])
            qy = ey - duy - (b10 * ref[i, 0] + b11 * ref[i, 1] + b12 * ref[i, 2])
            qz = ez - duz - (b20 * ref[i, 0] + b21 * ref[i, 1] + b22 * ref[i, 2])
            r2 = max(r2, qx * qx + qy * qy + qz * qz)
            ws += _past_slack(slack, i, wgeom, ex, ey, ez)
    return bad, m2, r2, ws


@kernel
def first_bad(n, pos, vel, omg):
    """Index of the first particle with a non-finite position, velocity or spin (-1: none)."""
    for i in range(n):
        for c in range(3):
            if not (math.isfinite(pos[i, c]) and math.isfinite(vel[i, c]) and math.isfinite(omg[i, c])):
                return i
    return -1


@kernel
def worst_overlap(npairs, pi, pj, pos, radius, periodic_len, n, wgeom, nw):
    """(particle index, ratio) of the largest overlap/min radius over pairs and walls."""
    best = -1.0
    who = -1
    for k in range(npairs):
        a = pi[k]
        b = pj[k]
        dx = _min_image(pos[b, 0] - pos[a, 0], periodic_len[0])
        dy = _min_image(pos[b, 1] - pos[a, 1], periodic_len[1])
        dz = _min_image(pos[b, 2] - pos[a, 2], periodic_len[2])
        dn = radius[a] + radius[b] - math.sqrt(dx * dx + dy * dy + dz * dz)
        q = dn / min(radius[a], radius[b])
        if q > best:
            best = q
            who = a if radius[a] <= radius[b] else b
    for i in range(n):
        for w in range(nw):
            ov, nx, ny, nz, qx, qy, qz = wall_contact(wgeom, w, pos[i, 0], pos[i, 1], pos[i, 2], radius[i])
            if ov > 0.0 and ov / radius[i] > best:
                best = ov / radius[i]
                who = i
    return who, best


@kernel
def elastic_energy(npairs, pi, pj, pos, radius, periodic_len, hist, pp, n, wgeom, nw, wpar, whist):
    """Energy stored in the contact springs (pairs with the row ``pp``, walls with ``wpar``): the
    ``energy`` kernel of each contact's law (:func:`cfddem.particles.contact.spring_energy`)."""
    e = 0.0
    for k in range(npairs):
        a = pi[k]
        b = pj[k]
        dx = _min_image(pos[b, 0] - pos[a, 0], periodic_len[0])
        dy = _min_image(pos[b, 1] - pos[a, 1], periodic_len[1])
        dz = _min_image(pos[b, 2] - pos[a, 2], periodic_len[2])
        dn = radius[a] + radius[b] - math.sqrt(dx * dx + dy * dy + dz * dz)
        if dn > 0.0:
            e += spring_energy(pp[P_MODEL], pp[P_1], pp[P_2], pp[P_3], pp[P_4],
                               radius[a] * radius[b] / (radius[a] + radius[b]), dn, hist[k, 0], hist[k, 1], hist[k, 2])
    for i in range(n):
        for w in range(nw):
            ov, nx, ny, nz, qx, qy, qz = wall_contact(wgeom, w, pos[i, 0], pos[i, 1], pos[i, 2], radius[i])
            if ov > 0.0:
                e += spring_energy(wpar[w, P_MODEL], wpar[w, P_1], wpar[w, P_2], wpar[w, P_3], wpar[w, P_4],
                                   radius[i], ov, whist[i, w, 0], whist[i, w, 1], whist[i, w, 2])
    return e


@kernel
def mesh_elastic_energy(n, K, ms_mesh, ms_ov, ms_h, mpar, radius):
    """Energy in the springs of the mesh-wall contacts at the last evaluation (slots of
    :mod:`cfddem.particles.mesh`), see :func:`cfddem.particles.contact.spring_energy`."""
    e = 0.0
    for i in range(n):
        for s in range(K):
            m = ms_mesh[i, s]
            if m >= 0:
                e += spring_energy(mpar[m, P_MODEL], mpar[m, P_1], mpar[m, P_2], mpar[m, P_3], mpar[m, P_4],
                                   radius[i], ms_ov[i, s], ms_h[i, s, 0], ms_h[i, s, 1], ms_h[i, s, 2])
    return e


@parallel_kernel
def overlap_check(pos, radius, n, newpos, newrad, m, periodic_len, out):
    """out[q] = new sphere q overlaps an existing particle or an earlier/later new sphere."""
    for q in prange(m):
        x = newpos[q, 0]
        y = newpos[q, 1]
        z = newpos[q, 2]
        r = newrad[q]
        hit = False
        for i in range(n):
            dx = _min_image(pos[i, 0] - x, periodic_len[0])
            dy = _min_image(pos[i, 1] - y, periodic_len[1])
            dz = _min_image(pos[i, 2] - z, periodic_len[2])
            c = r + radius[i]
            if dx * dx + dy * dy + dz * dz < c * c:
                hit = True
                break
        if not hit:
            for p in range(m):
                if p == q:
                    continue
                dx = _min_image(newpos[p, 0] - x, periodic_len[0])
                dy = _min_image(newpos[p, 1] - y, periodic_len[1])
                dz = _min_image(newpos[p, 2] - z, periodic_len[2])
                c = r + newrad[p]
                if dx * dx + dy * dy + dz * dz < c * c:
                    hit = True
                    break
        out[q] = hit


@kernel
def reduce_walls(n, nw, won, wfw, wtw, fout, tout):
    """Ordered (particle index) reduction of per-particle wall contributions."""
    for w in range(nw):
        for c in range(3):
            fout[w, c] = 0.0
            tout[w, c] = 0.0
    for i in range(n):
        for w in range(nw):
            if won[i, w] == 1:
                for c in range(3):
                    fout[w, c] += wfw[i, w, c]
                    tout[w, c] += wtw[i, w, c]


@kernel(inline="always")
def _in_zone(zones, z, x, y, w):
    """Whether the point (x, y, w) lies in zone row z: lo <= r < hi on every axis."""
    return (zones[z, 0] <= x < zones[z, 3] and zones[z, 1] <= y < zones[z, 4]
            and zones[z, 2] <= w < zones[z, 5])


@kernel
def velocity_zones(n, pos, vel, body, held, zones, nz):
    """Velocity zones (a feeder): each row of ``zones`` is (lo x, y, z, hi x, y, z, axis, value);
    a free sphere (not a clump member, not held) whose centre lies in a zone gets its velocity
    component ``axis`` set to ``value`` (the first zone that holds it).  Returns how many were set."""
    cnt = 0
    for i in range(n):
        if body[i] >= 0 or held[i] == 1:
            continue
        for z in range(nz):
            if _in_zone(zones, z, pos[i, 0], pos[i, 1], pos[i, 2]):
                vel[i, int(zones[z, 6])] = zones[z, 7]
                cnt += 1
                break
    return cnt


@kernel
def clump_velocity_zones(nb, start, members, com, bvel, vfix, pvel, zones, nz):
    """:func:`velocity_zones` for rigid clumps: a clump whose centre of mass lies in a zone gets its
    velocity component set, and its members' velocities change by the same amount (their spin
    part is unchanged).  A clump whose component is held (``vfix``) is skipped.  Returns how many
    clumps were set."""
    cnt = 0
    for b in range(nb):
        for z in range(nz):
            if _in_zone(zones, z, com[b, 0], com[b, 1], com[b, 2]):
                a = int(zones[z, 6])
                if vfix[b, a] != 0.0:
                    break
                dv = zones[z, 7] - bvel[b, a]
                bvel[b, a] = zones[z, 7]
                for k in range(start[b], start[b + 1]):
                    pvel[members[k], a] += dv
                cnt += 1
                break
    return cnt


kick_drift_s = serial_twin(kick_drift)
pair_forces_s = serial_twin(pair_forces)
body_kick_s = serial_twin(body_kick)
wall_forces_s = serial_twin(wall_forces)
