"""Sweep logic without a cluster: variant expansion, folder names, variants files, the summary
files, the skip of complete runs (fake run folders), and the error paths."""

from __future__ import annotations

import csv
import json
import sys

import numpy as np
import pytest

from cfddem import sweep as S
from cfddem.config import load_case
from cfddem.errors import CaseError
from cfddem.io.results import ResultsFile

BOX = S.Path(__file__).resolve().parents[2] / "cases" / "box_small"


# ------------------------------------------------------------------------------ variants
def test_split_values_respects_brackets_and_quotes():
    assert S.split_values("0.1, 0.2,0.3") == ["0.1", "0.2", "0.3"]
    assert S.split_values("[0, 0, 1],[1,0,0]") == ["[0, 0, 1]", "[1,0,0]"]
    assert S.split_values('"a,b",c') == ['"a,b"', "c"]


def test_parse_vary_parses_toml_values():
    k, v = S.parse_vary("contact.particle_wall.mu=0.1,0.3,1")
    assert k == "contact.particle_wall.mu" and v == [0.1, 0.3, 1]
    assert isinstance(v[2], int)
    assert S.parse_vary("gas.enabled=true,false") == ("gas.enabled", [True, False])
    assert S.parse_vary("inlet.type=none,sluice") == ("inlet.type", ["none", "sluice"])
    assert S.parse_vary("frame.axis_point=[0,0,0],[0.04, 0, -0.035]")[1] == [[0, 0, 0], [0.04, 0, -0.035]]
    for bad in ("mu", "=1,2", "a..b=1", "a=1,,2"):
        with pytest.raises(CaseError):
            S.parse_vary(bad)


def test_expand_variants_is_cartesian_first_key_outermost():
    v = S.expand_variants([("a", [1, 2]), ("b", ["x", "y", "z"])])
    assert len(v) == 6
    assert v[0] == {"a": 1, "b": "x"} and v[2] == {"a": 1, "b": "z"} and v[3] == {"a": 2, "b": "x"}
    assert list(v[4]) == ["a", "b"]
    assert S.expand_variants([]) == [{}]
    with pytest.raises(CaseError, match="twice"):
        S.expand_variants([("a", [1]), ("a", [2])])


def test_variants_file_toml_and_csv(tmp_path):
    t = tmp_path / "v.toml"
    t.write_text('[[variants]]\n"contact.particle_wall.mu" = 0.1\n\n'
                 '[[variants]]\ncontact.particle_wall.mu = 0.3\ntime.end_time = 0.02\n')
    rows = S.read_variants_file(t)
    assert rows == [{"contact.particle_wall.mu": 0.1},
                    {"contact.particle_wall.mu": 0.3, "time.end_time": 0.02}]
    c = tmp_path / "v.csv"
    c.write_text("contact.particle_wall.mu,gas.enabled,inlet.type\n0.1,true,sluice\n0.5,,none\n\n")
    rows = S.read_variants_file(c)
    assert rows == [{"contact.particle_wall.mu": 0.1, "gas.enabled": True, "inlet.type": "sluice"},
                    {"contact.particle_wall.mu": 0.5, "inlet.type": "none"}]
    assert S.varied_keys(rows) == ["contact.particle_wall.mu", "gas.enabled", "inlet.type"]
    combined = S.combine_variants(rows, [("time.dt", [1e-5, 2e-5])])
    assert len(combined) == 4 and combined[1] == {**rows[0], "time.dt": 2e-5}
    with pytest.raises(CaseError, match="also set"):
        S.combine_variants(rows, [("inlet.type", ["none"])])
    for text, suffix in (("x = 1\n", ".toml"), ("", ".csv"), ("a\n", ".txt")):
        f = tmp_path / f"bad{suffix}"
        f.write_text(text)
        with pytest.raises(CaseError):
            S.read_variants_file(f)
    with pytest.raises(CaseError, match="no file"):
        S.read_variants_file(tmp_path / "missing.toml")


# ------------------------------------------------------------------------------ names
def test_variant_names_and_sanitising():
    assert S.variant_name({"contact.particle_wall.mu": 0.1, "time.dt": 1e-05}) == \
        "contact.particle_wall.mu=0.1__time.dt=1e-05"
    assert S.variant_name({"frame.rpm": 16.0, "gas.enabled": True}) == "frame.rpm=16.0__gas.enabled=true"
    assert S.variant_name({"frame.axis_point": [0.04, 0, -0.035]}) == "frame.axis_point=0.04_0_-0.035"
    assert S.variant_name({}) == "base"
    assert S.variant_name({"contact.particle_wall.mu": -0.2}) == "contact.particle_wall.mu=-0.2"
    assert S.variant_name({"case.name": "../../etc"}) == "case.name=.._.._etc"
    assert S.sanitise("a/b c:*?d") == "a_b_c_d"
    assert S.sanitise("../x") == "x"
    assert S.sanitise("-rf") == "rf"
    long = S.variant_name({"case.description": "x" * 400})
    assert len(long) <= S.MAX_NAME and long != S.variant_name({"case.description": "x" * 401})
    # sanitising merges "a/b" and "a b": both get a hash, and stay distinct
    names = S.variant_names([{"case.name": "a/b"}, {"case.name": "a b"}, {"case.name": "c"}])
    assert len(set(names)) == 3 and names[2] == "case.name=c" and names[0].startswith("case.name=a_b__")
    with pytest.raises(CaseError, match="twice"):
        S.variant_names([{"a": 1}, {"a": 1}])


# ------------------------------------------------------------------------------ fake runs
def fake_run(out, case, status="done", vz=(0.2, 0.15), measurements=None, n=1, mass_out=0.0, steps=1000):
    """A run folder as Simulation writes it: results.h5 (config, series, measurements) and
    run.json."""
    out.mkdir(parents=True, exist_ok=True)
    with ResultsFile(out / "results.h5") as r:
        r.write_config(case.raw_text, case.resolved)
        for i, v in enumerate(vz):
            r.append_series(0.005 * i, mean_velocity_z=v, n_particles=n, mass_out=mass_out)
        for name, val in (measurements or {}).items():
            r.write_measurements(name, val)
    (out / "run.json").write_text(json.dumps({"program": "cfddem", "status": status, "wall_time": 1.5,
                                              "steps": steps, "time": 0.01, "n_particles": n,
                                              "mass_out": mass_out, "message": ""}))
    return out


def test_read_run_summary_collects_series_and_scalar_measurements(tmp_path):
    case = load_case(BOX)
    out = fake_run(tmp_path / "r", case, vz=(0.2, 0.17, 0.12), n=3, mass_out=0.25,
                   measurements={"chute": {"flow_rate": np.float64(1.6), "profile": np.arange(4.0),
                                           "label": "x", "inner": {"h": np.int64(7)}},
                                 "bed_height_mean": 0.012})
    s = S.read_run_summary(out)
    assert s["status"] == "done" and s["steps"] == 1000 and s["n_particles"] == 3 and s["mass_out"] == 0.25
    assert s["mean_velocity_z"] == pytest.approx(0.12)
    assert s["measurements"] == {"chute/flow_rate": 1.6, "chute/inner/h": 7, "bed_height_mean": 0.012}
    assert isinstance(s["measurements"]["chute/inner/h"], int)
    assert S.read_run_summary(tmp_path / "nothing") == {"measurements": {}}


def test_run_is_complete_needs_done_results_and_same_config(tmp_path):
    case = load_case(BOX, overrides={"contact.particle_wall.mu": 0.1})
    other = load_case(BOX, overrides={"contact.particle_wall.mu": 0.5})
    out = fake_run(tmp_path / "a", case)
    assert S.run_is_complete(out) and S.run_is_complete(out, case)
    assert not S.run_is_complete(out, other)  # changed setting: not the same run
    assert not S.run_is_complete(fake_run(tmp_path / "b", case, status="failed"), case)
    assert not S.run_is_complete(fake_run(tmp_path / "c", case, status="stopped"), case)
    (tmp_path / "c" / "run.json").write_text('{"status": "running"}')
    assert not S.run_is_complete(tmp_path / "c", case)
    d = fake_run(tmp_path / "d", case)
    (d / "results.h5").write_bytes(b"not hdf5")
    assert not S.run_is_complete(d, case)
    e = fake_run(tmp_path / "e", case)
    (e / "results.h5").unlink()
    assert not S.run_is_complete(e, case)
    assert not S.run_is_complete(tmp_path / "none", case)


def test_a_run_made_before_a_key_existed_is_the_same_run_at_the_keys_default(tmp_path):
    """A key added to cfddem after a run (here: frame.rpm, removed from the stored configuration)
    leaves the run reusable while the case holds the key's default, not when it sets another."""
    import copy

    case = load_case(BOX)
    old = copy.deepcopy(case)
    del old.resolved["frame"]["rpm"]
    out = fake_run(tmp_path / "a", old)
    assert S.run_is_complete(out, case)
    assert not S.run_is_complete(out, load_case(BOX, overrides={"frame.rpm": 8.0}))
    assert not S.run_is_complete(out, load_case(BOX, overrides={"contact.particle_wall.mu": 0.5}))
    # a key the run had and the case no longer has: not the same run
    new = copy.deepcopy(case)
    new.resolved["frame"]["gone"] = 1.0
    assert not S.run_is_complete(fake_run(tmp_path / "b", new), case)


# ------------------------------------------------------------------------------ summary files
ROWS = [
    {"name": "mu=0.1__e=0.5", "values": {"mu": 0.1, "e": 0.5}, "status": "done", "wall_time": 1.25, "threads": 1,
     "steps": 1000, "time": 0.01, "n_particles": 1, "mass_out": 0.0, "mean_velocity_z": 0.19,
     "measurements": {"chute/h": 0.004}, "error": ""},
    {"name": "mu=0.5__e=0.5", "values": {"mu": 0.5, "e": 0.5}, "status": "skipped", "wall_time": 1.5,
     "steps": 1000, "time": 0.01, "n_particles": 1, "mass_out": 0.0, "mean_velocity_z": 0.15,
     "measurements": {"chute/h": 0.006, "chute/q": 2.0}, "error": ""},
    {"name": "mu=-1__e=0.5", "values": {"mu": -1, "e": 0.5}, "status": "failed", "wall_time": 0.1,
     "measurements": {}, "error": "bad input: contact.particle_wall.mu: -1 | below 0"},
    {"name": "mu=0.1__e=0.9", "values": {"mu": 0.1, "e": 0.9}, "status": "done", "wall_time": 1.0,
     "steps": 1000, "time": 0.01, "n_particles": 1, "mass_out": 0.0, "mean_velocity_z": 0.18,
     "measurements": {"chute/h": 0.005}, "error": ""},
    {"name": "mu=0.5__e=0.9", "values": {"mu": 0.5, "e": 0.9}, "status": "done", "wall_time": 1.0,
     "steps": 1000, "time": 0.01, "n_particles": 1, "mass_out": 0.0, "mean_velocity_z": 0.14,
     "measurements": {"chute/h": 0.007}, "error": ""},
]


def test_summary_csv_and_markdown(tmp_path):
    keys = ["mu", "e"]
    S.write_summary_csv(ROWS, keys, tmp_path / "summary.csv")
    with (tmp_path / "summary.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["status"] for r in rows] == ["done", "skipped", "failed", "done", "done"]
    assert list(rows[0])[:4] == ["name", "mu", "e", "status"]
    assert {"wall_time", "n_particles", "mass_out", "mean_velocity_z", "chute/h", "chute/q", "error"} <= set(rows[0])
    assert float(rows[1]["mean_velocity_z"]) == 0.15 and rows[1]["chute/q"] == "2.0" and rows[0]["chute/q"] == ""
    assert rows[2]["error"].startswith("bad input") and rows[2]["mean_velocity_z"] == ""
    md = S.write_summary_md(ROWS, keys, tmp_path / "summary.md").read_text().splitlines()
    assert md[2] == "3 done, 1 failed, 1 skipped of 5 variants"
    table = [line for line in md if line.startswith("|")]
    assert len(table) == 2 + 5
    assert "-1 \\| below 0" in table[4]  # the pipe in the message is escaped
    assert table[0].count("|") == table[2].count("|") == table[4].count("|") - 1  # one escaped pipe


def test_chart_is_written_per_second_key(tmp_path):
    png = S.write_chart(ROWS, ["mu", "e"], "mean_velocity_z", tmp_path / "c.png")
    assert png is not None and png.stat().st_size > 5000
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert S.default_chart(ROWS) == "chute/h"
    # integer counters and constants are not charted by default; what differs is
    more = [dict(r, measurements={"n_samples": 12 + i, "t_first": 0.001, **r["measurements"]})
            for i, r in enumerate(ROWS)]
    assert S.default_chart(more) == "chute/h"
    flat = [dict(r, measurements={"n_samples": 12, "t_first": 0.001}) for r in ROWS]
    assert S.default_chart(flat) == "mean_velocity_z"
    same_v = [dict(r, mean_velocity_z=0.1, n_particles=i, measurements={}) for i, r in enumerate(ROWS)]
    assert S.default_chart(same_v) == "n_particles"
    assert S.default_chart([ROWS[2]]) == "mean_velocity_z"  # nothing finished
    assert S.default_chart(ROWS[2:3]) == "mean_velocity_z"
    assert S.write_chart(ROWS, ["mu", "e"], "no_such", tmp_path / "d.png") is None
    cat = [dict(r, values={"inlet.type": t}) for r, t in zip(ROWS[:2], ("none", "sluice"))]
    assert S.write_chart(cat, ["inlet.type"], "chute/h", tmp_path / "e.png") is not None


# ------------------------------------------------------------------------------ sweep logic
def test_sweep_skips_complete_runs_and_reports_bad_input_without_a_cluster(tmp_path, capsys):
    """All runnable variants complete -> nothing is submitted (no Dask needed): rows skipped,
    bad value failed with its message, the summary files written."""
    sweep_dir = tmp_path / "sw"
    for mu, vz in ((0.1, 0.19), (0.5, 0.15)):
        case = load_case(BOX, overrides={"time.end_time": 0.005, "contact.particle_wall.mu": mu})
        fake_run(sweep_dir / f"contact.particle_wall.mu={mu}", case, vz=(0.2, vz))
    variants = S.expand_variants([("contact.particle_wall.mu", [0.1, -1.0, 0.5])])
    rows = S.run_sweep(BOX, variants, sweep_dir, common=["time.end_time=0.005"], echo=None)
    assert [r["status"] for r in rows] == ["skipped", "failed", "skipped"]
    assert "contact.particle_wall.mu" in rows[1]["error"] and rows[1]["error"].startswith("bad input")
    assert rows[0]["mean_velocity_z"] == pytest.approx(0.19) and rows[2]["mean_velocity_z"] == pytest.approx(0.15)
    assert rows[0]["wall_time"] == 1.5  # the original run's wall time
    with (sweep_dir / "summary.csv").open() as f:
        got = list(csv.DictReader(f))
    assert [g["contact.particle_wall.mu"] for g in got] == ["0.1", "-1.0", "0.5"]
    assert (sweep_dir / "summary.md").exists()
    assert (sweep_dir / "chart_mean_velocity_z.png").stat().st_size > 5000


def test_run_sweep_from_args_exit_codes_and_bad_arguments(tmp_path, capsys):
    import argparse

    p = argparse.ArgumentParser()
    S.add_sweep_parser(p.add_subparsers(dest="command"))
    with pytest.raises(CaseError, match="--vary"):
        S.run_sweep_from_args(p.parse_args(["sweep", str(BOX)]))
    args = p.parse_args(["sweep", str(BOX), "--vary", "contact.particle_wall.mu=-1,-2", "--out", str(tmp_path / "s")])
    assert S.run_sweep_from_args(args) == 3  # every variant failed validation; nothing ran
    assert "2 of 2 variant(s) failed" in capsys.readouterr().err
    vf = tmp_path / "v.csv"
    vf.write_text("contact.particle_wall.mu\n-1\n")
    args = p.parse_args(["sweep", str(BOX), "--variants", str(vf), "--vary", "time.end_time=0.01,0.02",
                         "--out", str(tmp_path / "f")])
    assert S.run_sweep_from_args(args) == 3
    with (tmp_path / "f" / "summary.csv").open() as f:
        got = list(csv.DictReader(f))
    assert [(g["contact.particle_wall.mu"], g["time.end_time"], g["status"]) for g in got] == \
        [("-1", "0.01", "failed"), ("-1", "0.02", "failed")]
    with pytest.raises(CaseError, match="--workers"):
        S.run_sweep(BOX, [{"time.end_time": 0.01}], tmp_path / "t", workers=0, echo=None)
    assert S.main([str(BOX), "--vary", "nonsense"]) == 2
    assert "expected KEY=V1,V2" in capsys.readouterr().err


def test_missing_dask_gives_a_one_line_case_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed -> ImportError
    with pytest.raises(CaseError, match=r"pip install 'cfddem\[sweep\]'") as e:
        S._import_distributed()
    assert "\n" not in str(e.value)


def test_run_variant_returns_failed_row_for_bad_input(tmp_path):
    """The task never raises: a bad value comes back as a failed row with the message."""
    row = S.run_variant(str(BOX), {"time.dt": -1.0}, str(tmp_path / "v"), threads=1)
    assert row["status"] == "failed" and "time.dt" in row["error"]
    assert row["threads"] == 1 and row["wall_time"] >= 0 and row["measurements"] == {}
    assert not (tmp_path / "v").exists()


def test_resume_only_an_unfinished_run_of_the_same_case_with_a_checkpoint(tmp_path):
    case = load_case(BOX, overrides={"contact.particle_wall.mu": 0.1})
    other = load_case(BOX, overrides={"contact.particle_wall.mu": 0.5})
    out = fake_run(tmp_path / "a", case, status="running")
    assert not S.can_resume(out, case)  # no checkpoint
    from cfddem.io.checkpoint import checkpoint_path

    (out / "checkpoints").mkdir()
    checkpoint_path(out / "checkpoints", 500).write_bytes(b"x")  # validity is the run's business
    assert S.can_resume(out, case) and S.simulation_kwargs(out, case) == \
        {"overwrite": True, "echo": False, "progress": False, "resume": True}
    assert not S.can_resume(out, other)  # another configuration: start afresh
    (out / "run.json").write_text('{"status": "done"}')
    assert not S.can_resume(out, case)
    assert S.simulation_kwargs(tmp_path / "new", case)["resume"] is False
