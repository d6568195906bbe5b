"""Sets of files that belong together (issue 23): a reader never sees old and new members mixed.

A result folder (``benchmark --out``, ``export --firmware``) is written by ``fileio.staged_set``:
members into a staging folder, the manifest removed, members renamed in, the manifest written last.
The tests kill writers with SIGKILL at random (seeded) times (each writer a process forked from one that
imported the toolbox once, so the kill times fall in the writing, not in the imports) and check what
every reader sees: either
no complete set (``verify_manifest``/``read_results`` refuse, ``make`` refuses) or exactly one
generation's files. Temporaries of killed writers are removed by the next write.
"""

from __future__ import annotations

import hashlib
import json
import os
import random
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from forecast_design import fileio
from forecast_design.benchmark import CellResult, parse_compensators, parse_reference, read_results, run_benchmark
from forecast_design.benchmark import BenchmarkSpec
from forecast_design.errors import OutputError
from forecast_design.fileio import MANIFEST, staged_set, verify_manifest
from forecast_design.controllers import PD
from forecast_design.params import environment_preset

TEMP = fileio._TEMP_NAME


def _temporaries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob("*") if TEMP.match(p.name))


_FORKER = textwrap.dedent("""
    import importlib, json, os, signal, sys, time
    from pathlib import Path

    from forecast_design.fileio import atomic_write, staged_set

    for name in sys.argv[1:]:     # what the writers import, imported once: an import writes nothing
        importlib.import_module(name)


    def staged_writer(root):
        for gen in range(10**9):
            with staged_set(Path(root)) as st:
                for name in ("a.txt", "b.bin", "c.txt") + (("odd.txt",) if gen % 2 else ()):
                    atomic_write(st / name, f"{gen}\\n" * (1 + 5000 * (name == "b.bin")))


    for line in sys.stdin:
        job = json.loads(line)
        t0 = time.monotonic()
        pid = os.fork()
        if pid == 0:                       # the writer: a process of its own, from a state that wrote nothing
            code = 1
            try:
                null = os.open(os.devnull, os.O_RDWR)
                for fd in (0, 1, 2):
                    os.dup2(null, fd)
                argv = job["argv"]
                if argv[0] == "staged-writer":
                    code = staged_writer(argv[1])
                else:
                    from forecast_design.cli import main
                    code = main(argv)
            finally:
                os._exit(code or 0)
        deadline = None if job["kill_after_s"] is None else t0 + job["kill_after_s"]
        killed = False
        while True:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                break
            if deadline is not None and time.monotonic() >= deadline:
                os.kill(pid, signal.SIGKILL)
                killed = True
                done, status = os.waitpid(pid, 0)
                break
            time.sleep(0.002)
        # reaped: its pid no longer runs, so its temporaries count as stale
        print(json.dumps({"code": os.waitstatus_to_exitcode(status), "killed": killed,
                          "seconds": time.monotonic() - t0}), flush=True)
""")


class _Forker:
    """Runs writers as processes forked from one that imported the toolbox once (the import is not what
    a kill should hit, and it costs more than the writing): ``run`` waits for one, ``kill_at`` sends it
    SIGKILL after ``delay_s`` [s] unless it finished before. Each writer is reaped before the call returns."""

    def __init__(self, folder: Path, preload: tuple[str, ...] = ()) -> None:
        script = folder / "forker.py"
        script.write_text(_FORKER)
        self.proc = subprocess.Popen([sys.executable, str(script), *preload], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True, env={**os.environ, "MPLBACKEND": "Agg"})

    def _job(self, argv: list[str], kill_after_s: float | None) -> dict:
        self.proc.stdin.write(json.dumps({"argv": argv, "kill_after_s": kill_after_s}) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        assert line, "the forking process died"
        return json.loads(line)

    def run(self, argv: list[str]) -> dict:
        done = self._job(argv, None)
        assert done["code"] == 0, done
        return done

    def kill_at(self, argv: list[str], delay_s: float) -> dict:
        return self._job(argv, delay_s)

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=60)
        self.proc.stdout.close()


@pytest.fixture
def forker(tmp_path):
    f = _Forker(tmp_path)
    yield f
    f.close()


@pytest.fixture
def cli_forker(tmp_path):
    """A forker whose writers run the command line (its modules, the table and plot libraries imported)."""
    f = _Forker(tmp_path, ("forecast_design.cli", "forecast_design.benchmark", "forecast_design.plotting.benchmark",
                           "forecast_design.export.firmware", "matplotlib.pyplot", "pyarrow.parquet"))
    yield f
    f.close()


def _digests(folder: Path, names) -> dict[str, str]:
    return {n: hashlib.sha256((folder / n).read_bytes()).hexdigest() for n in names}


# --- the mechanism ------------------------------------------------------------------------------------------------

def test_a_staged_set_killed_at_random_times_is_one_generation_or_refused(tmp_path, forker):
    """A writer replaces a set of 3-4 files again and again (a generation takes some ms) until it is
    killed at a random time: a reader then sees one generation or no set."""
    root = tmp_path / "set"
    rng = random.Random(23)
    seen = {"complete": 0, "refused": 0}
    for _ in range(12):
        assert forker.kill_at(["staged-writer", str(root)], rng.uniform(0.05, 0.6))["killed"]
        try:
            members = verify_manifest(root)
        except OutputError as exc:
            assert "no MANIFEST.sha256" in str(exc) or "differs from" in str(exc)
            seen["refused"] += 1
            continue
        seen["complete"] += 1
        gens = {p.read_text().splitlines()[0] for p in members.values()}
        assert len(gens) == 1, gens                                   # one generation, never a mix
        odd = int(gens.pop()) % 2 == 1
        assert set(members) == {"a.txt", "b.bin", "c.txt"} | ({"odd.txt"} if odd else set())
        assert (root / "odd.txt").exists() == odd                     # a dropped member is gone too
    assert seen["complete"] + seen["refused"] == 12
    fileio._CLEANED.discard(os.path.abspath(root))
    with staged_set(root) as st:                                     # the next write removes the leftovers
        (st / "a.txt").write_text("final\n")
    assert _temporaries(root) == [] and set(verify_manifest(root)) == {"a.txt"}
    assert sorted(p.name for p in root.iterdir()) == ["MANIFEST.sha256", "a.txt"]


class _Interrupt(BaseException):
    pass


@pytest.mark.parametrize("renames_before", [0, 1, 2, 3, 4, 5])
def test_an_interrupted_commit_is_the_old_set_the_new_one_or_refused_at_every_step(tmp_path, monkeypatch,
                                                                                   renames_before):
    """Renames: the pending list, three members, the manifest; interrupted before each of them."""
    root = tmp_path / "set"
    with staged_set(root) as st:
        for name in ("a.txt", "b.txt", "c.txt", "gone.txt"):
            (st / name).write_text("old\n")
    real, calls = os.replace, []

    def replace(src, dst):
        if len(calls) == renames_before:
            raise _Interrupt()
        calls.append(dst)
        return real(src, dst)

    monkeypatch.setattr(fileio.os, "replace", replace)
    interrupted = True
    try:
        with staged_set(root) as st:
            for name in ("a.txt", "b.txt", "c.txt"):
                (st / name).write_text("new\n")
        interrupted = False
    except _Interrupt:
        pass
    monkeypatch.setattr(fileio.os, "replace", real)
    assert interrupted == (renames_before < 5)
    assert not list(root.glob("*.tmpdir"))                            # an exception (not a kill) cleans up
    try:
        members = verify_manifest(root)
    except OutputError as exc:
        assert 1 <= renames_before <= 4 and "no MANIFEST.sha256" in str(exc)
    else:
        generation = {p.read_text() for p in members.values()}
        assert generation == ({"old\n"} if renames_before == 0 else {"new\n"})
        assert set(members) == ({"a.txt", "b.txt", "c.txt", "gone.txt"} if renames_before == 0
                                else {"a.txt", "b.txt", "c.txt"})
    with staged_set(root) as st:                                     # the next write completes a set
        (st / "a.txt").write_text("next\n")
    assert set(verify_manifest(root)) == {"a.txt"}
    assert sorted(p.name for p in root.iterdir()) == ["MANIFEST.sha256", "a.txt"]   # no stale member left


def test_verify_manifest_names_a_member_that_changed(tmp_path):
    with staged_set(tmp_path) as st:
        (st / "x.csv").write_text("1\n")
    (tmp_path / "x.csv").write_text("2\n")
    with pytest.raises(OutputError, match=r"x\.csv: differs from MANIFEST\.sha256"):
        verify_manifest(tmp_path)
    (tmp_path / "x.csv").unlink()
    with pytest.raises(OutputError, match=r"x\.csv: listed in MANIFEST\.sha256"):
        verify_manifest(tmp_path)


# --- benchmark result folders -------------------------------------------------------------------------------------


def _bench_argv(out: Path, seed: int) -> list[str]:
    return ["benchmark", "--envs", "soft", "--compensator", "none", "--repetitions", "2", "--duration", "0.2",
            "--workers", "1", "--seed", str(seed), "--out", str(out)]


def test_benchmark_killed_at_random_times_leaves_one_consistent_result_set(tmp_path, cli_forker):
    forker = cli_forker
    # report.md and summary.json also say how the run went (cells reused, seconds): compared through the seed
    names = ("results.csv", "results.parquet", "indicators.png", "overlays.png", "heatmap.png")
    work = tmp_path / "work"
    duration = forker.run(_bench_argv(work, 0))["seconds"]      # the folder's set: run 0
    old = _digests(work, names)
    rng = random.Random(2023)
    seen = []
    for _ in range(3):                        # run 1 over it, killed at random times
        forker.kill_at(_bench_argv(work, 1), rng.uniform(0.3, 1.1) * duration)
        try:
            doc, table = read_results(work)
        except OutputError as exc:
            assert "no MANIFEST.sha256" in str(exc), exc        # mid-swap: refused, not a mix
            seen.append(None)
            continue
        seen.append((doc["benchmark"]["seed"], _digests(work, names)))
        assert len(table) > 0
    forker.run(_bench_argv(work, 1))
    doc, _ = read_results(work)
    new = _digests(work, names)
    assert doc["benchmark"]["seed"] == 1 and new != old
    for state in seen:                          # every state a reader saw was one whole run's set
        assert state is None or state in ((0, old), (1, new)), "a mixed result set"
    assert _temporaries(work) == []                                    # killed runs' temporaries removed


def test_reused_cells_must_be_the_ones_their_key_names_and_intact(tmp_path):
    spec = BenchmarkSpec(controllers=(PD(P=5.0, D=0.1),), compensators=parse_compensators("none"),
                         environments=(("soft", environment_preset("soft")), ("locked", environment_preset("locked"))),
                         references=(parse_reference("step:0.2:0.2"),), repetitions=2)
    cells, info = run_benchmark(spec, out=tmp_path)
    assert info["computed"] == 2
    folder = tmp_path / "cells"
    a, b = (c.key for c in cells)
    assert CellResult.load(folder, a) is not None
    # swap the traces of two cells: neither is reused
    npz_a, npz_b = (folder / f"{a}.npz").read_bytes(), (folder / f"{b}.npz").read_bytes()
    (folder / f"{a}.npz").write_bytes(npz_b)
    (folder / f"{b}.npz").write_bytes(npz_a)
    assert CellResult.load(folder, a) is None and CellResult.load(folder, b) is None
    again, info = run_benchmark(spec, out=tmp_path)
    assert info["computed"] == 2 and info["reused"] == 0
    np.testing.assert_array_equal(again[0].tau_s, cells[0].tau_s)
    # a truncated .npz (a full disk, a copy cut short): recomputed, no BadZipFile
    (folder / f"{a}.npz").write_bytes((folder / f"{a}.npz").read_bytes()[:100])
    # a JSON whose key names another cell: not reused either
    (folder / f"{b}.json").write_text((folder / f"{b}.json").read_text().replace(b, a))
    again, info = run_benchmark(spec, out=tmp_path)
    assert info["computed"] == 2
    again, info = run_benchmark(spec, out=tmp_path)
    assert info["reused"] == 2


# --- firmware projects ----------------------------------------------------------------------------------------------


def _export_argv(out: Path, compensator: str, w_q: str) -> list[str]:
    return ["export", "--firmware", "--compensator", compensator, "--w-q-hz", w_q, "--out", str(out)]


def test_firmware_export_killed_at_random_times_never_builds_a_mixed_project(tmp_path, cli_forker):
    forker = cli_forker
    variants = {"A": ("lo-dob", "10"), "B": ("ea-fob", "20")}
    ref = {}
    for tag, (comp, wq) in variants.items():
        seconds = forker.run(_export_argv(tmp_path / tag, comp, wq))["seconds"]
        names = sorted(p.name for p in (tmp_path / tag).iterdir() if p.name != MANIFEST)
        ref[tag] = _digests(tmp_path / tag, names), seconds
    assert ref["A"][0]["fd_blob.c"] != ref["B"][0]["fd_blob.c"]
    work = tmp_path / "work"
    forker.run(_export_argv(work, *variants["A"]))
    rng = random.Random(42)
    for i in range(6):
        tag = "B" if i % 2 == 0 else "A"
        forker.kill_at(_export_argv(work, *variants[tag]), rng.uniform(0.4, 1.0) * ref[tag][1])
        make = subprocess.run(["make", "-n", "-C", str(work)], capture_output=True, text=True)
        try:
            members = verify_manifest(work)
        except OutputError:
            assert make.returncode != 0 and "MANIFEST.sha256" in make.stderr   # make refuses too
            continue
        assert make.returncode == 0, make.stderr
        found = _digests(work, members)
        assert found in (ref["A"][0], ref["B"][0]), "a mixed firmware project"
    forker.run(_export_argv(work, *variants["B"]))
    assert _digests(work, verify_manifest(work)) == ref["B"][0] and _temporaries(work) == []
