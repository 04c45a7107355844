"""ParaView output: VTU files written with meshio and hand-written ``.pvd`` collections.

* particles: one ``vertex`` cell per particle (points without cells render badly in
  ParaView); point data ``radius``, ``velocity``, ``spin``, ``id`` and any extra arrays.
  In ParaView apply a *Glyph* filter (glyph type Sphere, scale array ``radius``, scale
  factor 2 because ParaView's sphere glyph has radius 0.5) to see the spheres.
* gas: an unstructured hexahedral mesh of the grid cells with cell-centred fields.
* walls: ``quad`` cells.
* mesh walls (triangle meshes, :class:`cfddem.particles.MeshWall`): ``triangle`` cells with the
  cell data ``mesh`` (the mesh's index); written once when no mesh moves, else every frame.

Every VTU is written to a temporary file and renamed, and :class:`PvdIndex` rewrites its
collection atomically after every frame, so a crashed run leaves valid files and a valid
index of the frames written so far. All VTU files are binary with zlib compression.
"""

from __future__ import annotations

import os
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path
from xml.sax.saxutils import quoteattr

import meshio
import numpy as np


def _write_vtu_atomic(path: str | Path, mesh: meshio.Mesh) -> Path:
    # An empty mesh is written uncompressed: zlib blocks of zero bytes are legal VTK but
    # meshio's reader chokes on them; VTK/ParaView read either form.
    compression = "zlib" if len(mesh.points) else None
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix="." + path.name + ".", suffix=".tmp", dir=path.parent)
    os.close(fd)
    try:
        meshio.write(tmp, mesh, file_format="vtu", binary=True, compression=compression)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def write_particles_vtu(path, pos, radius, vel=None, omega=None, ids=None, **point_data) -> Path:
    """Write particles as VTU: points ``pos`` (n,3), one ``vertex`` cell each.

    Point data: ``radius`` (n,), ``velocity`` (n,3) from ``vel``, ``spin`` (n,3) from
    ``omega``, ``id`` (n,) int64 from ``ids``, plus every extra keyword array (n,) or (n,k).
    An empty particle set (n = 0) gives a valid VTU piece with no points (uncompressed),
    so a frame before the first particle enters still opens in ParaView.
    """
    pos = np.ascontiguousarray(pos, dtype=np.float64).reshape(-1, 3)
    n = pos.shape[0]
    data = {"radius": np.asarray(radius, dtype=np.float64).reshape(n)}
    if vel is not None:
        data["velocity"] = np.asarray(vel, dtype=np.float64).reshape(n, 3)
    if omega is not None:
        data["spin"] = np.asarray(omega, dtype=np.float64).reshape(n, 3)
    if ids is not None:
        data["id"] = np.asarray(ids, dtype=np.int64).reshape(n)
    for k, v in point_data.items():
        a = np.asarray(v)
        if a.shape[0] != n:
            raise ValueError(f"point data {k!r} has {a.shape[0]} rows for {n} particles")
        data[k] = a
    cells = [("vertex", np.arange(n, dtype=np.int64).reshape(n, 1))]
    return _write_vtu_atomic(path, meshio.Mesh(pos, cells, point_data=data))


def grid_points_and_hexes(origin, spacing, shape) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and VTK hexahedron connectivity of a uniform grid of ``shape`` = (nx, ny, nz)
    cells. Cell (i, j, k) is row ``(i*ny + j)*nz + k`` (C order, as ``a.reshape(-1)`` of an
    (nx, ny, nz) field); node (i, j, k) is ``(i*(ny+1) + j)*(nz+1) + k``."""
    nx, ny, nz = (int(s) for s in shape)
    ox, oy, oz = (float(o) for o in origin)
    dx, dy, dz = (float(s) for s in np.broadcast_to(np.asarray(spacing, dtype=float), (3,)))
    xs = ox + dx * np.arange(nx + 1)
    ys = oy + dy * np.arange(ny + 1)
    zs = oz + dz * np.arange(nz + 1)
    X, Y, Z = np.meshgrid(xs, ys, zs, indexing="ij")
    points = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])

    def node(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    I, J, K = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    I, J, K = I.ravel(), J.ravel(), K.ravel()
    hexes = np.column_stack([
        node(I, J, K), node(I + 1, J, K), node(I + 1, J + 1, K), node(I, J + 1, K),
        node(I, J, K + 1), node(I + 1, J, K + 1), node(I + 1, J + 1, K + 1), node(I, J + 1, K + 1),
    ]).astype(np.int64)
    return points, hexes


def write_grid_vtu(path, origin, spacing, shape, cell_data: dict) -> Path:
    """Write a uniform grid of ``shape`` = (nx, ny, nz) cells as hexahedra.

    ``origin`` is the lower corner, ``spacing`` the cell size (scalar or 3 values).
    ``cell_data`` maps names to cell-centred fields of shape (nx, ny, nz) (scalars) or
    (nx, ny, nz, 3) (vectors; face velocities must be averaged to centres first).
    """
    nx, ny, nz = (int(s) for s in shape)
    points, hexes = grid_points_and_hexes(origin, spacing, shape)
    ncell = nx * ny * nz
    data = {}
    for k, v in cell_data.items():
        a = np.asarray(v, dtype=np.float64)
        if a.shape[:3] != (nx, ny, nz) or a.ndim not in (3, 4):
            raise ValueError(f"cell field {k!r} has shape {a.shape}, expected {(nx, ny, nz)}[+(3,)]")
        data[k] = [a.reshape(ncell, *a.shape[3:])]
    return _write_vtu_atomic(path, meshio.Mesh(points, [("hexahedron", hexes)], cell_data=data))


def write_walls_vtu(path, quads) -> Path:
    """Write wall quadrilaterals, each a (4, 3) array of corners in order around the edge."""
    q = np.asarray(quads, dtype=np.float64).reshape(-1, 4, 3)
    points = q.reshape(-1, 3)
    cells = [("quad", np.arange(points.shape[0], dtype=np.int64).reshape(-1, 4))]
    return _write_vtu_atomic(path, meshio.Mesh(points, cells))


def write_meshes_vtu(path, vertices, triangles, mesh=None) -> Path:
    """Write triangle meshes: ``vertices`` (nv, 3), ``triangles`` (nt, 3) indices, ``mesh``
    (nt,) the index of the mesh each triangle belongs to (cell data ``mesh``)."""
    V = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    F = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    data = {} if mesh is None else {"mesh": [np.asarray(mesh, dtype=np.int64).reshape(len(F))]}
    return _write_vtu_atomic(path, meshio.Mesh(V, [("triangle", F)], cell_data=data))


class PvdIndex:
    """A ParaView ``.pvd`` collection, rewritten atomically after every frame.

    ``PvdIndex(path)`` starts an empty collection; ``PvdIndex(path, append=True)`` keeps
    the frames of an existing index (restarted run), dropping those at times after
    ``restart_time`` when it is given. ``add(time, relative_file)`` records one frame;
    the file name is stored relative to the ``.pvd``'s folder.
    """

    def __init__(self, path, append: bool = False, restart_time: float | None = None):
        self.path = Path(path)
        self.entries: list[tuple[float, str]] = []
        if append and self.path.exists():
            root = ET.parse(self.path).getroot()
            for ds in root.iter("DataSet"):
                t = float(ds.get("timestep"))
                if restart_time is None or t <= restart_time:
                    self.entries.append((t, ds.get("file")))
        self._write()

    def add(self, time: float, relative_file: str | Path) -> None:
        self.entries.append((float(time), str(relative_file)))
        self._write()

    def _write(self) -> None:
        lines = ['<?xml version="1.0"?>',
                 '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
                 "  <Collection>"]
        for t, f in self.entries:
            lines.append(f'    <DataSet timestep="{t!r}" group="" part="0" file={quoteattr(f)}/>')
        lines += ["  </Collection>", "</VTKFile>", ""]
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix="." + self.path.name + ".", suffix=".tmp",
                                   dir=self.path.parent)
        with os.fdopen(fd, "w") as fh:
            fh.write("\n".join(lines))
        os.replace(tmp, self.path)


class ParaViewOutput:
    """The ParaView series of a run in ``out_dir/vtk``: ``particles.pvd``, ``gas.pvd``,
    ``walls.pvd`` and (with mesh walls) ``meshes.pvd``, all indexed with the same times so they
    animate together.

    Frames are ``vtk/particles/particles_<NNNNNN>.vtu`` and ``vtk/gas/gas_<NNNNNN>.vtu``;
    the walls are static, written once to ``vtk/walls.vtu`` and listed at every time.  Mesh
    walls (``write(..., meshes=dict(vertices=, triangles=, mesh=, moving=))``) go to
    ``vtk/meshes.vtu`` once when none moves, else to ``vtk/meshes/meshes_<NNNNNN>.vtu`` per frame.
    """

    def __init__(self, out_dir, append: bool = False, restart_time: float | None = None):
        self.dir = Path(out_dir) / "vtk"
        self.dir.mkdir(parents=True, exist_ok=True)
        self.particles = PvdIndex(self.dir / "particles.pvd", append, restart_time)
        self.gas = PvdIndex(self.dir / "gas.pvd", append, restart_time)
        self.walls = PvdIndex(self.dir / "walls.pvd", append, restart_time)
        self.meshes = None
        self._append, self._restart_time = append, restart_time
        self._static_meshes_written = False
        self.frame = len(self.particles.entries)
        self._walls_file = "walls.vtu" if (self.dir / "walls.vtu").exists() else None

    def set_walls(self, quads) -> None:
        write_walls_vtu(self.dir / "walls.vtu", quads)
        self._walls_file = "walls.vtu"

    def write(self, time: float, pos, radius, vel=None, omega=None, ids=None,
              gas: dict | None = None, meshes: dict | None = None, **point_data) -> int:
        """Write one frame; ``gas`` = dict(origin=, spacing=, shape=, cell_data=) or None;
        ``meshes`` = dict(vertices=, triangles=, mesh=, moving=) (the mesh walls now, e.g.
        :meth:`ParticleSystem.mesh_surfaces`) or None.  Returns the frame number."""
        k = self.frame
        rel = f"particles/particles_{k:06d}.vtu"
        write_particles_vtu(self.dir / rel, pos, radius, vel, omega, ids, **point_data)
        self.particles.add(time, rel)
        if gas is not None:
            relg = f"gas/gas_{k:06d}.vtu"
            write_grid_vtu(self.dir / relg, gas["origin"], gas["spacing"], gas["shape"],
                           gas["cell_data"])
            self.gas.add(time, relg)
        if self._walls_file is not None:
            self.walls.add(time, self._walls_file)
        if meshes is not None:
            if self.meshes is None:
                self.meshes = PvdIndex(self.dir / "meshes.pvd", self._append, self._restart_time)
            if meshes.get("moving", True):
                relm = f"meshes/meshes_{k:06d}.vtu"
            else:
                relm = "meshes.vtu"
            if relm != "meshes.vtu" or not self._static_meshes_written:
                write_meshes_vtu(self.dir / relm, meshes["vertices"], meshes["triangles"], meshes.get("mesh"))
                self._static_meshes_written = relm == "meshes.vtu"
            self.meshes.add(time, relm)
        self.frame = k + 1
        return k
