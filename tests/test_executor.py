"""The executor: serial, local processes and a real Dask cluster on the loopback give identical results."""

import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from conftest import loopback_cluster

from forecast_design.benchmark import BenchmarkSpec, parse_compensators, parse_reference, run_benchmark
from forecast_design.errors import ParameterError
from forecast_design.executor import DaskExecutor, LocalExecutor, batched, make_executor
from forecast_design.controllers import PD
from forecast_design.params import environment_preset


def _spec(duration_s=0.5, repetitions=2, envs=("exp-soft", "locked")):
    return BenchmarkSpec(controllers=(PD(P=5.0, D=0.1),), compensators=parse_compensators("none,ea-fob"),
                         environments=tuple((n, environment_preset(n)) for n in envs),
                         references=(parse_reference(f"step:0.2:{duration_s}"),), repetitions=repetitions)


def _same(a, b):
    """Bit-for-bit equality of two benchmarks' cells."""
    assert [c.key for c in a] == [c.key for c in b]
    for x, y in zip(a, b):
        # JSON text: exact float repr, and NaN (undefined metrics) equal to NaN
        assert json.dumps(x.to_mapping(), sort_keys=True) == json.dumps(y.to_mapping(), sort_keys=True)
        for name in ("t", "tau_s", "expected", "tau_r"):
            assert np.array_equal(getattr(x, name), getattr(y, name))


@pytest.fixture(scope="module")
def local_run():
    return run_benchmark(_spec(), executor=LocalExecutor(1), sfm_params=None)[0]


def test_batches_concatenate_to_the_items():
    items = list(range(11))
    b = batched(items, 4)
    assert [len(x) for x in b] == [4, 4, 3] and [i for x in b for i in x] == items
    with pytest.raises(ParameterError):
        batched(items, 0)


def test_local_processes_give_the_serial_results_bit_for_bit(local_run):
    with LocalExecutor(2) as ex:
        cells, info = run_benchmark(_spec(), executor=ex)
    assert info["workers"] == 2 and info["computed"] == 4
    _same(local_run, cells)


def test_map_batched_is_map_in_order():
    with LocalExecutor(2) as ex:
        out = ex.map_batched(abs, list(range(-7, 3)), batch_size=3)
    assert out == [abs(i) for i in range(-7, 3)]


def test_a_killed_local_worker_loses_no_result():
    # os.getpid of a task names its worker; killing that worker breaks the pool, the executor
    # starts a new one and the unfinished tasks are computed again
    ex = LocalExecutor(2)
    done = []

    def progress(d, n):
        done.append(d)

    def killer():
        while not done:
            time.sleep(0.01)
        for child in _children(os.getpid()):
            os.kill(child, signal.SIGKILL)
            break

    th = threading.Thread(target=killer)
    th.start()
    out = ex.map(_slow_square, list(range(12)), progress=progress)
    th.join()
    assert out == [i * i for i in range(12)]
    assert ex.restarts >= 1


def _slow_square(x):
    time.sleep(0.15)
    return x * x


def _children(pid):
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as fh:
            text = fh.read()
    except OSError:
        pytest.skip("no /proc children list on this platform")
    return [int(p) for p in text.split()]


def test_importing_the_executor_and_cli_does_not_import_dask():
    code = ("import sys, forecast_design.executor, forecast_design.cli, forecast_design.benchmark; "
            "print(sorted(m for m in ('dask', 'distributed') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_bad_scheduler_address_is_a_one_line_error():
    with pytest.raises(ParameterError, match="tcp://HOST:PORT"):
        make_executor("localhost:8786")
    with pytest.raises(ParameterError, match="cannot reach the Dask scheduler"):
        DaskExecutor("tcp://127.0.0.1:9", timeout_s=1.0)


# --- tune-q over large sets through the executor ----------------------------------------------------


def _tune(executor=None):
    from forecast_design.tuning import tune_q

    # the LD-DOB over soft and stiff with +-10 % on J, d, k_e (18 plants): the answer lies inside the band
    return tune_q("ld-dob", "soft,stiff", uncertainty=0.1, executor=executor, certify=False)


@pytest.fixture(scope="module")
def serial_tuning():
    return _tune()


def test_tune_q_through_local_processes_equals_the_serial_tuning(serial_tuning):
    with LocalExecutor(2) as ex:
        spread = _tune(ex)
    assert 0.5 < serial_tuning.w_q_hz < 30.0 and serial_tuning.plants == 18
    a, b = serial_tuning.to_mapping(), spread.to_mapping()
    a.pop("evaluations"), b.pop("evaluations")           # no early stop on the executor: may count more
    assert a == b                                         # same cutoff, worst ratio and plant, bit for bit


def test_tune_q_verb_with_workers_gives_the_same_cutoff(capsys):
    from forecast_design.cli import main
    from forecast_design.tuning import tune_q

    assert main(["tune-q", "--compensator", "ld-dob", "--envs", "soft,stiff", "--uncertainty", "0.1",
                 "--workers", "2", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    serial = tune_q("ld-dob", "soft,stiff", uncertainty=0.1)      # the verb certifies over the box, as here
    assert doc["w_q_hz"] == serial.w_q_hz and doc["worst_ratio"] == serial.worst_ratio and doc["certified"]


# --- issue 23: no hang, one line: malformed addresses, a scheduler without workers, a scheduler that dies ----------


@pytest.mark.parametrize("address", ["http://x", "tcp://127.0.0.1", "tcp://127.0.0.1:99999", "tcp://:8786",
                                     "127.0.0.1:8786", ""])
def test_malformed_scheduler_addresses_are_refused_at_once_in_one_line(address, capsys):
    from forecast_design.cli import main

    if not address:
        with pytest.raises(ParameterError, match="tcp://HOST:PORT"):
            DaskExecutor(address)
        return
    for argv in (["benchmark", "--out", "unused-folder"], ["tune-q", "--observer", "ea-fob"]):
        t0 = time.monotonic()
        code = main([*argv, "--scheduler", address])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and "tcp://HOST:PORT (with the port)" in err[0], (argv, err)
        # no client was made: nothing waits in its destructor (a connection attempt waits 20 s)
        assert time.monotonic() - t0 < 15.0
    assert not os.path.exists("unused-folder")


def test_a_scheduler_without_workers_fails_in_one_line_after_the_stated_wait(monkeypatch, capsys, tmp_path):
    distributed = pytest.importorskip("distributed")
    from forecast_design import executor
    from forecast_design.cli import main

    with distributed.LocalCluster(n_workers=0, host="127.0.0.1", dashboard_address="127.0.0.1:0") as empty:
        t0 = time.monotonic()
        with pytest.raises(ParameterError, match=r"has no worker after 1\.5 s; start workers"):
            DaskExecutor(empty.scheduler_address, worker_wait_s=1.5)
        assert 1.5 <= time.monotonic() - t0 < 30.0
        monkeypatch.setattr(executor, "DASK_WORKER_WAIT_S", 1.0)
        for argv in (["benchmark", "--envs", "soft", "--compensator", "none", "--repetitions", "2",
                      "--duration", "0.2", "--out", str(tmp_path / "b")],
                     ["tune-q", "--observer", "ea-fob", "--envs", "soft"]):
            assert main(argv + ["--scheduler", empty.scheduler_address]) == 2
            err = capsys.readouterr().err.strip().splitlines()
            assert len(err) == 1 and err[0].startswith("forecast-design: error: the Dask cluster at ") \
                and "has no worker after 1 s" in err[0], err


@pytest.mark.parametrize("behaviour", ["silent", "hang-up"])
def test_an_address_that_is_no_scheduler_fails_in_one_line_after_the_connect_timeout(behaviour):
    """A port that accepts and never speaks (or hangs up at once) is not a scheduler: one line, no hang."""
    pytest.importorskip("distributed")
    import socket
    import threading

    server = socket.create_server(("127.0.0.1", 0))
    held, stop = [], threading.Event()

    def accept():
        server.settimeout(0.2)
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            if behaviour == "silent":
                held.append(conn)
            else:
                conn.close()

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    try:
        address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
        t0 = time.monotonic()
        with pytest.raises(ParameterError, match="cannot reach the Dask scheduler at tcp://127.0.0.1:") as info:
            DaskExecutor(address, timeout_s=2.0)
        assert len(str(info.value).splitlines()) == 1
        # a silent peer is given the stated wait, and no more than a liveness bound (dask's own connect
        # bounds the TCP connection but not its handshake: this hung for ever)
        elapsed = time.monotonic() - t0
        assert elapsed < 60.0 and (behaviour != "silent" or elapsed >= 2.0)
    finally:
        stop.set()
        thread.join()
        for conn in held:
            conn.close()
        server.close()


@pytest.mark.slow
def test_a_scheduler_killed_mid_benchmark_ends_the_command_in_one_line(tmp_path):
    distributed = pytest.importorskip("distributed")
    dask = os.path.join(os.path.dirname(sys.executable), "dask")
    file = tmp_path / "scheduler.json"
    scheduler = subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--dashboard-address",
                                  "127.0.0.1:0", "--scheduler-file", str(file)],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    worker = bench = None
    try:
        deadline = time.monotonic() + 120
        address = None
        while address is None and time.monotonic() < deadline:     # the file appears before it is written
            try:
                address = json.loads(file.read_text())["address"]
            except (FileNotFoundError, json.JSONDecodeError, KeyError):
                time.sleep(0.2)
        assert address is not None, "the scheduler wrote no address within 120 s"
        worker = subprocess.Popen([dask, "worker", address, "--nthreads", "1", "--nworkers", "1"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        with distributed.Client(address, timeout=60) as watch:
            watch.wait_for_workers(1, timeout=120)
            bench = subprocess.Popen([sys.executable, "-m", "forecast_design", "benchmark", "--envs",
                                      "soft,stiff,exp-soft,locked", "--compensator", "none,ea-fob", "--repetitions",
                                      "4", "--duration", "3", "--workers", "1", "--out", str(tmp_path / "b"),
                                      "--scheduler", address], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
            while not any(watch.processing().values()) and time.monotonic() < deadline:   # a task runs
                time.sleep(0.1)
        scheduler.kill()
        scheduler.wait()
        out, err = bench.communicate(timeout=300)
    finally:
        for proc in (bench, worker, scheduler):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
    lines = err.strip().splitlines()
    assert bench.returncode == 2 and len(lines) == 1, err
    assert lines[0].startswith("forecast-design: error: the Dask cluster at ") and "Traceback" not in err


@pytest.mark.slow
def test_a_cluster_that_loses_every_worker_ends_the_command_in_one_line(tmp_path, monkeypatch, capsys):
    """The only worker (no nanny to restart it) is killed while a task runs: no hang, one line."""
    distributed = pytest.importorskip("distributed")
    from forecast_design import executor
    from forecast_design.cli import main

    dask = os.path.join(os.path.dirname(sys.executable), "dask")
    monkeypatch.setattr(executor, "DASK_WORKER_WAIT_S", 3.0)
    with distributed.LocalCluster(n_workers=0, host="127.0.0.1", dashboard_address="127.0.0.1:0") as cluster:
        worker = subprocess.Popen([dask, "worker", cluster.scheduler_address, "--nthreads", "1", "--no-nanny"],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            with distributed.Client(cluster.scheduler_address, timeout=60) as watch:
                watch.wait_for_workers(1, timeout=120)

                def killer():
                    deadline = time.monotonic() + 120
                    while not any(watch.processing().values()) and time.monotonic() < deadline:
                        time.sleep(0.05)
                    worker.kill()

                th = threading.Thread(target=killer, daemon=True)
                th.start()
                t0 = time.monotonic()
                code = main(["benchmark", "--envs", "soft,stiff,exp-soft,locked", "--compensator", "none,ea-fob",
                             "--repetitions", "4", "--duration", "3", "--out", str(tmp_path / "b"),
                             "--scheduler", cluster.scheduler_address])
                th.join(10)
        finally:
            if worker.poll() is None:
                worker.kill()
            worker.wait()
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "lost every worker and none came back within 3 s" in err[0] and time.monotonic() - t0 < 120


# --- on a Dask cluster on the loopback (last: its idle workers use CPU until the module ends) ---------------


@pytest.fixture(scope="module")
def cluster():
    with loopback_cluster() as c:
        yield c


@pytest.mark.slow
def test_dask_cluster_gives_the_local_results_bit_for_bit(cluster, local_run):
    with make_executor(cluster.scheduler_address) as ex:
        assert ex.workers == 2
        cells, info = run_benchmark(_spec(), executor=ex)
    assert info["executor"] == "dask" and info["computed"] == 4
    _same(local_run, cells)


@pytest.mark.slow
def test_a_dask_worker_killed_mid_run_loses_no_result(cluster):
    spec = _spec(duration_s=2.0, repetitions=2, envs=("exp-soft", "locked", "soft", "stiff"))
    expected = run_benchmark(spec, executor=LocalExecutor(1))[0]
    ex = make_executor(cluster.scheduler_address)
    killed = []

    def killer():
        deadline = time.time() + 60
        while time.time() < deadline:
            busy = {w: tasks for w, tasks in ex.client.processing().items() if tasks}
            if busy:
                addr = next(iter(busy))
                for worker in cluster.workers.values():
                    if getattr(worker, "worker_address", None) == addr and worker.process is not None:
                        os.kill(worker.process.pid, signal.SIGKILL)
                        killed.append(addr)
                        return
            time.sleep(0.02)

    th = threading.Thread(target=killer)
    th.start()
    try:
        cells, _ = run_benchmark(spec, executor=ex)
    finally:
        th.join()
        ex.close()
    assert killed, "no worker was killed while tasks ran"
    _same(expected, cells)


@pytest.mark.slow
def test_tune_q_on_a_dask_cluster_equals_local(cluster, serial_tuning):
    with make_executor(cluster.scheduler_address) as ex:
        on_dask = _tune(ex)
    with LocalExecutor(1) as ex:
        local = _tune(ex)
    assert on_dask.to_mapping() == local.to_mapping()
    assert on_dask.w_q_hz == serial_tuning.w_q_hz and on_dask.worst_ratio == serial_tuning.worst_ratio
