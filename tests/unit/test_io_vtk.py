"""VTU writers (read back with meshio) and atomic PVD collections."""

import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest

from cfddem.io.vtk import (ParaViewOutput, PvdIndex, write_grid_vtu, write_particles_vtu,
                           write_walls_vtu)


def test_particles_vtu_roundtrip(tmp_path):
    rng = np.random.default_rng(0)
    n = 50
    pos, vel, om = rng.random((n, 3)), rng.random((n, 3)), rng.random((n, 3))
    rad = np.full(n, 1.5e-3)
    ids = np.arange(100, 100 + n, dtype=np.int64)
    p = write_particles_vtu(tmp_path / "p.vtu", pos, rad, vel, om, ids, overlap=rng.random(n))
    raw = p.read_bytes()
    assert b'format="binary"' in raw and b"vtkZLibDataCompressor" in raw
    m = meshio.read(p)
    np.testing.assert_allclose(m.points, pos)
    assert m.cells[0].type == "vertex" and len(m.cells[0].data) == n
    np.testing.assert_allclose(m.point_data["velocity"], vel)
    np.testing.assert_allclose(m.point_data["spin"], om)
    np.testing.assert_array_equal(m.point_data["id"], ids)
    assert set(m.point_data) == {"radius", "velocity", "spin", "id", "overlap"}
    assert not list(tmp_path.glob(".*tmp"))


def test_particles_vtu_empty(tmp_path):
    # meshio 5.3 cannot read an empty piece back, so check the XML itself
    p = write_particles_vtu(tmp_path / "e.vtu", np.zeros((0, 3)), np.zeros(0), vel=np.zeros((0, 3)))
    root = ET.parse(p).getroot()
    piece = root.find("UnstructuredGrid/Piece")
    assert piece.get("NumberOfPoints") == "0" and piece.get("NumberOfCells") == "0"
    names = {d.get("Name") for d in piece.find("PointData")}
    assert names == {"radius", "velocity"}


def test_particles_bad_point_data(tmp_path):
    with pytest.raises(ValueError):
        write_particles_vtu(tmp_path / "b.vtu", np.zeros((3, 3)), np.ones(3), T=np.ones(2))


def test_grid_vtu_cell_order_and_geometry(tmp_path):
    nx, ny, nz = 2, 3, 4
    origin, h = (0.0, 0.0, -0.1), (0.005, 0.003, 0.006)
    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    code = 100 * i + 10 * j + k
    vec = np.stack([i, j, k], axis=-1).astype(float)
    p = write_grid_vtu(tmp_path / "g.vtu", origin, h, (nx, ny, nz), {"code": code, "u": vec})
    m = meshio.read(p)
    assert m.points.shape == ((nx + 1) * (ny + 1) * (nz + 1), 3)
    hexes = m.cells[0].data
    assert m.cells[0].type == "hexahedron" and hexes.shape == (nx * ny * nz, 8)
    centres = m.points[hexes].mean(axis=1)
    got_code = m.cell_data["code"][0]
    # the centre of each hexahedron must be the centre of the cell its value belongs to
    ii, jj, kk = got_code // 100, (got_code // 10) % 10, got_code % 10
    expect = np.column_stack([origin[0] + (ii + 0.5) * h[0], origin[1] + (jj + 0.5) * h[1],
                              origin[2] + (kk + 0.5) * h[2]])
    np.testing.assert_allclose(centres, expect, atol=1e-12)
    np.testing.assert_allclose(m.cell_data["u"][0], np.column_stack([ii, jj, kk]))
    # positive volume (VTK node order): (p1-p0) x (p3-p0) . (p4-p0) > 0
    P = m.points[hexes]
    vol = np.einsum("ij,ij->i", np.cross(P[:, 1] - P[:, 0], P[:, 3] - P[:, 0]), P[:, 4] - P[:, 0])
    np.testing.assert_allclose(vol, h[0] * h[1] * h[2])
    with pytest.raises(ValueError):
        write_grid_vtu(tmp_path / "x.vtu", origin, h, (nx, ny, nz), {"bad": np.zeros((2, 2, 2))})


def test_walls_vtu(tmp_path):
    quad = np.array([[0, 0, 0], [0.08, 0, 0], [0.08, 0, 0.9], [0, 0, 0.9]], float)
    m = meshio.read(write_walls_vtu(tmp_path / "w.vtu", [quad, quad + [0, 0.045, 0]]))
    assert m.cells[0].type == "quad" and m.cells[0].data.shape == (2, 4)
    np.testing.assert_allclose(m.points[m.cells[0].data[1]], quad + [0, 0.045, 0])


def _pvd_entries(path):
    return [(float(d.get("timestep")), d.get("file")) for d in ET.parse(path).getroot().iter("DataSet")]


def test_pvd_valid_after_every_frame_and_append(tmp_path):
    pvd = tmp_path / "p.pvd"
    idx = PvdIndex(pvd)
    assert _pvd_entries(pvd) == []
    idx.add(0.0, "a/p_0.vtu")
    assert _pvd_entries(pvd) == [(0.0, "a/p_0.vtu")]
    idx.add(0.1, "a/p_1.vtu")
    idx.add(0.2, "a/p_2.vtu")
    assert _pvd_entries(pvd)[-1] == (0.2, "a/p_2.vtu")
    idx2 = PvdIndex(pvd, append=True, restart_time=0.1)
    assert _pvd_entries(pvd) == [(0.0, "a/p_0.vtu"), (0.1, "a/p_1.vtu")]
    idx2.add(0.15, "a/p_r.vtu")
    assert len(_pvd_entries(pvd)) == 3
    assert [f.name for f in tmp_path.iterdir()] == ["p.pvd"]


def test_paraview_output_same_times(tmp_path):
    out = ParaViewOutput(tmp_path)
    out.set_walls([np.array([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]], float)])
    gas = dict(origin=(0, 0, 0), spacing=0.01, shape=(2, 2, 2), cell_data={"p": np.zeros((2, 2, 2))})
    for k, t in enumerate([0.0, 0.05]):
        out.write(t, np.zeros((2, 3)), np.ones(2), gas=gas)
    d = tmp_path / "vtk"
    times = [[t for t, _ in _pvd_entries(d / f"{s}.pvd")] for s in ("particles", "gas", "walls")]
    assert times[0] == times[1] == times[2] == [0.0, 0.05]
    for s in ("particles", "gas"):
        for _, f in _pvd_entries(d / f"{s}.pvd"):
            assert (d / f).is_file()
    again = ParaViewOutput(tmp_path, append=True)
    assert again.frame == 2
