"""Tiny sweeps on real Dask clusters (this machine only, 127.0.0.1).

The case is ``cases/box_small``: one bead sliding on the floor at v0 = 0.2 m/s.  While it
slides, v_z(t) = v0 - mu_w g t (it rolls only after t = 2 v0 / (7 mu_w g) = 11.7 ms for
mu_w = 0.5), so at t = 10 ms: 0.1902 m/s (mu_w = 0.1) and 0.1510 m/s (mu_w = 0.5), and at
t = 5 ms with mu_w = 0.1: 0.1951 m/s.  The engine resolves the normal load as a lightly
damped spring about m g, so the measured values agree to well under 1 %.

Worker start-up and the numba compile dominate: every worker shares ``NUMBA_CACHE_DIR``.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("distributed")

from cfddem import sweep as S  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
BOX = ROOT / "cases" / "box_small"
G = 9.81
V0 = 0.2
MU = "contact.particle_wall.mu"
END = "time.end_time"


def sliding_velocity(mu: float, t: float) -> float:
    """v_z of a sphere sliding with Coulomb friction before it rolls (t < 2 v0 / (7 mu g))."""
    assert t < 2 * V0 / (7 * mu * G)
    return V0 - mu * G * t


@pytest.fixture(scope="module", autouse=True)
def shared_numba_cache(tmp_path_factory):
    """One NUMBA_CACHE_DIR for this process and every worker it starts (inherited env)."""
    old = os.environ.get("NUMBA_CACHE_DIR")
    if not old:
        os.environ["NUMBA_CACHE_DIR"] = str(tmp_path_factory.mktemp("numba_cache"))
    yield os.environ["NUMBA_CACHE_DIR"]
    if not old:
        os.environ.pop("NUMBA_CACHE_DIR", None)


def by_name(rows):
    return {r["name"]: r for r in rows}


def test_local_cluster_sweep_physics_failures_and_skip_on_rerun(tmp_path):
    variants = [
        {MU: 0.1, END: 0.01},
        {MU: 0.5, END: 0.01},
        {MU: 0.1, END: 0.005},
        {MU: -0.2, END: 0.01},  # invalid value: refused before it is submitted
        {MU: 0.1, END: 0.01, "time.dt": 1e-3},  # dt > t_c/5: refused by the run, in the worker
    ]
    out = tmp_path / "sweep"
    lines = []
    rows = S.run_sweep(BOX, variants, out, workers=1, threads=1, echo=lines.append)
    r = by_name(rows)
    a, b, c = r["contact.particle_wall.mu=0.1__time.end_time=0.01"], r["contact.particle_wall.mu=0.5__time.end_time=0.01"], \
        r["contact.particle_wall.mu=0.1__time.end_time=0.005"]
    bad_mu = r["contact.particle_wall.mu=-0.2__time.end_time=0.01"]
    bad_dt = r["contact.particle_wall.mu=0.1__time.end_time=0.01__time.dt=0.001"]
    assert [x["status"] for x in (a, b, c)] == ["done"] * 3, [x.get("error") for x in rows]
    assert bad_mu["status"] == "failed" and MU in bad_mu["error"]
    assert bad_dt["status"] == "failed" and "time.dt" in bad_dt["error"] and "t_c" in bad_dt["error"]
    # physics: more friction -> slower; a longer run -> more steps and more deceleration
    assert a["mean_velocity_z"] == pytest.approx(sliding_velocity(0.1, 0.01), rel=5e-3)
    assert b["mean_velocity_z"] == pytest.approx(sliding_velocity(0.5, 0.01), rel=5e-3)
    assert c["mean_velocity_z"] == pytest.approx(sliding_velocity(0.1, 0.005), rel=5e-3)
    assert b["mean_velocity_z"] < a["mean_velocity_z"] - 0.03
    assert (a["steps"], c["steps"]) == (1000, 500)
    assert a["n_particles"] == 1 and a["mass_out"] == 0.0 and a["threads"] == 1
    assert any("local Dask cluster: 1 worker" in s for s in lines)

    with (out / "summary.csv").open() as f:
        table = list(csv.DictReader(f))
    assert len(table) == 5
    assert [t["status"] for t in table] == ["done", "done", "done", "failed", "failed"]
    assert [t[MU] for t in table] == ["0.1", "0.5", "0.1", "-0.2", "0.1"]
    assert [t["time.dt"] for t in table] == ["", "", "", "", "0.001"]
    assert float(table[1]["mean_velocity_z"]) == b["mean_velocity_z"]
    assert (out / "summary.md").read_text().count("\n|") == 2 + 5  # header, separator, rows
    assert (out / "chart_mean_velocity_z.png").stat().st_size > 5000
    for x in (a, b, c):
        assert (out / x["name"] / "run.json").is_file() and (out / x["name"] / "results.h5").is_file()

    # re-run: the complete runs are skipped (untouched), the failed ones tried again
    stamp = {x["name"]: (out / x["name"] / "run.json").stat().st_mtime_ns for x in (a, b, c)}
    rows2 = S.run_sweep(BOX, variants, out, workers=1, threads=1, echo=None)
    assert [x["status"] for x in rows2] == ["skipped", "skipped", "skipped", "failed", "failed"]
    for x in rows2[:3]:
        assert (out / x["name"] / "run.json").stat().st_mtime_ns == stamp[x["name"]]
        assert x["mean_velocity_z"] == by_name(rows)[x["name"]]["mean_velocity_z"]
    assert "t_c" in rows2[4]["error"]
    # a changed base setting is a different run: not skipped
    rows3 = S.run_sweep(BOX, variants[2:3], out, common=["contact.particle_wall.e_n=0.9"], workers=1, threads=1,
                        echo=None)
    assert rows3[0]["status"] == "done"


def test_local_cluster_sets_numba_threads_in_the_worker_environment():
    cluster, client = S.start_local_cluster(2, 1)
    try:
        env = client.run(lambda: os.environ.get("NUMBA_NUM_THREADS"))
        assert sorted(env.values()) == ["1", "1"]

        def pool():
            import numba

            return numba.config.NUMBA_NUM_THREADS, S.task_threads(None), numba.get_num_threads()

        # this machine may have more cores, but the worker's numba pool is what we set
        assert client.submit(pool, pure=False).result(timeout=120) == (1, 1, 1)
        info = client.scheduler_info()["workers"]
        assert len(info) == 2 and all(w["nthreads"] == 1 for w in info.values())
        assert all(w["host"] == "127.0.0.1" for w in info.values())
    finally:
        client.close()
        cluster.close()


@pytest.fixture
def dask_scheduler(tmp_path):
    """A separately started ``dask scheduler`` and one ``dask worker`` (127.0.0.1, one thread,
    NUMBA_NUM_THREADS=1), killed at the end whatever happens; both exit on their own if
    orphaned (scheduler idle timeout, worker death timeout)."""
    # `dask scheduler` / `dask worker`, run with this interpreter (the same environment)
    scheduler_cmd = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
    worker_cmd = [sys.executable, "-m", "distributed.cli.dask_worker"]
    sched_file = tmp_path / "scheduler.json"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1")
    logs = [open(tmp_path / "scheduler.log", "w"), open(tmp_path / "worker.log", "w")]
    procs = []
    try:
        procs.append(subprocess.Popen(
            [*scheduler_cmd, "--host", "127.0.0.1", "--port", "0", "--no-dashboard", "--scheduler-file",
             str(sched_file), "--idle-timeout", "300"], stdout=logs[0], stderr=subprocess.STDOUT, env=env,
            cwd=tmp_path))
        t_end = time.monotonic() + 60
        while not sched_file.exists() and time.monotonic() < t_end:
            assert procs[0].poll() is None, (tmp_path / "scheduler.log").read_text()
            time.sleep(0.2)
        assert sched_file.exists(), "the scheduler did not start within 60 s"
        import json

        address = json.loads(sched_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        procs.append(subprocess.Popen(
            [*worker_cmd, address, "--nthreads", "1", "--nworkers", "1", "--host", "127.0.0.1", "--no-dashboard",
             "--death-timeout", "60", "--local-directory", str(tmp_path / "worker")],
            stdout=logs[1], stderr=subprocess.STDOUT, env=env, cwd=tmp_path))
        from distributed import Client

        with Client(address, timeout="30s") as c:
            c.wait_for_workers(1, timeout=90)
        yield address
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=15)
        for f in logs:
            f.close()


def test_sweep_on_a_separately_started_scheduler(dask_scheduler, tmp_path, capsys):
    out = tmp_path / "sweep"
    code = S.main([str(BOX), "--vary", "contact.particle_wall.mu=0.1,0.5", "--set", "time.end_time=0.01",
                   "--scheduler", dask_scheduler, "--out", str(out), "--chart", "mean_velocity_z"])
    assert code == 0, capsys.readouterr()
    with (out / "summary.csv").open() as f:
        table = list(csv.DictReader(f))
    assert [t["status"] for t in table] == ["done", "done"]
    assert [t["threads"] for t in table] == ["1", "1"]  # from the worker's NUMBA_NUM_THREADS
    v = [float(t["mean_velocity_z"]) for t in table]
    assert v[0] == pytest.approx(sliding_velocity(0.1, 0.01), rel=5e-3)
    assert v[1] == pytest.approx(sliding_velocity(0.5, 0.01), rel=5e-3)
    assert (out / "chart_mean_velocity_z.png").is_file()
    # a scheduler that is not there: a one-line CaseError naming --scheduler
    from cfddem.errors import CaseError

    with pytest.raises(CaseError, match=r"--scheduler: cannot connect to tcp://127.0.0.1:9") as e:
        S.run_sweep(BOX, [{MU: 0.2}], tmp_path / "s2", scheduler="tcp://127.0.0.1:9", connect_timeout=2, echo=None)
    assert "\n" not in str(e.value)


def test_rerun_resumes_an_unfinished_variant_from_its_checkpoint(tmp_path):
    """A variant whose run was cut short (run.json still "running", as after a killed worker)
    is continued from its newest checkpoint, and ends where an uninterrupted run ends."""
    variants = [{MU: 0.1, "checkpoint.interval": 0.004}]
    out = tmp_path / "sweep"
    first = S.run_sweep(BOX, variants, out, workers=1, threads=1, echo=None)[0]
    assert first["status"] == "done" and first["resumed"] is False, first
    run = out / first["name"]
    ckpts = sorted((run / "checkpoints").glob("*.h5"))
    assert len(ckpts) == 2, ckpts  # t = 4 ms and 8 ms (keep = 2)
    ckpts[-1].unlink()  # the crash came before the 8 ms checkpoint
    meta = json.loads((run / "run.json").read_text())
    (run / "run.json").write_text(json.dumps(dict(meta, status="running")))
    lines = []
    again = S.run_sweep(BOX, variants, out, workers=1, threads=1, echo=lines.append)[0]
    assert again["status"] == "done" and again["resumed"] is True, (again, lines)
    assert any("(resumed)" in s for s in lines)
    assert "resuming from" in (run / "run.log").read_text()
    assert again["steps"] == 1000
    assert again["mean_velocity_z"] == first["mean_velocity_z"]  # bit-identical continuation
    assert S.run_sweep(BOX, variants, out, echo=None)[0]["status"] == "skipped"
