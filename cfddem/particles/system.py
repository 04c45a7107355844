"""ParticleSystem: the Python orchestrator of the DEM engine.

Holds structure-of-arrays particle data with spare capacity, the neighbour list and contact
history, and advances the system with velocity Verlet (see :mod:`cfddem.particles.integrate`).
Frame agnostic: it knows gravity, a frame rotation Omega about an axis through ``axis_point``,
walls and particles.

Particle order is not stable: the arrays are re-sorted by cell at every neighbour rebuild (for
cache locality) and compacted on removal.  Track particles by ``ids`` (int64, unique, never
reused).  ``force``/``torque`` hold the contact + wall + gravity + centrifugal force (and the
torques) of the last evaluation; ``ext_force``/``ext_torque`` are user arrays added at every
step (they persist until changed) and are not included in ``force``/``torque``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from cfddem import _jit  # noqa: F401  (numba flags and threading layer before numba starts)
import numba  # noqa: E402
import numpy as np

from cfddem.errors import CaseError
from cfddem.particles import clumps as cl
from cfddem.particles import integrate as it
from cfddem.particles import neighbours as nb
from cfddem.particles import mesh as mw
from cfddem.particles.contact import P_MU, P_MUR, ContactLaw
from cfddem.particles import walls as wl
from cfddem.particles.walls import KIND_OFF, MAX_FILTERED_WALLS, Wall, pack_walls


@dataclass
class StepStatus:
    """Outcome of :meth:`ParticleSystem.step`.  ``flag``: None, "nan", "overlap", "mesh_contacts"
    (a particle touched more mesh faces, edges or vertices at once than it has mesh contact
    slots) or "overflow_unrecoverable"; ``index``: the particle id concerned (-1 if none);
    ``value``: the offending quantity; ``message``: one sentence with step, particle, quantity, likely cause."""

    ok: bool = True
    flag: str | None = None
    index: int = -1
    value: float = 0.0
    message: str = ""
    steps_done: int = 0


_PARTICLE_ARRAYS = ("pos", "vel", "omega", "force", "torque", "radius", "mass", "inertia", "ids",
                    "ext_force", "ext_torque", "prev", "ref", "body", "boff", "held", "label")
_WALL_ARRAYS = ("whist", "won", "wfn", "wfw", "wtw")
# mesh-wall contact slots (cfddem.particles.mesh): mesh index (-1: free), last normal, last
# contact point, tangential spring, overlap, |F_n|, force and torque on the mesh
_MESH_ARRAYS = ("ms_mesh", "ms_n", "ms_q", "ms_h", "ms_ov", "ms_fn", "ms_fw", "ms_tw")
_ROW_ARRAYS = _PARTICLE_ARRAYS + _WALL_ARRAYS + _MESH_ARRAYS
# rows a rebuild need not carry into the new order (each permuted array costs a gather and a
# copy of its rows): the reference positions (set to the positions); when a force pass follows
# (a step's or a refresh's), the force and torque sums (zeroed and summed by the pair pass); the
# clump index and offsets of free spheres (-1 and 0 in every row without clumps); the per-wall
# force records, which the wall pass writes for every contact (and which are zero elsewhere):
# zeroed instead
_REBUILT_ROWS = ("force", "torque")
_CLUMP_ROWS = ("body", "boff")
_EVALUATED_WALL_ROWS = ("wfn", "wfw", "wtw")
#: the one-pass pair search keeps this many slots per particle at most (a denser neighbourhood,
#: e.g. a big particle among small ones, takes the count-and-fill passes instead)
MAX_PAIR_SLOTS = 48


class ParticleSystem:
    """DEM particles, walls, neighbour list and integrator (see module docstring)."""

    #: below this many particles the serial twins of the kernels run (same results, no
    #: thread start-up cost: the periodic chute of 3,000 particles took 99 ns per particle-step
    #: on one thread and 181 ns on two, 30,000 took 107 and 80 ns; benchmarks/size_scaling.py);
    #: tests set it to 0 to exercise the parallel kernels.
    serial_below: int = 10000

    def __init__(self, *, pp: ContactLaw, walls: list[Wall], dt: float,
                 gravity=(0.0, 0.0, 0.0), omega=(0.0, 0.0, 0.0), axis_point=(0.0, 0.0, 0.0),
                 periodic=(None, None, None), skin: float | None = None,
                 capacity: int = 1024, max_overlap_ratio: float = 0.5, mesh_slots: int = 6):
        if not (dt > 0 and math.isfinite(dt)):
            raise CaseError("dt", f"time step must be positive, got {dt}")
        if skin is not None and not skin > 0:
            raise CaseError("skin", f"must be positive, got {skin}")
        self.pp = pp
        # analytic walls and triangle-mesh walls (cfddem.particles.mesh.MeshWall) are kept apart:
        # ``walls`` / ``wall_forces()`` are the analytic ones, ``meshes`` / ``mesh_forces()`` the meshes
        self.walls = [w for w in walls if not isinstance(w, mw.MeshWall)]
        self.meshes = [w for w in walls if isinstance(w, mw.MeshWall)]
        names = [w.name for w in self.walls + self.meshes if w.name]
        if len(set(names)) < len(names):
            raise CaseError("walls", f"wall names must be unique, got {names}")
        if not 1 <= int(mesh_slots) <= 60:
            raise CaseError("mesh_slots", f"must be in 1..60, got {mesh_slots}")
        self._mt = mw.MeshTables(self.meshes)
        self.nm = len(self.meshes)
        self._K = int(mesh_slots) if self.nm else 1
        self._mesh_over = 0
        self._mesh_cells = 0
        self._mstart = np.zeros(1, np.int64)
        self._mlist = np.zeros(1, np.int64)
        self._mplist = np.zeros(0, np.int64)  # particles with candidate triangles
        self.dt = float(dt)
        self.gravity = np.asarray(gravity, float).reshape(3)
        self.frame_omega = np.asarray(omega, float).reshape(3)
        self.axis_point = np.asarray(axis_point, float).reshape(3)
        self.max_overlap_ratio_limit = float(max_overlap_ratio)
        self._skin_user = skin
        self._pp_params = pp.params().reshape(1, -1)
        self._has_roll = pp.mu_r > 0.0
        # slabs of the force pass (neighbours.slab_starts), set at each neighbour rebuild
        self._slab_start = np.zeros(2, np.int64)
        self._slab_ov = np.zeros(1)
        self._no_pf = np.zeros((1, 6))
        self._no_pr = np.zeros((1, 3))
        # walls within each particle's reach (walls.wall_candidates), set at each rebuild
        self._wmask = np.zeros(1, np.int64)
        self._wfilt = np.zeros(1, np.int64)
        # each particle's margins before a standing wall it is not a candidate of (walls.wall_candidates)
        self._wslack = np.array([[np.inf, np.inf, -1.0]])
        self._pair_slots = 0  # slots per particle of the one-pass pair search (0: count and fill)
        self._slot_buf = np.empty(0, np.int64)
        self._ndrift = 0  # drifts since the last rebuild
        self._ubar = np.zeros(3)  # the velocity field fitted at the last rebuild: u0 + G r
        self._ugrad = np.zeros((3, 3))
        self._ugrad_norm = 0.0
        self._rmax_built = 0.0
        self._pending_disp = None
        self._wplist = np.zeros(0, np.int64)  # particles near a wall (it.wall_forces)
        self._friction_built = None  # (mu, mu_r) of the contact tables as built (set_friction)
        self._has_ext = False
        self._wgeom, self._wref, self._wpar = pack_walls(self.walls)
        self.nw = len(self.walls)
        self._plen = np.zeros(3)
        self._plo = np.zeros(3)
        self._periodic = [False, False, False]
        if len(periodic) != 3:
            raise CaseError("periodic", "needs one entry per axis")
        for a, p in enumerate(periodic):
            if p is not None:
                lo, hi = float(p[0]), float(p[1])
                if not hi > lo:
                    raise CaseError("periodic", f"axis {a}: need hi > lo, got ({lo}, {hi})")
                self._plo[a], self._plen[a] = lo, hi - lo
                self._periodic[a] = True
        self._rotating = bool(np.any(self.frame_omega != 0.0))
        self._Rv = it.rotation_matrix(self.frame_omega, 2.0, 0.5 * self.dt)
        self._Rw = it.rotation_matrix(self.frame_omega, 1.0, 0.5 * self.dt)
        self.n = 0
        self.time = 0.0
        self.step_count = 0
        self._next_id = 0
        self._cap = 0
        #: called with this system after every completed step (e.g. a momentum budget that
        #: accumulates every step's forces); None: nothing.  Not state: whoever sets it sets it
        #: again after a restart.
        self.step_hook = None
        self._alloc_particles(max(int(capacity), 16))
        # neighbour list: current and previous (for history remap) buffers
        self._pcap = 0
        self._npairs = 0
        self._n_built = 0
        self._skin_built = 0.0
        self._cur = self._alloc_pairs(max(4 * self._cap, 64), self._cap)
        self._old = self._alloc_pairs(16, self._cap)
        self._need_rebuild = True
        self._forces_stale = True
        self._last_ov = 0.0
        # >= 0: the opening half kick and drift of the next step are already done (fused into the
        # previous step's gather; only left pending when a step() call stops on a bad flag)
        self._pending_m2 = -1.0
        self.n_rebuilds = 0
        # particles that came to an analytic wall from its back (no contact, see
        # integrate.wall_forces): the total, and the events not yet reported
        # (step, particle id, wall name, count in that evaluation) for the caller to log
        self.wall_back_count = 0
        self.wall_back_events: list[tuple[int, int, str, int]] = []
        self._fw = np.zeros((max(self.nw, 1), 3))
        self._tw = np.zeros((max(self.nw, 1), 3))
        # wall motion: kind saved while a wall is switched off; walls with v != 0 are translated
        self._wkind = self._wgeom[:, 0].copy()
        self._moving = np.flatnonzero(np.any(self._wgeom[: self.nw, 16:19] != 0.0, axis=1))
        # rigid clumps (cfddem.particles.clumps): None until add_clumps is called
        self.clumps = None
        # particles.rotation = 'locked': particles and clumps added from now on do not spin
        self.rotation_locked = False
        # velocity zones (add_velocity_zone): rows (lo xyz, hi xyz, axis, value); bodies set last step
        self._zones = np.zeros((0, 8))
        self.zone_count = 0
        # a sink plane (set_sink): (point, unit outward normal) or None; what it took so far
        self._sink = None
        self.sunk_count = 0
        self.sunk_mass = 0.0
        # what the sink took since the system was made, never reset: particles, and clumps whole
        self.sunk_total = 0
        self.sunk_bodies = 0

    # ------------------------------------------------------------------ storage
    def _alloc_particles(self, cap):
        old = {k: getattr(self, "_" + k, None) for k in _ROW_ARRAYS}
        nw = max(self.nw, 1)
        K = self._K
        shapes = dict(pos=(cap, 3), vel=(cap, 3), omega=(cap, 3), force=(cap, 3), torque=(cap, 3),
                      radius=(cap,), mass=(cap,), inertia=(cap,), ids=(cap,), label=(cap,), ext_force=(cap, 3),
                      ext_torque=(cap, 3), prev=(cap,), ref=(cap, 3), body=(cap,), boff=(cap, 3), held=(cap,),
                      whist=(cap, nw, 3),
                      won=(cap, nw), wfn=(cap, nw), wfw=(cap, nw, 3), wtw=(cap, nw, 3),
                      ms_mesh=(cap, K), ms_n=(cap, K, 3), ms_q=(cap, K, 3), ms_h=(cap, K, 3),
                      ms_ov=(cap, K), ms_fn=(cap, K), ms_fw=(cap, K, 3), ms_tw=(cap, K, 3))
        dtypes = dict(ids=np.int64, label=np.int64, prev=np.int64, body=np.int64, won=np.uint8, held=np.uint8,
                      ms_mesh=np.int64)
        for k, shp in shapes.items():
            a = np.zeros(shp, dtype=dtypes.get(k, np.float64))
            if k in ("mass", "inertia", "radius"):
                a[:] = 1.0  # harmless values beyond n
            if k == "ms_mesh":
                a[:] = -1
            o = old[k]
            if o is not None and self.n > 0:
                a[: self.n] = o[: self.n]
            setattr(self, "_" + k, a)
        # per-evaluation mesh scratch (not carried over): new contacts, summed force and torque
        self._mc = np.zeros((cap, K, 9))
        self._mf = np.zeros((cap, 3))
        self._mtq = np.zeros((cap, 3))
        self._cap = cap

    def _alloc_pairs(self, pcap, cap):
        return dict(pcap=pcap, pi=np.zeros(pcap, np.int64), pj=np.zeros(pcap, np.int64),
                    hist=np.zeros((pcap, 3)),
                    second_list=np.zeros(pcap, np.int64),
                    first_start=np.zeros(cap + 1, np.int64), second_start=np.zeros(cap + 1, np.int64),
                    counts=np.zeros(cap, np.int64))

    # ------------------------------------------------------------------ views
    pos = property(lambda s: s._pos[: s.n])
    vel = property(lambda s: s._vel[: s.n])
    omega = property(lambda s: s._omega[: s.n])
    force = property(lambda s: s._force[: s.n])
    torque = property(lambda s: s._torque[: s.n])
    radius = property(lambda s: s._radius[: s.n])
    mass = property(lambda s: s._mass[: s.n])
    inertia = property(lambda s: s._inertia[: s.n])
    ids = property(lambda s: s._ids[: s.n])
    #: tracer label per particle (colour or species; 0 unless set): kept through sorting, removal,
    #: periodic wraps and checkpoints; clump members carry their clump's label
    label = property(lambda s: s._label[: s.n])
    ext_force = property(lambda s: s._ext_force[: s.n])
    ext_torque = property(lambda s: s._ext_torque[: s.n])

    @property
    def skin(self) -> float:
        if self._skin_user is not None:
            return float(self._skin_user)
        return 0.3 * 2.0 * float(self.radius.max()) if self.n else 0.0

    @property
    def n_pairs(self) -> int:
        return self._npairs

    # ------------------------------------------------------------------ particles in/out
    def add_particles(self, pos, vel, radius, density, omega=None, held: bool = False, label=0,
                      rotation_locked: bool | None = None) -> np.ndarray:
        """Append spheres; returns their new ids.  radius, density, label (tracer label, an
        integer): scalars or (m,) arrays.
        m = rho 4/3 pi R^3, I = 2/5 m R^2.  Positions are wrapped into periodic boxes.
        ``held``: the new spheres move at their given velocity and spin, unaffected by forces,
        until :meth:`release` (a feed that pushes like a piston; they still push others).
        ``rotation_locked`` (None: :attr:`rotation_locked`, the case's ``particles.rotation``):
        the spheres never spin (their spin is set to 0 and contact torques are ignored).

        ``held`` per row: 0 free, 1 held (a feed), 2 translating freely with the spin locked."""
        pos = np.atleast_2d(np.asarray(pos, float))
        m = len(pos)
        if pos.shape != (m, 3):
            raise CaseError("pos", f"needs shape (m, 3), got {pos.shape}")
        vel = np.broadcast_to(np.asarray(vel, float), (m, 3))
        rad = np.broadcast_to(np.asarray(radius, float), (m,))
        rho = np.broadcast_to(np.asarray(density, float), (m,))
        locked = self.rotation_locked if rotation_locked is None else bool(rotation_locked)
        om = (np.zeros((m, 3)) if omega is None or locked
              else np.broadcast_to(np.asarray(omega, float), (m, 3)))
        lab = np.broadcast_to(np.asarray(label), (m,))
        if m == 0:
            return np.zeros(0, np.int64)
        if not np.issubdtype(lab.dtype, np.integer):
            raise CaseError("label", "tracer labels must be integers")
        if not np.all(rad > 0):
            raise CaseError("radius", "particle radii must be positive")
        if not np.all(rho > 0):
            raise CaseError("density", "particle densities must be positive")
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(vel)) and np.all(np.isfinite(om))):
            raise CaseError("pos", "non-finite position, velocity or spin")
        if self.n + m > self._cap:
            self._alloc_particles(max(int(1.5 * (self.n + m)), 16))
        s = slice(self.n, self.n + m)
        p = pos.copy()
        for a in range(3):
            if self._periodic[a]:
                p[:, a] = self._plo[a] + np.mod(p[:, a] - self._plo[a], self._plen[a])
        self._pos[s] = p
        self._vel[s] = vel
        self._omega[s] = om
        self._radius[s] = rad
        self._mass[s] = rho * 4.0 / 3.0 * np.pi * rad**3
        self._inertia[s] = 0.4 * self._mass[s] * rad**2
        ids = np.arange(self._next_id, self._next_id + m, dtype=np.int64)
        self._ids[s] = ids
        self._label[s] = lab
        self._next_id += m
        for k in ("force", "torque", "ext_force", "ext_torque", "ref", "whist", "wfn", "wfw", "wtw"):
            getattr(self, "_" + k)[s] = 0.0
        self._won[s] = 0
        for k in _MESH_ARRAYS:
            getattr(self, "_" + k)[s] = -1 if k == "ms_mesh" else 0.0
        self._prev[s] = -1
        self._body[s] = -1
        self._boff[s] = 0.0
        self._held[s] = 1 if held else (2 if locked else 0)
        self.n += m
        self._need_rebuild = True
        self._forces_stale = True
        return ids

    def remove_particles(self, mask) -> tuple[int, float]:
        """Remove particles where ``mask`` (length n) is True; returns (count, mass removed)."""
        mask = np.asarray(mask, bool)
        if mask.shape != (self.n,):
            raise CaseError("mask", f"needs shape ({self.n},), got {mask.shape}")
        if self._has_clumps():
            mask = self._clump_remove(mask)
        cnt = int(mask.sum())
        if cnt == 0:
            return 0, 0.0
        removed_mass = float(self.mass[mask].sum())
        # the last particles kept move into the holes (the rebuild that follows sorts them anyway):
        # work in proportion to the particles removed, not to all of them
        k = self.n - cnt
        holes = np.flatnonzero(mask[:k])
        movers = k + np.flatnonzero(~mask[k:])
        if len(holes):
            for name in _ROW_ARRAYS:
                if name in _MESH_ARRAYS and not self.nm:
                    continue  # no mesh walls: every row holds the same (free slots)
                a = getattr(self, "_" + name)
                a[holes] = a[movers]
        self.n = k
        if self._has_clumps():
            self.clumps.rebuild_csr(self._body[:k], self._ids[:k])
        self._need_rebuild = True
        self._forces_stale = True
        return cnt, removed_mass

    def set_sink(self, point=None, normal=None) -> None:
        """Particles whose centre lies beyond the plane through ``point`` with outward
        ``normal`` leave the system at the next neighbour rebuild that :meth:`step` makes (a
        clump when one of its members does), instead of forcing one of their own: an exit that
        costs no rebuilds.  They count in ``sunk_count`` / ``sunk_mass`` (:meth:`take_sunk`), and in
        ``sunk_total`` / ``sunk_bodies`` (particles, and clumps, since the system was made; never reset).
        Until then they move and touch like the others.  ``set_sink()`` removes the sink."""
        if point is None:
            self._sink = None
            return
        nrm = np.asarray(normal, float).reshape(3)
        ln = float(np.linalg.norm(nrm))
        if not ln > 0.0 or not np.all(np.isfinite(nrm)):
            raise CaseError("normal", f"the sink's normal must be a non-zero vector, got {nrm.tolist()}")
        self._sink = (np.asarray(point, float).reshape(3).copy(), nrm / ln)

    def beyond_sink(self) -> np.ndarray:
        """(n,) bool: the particles beyond the sink plane (all False without a sink)."""
        if self._sink is None:
            return np.zeros(self.n, bool)
        p, nrm = self._sink
        return self.pos @ nrm > float(p @ nrm)

    def drain_sink(self) -> tuple[int, float]:
        """Remove the particles beyond the sink plane now (the next step rebuilds the lists);
        returns (count, mass), which also count in ``sunk_count`` / ``sunk_mass``."""
        if self._sink is None or not self.n:
            return 0, 0.0
        beyond = self.beyond_sink()
        if not beyond.any():
            return 0, 0.0
        nb0 = 0 if self.clumps is None else int(self.clumps.nb)
        k, m = self.remove_particles(beyond)
        self.sunk_count += k
        self.sunk_mass += m
        self.sunk_total += k
        self.sunk_bodies += nb0 - (0 if self.clumps is None else int(self.clumps.nb))
        return k, m

    @property
    def steps_since_rebuild(self) -> int:
        """Drifts since the last neighbour rebuild."""
        return self._ndrift

    def take_sunk(self) -> tuple[int, float]:
        """(count, mass) that the sink took since the last call, and reset them."""
        out = (self.sunk_count, self.sunk_mass)
        self.sunk_count, self.sunk_mass = 0, 0.0
        return out

    def overlaps(self, pos, radius) -> np.ndarray:
        """Would these new spheres overlap existing particles or each other?  (m,) bool."""
        pos = np.ascontiguousarray(np.atleast_2d(np.asarray(pos, float)))
        m = len(pos)
        rad = np.ascontiguousarray(np.broadcast_to(np.asarray(radius, float), (m,)))
        out = np.zeros(m, np.bool_)
        if m:
            n = self.n
            pp, rr = self._pos, self._radius
            if n > 4 * m:  # only the particles in the new spheres' box (non-periodic axes) can touch them
                reach = float(rad.max()) + (float(self._radius[:n].max()) if n else 0.0)
                near = np.ones(n, bool)
                for a in range(3):
                    if self._periodic[a]:
                        continue
                    x = self._pos[:n, a]
                    near &= (x > pos[:, a].min() - reach) & (x < pos[:, a].max() + reach)
                pp, rr = np.ascontiguousarray(self._pos[:n][near]), np.ascontiguousarray(self._radius[:n][near])
                n = len(rr)
            it.overlap_check(pp, rr, n, pos, rad, m, self._plen, out)
        return out

    def _serial(self, n: int) -> bool:
        return n < self.serial_below or numba.get_num_threads() == 1

    # ------------------------------------------------------------------ neighbour list
    def _rebuild(self, forces_follow: bool = True):
        """Sort the particles by cell and build the pair, wall and mesh lists.  ``forces_follow``:
        a force pass comes next (in a step or a refresh), so the rows it writes anew are not
        carried into the new order (_REBUILT_ROWS); False (a list asked for between steps)
        carries every row."""
        n = self.n
        skin = self.skin
        rmax = float(self.radius.max()) if n else 0.0
        cut = 2 * rmax + skin
        for a in range(3):
            if self._periodic[a] and self._plen[a] < 2 * cut:
                raise CaseError("periodic", f"axis {a}: periodic length {self._plen[a]:g} m is "
                                f"shorter than twice the neighbour cutoff 2*(2 R_max + skin) = {2 * cut:g} m")
        lo, size, nc = nb.cell_grid(self._pos, n, rmax, skin, self._plo, self._plo + self._plen,
                                    self._periodic, serial=self._serial(n))
        ncell = int(nc[0] * nc[1] * nc[2])
        cell_of = np.empty(n, np.int64)
        order = np.empty(n, np.int64)
        cell_start = np.empty(ncell + 1, np.int64)
        nb.cell_sort(self._pos, n, lo, size, nc, cell_of, order, cell_start)
        self._slab_start = nb.slab_starts(nc, cell_start, self._periodic)
        self._slab_ov = np.zeros(max(len(self._slab_start) - 1, 1))
        # reorder particle arrays by cell (prev keeps each particle's index at the last build)
        ser = self._serial(n)
        width = 3 * max(self.nw, self._K, 1)
        if getattr(self, "_scratch", None) is None or self._scratch.size < n * width:
            self._scratch = np.empty(self._cap * width)
        clumped = self._has_clumps()
        for name in _ROW_ARRAYS:
            if name in _MESH_ARRAYS and not self.nm:
                continue  # no mesh walls: every row holds the same (free slots)
            if (name == "ref" or (forces_follow and name in _REBUILT_ROWS)
                    or (name in _CLUMP_ROWS and not clumped)):
                continue  # written before they are read again / the same in every row (-1, 0)
            if forces_follow and name in _EVALUATED_WALL_ROWS:
                getattr(self, "_" + name)[:n] = 0.0  # the next force pass writes the contacts' rows
                continue
            nb.permute_rows(getattr(self, "_" + name), order, n, self._scratch, ser)
        old_index = self._prev[:n].copy()
        # swap buffers: the current list becomes the old one
        self._old, self._cur = self._cur, self._old
        n_old, np_old = self._n_built, self._npairs
        cur = self._cur
        if len(cur["first_start"]) < n + 1:
            cur.update(first_start=np.zeros(self._cap + 1, np.int64),
                       second_start=np.zeros(self._cap + 1, np.int64),
                       counts=np.zeros(self._cap, np.int64))
        slots = self._pair_slots
        if 0 < slots <= MAX_PAIR_SLOTS:
            # one search pass into per-particle slots (the slots from the last build's largest
            # count: a particle with more makes it search again with more slots)
            while True:
                if len(self._slot_buf) < n * slots:
                    self._slot_buf = np.empty(int(1.2 * n * slots) + 64, np.int64)
                most = (nb.pair_search_s if ser else nb.pair_search)(
                    self._pos, self._radius, n, skin, lo, size, nc, self._plen, cell_start, cur["first_start"],
                    slots, self._slot_buf, cur["counts"])
                if most <= slots:
                    break
                slots = int(most) + 4
            need = nb.prefix_sum(cur["counts"], n, cur["first_start"])
            if need > cur["pcap"]:
                fs, ss, cn = cur["first_start"], cur["second_start"], cur["counts"]
                cur.update(self._alloc_pairs(int(1.3 * need) + 64, 0))
                cur.update(first_start=fs, second_start=ss, counts=cn)
            (nb.pair_compact_s if ser else nb.pair_compact)(n, slots, self._slot_buf, cur["first_start"],
                                                            cur["pi"], cur["pj"])
        else:
            search = nb.pair_search_s if ser else nb.pair_search
            cur["first_start"][: n + 1] = 0  # no room: count
            search(self._pos, self._radius, n, skin, lo, size, nc, self._plen, cell_start, cur["first_start"], 0,
                   cur["pj"], cur["counts"])
            need = nb.prefix_sum(cur["counts"], n, cur["first_start"])
            if need > cur["pcap"]:
                fs, ss, cn = cur["first_start"], cur["second_start"], cur["counts"]
                cur.update(self._alloc_pairs(int(1.3 * need) + 64, 0))
                cur.update(first_start=fs, second_start=ss, counts=cn)
            search(self._pos, self._radius, n, skin, lo, size, nc, self._plen, cell_start, cur["first_start"], 0,
                   cur["pj"], cur["counts"])
            (nb.pair_compact_s if ser else nb.pair_compact)(n, 0, cur["pj"], cur["first_start"], cur["pi"], cur["pj"])
        # slots for the next build: this build's largest count and some room
        self._pair_slots = int(cur["counts"][:n].max()) + 4 if n else 0
        npairs = int(need)
        if self._has_clumps():  # pairs of two members of one clump never touch
            npairs = int(cl.drop_intra_pairs(n, cur["first_start"], cur["pi"], cur["pj"], self._body))
        nb.second_csr(cur["pj"], npairs, n, cur["second_start"], cur["second_list"])
        old = self._old
        (nb.remap_history_s if ser else nb.remap_history)(cur["pi"], cur["pj"], npairs, cur["hist"], old_index, old["pi"], old["pj"],
                         old["hist"], old["first_start"], old["second_start"], old["second_list"],
                         n_old if np_old >= 0 else 0)
        self._npairs = npairs
        self._n_built = n
        self._skin_built = skin
        if self.nm:
            self._mesh_lists(lo, size, nc, rmax, skin, ser)
        self._wall_lists(skin, ser)
        self._prev[:n] = np.arange(n)
        self._ref[:n] = self._pos[:n]
        self._ndrift = 0
        self._fit_velocity_field()
        self._rmax_built = rmax
        if self._has_clumps():
            self.clumps.rebuild_csr(self._body[:n], self._ids[:n])
        self._need_rebuild = False
        self.n_rebuilds += 1

    def _bed_drift(self, ahead: int):
        """The bed's estimated displacement field since the last rebuild after ``ahead`` more
        drifts, u(r_ref) = u0 + B r_ref: the velocity field fitted at the rebuild (an affine
        least-squares fit, constant along periodic axes) times the time drifted.  Any field is
        a valid reference for :meth:`_expired`; a good one lets a flowing bed keep its lists
        while its particles keep their neighbours.  Returns (u0 (3), B (3, 3))."""
        tau = self.dt * (self._ndrift + ahead)
        return self._ubar * tau, self._ugrad * tau

    def _fit_velocity_field(self) -> None:
        """The affine velocity field v ~ u0 + G r of the particles at a rebuild (least squares;
        G's columns along periodic axes zero, so the field is periodic too; zero for clumps)."""
        n = self.n
        self._ubar = np.zeros(3)
        self._ugrad = np.zeros((3, 3))
        self._ugrad_norm = 0.0
        if self._has_clumps() or n < 16:
            return
        free = np.array([a for a in range(3) if not self._periodic[a]], np.int64)
        m = len(free) + 1
        xx, xv = np.empty((m, m)), np.empty((m, 3))
        # the normal equations in one compiled pass (np.linalg.lstsq on the n x m matrix took
        # ~2 ms of a 19 ms rebuild at 30,000 particles); any field makes an exact test
        nb.affine_moments(self._pos, self._vel, n, free, len(free), np.empty(4), xx, xv)
        scale = np.sqrt(np.maximum(np.diag(xx), 1e-300))  # columns scaled to unit norm
        coef, *_ = np.linalg.lstsq(xx / np.outer(scale, scale), xv / scale[:, None], rcond=1e-12)
        coef = coef / scale[:, None]
        c = self._pos[0, free]
        G = np.zeros((3, 3))
        G[:, free] = coef[1:].T
        u0 = coef[0] - G[:, free] @ c
        if not (np.all(np.isfinite(G)) and np.all(np.isfinite(u0))):
            return
        self._ugrad = G
        self._ubar = u0
        self._ugrad_norm = float(np.linalg.norm(G))  # Frobenius: bounds the 2-norm

    def _expired(self, m2: float, disp) -> bool:
        """Whether the neighbour, wall and mesh lists may miss a contact after this drift.

        ``disp`` = (max |d|^2, max |d - u|^2, the count of particles past their wall margins)
        over the particles' displacements d since the last rebuild (u = :meth:`_bed_drift`), or
        None (the plain test: max |d| beyond half the skin).

        Pairs: a pair left out of the list was farther apart than R_i + R_j + skin and can touch
        only once |d_i - d_j| > skin; |d_i - d_j| <= |d_i - u| + |d_j - u| <= 2 max |d - u| for
        any u.  So the pairs hold while max |d - u| <= skin/2 (with u = 0 the classic test), and
        a bed moving as a whole does not call for rebuilds, only its particles' relative motion.
        Standing walls: a particle is a candidate of wall w while its reach
        (:func:`cfddem.particles.walls.wall_reach`, a lower bound of its distance) is below
        r + skin; any other particle may move by its margin, its smallest reach minus r among the
        walls it is not a candidate of (at least the skin; far from the walls much more), across
        that wall (|d.n| for a plane: a bed sliding along its wall keeps its wall lists) and by
        the second smallest in all, before it could touch one.  Meshes: the largest |d| plus the meshes' own motion stays below the
        skin."""
        skin = self._skin_built
        if disp is None or not math.isfinite(m2):
            return not m2 <= (0.5 * skin) ** 2 or self._mt.disp > 0.5 * skin
        _, r2, ws = disp
        # |u_i - u_j| <= |B| |r_i - r_j|_ref <= |B| (2 R_max + |d_i - d_j|) for a pair that comes
        # to touch: it stays out of reach while 2 max|d - u| + 2 |B| R_max <= (1 - |B|) skin
        nb_ = self._ugrad_norm * self.dt * self._ndrift
        if not 2.0 * math.sqrt(r2) + 2.0 * nb_ * self._rmax_built <= (1.0 - nb_) * skin:
            return True
        if self.nm and math.sqrt(m2) + self._mt.disp > skin:
            return True
        return ws > 0.0

    def _filterable(self, w: int) -> bool:
        """Whether wall ``w`` may be skipped by the particles out of its reach (walls.wall_reach):
        it stands still, and its reach does not change when a particle wraps round a periodic
        axis (a plane, rectangle or annulus parallel to that axis, a cylinder along it).  Other
        walls are visited by every particle."""
        g = self._wgeom[w]
        if np.any(g[16:19] != 0.0):
            return False
        for a in range(3):
            if not self._periodic[a]:
                continue
            if g[0] == 2.0:  # cylinder: the axis must be the periodic one
                if abs(abs(g[4 + a]) - 1.0) > 1e-12:
                    return False
            elif abs(g[4 + a]) > 1e-12:
                return False
        return True

    def _wall_lists(self, skin, ser):
        """Each particle's analytic walls within reach until the next rebuild (a bit mask;
        :func:`cfddem.particles.walls.wall_candidates`): standing walls are filtered, moving
        ones visited by every particle."""
        n, nw = self.n, self.nw
        if len(self._wmask) < max(n, 1):
            self._wmask = np.zeros(max(self._cap, n, 1), np.int64)
            self._wslack = np.zeros((max(self._cap, n, 1), 3))
        self._wfilt = np.zeros(max(nw, 1), np.int64)
        for w in range(nw):
            self._wfilt[w] = self._filterable(w)
        (wl.wall_candidates_s if ser else wl.wall_candidates)(
            n, self._pos, self._radius, skin, self._wgeom, nw, MAX_FILTERED_WALLS, self._wfilt, self._wmask,
            self._wslack, self._won, self._wfn, self._whist, self._wfw, self._wtw)
        self._wall_plist()

    @property
    def _wall_candidates(self) -> int:
        """The (particle, wall) candidates of the last rebuild: the bits set in the masks
        (a statistic, counted when asked)."""
        return int(np.unpackbits(self._wmask[: self._n_built].view(np.uint8)).sum())

    def _wall_plist(self):
        """The particles the wall pass visits: walls within reach, or candidate mesh triangles."""
        n = self._n_built
        near = self._wmask[:n] != 0
        if self.nw > MAX_FILTERED_WALLS:
            near[:] = True
        if self.nm:
            near |= self._mstart[1: n + 1] > self._mstart[:n]
        self._wplist = np.flatnonzero(near).astype(np.int64)

    def _mesh_lists(self, lo, size, nc, rmax, skin, ser):
        """Bin the triangles into the particle cells and build each particle's candidate
        triangles (cfddem.particles.mesh, 'Search')."""
        n = self.n
        t = self._mt
        cut = rmax + skin
        counts = np.zeros(t.nt, np.int64)
        (mw.tri_cell_count_s if ser else mw.tri_cell_count)(t.T, t.nt, lo, size, nc, cut, counts)
        start = np.zeros(t.nt + 1, np.int64)
        np.cumsum(counts, out=start[1:])
        ne = int(start[-1])
        cells = np.empty(ne, np.int64)
        tris = np.empty(ne, np.int64)
        (mw.tri_cell_fill_s if ser else mw.tri_cell_fill)(t.T, t.nt, lo, size, nc, cut, start, cells, tris)
        order = np.argsort(cells, kind="stable")
        ncell = int(nc[0] * nc[1] * nc[2])
        ctstart = np.zeros(ncell + 1, np.int64)
        np.cumsum(np.bincount(cells, minlength=ncell), out=ctstart[1:])
        ctri = np.ascontiguousarray(tris[order])
        cnt = np.zeros(n, np.int64)
        (mw.mesh_cand_count_s if ser else mw.mesh_cand_count)(n, self._pos, self._radius, skin, lo, size, nc,
                                                              ctstart, ctri, t.T, cnt)
        mstart = np.zeros(max(self._cap, n) + 1, np.int64)
        np.cumsum(cnt, out=mstart[1: n + 1])
        mlist = np.empty(max(int(mstart[n]), 1), np.int64)
        (mw.mesh_cand_fill_s if ser else mw.mesh_cand_fill)(n, self._pos, self._radius, skin, lo, size, nc,
                                                            ctstart, ctri, t.T, mstart, mlist)
        self._mstart, self._mlist = mstart, mlist
        # only particles with candidate triangles can touch a mesh: the force kernel visits them
        # alone (a particle without candidates had no contact at the last evaluation either;
        # its slots are cleared here all the same)
        self._mplist = np.flatnonzero(cnt).astype(np.int64)
        self._mstat = np.zeros((max(len(self._mplist), 1), 2))
        none = cnt == 0
        if np.any(self._ms_mesh[:n][none] >= 0):
            for k in _MESH_ARRAYS:
                getattr(self, "_" + k)[:n][none] = -1 if k == "ms_mesh" else 0.0
        self._mesh_cells = ne
        t.disp = 0.0

    def mesh_stats(self) -> dict:
        """Cost of the mesh-wall search at the last neighbour rebuild: triangles, (cell,
        triangle) bin entries, candidate (particle, triangle) pairs and their mean per particle,
        and the mesh contacts now."""
        n = self.n
        cand = int(self._mstart[n]) if self.nm and len(self._mstart) > n else 0
        return dict(triangles=self._mt.nt, bin_entries=int(self._mesh_cells), candidates=cand,
                    candidates_per_particle=cand / n if n else 0.0,
                    contacts=int(np.sum(self._ms_mesh[:n] >= 0)) if self.nm else 0)

    # ------------------------------------------------------------------ stepping
    def _forces(self, kick: bool, dt_hist: float, drift_next: bool = False):
        cur = self._cur
        ser = self._serial(self.n)
        ov_m = 0.0
        if self.nm:
            t = self._mt
            nl = len(self._mplist)
            over, ov_m = (mw.mesh_forces_s if self._serial(nl) else mw.mesh_forces)(
                nl, self._mplist, self._pos, self._vel, self._omega, self._radius, self._mass, self._mstart,
                self._mlist, t.T, t.tmesh, t.tedge, t.tvert, t.estart, t.etri, t.vstart, t.vtri,
                t.par, t.vel, t.omg, t.cen, t.ref, t.act, self._K, self._mc, self._ms_mesh, self._ms_n,
                self._ms_q, self._ms_h, self._ms_ov, self._ms_fn, self._ms_fw, self._ms_tw, self._mf,
                self._mtq, self._mstat, dt_hist)
            self._mesh_over = int(over)
        ov_pp = self._pair_pass(self._force, self._torque, cur["hist"], False, self._no_pf, self._no_pr,
                                dt_hist, ser)
        ov_w, nback, kback = 0.0, 0, 0
        nl = len(self._wplist)
        if nl:
            # a wall candidate costs about four particles' kick (27 ns warm, 65 cold per
            # candidate against 15-25 ns per particle): threads pay from a quarter of the count
            ov_w, nback, kback = (it.wall_forces_s if self._serial(4 * nl) else it.wall_forces)(
                nl, self._wplist, self._pos, self._vel, self._omega, self._force, self._torque, self._radius,
                self._mass, self._inertia, self._ext_torque, self._has_ext, self._wgeom, self._wref, self._wpar,
                self.nw, self._wmask, MAX_FILTERED_WALLS, self._whist, self._won, self._wfw, self._wtw, self._wfn,
                self.nm > 0, self._mstart, self._K, self._ms_mesh, self._ms_fn, self._ms_tw, self._mt.par,
                self._mf, self._mtq, self.dt, dt_hist)
        g, om, ap = self.gravity, self.frame_omega, self.axis_point
        drift_next = (drift_next and max(ov_pp, ov_m, ov_w) <= self.max_overlap_ratio_limit
                      and not self._mesh_over)
        u, B = self._bed_drift(1 if drift_next else 0)
        bad, *disp = (it.body_kick_s if ser else it.body_kick)(
            self.n, self._pos, self._vel, self._omega, self._force, self._torque, self._mass, self._inertia,
            self._ext_force, self._ext_torque, self._has_ext, g[0], g[1], g[2], om[0], om[1], om[2],
            ap[0], ap[1], ap[2], self.dt, kick, self._rotating, self._Rv, self._Rw, drift_next, self._plen,
            self._plo, self._ref, self._held, u[0], u[1], u[2], B, self._wslack, self._wgeom)
        self._last_ov = max(ov_pp, ov_w, ov_m)
        self._pending_m2 = disp[0] if drift_next else -1.0
        if drift_next:
            self._pending_disp = disp
            self._ndrift += 1
        if nback:
            i, w = divmod(int(kback) - 1, self.nw)
            self.wall_back_count += int(nback)
            if len(self.wall_back_events) < 1000:  # the caller drains them after each step() call
                self.wall_back_events.append((self.step_count + (1 if kick else 0), int(self._ids[i]),
                                              self.walls[w].name or f"#{w}", int(nback)))
        return bad

    def _pair_pass(self, force, torque, hist, store, pf, pr, dt_hist, ser):
        cur = self._cur
        return (it.pair_forces_s if ser else it.pair_forces)(
            self.n, len(self._slab_start) - 1, self._slab_start, self._slab_ov, cur["first_start"],
            cur["pj"],
            self._pos, self._vel, self._omega, self._radius, self._mass, self._inertia, self._pp_params,
            self._plen, hist, force, torque, store, pf, pr, self.dt, dt_hist)

    def pair_forces(self) -> dict:
        """The contact forces pair by pair at the current state (between steps): ``pi``, ``pj``
        (rows of the particle arrays, the list's pairs), ``force`` (npairs, 3) on ``pi`` from
        ``pj`` (zero where they do not touch), ``nxft`` (npairs, 3) n x F_t (the torques are
        R_a and R_b times it) and ``rolling`` (npairs, 3) the rolling torque on ``pi``.

        The step sums the pairs' forces into each particle without keeping them; this
        evaluates the contact laws once more at the current positions and velocities without
        advancing the tangential springs (the forces a restart would start from), and leaves
        the system as it was."""
        if self._forces_stale or self._need_rebuild:
            st = self._refresh()
            if st is not None:
                raise RuntimeError(st.message)
        n, npairs = self.n, self._npairs
        pf = np.zeros((max(npairs, 1), 6))
        pr = np.zeros((max(npairs, 1), 3))
        if n:
            self._pair_pass(np.zeros((n, 3)), np.zeros((n, 3)), self._cur["hist"][: max(npairs, 1)].copy(),
                            True, pf, pr, 0.0, self._serial(n))
        cur = self._cur
        return dict(pi=cur["pi"][:npairs].copy(), pj=cur["pj"][:npairs].copy(), force=pf[:npairs, :3],
                    nxft=pf[:npairs, 3:], rolling=pr[:npairs])

    def _refresh(self):
        """After insertion/removal: rebuild and re-evaluate forces at the current state without
        advancing the tangential springs (dt_hist = 0)."""
        try:
            self._rebuild()
        except MemoryError as exc:
            return self._fail("overflow_unrecoverable", -1, float("nan"),
                              f"step {self.step_count}: neighbour list could not grow ({exc})")
        n = self.n
        self._has_ext = bool(np.any(self._ext_force[:n]) or np.any(self._ext_torque[:n]))
        bad = self._forces(kick=False, dt_hist=0.0)
        if self._has_clumps():
            bad += self._clump_close(False)
        self._forces_stale = False
        if bad:
            return self._nan_status()
        return None

    def step(self, n_steps: int = 1) -> StepStatus:
        """Advance ``n_steps`` steps of velocity Verlet; stops early on a bad flag.

        Within one call the closing half kick of a step and the opening half kick + drift of the
        next are done in one pass (same arithmetic as separate passes).  After a "nan" or a wall
        "overlap" flag the positions may already hold the next step's drift (the state of a
        failed run is for diagnosis only).
        """
        if self.n == 0:
            if len(self._moving):
                self._translate_moving_walls(n_steps * self.dt)
            for k in range(n_steps):
                self._move_meshes(self.time + (k + 1) * self.dt)
            self.time += n_steps * self.dt
            self.step_count += n_steps
            return StepStatus(ok=True, steps_done=n_steps)
        if self._forces_stale or self._need_rebuild:
            self.drain_sink()
            if self.n == 0:
                return self.step(n_steps)
            st = self._refresh()
            if st is not None:
                return st
        dt = self.dt
        n = self.n
        self._has_ext = bool(np.any(self._ext_force[:n]) or np.any(self._ext_torque[:n]))
        clumped = self._has_clumps()
        for s in range(n_steps):
            if self._pending_m2 >= 0.0:
                # the opening kick + drift of this step were fused into the previous gather
                disp = self._pending_disp
                self._pending_m2 = -1.0
            else:
                kd = it.kick_drift_s if self._serial(self.n) else it.kick_drift
                u, B = self._bed_drift(1)
                disp = kd(self.n, self._pos, self._vel, self._omega, self._force, self._torque,
                          self._mass, self._inertia, self._ext_force, self._ext_torque, self._has_ext, dt,
                          self._rotating, self._Rv, self._Rw, self._plen, self._plo, self._ref, self._held,
                          u[0], u[1], u[2], B, self._wslack, self._wgeom)
                self._ndrift += 1
            m2 = disp[0]
            if clumped:  # bodies: opening kick, rotation, drift; members follow
                m2 = max(m2, self._clump_open())
                disp = None  # (members' displacements: the plain test)
            if len(self._moving):
                # walls move with the particles' drift: geometry at t + dt for the new forces
                self._translate_moving_walls(dt)
            if self.nm:
                self._move_meshes(self.time + dt)
            if self._need_rebuild or self._expired(m2, disp):
                if self._sink is not None and self.drain_sink()[0]:
                    # they left mid-step: the forces of the rows that stay are evaluated below,
                    # after the rebuild, as in any step (no refresh needed)
                    self._forces_stale = False
                    if self.n == 0:  # the last ones left: the walls have moved, the clock goes on
                        self._forces_stale = True
                        self.time += dt
                        self.step_count += 1
                        self.step(n_steps - s - 1)
                        return StepStatus(ok=True, steps_done=n_steps)
                try:
                    self._rebuild()
                except MemoryError as exc:
                    return self._fail("overflow_unrecoverable", -1, float("nan"),
                                      f"step {self.step_count + 1}: neighbour list could not grow ({exc})",
                                      s)
            zoned = len(self._zones) > 0
            bad = self._forces(kick=True, dt_hist=dt, drift_next=s < n_steps - 1 and not clumped and not zoned)
            if clumped:
                bad += self._clump_close(True)
            if zoned:
                self._apply_zones()
            self.time += dt
            self.step_count += 1
            if bad:
                st = self._nan_status()
                st.steps_done = s + 1
                return st
            if self.step_hook is not None:
                self.step_hook(self)
            if self._mesh_over:
                i = int(np.argmax(np.sum(self._ms_mesh[: self.n] >= 0, axis=1)))
                pid = int(self._ids[i])
                return self._fail("mesh_contacts", pid, float(self._K),
                                  f"step {self.step_count}: particle id {pid} touches more than "
                                  f"mesh_slots = {self._K} mesh faces, edges or vertices at once; "
                                  "likely cause: a very fine or crumpled mesh around a particle "
                                  "(raise ParticleSystem(mesh_slots=...))", s + 1)
            if self._last_ov > self.max_overlap_ratio_limit:
                who, val = it.worst_overlap(self._npairs, self._cur["pi"], self._cur["pj"], self._pos,
                                            self._radius, self._plen, self.n, self._wgeom, self.nw)
                if self.nm:
                    q = self._ms_ov[: self.n] / self._radius[: self.n, None]
                    if q.size and q.max() > val:
                        who, val = int(np.unravel_index(np.argmax(q), q.shape)[0]), float(q.max())
                if who >= 0 and val >= self.max_overlap_ratio_limit:
                    pid = int(self._ids[who])
                    what = f"particle id {pid} has overlap/radius = {val:.3g}"
                else:  # the overlapping particle has moved on (e.g. through a wall) since the force evaluation
                    pid, val = -1, self._last_ov
                    what = f"a contact reached overlap/radius = {val:.3g}"
                return self._fail(
                    "overlap", pid, float(val),
                    f"step {self.step_count}: {what} > "
                    f"{self.max_overlap_ratio_limit:g}; likely cause: {self._dt_hint()} "
                    "(or particles inserted into each other / too fast)", s + 1)
        return StepStatus(ok=True, steps_done=n_steps)

    def _max_speed(self) -> float:
        """The fastest particle's speed (finite values only; 0 without any)."""
        sp = np.sqrt(np.sum(self.vel**2, axis=1))
        sp = sp[np.isfinite(sp)]
        return float(sp.max()) if sp.size else 0.0

    def _min_tc(self) -> float:
        if self.n == 0:
            return float("inf")
        mmin = float(self.mass.min())
        rmin = float(self.radius.min())
        # impact speed for the Hertz time (ignored by the linear law): the fastest particle
        v = max(self._max_speed(), 1e-3)
        tc = self.pp.collision_time(0.5 * mmin, 0.5 * rmin, v)
        for w in self.walls + self.meshes:
            tc = min(tc, w.contact.collision_time(mmin, rmin, v))
        return tc

    def _stable_dt(self) -> float:
        """The stable step of velocity Verlet on one contact (:func:`cfddem.stability.contact_step_limit`),
        the smallest over the particle-particle law and the walls, at the fastest particle's
        speed (at least 1 mm/s); inf when no law gives one."""
        from cfddem.stability import contact_step_limit

        if self.n == 0:
            return math.inf
        mmin = float(self.mass.min())
        rmin = float(self.radius.min())
        v = max(self._max_speed(), 1e-3)
        lim = [contact_step_limit(self.pp, 0.5 * mmin, 0.5 * rmin, v)]
        lim += [contact_step_limit(w.contact, mmin, rmin, v) for w in self.walls + self.meshes]
        return min((x for d in lim for x in d.values()), default=math.inf)

    def _dt_hint(self) -> str:
        tc = self._min_tc()
        text = f"time step too large for this stiffness: dt = {self.dt / (tc / 20):.2g} t_c/20"
        dts = self._stable_dt()
        if self.dt <= 0.5 * dts:
            why = (f"{self.wall_back_count} particle(s) came to a wall from its back in this run: particles "
                   "left the region the walls enclose" if self.wall_back_count else
                   "look for particles inserted into each other or into a wall, a wall moved into particles, "
                   "or a particle leaving the walls' region")
            soft = self._soft_hint()
            if soft:
                why = f"{soft}; else {why}"
            text = (f"NOT the time step: dt = {self.dt:.3g} s is {self.dt / dts:.2g} of the stable step of one "
                    f"contact ({dts:.3g} s at the fastest particle's speed); {why}")
        return text

    def _soft_hint(self) -> str:
        """'' or a sentence when a head-on impact of the two fastest particles would overlap more
        than the overlap limit even when resolved exactly (undamped, k_n linearised at the
        impact): the contacts are too soft for the speeds, whatever the time step."""
        v = 2.0 * self._max_speed() if self.n else 0.0
        if v == 0.0:
            return ""
        mmin, rmin = float(self.mass.min()), float(self.radius.min())
        lin = self.pp.linearised(0.5 * mmin, 0.5 * rmin, v)
        if not lin or not lin.get("k_n"):
            return ""
        ratio = v * math.sqrt(0.5 * mmin / lin["k_n"]) / rmin
        if ratio <= self.max_overlap_ratio_limit:
            return ""
        return (f"the contacts are too soft for the speeds: a head-on impact at {v:.3g} m/s overlaps "
                f"{ratio:.2g} radii even when resolved exactly (k_n = {lin['k_n']:.3g} N/m at that impact): "
                f"raise the stiffness or lower the speeds")

    def _nan_status(self) -> StepStatus:
        i = it.first_bad(self.n, self._pos, self._vel, self._omega)
        pid = int(self._ids[i]) if i >= 0 else -1
        return self._fail("nan", pid, float("nan"),
                          f"step {self.step_count}: particle id {pid} has a non-finite position, "
                          f"velocity or spin; likely cause: {self._dt_hint()}")

    def _fail(self, flag, pid, val, msg, steps_done=0) -> StepStatus:
        return StepStatus(ok=False, flag=flag, index=pid, value=val, message=msg, steps_done=steps_done)

    # ------------------------------------------------------------------ diagnostics
    def kinetic_energy(self) -> float:
        """sum 1/2 m |v|^2 + 1/2 I |w|^2 in this frame (clumps: 1/2 M |v|^2 + 1/2 L.w per body)."""
        if self._has_clumps():
            free = self._body[: self.n] < 0
            return float(0.5 * np.sum(self.mass[free] * np.sum(self.vel[free]**2, axis=1))
                         + 0.5 * np.sum(self.inertia[free] * np.sum(self.omega[free]**2, axis=1))
                         + self.clumps.kinetic_energy())
        return float(0.5 * np.sum(self.mass * np.sum(self.vel**2, axis=1))
                     + 0.5 * np.sum(self.inertia * np.sum(self.omega**2, axis=1)))

    def momentum(self) -> np.ndarray:
        if self._has_clumps():
            free = self._body[: self.n] < 0
            c = self.clumps
            return (np.sum(self.mass[free, None] * self.vel[free], axis=0)
                    + np.sum(c.mass[:, None] * c.vel, axis=0))
        return np.sum(self.mass[:, None] * self.vel, axis=0)

    def elastic_energy(self) -> float:
        """Energy stored in contact springs (pair and wall): linear 1/2 k_n d_n^2 + 1/2 k_t |d_t|^2,
        Hertz-Mindlin (8/15) E* sqrt(R*) d_n^(5/2) + 1/2 S_t |d_t|^2."""
        if self.n == 0:
            return 0.0
        if self._need_rebuild:
            self._rebuild(forces_follow=False)
        cur = self._cur
        e = float(it.elastic_energy(self._npairs, cur["pi"], cur["pj"], self._pos, self._radius,
                                    self._plen, cur["hist"], self._pp_params[0], self.n, self._wgeom,
                                    self.nw, self._wpar, self._whist))
        if self.nm:  # mesh contacts as at the last force evaluation
            e += float(it.mesh_elastic_energy(self.n, self._K, self._ms_mesh, self._ms_ov, self._ms_h,
                                              self._mt.par, self._radius))
        return e

    def max_overlap_ratio(self) -> float:
        """Max over contacts (pairs and walls) of overlap / min radius at the last evaluation."""
        return float(self._last_ov)

    def wall_forces(self) -> np.ndarray:
        """(n_walls, 3) force exerted by the particles on each wall at the last evaluation."""
        it.reduce_walls(self.n, self.nw, self._won, self._wfw, self._wtw, self._fw, self._tw)
        return self._fw[: self.nw].copy()

    def wall_torques(self) -> np.ndarray:
        """(n_walls, 3) torque exerted by the particles on each wall about its reference point."""
        it.reduce_walls(self.n, self.nw, self._won, self._wfw, self._wtw, self._fw, self._tw)
        return self._tw[: self.nw].copy()

    def wall_labels(self) -> list[str]:
        """The name of each analytic wall (``wall<k>`` for an unnamed one), in engine order."""
        return [w.name or f"wall{k}" for k, w in enumerate(self.walls)]

    def mesh_labels(self) -> list[str]:
        """The name of each mesh wall (``mesh<k>`` for an unnamed one), in engine order."""
        return [w.name or f"mesh{k}" for k, w in enumerate(self.meshes)]

    def force_breakdown(self) -> dict:
        """Each particle's force at the last evaluation, split by origin: a dict of (n, 3)
        arrays (force ON the particle, in this frame)::

            gravity       m g
            centrifugal   -m Omega x (Omega x (r - axis_point))
            coriolis      -2 m Omega x v (at the current velocity; the integrator applies it as
                          an exact rotation of v over the half kicks, of which this is the rate)
            walls         {name: force} of each analytic wall (zero where not touching)
            meshes        {name: force} of each mesh wall
            contacts      particle-particle contacts: the engine's summed force minus the walls,
                          meshes, gravity and centrifugal force above (summed over a group of
                          particles, the pairs inside the group cancel: what is left is the force
                          across the group's boundary)
            external      ``ext_force`` (e.g. the gas's drag and pressure forces)

        ``held`` (n,) bool marks particles moving at a set velocity (a feed): their forces are
        computed but not applied.  Clump members carry their own sphere's forces.  Valid after
        a step (the forces belong to the current positions)."""
        if self._forces_stale or self._need_rebuild:
            st = self._refresh()
            if st is not None:
                raise RuntimeError(st.message)
        n = self.n
        m = self.mass[:, None]
        g = m * self.gravity[None, :]
        om = self.frame_omega
        r = self.pos - self.axis_point[None, :]
        cen = -m * np.cross(om[None, :], np.cross(om[None, :], r))
        cor = -2.0 * m * np.cross(om[None, :], self.vel)
        walls = {name: -self._wfw[:n, k, :].copy() for k, name in enumerate(self.wall_labels())}
        meshes = {}
        if self.nm:
            has = (self._mstart[1: n + 1] > self._mstart[:n])[:, None]
            for k, name in enumerate(self.mesh_labels()):
                on = self._ms_mesh[:n] == k
                meshes[name] = np.where(has, -np.einsum("ij,ijc->ic", on.astype(float),
                                                                        self._ms_fw[:n]), 0.0)
        contacts = self.force - g - cen
        for f in list(walls.values()) + list(meshes.values()):
            contacts = contacts - f
        return dict(gravity=g, centrifugal=cen, coriolis=cor, walls=walls, meshes=meshes, contacts=contacts,
                    external=self.ext_force.copy(), held=self.held)

    # ------------------------------------------------------------------ velocity zones
    def add_velocity_zone(self, lo, hi, axis: int, value: float) -> None:
        """A feeder: from now on, at the end of every step, every free sphere whose centre lies in
        the box ``lo`` <= r < ``hi`` (and every clump whose centre of mass does) gets its velocity
        component ``axis`` (0, 1, 2) set to ``value``.  This is the feeder of the blending
        thesis, a body force m (value - v)/dt with v the velocity of the previous step: the
        contacts and gravity of the next step still act on the particle (it drifts at value +
        dt/2 a and ends the step at value again).  Held particles are
        left alone.  The other components are untouched.  Zones are configuration, not state:
        whoever builds the system adds them again after a restart."""
        lo = np.asarray(lo, float).reshape(3)
        hi = np.asarray(hi, float).reshape(3)
        if not np.all(hi > lo):
            raise CaseError("zone", f"needs hi > lo on every axis (lo {lo.tolist()}, hi {hi.tolist()})")
        if axis not in (0, 1, 2):
            raise CaseError("zone", f"axis must be 0, 1 or 2, got {axis!r}")
        if not math.isfinite(value):
            raise CaseError("zone", f"velocity must be finite, got {value!r}")
        row = np.concatenate([lo, hi, [float(axis), float(value)]])
        self._zones = np.vstack([self._zones, row[None, :]])

    def clear_velocity_zones(self) -> None:
        self._zones = np.zeros((0, 8))

    def _apply_zones(self) -> None:
        nz = len(self._zones)
        cnt = it.velocity_zones(self.n, self._pos, self._vel, self._body, self._held, self._zones, nz)
        if self._has_clumps():
            c = self.clumps
            cnt += it.clump_velocity_zones(c.nb, c.start, c.members, c._com, c._vel, c._vfix, self._vel,
                                           self._zones, nz)
        self.zone_count = int(cnt)

    # ------------------------------------------------------------------ held particles
    @property
    def held(self) -> np.ndarray:
        """(n,) bool: particles moving at a set velocity, unaffected by forces (a feed)."""
        return self._held[: self.n] == 1

    def lock_rotation(self) -> int:
        """Lock the spin of every particle and clump now in the system (spin set to 0; contact
        torques ignored from now on), and of those added later (:attr:`rotation_locked`).  Held
        feed particles stay held and are locked at their release.  Returns the number of units
        (spheres and clumps) locked."""
        self.rotation_locked = True
        n = self.n
        free = (self._held[:n] == 0) & (self._body[:n] < 0)
        self._held[:n][free] = 2
        self._omega[:n][free] = 0.0
        k = int(free.sum())
        if self._has_clumps():
            c = self.clumps
            new = c.wfix[:, 0] == 0.0
            c.wfix[new] = 1.0
            c.L[new] = 0.0
            k += int(new.sum())
            body = self._body[:n]
            mem = body >= 0
            mem[mem] = new[body[mem]]  # the members of the clumps locked now
            self._omega[:n][mem] = 0.0
            self._held[:n][mem] = 2
        self._forces_stale = True
        return k

    def perturb_velocities(self, rms: float, seed: int) -> int:
        """Add a seeded random velocity to every free unit - a free sphere (not held, not a clump
        member) or a clump none of whose centre-of-mass components is held (all its members
        move with it, its spin unchanged) - such that the mass-weighted mean of the added
        velocities is zero (no net momentum) and their root-mean-square magnitude over the units
        is ``rms`` exactly (with one unit: ``rms``, no mean removal).  The draws go to the units
        in the order of their particle ids (a clump: its first member's), so the result does not
        depend on the storage order.  Returns the number of units perturbed."""
        n = self.n
        body = self._body[:n]
        ids = self._ids[:n]
        free = np.flatnonzero((body < 0) & (self._held[:n] != 1))
        keys, masses = [ids[free]], [self._mass[:n][free]]
        bodies = np.zeros(0, np.int64)
        if self._has_clumps():
            c = self.clumps
            bodies = np.flatnonzero(np.all(c.vfix == 0.0, axis=1))
            keys.append(ids[c.members[c.start[bodies]]])
            masses.append(c.mass[bodies])
        key, mass = np.concatenate(keys), np.concatenate(masses)
        m = len(key)
        if m == 0 or rms <= 0.0:
            return 0
        order = np.argsort(key, kind="stable")
        draw = np.random.default_rng(int(seed)).standard_normal((m, 3))  # in id order
        if m > 1:
            mo = mass[order]
            draw -= (mo[:, None] * draw).sum(axis=0) / mo.sum()
        draw *= rms / np.sqrt(np.mean(np.sum(draw * draw, axis=1)))
        dv = np.empty_like(draw)
        dv[order] = draw
        nf = len(free)
        self._vel[:n][free] += dv[:nf]
        if len(bodies):
            c = self.clumps
            c.vel[bodies] += dv[nf:]
            for j, b in enumerate(bodies):
                self._vel[:n][c.members[c.start[b]:c.start[b + 1]]] += dv[nf + j]
        return m

    def release(self, mask) -> int:
        """Let the held particles where ``mask`` is True move under forces from now on; returns
        how many were released."""
        mask = np.asarray(mask, bool) & (self._held[: self.n] == 1)
        self._held[: self.n][mask] = 2 if self.rotation_locked else 0
        return int(mask.sum())

    def set_label(self, mask, value) -> int:
        """Give the particles where ``mask`` (length n) is True the tracer label ``value`` (an
        integer); a clump member selected selects its whole clump.  Returns how many particles
        were relabelled."""
        mask = np.asarray(mask, bool)
        if mask.shape != (self.n,):
            raise CaseError("mask", f"needs shape ({self.n},), got {mask.shape}")
        if not isinstance(value, (int, np.integer)):
            raise CaseError("label", f"tracer labels must be integers, got {value!r}")
        body = self._body[: self.n]
        if self._has_clumps() and np.any(body[mask] >= 0):
            mask = mask | ((body >= 0) & np.isin(body, body[mask & (body >= 0)]))
        self._label[: self.n][mask] = int(value)
        return int(mask.sum())

    # ------------------------------------------------------------------ mesh walls
    def _lookup(self, items, wall, what: str) -> int:
        """Index of ``wall`` (a name or an index) in ``items`` (``walls`` or ``meshes``)."""
        if isinstance(wall, str):
            for k, w in enumerate(items):
                if w.name == wall:
                    return k
            raise KeyError(f"no {what} named {wall!r} (walls: {[w.name for w in self.walls + self.meshes]})")
        k = int(wall)
        if not 0 <= k < len(items):
            raise IndexError(f"{what} index {k} out of range (0..{len(items) - 1})")
        return k

    def _mesh_index(self, wall) -> int:
        return self._lookup(self.meshes, wall, "mesh wall")

    def _is_mesh(self, wall) -> bool:
        return isinstance(wall, str) and any(w.name == wall for w in self.meshes)

    def _move_meshes(self, t_new: float) -> None:
        """Apply the switch events due by ``t_new`` and move the moving meshes by one step."""
        mt = self._mt
        while mt.next_event < len(mt.events) and mt.events[mt.next_event][0] <= t_new + 1e-9 * self.dt:
            _, k, on = mt.events[mt.next_event]
            mt.next_event += 1
            self.set_mesh_active(k, on)
        if len(mt.moving()):
            mt.advance(self.dt)

    def set_mesh_active(self, wall, active: bool) -> None:
        """Switch mesh wall ``wall`` (name or index into ``meshes``) on or off; off drops its
        contacts (and their history) at the next evaluation."""
        self._mt.act[self._mesh_index(wall)] = 1 if active else 0
        self._forces_stale = True

    def mesh_active(self, wall) -> bool:
        return bool(self._mt.act[self._mesh_index(wall)])

    def set_mesh_motion(self, wall, velocity=None, angular_velocity=None) -> None:
        """Change the translation velocity (m/s) and/or the angular velocity (rad/s, about the
        mesh's centre, which moves with it) of mesh wall ``wall`` from now on."""
        k = self._mesh_index(wall)
        if velocity is not None:
            self._mt.vel[k] = mw._vec3("velocity", velocity)
        if angular_velocity is not None:
            self._mt.omg[k] = mw._vec3("angular_velocity", angular_velocity)
        self._mt.motion_changed()

    def mesh_vertices(self, wall) -> np.ndarray:
        """(nv, 3) current vertex positions of mesh wall ``wall`` (triangles: ``meshes[k].triangles``)."""
        return self._mt.vertices_now(self._mesh_index(wall))

    def mesh_surfaces(self) -> dict:
        """All mesh walls now, for ParaView (:meth:`cfddem.io.vtk.ParaViewOutput.write`):
        dict(vertices (nv, 3), triangles (nt, 3), mesh (nt,) index into ``meshes``, moving:
        whether any mesh moves)."""
        Vs, Fs, ks, off = [], [], [], 0
        for k, m in enumerate(self.meshes):
            Vs.append(self._mt.vertices_now(k))
            Fs.append(m.triangles + off)
            ks.append(np.full(m.n_triangles, k, np.int64))
            off += len(m.vertices)
        if not Vs:
            return dict(vertices=np.zeros((0, 3)), triangles=np.zeros((0, 3), np.int64),
                        mesh=np.zeros(0, np.int64), moving=False)
        return dict(vertices=np.concatenate(Vs), triangles=np.concatenate(Fs), mesh=np.concatenate(ks),
                    moving=bool(len(self._mt.moving())))

    def _reduce_meshes(self):
        fo = np.zeros((max(self.nm, 1), 3))
        to = np.zeros((max(self.nm, 1), 3))
        if self.nm:
            mw.reduce_meshes(self.n, self._K, self._ms_mesh, self._ms_fw, self._ms_tw, fo, to)
        return fo[: self.nm], to[: self.nm]

    def mesh_forces(self) -> np.ndarray:
        """(n_meshes, 3) force exerted by the particles on each mesh wall at the last evaluation."""
        return self._reduce_meshes()[0]

    def mesh_torques(self) -> np.ndarray:
        """(n_meshes, 3) torque exerted by the particles on each mesh wall about its reference
        point (``ref_point``, moving with the mesh's translation)."""
        return self._reduce_meshes()[1]

    def mesh_contacts(self) -> np.ndarray:
        """(n,) number of mesh-wall contacts of each particle at the last evaluation."""
        return np.sum(self._ms_mesh[: self.n] >= 0, axis=1) if self.nm else np.zeros(self.n, np.int64)

    # ------------------------------------------------------------------ wall control
    def _wall_index(self, wall) -> int:
        return self._lookup(self.walls, wall, "wall")

    def set_wall_active(self, wall, active: bool) -> None:
        """Switch wall ``wall`` (index or name) on or off.  Switching off drops its contacts and
        their tangential history at once (a silo gate that opens); switching on restores its
        kind (the caller makes sure no particle sits inside it).  Mesh walls by name too."""
        if self._is_mesh(wall):
            return self.set_mesh_active(wall, active)
        k = self._wall_index(wall)
        self._wgeom[k, 0] = self._wkind[k] if active else KIND_OFF
        if not active:
            n = self.n
            self._won[:n, k] = 0
            self._wfn[:n, k] = 0.0
            self._whist[:n, k] = 0.0
            self._wfw[:n, k] = 0.0
            self._wtw[:n, k] = 0.0
        self._forces_stale = True

    def set_friction(self, on: bool, pp_mu: float | None = None, pp_mur: float | None = None) -> None:
        """Switch the sliding and rolling friction of every contact (particle-particle, walls,
        mesh walls) off, or back on to the values the system was built with: a frictionless
        fill (the silo's ``frictionless_fill``).  Off keeps the tangential springs and dampers
        (with mu = 0 the Coulomb limit makes the tangential force zero).  With ``pp_mu`` (and
        ``on`` False) only the particle-particle sliding friction is set, to ``pp_mu``, and
        everything else keeps its built value: a fill with a lower friction (the silo's
        ``fill_friction``, the blending thesis's 0.15); ``pp_mur`` likewise sets the
        particle-particle rolling friction alone (``fill_rolling_friction``)."""
        tables = self._friction_tables()
        if self._friction_built is None:
            self._friction_built = [t[:, [P_MU, P_MUR]].copy() for t in tables]
        pair_only = not on and (pp_mu is not None or pp_mur is not None)
        changed = False
        for k, (t, built) in enumerate(zip(tables, self._friction_built)):
            new = np.broadcast_to(built if on or pair_only else 0.0, built.shape).copy()
            if pair_only and k == 0:
                if pp_mu is not None:
                    new[:, 0] = float(pp_mu)
                if pp_mur is not None:
                    new[:, 1] = float(pp_mur)
            changed |= not np.array_equal(t[:, [P_MU, P_MUR]], new)
            t[:, [P_MU, P_MUR]] = new
        if changed:  # the same friction again (a scene's resume) leaves the forces as they are
            self._forces_stale = True

    def _friction_tables(self) -> list[np.ndarray]:
        """The contact tables whose sliding and rolling friction :meth:`set_friction` switches."""
        return [self._pp_params, self._wpar, self._mt.par]

    def wall_active(self, wall) -> bool:
        if self._is_mesh(wall):
            return self.mesh_active(wall)
        return bool(self._wgeom[self._wall_index(wall), 0] >= 0.0)

    def set_wall_velocity(self, wall, velocity) -> None:
        """Translation velocity of wall ``wall`` (m/s, in the simulation frame): from now on the
        wall moves by v dt per step and v enters its relative contact velocity.  Mesh walls by
        name too (:meth:`set_mesh_motion`)."""
        if self._is_mesh(wall):
            return self.set_mesh_motion(wall, velocity=velocity)
        k = self._wall_index(wall)
        self._wgeom[k, 16:19] = np.asarray(velocity, float).reshape(3)
        if np.any(self._wgeom[k, 16:19] != 0.0) and k < len(self._wfilt):
            self._wfilt[k] = 0  # moving from now on: every particle visits it (set anew at each rebuild)
        self._moving = np.flatnonzero(np.any(self._wgeom[: self.nw, 16:19] != 0.0, axis=1))

    def set_wall_spin(self, wall, spin: float) -> None:
        """Angular speed (rad/s) of the surface of wall ``wall`` about its own axis / normal
        (:mod:`cfddem.particles.walls`) from now on: a drum that starts turning."""
        k = self._wall_index(wall)
        if not math.isfinite(spin):
            raise CaseError("wall.spin", f"must be finite, got {spin}")
        self._wgeom[k, 19] = float(spin)
        self._forces_stale = True

    def wall_position(self, wall) -> np.ndarray:
        """Current centre point p of wall ``wall``."""
        return self._wgeom[self._wall_index(wall), 1:4].copy()

    def move_wall(self, wall, displacement) -> None:
        """Translate wall ``wall`` (its point and torque reference) by ``displacement`` now."""
        k = self._wall_index(wall)
        d = np.asarray(displacement, float).reshape(3)
        self._wgeom[k, 1:4] += d
        self._wref[k] += d
        self._forces_stale = True

    def _translate_moving_walls(self, dt: float) -> None:
        for k in self._moving:
            d = dt * self._wgeom[k, 16:19]
            self._wgeom[k, 1:4] += d
            self._wref[k] += d

    def pairs(self) -> np.ndarray:
        """(n_pairs, 2) current neighbour pairs as particle *ids* (min id, max id)."""
        if self._need_rebuild and self.n:
            self._rebuild(forces_follow=False)
        cur = self._cur
        a = self._ids[cur["pi"][: self._npairs]]
        b = self._ids[cur["pj"][: self._npairs]]
        return np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)

    # ------------------------------------------------------------------ rigid clumps
    def _has_clumps(self) -> bool:
        return self.clumps is not None and self.clumps.nb > 0

    def add_clumps(self, shape, com, quat=None, vel=None, omega=None, label=0,
                   rotation_locked: bool | None = None) -> np.ndarray:
        """Add rigid clumps of ``shape`` (:class:`cfddem.particles.clumps.ClumpShape`) with
        centres of mass ``com`` (m, 3), orientations ``quat`` (m, 4) (body principal frame ->
        lab; None: the orientation the shape was given in), velocities ``vel`` and spins
        ``omega`` (lab frame), tracer ``label`` (scalar or (m,) integers, given to every member).
        ``rotation_locked`` (None: :attr:`rotation_locked`): the clumps keep their orientation
        (no spin; contact torques are ignored).
        Their member spheres become particles (``body`` >= 0).  Returns
        the clumps' body ids (stable; :meth:`body_index` gives their current index)."""
        locked = self.rotation_locked if rotation_locked is None else bool(rotation_locked)
        if locked:
            omega = None
        com = np.atleast_2d(np.asarray(com, float))
        m = len(com)
        if com.shape != (m, 3):
            raise CaseError("com", f"needs shape (m, 3), got {com.shape}")
        if m == 0:
            return np.zeros(0, np.int64)
        q = (np.tile(shape.orientation_identity(), (m, 1)) if quat is None
             else np.array(np.broadcast_to(np.asarray(quat, float), (m, 4))))
        q /= np.linalg.norm(q, axis=1)[:, None]
        v = np.zeros((m, 3)) if vel is None else np.broadcast_to(np.asarray(vel, float), (m, 3))
        w = np.zeros((m, 3)) if omega is None else np.broadcast_to(np.asarray(omega, float), (m, 3))
        if not (np.all(np.isfinite(com)) and np.all(np.isfinite(v)) and np.all(np.isfinite(w))):
            raise CaseError("com", "non-finite clump position, velocity or spin")
        if self.clumps is None:
            self.clumps = cl.ClumpSet()
        com = com.copy()
        for a in range(3):  # centres of mass wrapped into periodic boxes, as the members
            if self._periodic[a]:
                com[:, a] = self._plo[a] + np.mod(com[:, a] - self._plo[a], self._plen[a])
        k = len(shape.radii)
        R = np.array([cl.matrix_from_quat(qq) for qq in q])  # (m, 3, 3)
        L = np.einsum("bij,bj->bi", R, np.einsum("j,bj->bj", shape.inertia,
                                                     np.einsum("bji,bj->bi", R, w)))
        b0 = self.clumps.nb
        bids = self.clumps.add(m, shape.mass, shape.inertia, com, v, L, q)
        self.clumps.wfix[b0:] = 1.0 if locked else 0.0
        s_lab = np.einsum("bij,kj->bki", R, shape.offsets)  # (m, k, 3)
        pos = (com[:, None, :] + s_lab).reshape(-1, 3)
        mvel = (v[:, None, :] + np.cross(w[:, None, :], s_lab)).reshape(-1, 3)
        rad = np.tile(shape.radii, m)
        first = self.n
        self.add_particles(pos, mvel, rad, 1.0, omega=np.repeat(w, k, axis=0),
                           label=np.repeat(np.broadcast_to(np.asarray(label), (m,)), k), rotation_locked=locked)
        sl = slice(first, self.n)
        self._mass[sl] = np.tile(shape.member_mass, m)
        self._inertia[sl] = 0.4 * self._mass[sl] * rad**2
        self._body[sl] = np.repeat(np.arange(b0, b0 + m), k)
        self._boff[sl] = np.tile(shape.offsets, (m, 1))
        self.clumps.rebuild_csr(self._body[: self.n], self._ids[: self.n])
        return bids

    def body_index(self, bid) -> int:
        """Current index of the clump with body id ``bid``."""
        idx = np.flatnonzero(self.clumps.bid == int(bid))
        if len(idx) == 0:
            raise KeyError(f"no clump with body id {bid}")
        return int(idx[0])

    @property
    def body(self) -> np.ndarray:
        """(n,) clump index of each particle (-1: a free sphere)."""
        return self._body[: self.n]

    def _clump_open(self) -> float:
        c = self.clumps
        f = cl.clump_open_s if self._serial(c.nb) else cl.clump_open
        return f(c.nb, c.start, c.members, c._com, c._vel, c._L, c._quat, c._mass, c._inert, c._force,
                 c._torque, c._ext_force, c._ext_torque, c._vfix, c._vset, c._wfix, self.dt, self._rotating,
                 self._Rv, self._Rw, self._pos, self._vel, self._omega, self._boff, self._plen,
                 self._plo, self._ref)

    def _clump_close(self, kick: bool) -> int:
        c = self.clumps
        g, om, ap = self.gravity, self.frame_omega, self.axis_point
        f = cl.clump_close_s if self._serial(c.nb) else cl.clump_close
        return int(f(c.nb, c.start, c.members, c._com, c._vel, c._L, c._quat, c._mass, c._inert, c._force,
                     c._torque, c._ext_force, c._ext_torque, c._vfix, c._vset, c._wfix, c._cforce, self.dt, kick,
                     self._rotating, self._Rv, self._Rw, self._pos, self._vel, self._omega, self._boff,
                     self._force, self._torque, self._mass, self._ext_force, self._ext_torque,
                     self._has_ext, g[0], g[1], g[2], om[0], om[1], om[2], ap[0], ap[1], ap[2],
                     self._plen, self._plo))

    def _clump_remove(self, mask) -> np.ndarray:
        """Removing one member removes its whole clump: returns the widened mask and drops the
        bodies (remaps ``body``)."""
        n = self.n
        body = self._body[:n]
        gone = np.zeros(self.clumps.nb, bool)
        gone[body[mask & (body >= 0)]] = True
        mask = mask | ((body >= 0) & gone[np.maximum(body, 0)])
        if gone.any():
            newidx = self.clumps.keep(~gone)
            keep = body >= 0
            body[keep] = newidx[body[keep]]
        return mask

    # ------------------------------------------------------------------ restart
    def get_state(self) -> dict:
        """Everything needed to continue bit-identically (particles, contact history, lists)."""
        n = self.n
        st: dict = dict(n=n, time=self.time, step_count=self.step_count, next_id=self._next_id,
                        npairs=self._npairs, n_built=self._n_built, skin_built=self._skin_built,
                        need_rebuild=int(self._need_rebuild), forces_stale=int(self._forces_stale),
                        last_ov=self._last_ov, pending_m2=self._pending_m2, wall_back=self.wall_back_count,
                        w_geom=self._wgeom.copy(), w_ref=self._wref.copy(),
                        rotation_locked=int(self.rotation_locked))
        for name in _ROW_ARRAYS if self.nm else _PARTICLE_ARRAYS + _WALL_ARRAYS:
            st["p_" + name] = getattr(self, "_" + name)[:n].copy()
        if self.nm:
            st.update(self._mt.get_state())
            st["l_mstart"] = self._mstart[: self._n_built + 1].copy()
            st["l_mlist"] = self._mlist[: int(self._mstart[self._n_built])].copy()
        cur = self._cur
        npairs = self._npairs
        for name in ("pi", "pj", "hist", "second_list"):
            st["l_" + name] = cur[name][:npairs].copy()
        st["l_slab_start"] = self._slab_start.copy()
        st["l_wmask"] = self._wmask[: self._n_built].copy()
        st["l_wfilt"] = self._wfilt.copy()
        st["l_ubar"] = self._ubar.copy()
        st["l_ugrad"] = self._ugrad.copy()
        st["l_rmax_built"] = self._rmax_built
        st["l_ndrift"] = self._ndrift
        st["l_wslack"] = self._wslack[: self._n_built].copy()
        if self._pending_m2 >= 0.0:
            st["l_pending_disp"] = np.asarray(self._pending_disp, float)
        nbuilt = self._n_built
        for name in ("first_start", "second_start"):
            st["l_" + name] = cur[name][: nbuilt + 1].copy()
        if self.clumps is not None:
            st.update(self.clumps.get_state())
        if self._friction_built is not None:  # a fill's friction (set_friction) and the built values
            for k, (t, built) in enumerate(zip(self._friction_tables(), self._friction_built)):
                st[f"f_now{k}"] = t[:, [P_MU, P_MUR]].copy()
                st[f"f_built{k}"] = built.copy()
        return st

    def set_state(self, state) -> None:
        n = int(state["n"])
        if n > self._cap:
            self.n = 0
            self._alloc_particles(max(int(1.5 * n), 16))
        self.n = n
        for name in _ROW_ARRAYS:
            if name in _MESH_ARRAYS and "p_" + name not in state:  # written without mesh walls
                getattr(self, "_" + name)[:n] = -1 if name == "ms_mesh" else 0.0
                continue
            if name in ("body", "boff") and "p_" + name not in state:  # written before clumps
                getattr(self, "_" + name)[:n] = -1 if name == "body" else 0.0
                continue
            if name in ("held", "label") and "p_" + name not in state:  # written before held feeds / labels
                getattr(self, "_" + name)[:n] = 0
                continue
            a = np.asarray(state["p_" + name])
            getattr(self, "_" + name)[:n] = a.reshape(getattr(self, "_" + name)[:n].shape)
        npairs = int(state["npairs"])
        nbuilt = int(state["n_built"])
        cur = self._alloc_pairs(max(int(1.3 * npairs) + 64, 64), max(self._cap, nbuilt))
        for name in ("pi", "pj", "hist", "second_list"):
            cur[name][:npairs] = state["l_" + name]
        for name in ("first_start", "second_start"):
            cur[name][: nbuilt + 1] = state["l_" + name]
        self._cur = cur
        self._old = self._alloc_pairs(16, self._cap)
        self._npairs = npairs
        self._n_built = nbuilt
        self._skin_built = float(state["skin_built"])
        self._need_rebuild = bool(state["need_rebuild"])
        if "l_slab_start" in state and "l_wmask" in state:
            self._slab_start = np.ascontiguousarray(state["l_slab_start"], dtype=np.int64)
            self._slab_ov = np.zeros(max(len(self._slab_start) - 1, 1))
            self._wmask = np.zeros(max(self._cap, nbuilt, 1), np.int64)
            self._wmask[:nbuilt] = state["l_wmask"]
            self._wfilt = np.ascontiguousarray(state["l_wfilt"], dtype=np.int64)
            self._ubar = np.asarray(state["l_ubar"], float).reshape(3)
            self._ugrad = np.asarray(state["l_ugrad"], float).reshape(3, 3)
            self._ugrad_norm = float(np.linalg.norm(self._ugrad))
            self._rmax_built = float(state["l_rmax_built"])
            self._ndrift = int(state["l_ndrift"])
            self._wslack = np.zeros((max(self._cap, nbuilt, 1), 3))
            self._wslack[:nbuilt] = np.asarray(state["l_wslack"]).reshape(-1, 3)
        elif n:  # written before the slabs: rebuild the lists (and slabs) at the next step
            self._need_rebuild = True
        self._forces_stale = bool(state["forces_stale"])
        self._last_ov = float(state["last_ov"])
        self._pending_m2 = float(state["pending_m2"])
        if self._pending_m2 >= 0.0:
            if "l_pending_disp" in state:
                self._pending_disp = tuple(float(x) for x in np.asarray(state["l_pending_disp"]).ravel())
            else:  # written before: the plain test on the pending drift
                self._pending_disp = None
        self.wall_back_count = int(state.get("wall_back", 0))  # checkpoints written before the count: 0
        if "f_now0" in state:  # the friction switched by set_friction (written before: the scene sets it again)
            tables = self._friction_tables()
            self._friction_built = [np.asarray(state[f"f_built{k}"], float).reshape(t[:, [P_MU, P_MUR]].shape)
                                    for k, t in enumerate(tables)]
            for k, t in enumerate(tables):
                t[:, [P_MU, P_MUR]] = np.asarray(state[f"f_now{k}"], float).reshape(t[:, [P_MU, P_MUR]].shape)
        if "rotation_locked" in state:  # a lock taken mid-run (after a fill) holds for later particles
            self.rotation_locked = bool(int(state["rotation_locked"]))
        elif n and np.any(self._held[:n] == 2):  # written before the flag: a locked particle says so
            self.rotation_locked = True
        if "w_geom" in state:  # moved or switched walls
            self._wgeom[...] = np.asarray(state["w_geom"]).reshape(self._wgeom.shape)
            self._wref[...] = np.asarray(state["w_ref"]).reshape(self._wref.shape)
            self._moving = np.flatnonzero(np.any(self._wgeom[: self.nw, 16:19] != 0.0, axis=1))
        if self.nm and "m_offset" in state:
            self._mt.set_state(state)
            nb_ = int(state["n_built"])
            self._mstart = np.zeros(max(self._cap, nb_) + 1, np.int64)
            self._mstart[: nb_ + 1] = state["l_mstart"]
            self._mlist = np.zeros(max(len(state["l_mlist"]), 1), np.int64)
            self._mlist[: len(state["l_mlist"])] = state["l_mlist"]
            self._mplist = np.flatnonzero(np.diff(self._mstart[: nb_ + 1])).astype(np.int64)
            self._mstat = np.zeros((max(len(self._mplist), 1), 2))
        elif self.nm:
            self._need_rebuild = True
        if not self._need_rebuild:
            self._wall_plist()
        self.time = float(state["time"])
        self.step_count = int(state["step_count"])
        self._next_id = int(state["next_id"])
        if "c_nb" in state:
            from cfddem.particles.clumps import ClumpSet

            self.clumps = ClumpSet()
            self.clumps.set_state(state)
            self.clumps.rebuild_csr(self._body[:n], self._ids[:n])
        else:
            self.clumps = None
