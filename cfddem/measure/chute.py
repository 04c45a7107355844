"""Measurements on the chute (physics.md section 5): bed height, surface velocity, mean
streamwise velocity, depth profiles, and their time averages.

Axes: x across the chute (0..W), y normal to the floor (floor at y = 0), z down the chute.
Sides are named as seen in the direction of flow: the x = 0 side is the right (:data:`SIDES`,
:func:`side_of`; the one place that names them).  All functions take plain numpy arrays: ``pos`` (n,3), ``vel`` (n,3), ``radius`` (n,).
Positions are in the coordinates the caller passes; the Simulation passes z measured from
the measurement origin so that stations z = 0, 0.2, 0.4, 0.6 m mean what the study means.

Choices (also in docs/outputs.md):

* A particle belongs to the measurement cell that contains its centre (x, z); particles
  outside the grid are ignored.
* Bed height of a cell: max over its particles of y + r. Empty cells give ``empty``
  (NaN by default in :func:`bed_height_cells`; :class:`ChuteMeasurements` uses 0, the
  bare floor a height sensor would see).
* Sensor bed height: the area-weighted mean of the cell bed heights over a rectangle of
  5 x 5 cells (25 mm x 30 mm) centred exactly on the sensor; cells cut by the rectangle
  count with their covered fraction (the sensors at x = 0.015, 0.035, 0.065 m sit on cell
  edges, so a block of whole cells could not be centred on them). NaN cells are left out;
  the rectangle is clipped to the grid.
* Surface velocity of a cell: the mean velocity of the ``n_top`` = 6 particles with the
  highest y + r; a cell with fewer particles uses all it has; an empty cell is NaN. Its
  time average is weighted by the number of particles used.
* Depth profiles: particles are assigned to a slice by their centre in x and z, and their
  volume is distributed exactly over the y-bins (spherical segments between the bin
  planes). Solid fraction = that volume / (slice width * window length * bin height);
  velocity = solid-volume-weighted mean v_z per bin. For a lattice with an integer
  number of periods in the slice and window this is exact (no sampling error); at slice
  edges that particles cross the centre assignment is unbiased but noisy (an error of
  order one particle volume per edge-crossing particle, averaging out over time).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from cfddem.errors import CaseError

# ---------------------------------------------------------------------- sides
# The one place that names the chute's sides.  Axes are right-handed: x across the chute
# (walls at x = 0 and x = W), y up from the floor, z down the chute.  Left and right are
# seen in the direction of flow, by an observer on the floor facing down the chute (+z, y up):
# their right is forward x up = z x y = -x, so the x = 0 wall is on the RIGHT.
# physics.md section 5 counts its sensor positions 0.015, 0.045, 0.065 m from the wall it
# calls left, our x = W wall: its sensors are our x = W - 0.015, W - 0.045, W - 0.065.
SIDE_AT_X0 = "right"
SIDE_AT_XW = "left"
CENTRE = "centre"
#: the ``sides`` attribute of /measurements/chute and /measurements/momentum_budget; results
#: files written before it named the x = 0 side "left" (read_measurements swaps their names)
SIDES = "seen in the direction of flow (facing down the chute, +z, y up); right = the x = 0 side"
#: one line for reports, case files and docs
CONVENTION = ("axes right-handed, x across, y up from the floor, z down the chute; positive rpm = "
              "counter-clockwise seen from above; left/right seen in the direction of flow")


def side_of(x: float, width: float) -> str:
    """The side of the chute that x lies on, seen in the direction of flow: "right" below
    the centre line (the x = 0 side), "left" above, "centre" within a tenth of the width of
    the centre line."""
    if abs(x - 0.5 * width) <= 0.1 * width:
        return CENTRE
    return SIDE_AT_X0 if x < 0.5 * width else SIDE_AT_XW


def wall_at(name: str, width: float) -> str:
    """The wall a side name refers to, in words: "x = 0" for the right, "x = 80 mm" for
    the left side of a 0.08 m chute ("" for the centre and anything else)."""
    base = name.split("_")[0]
    if base == SIDE_AT_X0:
        return "x = 0"
    if base == SIDE_AT_XW:
        return f"x = {1e3 * width:.0f} mm" if math.isfinite(width) else "x = W"
    return ""


def side_label(name: str, width: float) -> str:
    """A figure label of a side, sensor or slice name: "right (x = 0 side)", "left half
    (x = 80 mm side)", "centre"."""
    wall = wall_at(name, width)
    words = name.replace("_", " ")
    return f"{words} ({wall} side)" if wall else words


def x_label(width: float) -> str:
    """The label of a figure's x axis across the chute, naming the walls' sides."""
    return f"x across the chute [mm] (x = 0: {SIDE_AT_X0} wall, {wall_at(SIDE_AT_XW, width)}: {SIDE_AT_XW} wall)"


def sensor_names(sensor_x, width: float) -> list[str]:
    """The names of sensors at ``sensor_x`` (:func:`side_of`)."""
    return [side_of(float(x), width) for x in sensor_x]


#: the names results files written before ``SIDES`` used, and the names they mean now
LEGACY_NAMES = {"left": "right", "right": "left", "left_half": "right_half", "right_half": "left_half"}


def _renamed(key: str, prefixes) -> str:
    for pre in prefixes:
        if key.startswith(pre):
            rest = key[len(pre):]
            for old in sorted(LEGACY_NAMES, key=len, reverse=True):  # "left_half" before "left"
                if rest == old or rest.startswith(old + "_"):
                    return pre + LEGACY_NAMES[old] + rest[len(old):]
    return key


def _renamed_segment(key: str) -> str:
    """``sum/profile/0/left/phi`` -> ``sum/profile/0/right/phi`` (:data:`LEGACY_NAMES`)."""
    parts = key.split("/")
    if len(parts) == 5 and parts[1] == "profile":
        parts[3] = LEGACY_NAMES.get(parts[3], parts[3])
    return "/".join(parts)


def upgrade_legacy_sides(meas: dict) -> dict:
    """``/measurements`` as :func:`cfddem.io.results.read_measurements` reads it (attributes
    under ``"@attrs"``), with the side names of a file written before the ``sides`` attribute
    (its chute group lacks it; the x = 0 side was then "left") swapped: in the chute group
    ``profile_<side>_*``, ``slice_<side>`` and the attribute ``sensor_names``, in the
    momentum budget ``wall_<side>*``.  The chute group then carries ``sides`` and
    ``sides_swapped_on_read = 1``.  Files with ``sides``, or without a chute group, are
    returned as they are.  Modifies and returns ``meas``."""
    chute = meas.get("chute")
    if not isinstance(chute, dict) or "sides" in chute.get("@attrs", {}):
        return meas
    for group, prefixes in (("chute", ("profile_", "slice_")), ("momentum_budget", ("wall_",))):
        g = meas.get(group)
        if not isinstance(g, dict):
            continue
        items = [(k if k == "@attrs" else _renamed(k, prefixes), v) for k, v in g.items()]
        g.clear()
        g.update(items)
    at = chute.setdefault("@attrs", {})
    if "sensor_names" in at:
        at["sensor_names"] = ",".join(LEGACY_NAMES.get(n, n) for n in str(at["sensor_names"]).split(","))
    at.update(sides=SIDES, sides_swapped_on_read=1)
    return meas


SENSOR_X = (0.015, 0.035, 0.065)   # the right, centre and left sensors of a 0.08 m chute
STATIONS = (0.0, 0.2, 0.4, 0.6)


# ---------------------------------------------------------------------- cells
@dataclass(frozen=True)
class MeasurementCells:
    """Uniform measurement cells dx (across) by dz (along) covering x in [x0, x0 + nx dx],
    z in [z0, z0 + nz dz]. Cell (i, k) is row i, column k of every (nx, nz) field."""

    x0: float
    z0: float
    dx: float
    dz: float
    nx: int
    nz: int

    @classmethod
    def for_chute(cls, width: float, z_range: tuple[float, float], dx: float = 0.005,
                  dz: float = 0.006) -> "MeasurementCells":
        """Cells over the width [0, W] and the z-range; nx = round(W/dx) (dx is adjusted
        by at most half a cell so that the cells tile the width exactly), nz = the number
        of whole dz cells that fit in the z-range starting at z_range[0]."""
        if width <= 0 or dx <= 0 or dz <= 0:
            raise CaseError("measure.cells", f"width, dx, dz must be > 0 (got {width}, {dx}, {dz})")
        z0, z1 = float(z_range[0]), float(z_range[1])
        if z1 <= z0:
            raise CaseError("measure.z_range", f"z_range must increase (got {z_range})")
        nx = max(1, int(round(width / dx)))
        nz = max(1, int(math.floor((z1 - z0) / dz + 1e-9)))
        return cls(0.0, z0, width / nx, dz, nx, nz)

    @property
    def shape(self) -> tuple[int, int]:
        return (self.nx, self.nz)

    @property
    def x_edges(self) -> np.ndarray:
        return self.x0 + self.dx * np.arange(self.nx + 1)

    @property
    def z_edges(self) -> np.ndarray:
        return self.z0 + self.dz * np.arange(self.nz + 1)

    @property
    def x_centres(self) -> np.ndarray:
        return self.x0 + self.dx * (np.arange(self.nx) + 0.5)

    @property
    def z_centres(self) -> np.ndarray:
        return self.z0 + self.dz * (np.arange(self.nz) + 0.5)

    def cell_index(self, pos: np.ndarray) -> np.ndarray:
        """Flat cell index ``i*nz + k`` of each particle centre, -1 outside the grid."""
        pos = np.asarray(pos, dtype=np.float64).reshape(-1, 3)
        i = np.floor((pos[:, 0] - self.x0) / self.dx).astype(np.int64)
        k = np.floor((pos[:, 2] - self.z0) / self.dz).astype(np.int64)
        ok = (i >= 0) & (i < self.nx) & (k >= 0) & (k < self.nz)
        return np.where(ok, i * self.nz + k, -1)


# ---------------------------------------------------------------------- bed height
def bed_height_cells(pos, radius, cells: MeasurementCells, empty: float = np.nan) -> np.ndarray:
    """Per cell the top of the highest particle, max(y + r) over the particles whose
    centre lies in the cell; (nx, nz) array, ``empty`` where a cell has no particle."""
    pos = np.asarray(pos, dtype=np.float64).reshape(-1, 3)
    top = pos[:, 1] + np.asarray(radius, dtype=np.float64)
    c = cells.cell_index(pos)
    m = c >= 0
    out = np.full(cells.nx * cells.nz, -np.inf)
    np.maximum.at(out, c[m], top[m])
    out[np.isneginf(out)] = empty
    return out.reshape(cells.shape)


def _overlap_weights(edges: np.ndarray, centre: float, half: float) -> np.ndarray:
    """Fraction of each cell [e_i, e_i+1] covered by [centre - half, centre + half]."""
    lo = np.maximum(edges[:-1], centre - half)
    hi = np.minimum(edges[1:], centre + half)
    return np.clip(hi - lo, 0.0, None) / np.diff(edges)


def bed_height_sensors(bed_cells: np.ndarray, cells: MeasurementCells, sensor_x=SENSOR_X,
                       sensor_z=None, block: int = 5) -> np.ndarray:
    """Bed height seen by sensors at (x, z) for every x in ``sensor_x`` and z in
    ``sensor_z`` (default: every cell centre along the chute): the area-weighted mean of
    ``bed_cells`` (nx, nz) over the ``block`` x ``block`` cell rectangle centred on the
    sensor, h_s = sum_ik w_i w_k h_ik / sum_ik w_i w_k over non-NaN cells, with w the
    covered fraction of each cell. Returns (len(sensor_x), len(sensor_z)); NaN where no
    covered cell has a value."""
    h = np.asarray(bed_cells, dtype=np.float64)
    if h.shape != cells.shape:
        raise ValueError(f"bed_cells has shape {h.shape}, cells are {cells.shape}")
    sz = cells.z_centres if sensor_z is None else np.atleast_1d(np.asarray(sensor_z, float))
    sx = np.atleast_1d(np.asarray(sensor_x, float))
    wx = np.array([_overlap_weights(cells.x_edges, x, 0.5 * block * cells.dx) for x in sx])
    wz = np.array([_overlap_weights(cells.z_edges, z, 0.5 * block * cells.dz) for z in sz])
    good = np.isfinite(h)
    hv = np.where(good, h, 0.0)
    num = wx @ hv @ wz.T
    den = wx @ good.astype(float) @ wz.T
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)


# ---------------------------------------------------------------------- surface velocity
def surface_velocity_cells(pos, vel, radius, cells: MeasurementCells, n_top: int = 6):
    """Per cell the mean velocity of the ``n_top`` topmost particles (largest y + r).

    Returns ``(v_stream, v_span, n_used)``: mean v_z and mean v_x, (nx, nz) each, NaN in
    empty cells, and the number of particles used per cell (min(n_top, particles in it)).
    """
    pos = np.asarray(pos, dtype=np.float64).reshape(-1, 3)
    vel = np.asarray(vel, dtype=np.float64).reshape(-1, 3)
    top = pos[:, 1] + np.asarray(radius, dtype=np.float64)
    c = cells.cell_index(pos)
    m = np.nonzero(c >= 0)[0]
    c, top = c[m], top[m]
    order = np.lexsort((-top, c))            # by cell, highest first within a cell
    cs = c[order]
    ncell = cells.nx * cells.nz
    counts = np.bincount(cs, minlength=ncell)
    start = np.concatenate([[0], np.cumsum(counts)[:-1]])
    rank = np.arange(cs.size) - start[cs]
    sel = order[rank < n_top]
    idx = m[sel]
    csel = c[sel]
    n_used = np.bincount(csel, minlength=ncell)
    sz = np.bincount(csel, weights=vel[idx, 2], minlength=ncell)
    sx = np.bincount(csel, weights=vel[idx, 0], minlength=ncell)
    with np.errstate(invalid="ignore", divide="ignore"):
        vz = np.where(n_used > 0, sz / np.maximum(n_used, 1), np.nan)
        vx = np.where(n_used > 0, sx / np.maximum(n_used, 1), np.nan)
    return vz.reshape(cells.shape), vx.reshape(cells.shape), n_used.reshape(cells.shape)


# ---------------------------------------------------------------------- mean velocity
def mean_streamwise_velocity(pos, vel, z_edges):
    """Mean v_z of the particles whose centre lies in each z-bin (all x and y).
    Returns ``(mean_vz, count)``, NaN where a bin is empty."""
    pos = np.asarray(pos, dtype=np.float64).reshape(-1, 3)
    vel = np.asarray(vel, dtype=np.float64).reshape(-1, 3)
    edges = np.asarray(z_edges, dtype=np.float64)
    nb = edges.size - 1
    b = np.searchsorted(edges, pos[:, 2], side="right") - 1
    ok = (b >= 0) & (b < nb)
    cnt = np.bincount(b[ok], minlength=nb)
    s = np.bincount(b[ok], weights=vel[ok, 2], minlength=nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, s / np.maximum(cnt, 1), np.nan), cnt


# ---------------------------------------------------------------------- depth profiles
def sphere_volume_below(r: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Volume of a sphere of radius r below a plane at signed height t above its centre:
    V = pi (t + r)^2 (2r - t) / 3 for -r <= t <= r (0 below, 4/3 pi r^3 above)."""
    t = np.clip(t, -r, r)
    return math.pi * (t + r) ** 2 * (2.0 * r - t) / 3.0


def default_slices(width: float, slice_width: float = 0.025) -> dict[str, tuple[float, float]]:
    """Right / centre / left slices of ``slice_width`` (against the x = 0 wall, centred,
    against the x = W wall; sides seen in the direction of flow), the whole width and the
    right and left halves."""
    w, s = float(width), float(slice_width)
    return {SIDE_AT_X0: (0.0, s), CENTRE: (0.5 * (w - s), 0.5 * (w + s)), SIDE_AT_XW: (w - s, w),
            "whole": (0.0, w), f"{SIDE_AT_X0}_half": (0.0, 0.5 * w), f"{SIDE_AT_XW}_half": (0.5 * w, w)}


def depth_profiles(pos, vel, radius, x_slices: dict, z_window: tuple[float, float], y_edges):
    """Streamwise velocity and solid volume fraction against height y, per x-slice.

    For each slice name -> (x_lo, x_hi): the particles with centre x in [x_lo, x_hi) and
    z in [z_lo, z_hi) contribute their exact volume between the planes of each y-bin,
    V_ab = V(y_b+1) - V(y_b) (:func:`sphere_volume_below`). Then

        phi_b = sum_a V_ab / ((x_hi - x_lo)(z_hi - z_lo)(y_b+1 - y_b))
        u_b   = sum_a V_ab v_z,a / sum_a V_ab          (NaN where no solid)

    Returns ``{name: {"vz": (nb,), "phi": (nb,), "solid_volume": (nb,)}}``.
    """
    pos = np.asarray(pos, dtype=np.float64).reshape(-1, 3)
    vel = np.asarray(vel, dtype=np.float64).reshape(-1, 3)
    rad = np.asarray(radius, dtype=np.float64).reshape(-1)
    ye = np.asarray(y_edges, dtype=np.float64)
    z_lo, z_hi = float(z_window[0]), float(z_window[1])
    inz = (pos[:, 2] >= z_lo) & (pos[:, 2] < z_hi)
    out = {}
    for name, (x_lo, x_hi) in x_slices.items():
        sel = inz & (pos[:, 0] >= x_lo) & (pos[:, 0] < x_hi)
        p, v, r = pos[sel], vel[sel], rad[sel]
        vb = sphere_volume_below(r[:, None], ye[None, :] - p[:, 1:2])  # (n, nb+1)
        vab = np.diff(vb, axis=1)
        solid = vab.sum(axis=0)
        mom = vab.T @ v[:, 2]
        bin_vol = (x_hi - x_lo) * (z_hi - z_lo) * np.diff(ye)
        with np.errstate(invalid="ignore", divide="ignore"):
            vz = np.where(solid > 0, mom / np.where(solid > 0, solid, 1.0), np.nan)
        out[name] = {"vz": vz, "phi": solid / bin_vol, "solid_volume": solid}
    return out


# ---------------------------------------------------------------------- time averaging
class TimeAverager:
    """NaN-aware weighted running means of named arrays from ``start_time`` on.

    ``add(time, name, a, weight=1)`` accumulates S += w a and W += w over the finite
    entries of a (NaN entries add nothing); ``mean(name)`` = S / W, NaN where W = 0.
    Samples before ``start_time`` are ignored (``add`` returns False). The state is a flat
    dict of arrays and scalars (for checkpoints): ``get_state()`` / ``set_state()``.
    """

    def __init__(self, start_time: float = 0.0):
        self.start_time = float(start_time)
        self._sum: dict[str, np.ndarray] = {}
        self._w: dict[str, np.ndarray] = {}
        self._n: dict[str, int] = {}
        self.first_time = math.nan
        self.last_time = math.nan

    def add(self, time: float, name: str, array, weight=None) -> bool:
        if time < self.start_time:
            return False
        a = np.asarray(array, dtype=np.float64)
        w = np.ones_like(a) if weight is None else np.broadcast_to(
            np.asarray(weight, dtype=np.float64), a.shape)
        good = np.isfinite(a) & (w > 0)
        if name not in self._sum:
            self._sum[name] = np.zeros(a.shape)
            self._w[name] = np.zeros(a.shape)
            self._n[name] = 0
        elif self._sum[name].shape != a.shape:
            raise ValueError(f"{name}: shape {a.shape} differs from {self._sum[name].shape}")
        self._sum[name] += np.where(good, w * a, 0.0)
        self._w[name] += np.where(good, w, 0.0)
        self._n[name] += 1
        if not (self.first_time <= time):
            self.first_time = float(time)
        if not (self.last_time >= time):
            self.last_time = float(time)
        return True

    def names(self) -> list[str]:
        return list(self._sum)

    def n_samples(self, name: str) -> int:
        return self._n.get(name, 0)

    def weight(self, name: str) -> np.ndarray:
        return self._w[name].copy()

    def mean(self, name: str) -> np.ndarray:
        s, w = self._sum[name], self._w[name]
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(w > 0, s / np.where(w > 0, w, 1.0), np.nan)

    def get_state(self) -> dict:
        st = {"start_time": self.start_time, "first_time": self.first_time,
              "last_time": self.last_time}
        for k in self._sum:
            st[f"sum/{k}"] = self._sum[k].copy()
            st[f"weight/{k}"] = self._w[k].copy()
            st[f"samples/{k}"] = np.int64(self._n[k])
        return st

    def set_state(self, state: dict) -> None:
        """Restore from :meth:`get_state`'s dict, or from the same keys read back from
        HDF5 as nested groups (``{"sum": {"a": ...}}`` is the same as ``{"sum/a": ...}``)."""
        state = _flatten(state)
        self.start_time = float(state["start_time"])
        self.first_time = float(state["first_time"])
        self.last_time = float(state["last_time"])
        self._sum, self._w, self._n = {}, {}, {}
        for key, v in state.items():
            if key.startswith("sum/"):
                k = key[4:]
                self._sum[k] = np.array(v, dtype=np.float64)
                self._w[k] = np.array(state[f"weight/{k}"], dtype=np.float64)
                self._n[k] = int(state[f"samples/{k}"])


def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}/"))
        else:
            out[f"{prefix}{k}"] = v
    return out


# ---------------------------------------------------------------------- the chute set
@dataclass
class ChuteMeasurements:
    """Everything measured on the chute, time-averaged from ``start_time`` on.

    Call :meth:`measure` at each measurement time; :meth:`results` gives the named arrays
    to store with ``ResultsFile.write_measurements(self.group, m.results(), m.attrs())``.

    Parameters: chute ``width``; ``z_range`` covered by the cells; ``stations`` (z of the
    surface-velocity and depth-profile stations); cell size ``dx`` x ``dz``; ``n_top``;
    ``sensor_x`` / ``sensor_z`` (None: every cell centre) / ``sensor_block``;
    ``profile_dy`` and ``profile_height`` (y-bins of the depth profiles); depth profiles
    are taken over z in [station - profile_half_length, station + profile_half_length);
    ``slices`` (None: :func:`default_slices`); ``empty_bed`` the bed height of an empty
    cell (0: bare floor).
    """

    width: float
    z_range: tuple[float, float]
    start_time: float = 0.0
    stations: tuple = STATIONS
    dx: float = 0.005
    dz: float = 0.006
    n_top: int = 6
    sensor_x: tuple = SENSOR_X
    sensor_z: tuple | None = None
    sensor_block: int = 5
    profile_dy: float = 0.0015
    profile_height: float = 0.045
    profile_half_length: float = 0.015
    slices: dict | None = None
    empty_bed: float = 0.0
    group: str = "chute"
    averager: TimeAverager = field(init=False)
    cells: MeasurementCells = field(init=False)

    def __post_init__(self):
        self.cells = MeasurementCells.for_chute(self.width, self.z_range, self.dx, self.dz)
        self.averager = TimeAverager(self.start_time)
        if self.slices is None:
            self.slices = default_slices(self.width)
        self.stations = tuple(float(s) for s in self.stations)
        n_y = max(1, int(round(self.profile_height / self.profile_dy)))
        self.y_edges = np.linspace(0.0, n_y * self.profile_dy, n_y + 1)

    def measure(self, time: float, pos, vel, radius) -> bool:
        """Accumulate one sample; returns False (nothing done) before ``start_time``."""
        if time < self.start_time:
            return False
        av, c = self.averager, self.cells
        av.add(time, "bed_height_cells", bed_height_cells(pos, radius, c, empty=self.empty_bed))
        vz, vx, n_used = surface_velocity_cells(pos, vel, radius, c, self.n_top)
        av.add(time, "surface_vz", vz, n_used)
        av.add(time, "surface_vx", vx, n_used)
        mvz, cnt = mean_streamwise_velocity(pos, vel, c.z_edges)
        av.add(time, "mean_vz", mvz, cnt)
        for j, zs in enumerate(self.stations):
            prof = depth_profiles(pos, vel, radius, self.slices,
                                  (zs - self.profile_half_length, zs + self.profile_half_length),
                                  self.y_edges)
            for name, d in prof.items():
                av.add(time, f"profile/{j}/{name}/phi", d["phi"])
                av.add(time, f"profile/{j}/{name}/vz", d["vz"], d["solid_volume"])
        return True

    @property
    def n_samples(self) -> int:
        return self.averager.n_samples("bed_height_cells")

    def results(self) -> dict:
        """Time-averaged results as named numpy arrays with their axes (SI units)::

            x_centres (nx,), z_centres (nz,), x_edges, z_edges      measurement cells [m]
            bed_height_cells (nx, nz)                               [m]
            sensor_x (3,), sensor_z (ns,), bed_height_sensor (3, ns) [m]
            surface_vz, surface_vx (nx, nz)                         [m/s]
            mean_vz (nz,) over the z-cells, mean_vz_z (nz,)         [m/s], [m]
            stations (nst,), profile_y (ny,) bin centres, profile_y_edges (ny+1,)
            profile_<slice>_vz, profile_<slice>_phi (nst, ny)       [m/s], [-]
            slice_<slice> (2,) x-range of each slice                [m]
            n_samples, t_first, t_last
        Empty when nothing was sampled yet (n_samples = 0 only).
        """
        av, c = self.averager, self.cells
        out: dict = {"n_samples": np.int64(self.n_samples)}
        if self.n_samples == 0:
            return out
        bed = av.mean("bed_height_cells")
        sz = c.z_centres if self.sensor_z is None else np.asarray(self.sensor_z, float)
        out.update(
            x_centres=c.x_centres, z_centres=c.z_centres, x_edges=c.x_edges, z_edges=c.z_edges,
            bed_height_cells=bed, sensor_x=np.asarray(self.sensor_x, float), sensor_z=sz,
            bed_height_sensor=bed_height_sensors(bed, c, self.sensor_x, sz, self.sensor_block),
            surface_vz=av.mean("surface_vz"), surface_vx=av.mean("surface_vx"),
            mean_vz=av.mean("mean_vz"), mean_vz_z=c.z_centres,
            stations=np.asarray(self.stations, float),
            profile_y=0.5 * (self.y_edges[1:] + self.y_edges[:-1]), profile_y_edges=self.y_edges,
            t_first=np.float64(av.first_time), t_last=np.float64(av.last_time))
        for name, rng in self.slices.items():
            out[f"slice_{name}"] = np.asarray(rng, float)
            for q in ("vz", "phi"):
                out[f"profile_{name}_{q}"] = np.array(
                    [av.mean(f"profile/{j}/{name}/{q}") for j in range(len(self.stations))])
        return out

    def attrs(self) -> dict:
        """Metadata for the measurement group."""
        return dict(dx=self.cells.dx, dz=self.cells.dz, n_top=self.n_top,
                    sensor_block=self.sensor_block, start_time=self.start_time,
                    empty_bed=self.empty_bed, profile_half_length=self.profile_half_length,
                    sensor_names=",".join(sensor_names(self.sensor_x, self.width)), sides=SIDES)

    def get_state(self) -> dict:
        return dict(self.averager.get_state(), sides_flow_seen=np.int64(1))

    def set_state(self, state: dict) -> None:
        self.averager.set_state(state)

    @staticmethod
    def upgrade_checkpoint(st: dict) -> dict:
        """A run's checkpoint state (``Simulation.get_state``) written before the side names
        were those seen in the direction of flow (its ``measure`` state lacks
        ``sides_flow_seen``), with the names swapped as :func:`upgrade_legacy_sides` swaps
        them in results files: the averages ``profile/<j>/<side>/...`` and the budget's
        ``rows/wall_<side>``, so that a resumed run adds to the right sums."""
        m = st.get("measure")
        if not isinstance(m, dict):
            return st
        m = _flatten(m)
        if "sides_flow_seen" in m:
            return st
        out = dict(st)
        out["measure"] = {_renamed_segment(k): v for k, v in m.items()}
        if isinstance(st.get("budget"), dict):
            out["budget"] = {_renamed(k, ("rows/wall_",)): v for k, v in _flatten(st["budget"]).items()}
        return out
