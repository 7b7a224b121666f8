"""Nothing lost: every converged step is on disk when a run stops, fails or is killed, and
``--resume`` continues it to the same final answer (also on another number of ranks)."""

import json
import os
import shutil
import signal
import subprocess
import time

import numpy as np
import pytest

pytest.importorskip("dolfinx")

from helpers import (  # noqa: E402
    MPI_ENV,
    ROOT,
    XDMF_FIELDS,
    read_outputs,
    run_slope_demo,
    slope_command,
)

SMALL = ["--particles", "70", "--seed", "1", "--steps", "4", "--no-figure"]


def demo(*args, ranks=1):
    """The slope demo's stdout for ``args`` (their own --out or --resume); it must succeed."""
    return run_slope_demo(None, *args, ranks=ranks)[0].stdout


def read(out):
    summary, rows = read_outputs(out)
    with open(os.path.join(out, "slope.xdmf")) as f:
        xdmf = f.read()
    return summary, rows, xdmf


def assert_same_run(a, b, rtol):
    (sa, ra, xa), (sb, rb, xb) = a, b
    assert sa["status"] == sb["status"] == "converged"
    assert sa["completed_steps"] == sb["completed_steps"]
    rel = abs(sa["footing_settlement"] - sb["footing_settlement"]) / abs(sa["footing_settlement"])
    assert rel <= rtol, (sa["footing_settlement"], sb["footing_settlement"])
    assert abs(sa["max_von_mises"] - sb["max_von_mises"]) <= rtol * sa["max_von_mises"]
    assert sa["cutbacks"] == sb["cutbacks"]
    for step in range(1, sa["completed_steps"] + 1):
        for xdmf in (xa, xb):  # each step once: u and von Mises
            assert xdmf.count(f'<Time Value="{step}"') == XDMF_FIELDS, step
    assert [s["t"] for s in sa["step_info"]] == [s["t"] for s in sb["step_info"]]
    if rtol <= 1e-12:  # same partition: the very same Newton iterations
        assert sa["iterations"] == sb["iterations"]
        assert [r["step"] for r in ra] == [r["step"] for r in rb]


@pytest.fixture(scope="module")
def uninterrupted_out(tmp_path_factory):
    """The folder of the SMALL run, straight through (tests copy it before they change it)."""
    out = tmp_path_factory.mktemp("full")
    demo(*SMALL, "--out", str(out))
    return out


@pytest.fixture(scope="module")
def uninterrupted(uninterrupted_out):
    return read(uninterrupted_out)


@pytest.mark.slow
def test_stop_and_resume_gives_the_same_answer(tmp_path, uninterrupted):
    out = str(tmp_path / "run")
    stdout = demo(*SMALL, "--out", out, "--stop-after", "2")
    assert "--resume" in stdout
    summary, rows, xdmf = read(out)
    assert summary["status"] == "stopped" and summary["completed_steps"] == 2
    assert sorted({int(r["step"]) for r in rows}) == [1, 2]
    assert xdmf.count("<Time Value") == 2 * XDMF_FIELDS
    with open(os.path.join(out, "slope.png"), "wb") as f:  # a figure of the stopped state
        f.write(b"stale")
    stdout = demo("--resume", out, "--no-figure")
    assert "resumed from" in stdout
    assert not os.path.exists(os.path.join(out, "slope.png"))  # not beside the finished run
    resumed = read(out)
    assert resumed[0]["resumed_from"] == 2 and resumed[0]["particles"] == 70
    assert_same_run(uninterrupted, resumed, 1e-12)


@pytest.fixture(scope="module")
def twelve_steps(tmp_path_factory):
    """The SMALL run with 12 footing steps, straight through: what interrupted runs resume to."""
    out = tmp_path_factory.mktemp("twelve")
    demo(*SMALL, "--out", str(out), "--steps", "12")
    return read(out)


def signal_after(out, sig, steps, ranks=1, output=subprocess.DEVNULL, total=12):
    """Start the SMALL run with ``total`` footing steps in ``out`` (under MPI for ranks > 1) and
    send ``sig`` to it (the launcher under MPI) once ``steps`` load steps are on disk; the
    process, finished."""
    proc = subprocess.Popen(
        slope_command(*SMALL, "--out", str(out), "--steps", str(total), ranks=ranks),
        cwd=ROOT,
        env=MPI_ENV,
        stdout=output,
        stderr=output,
        text=True,
    )
    try:
        deadline = time.time() + 300
        while time.time() < deadline and proc.poll() is None:
            try:
                with open(out / "summary.json") as f:
                    if json.load(f)["completed_steps"] >= steps:
                        break
            except (OSError, ValueError, KeyError):
                pass
            time.sleep(0.005)
        proc.send_signal(sig)
        proc.stdout_text, proc.stderr_text = proc.communicate(timeout=300)
    finally:
        proc.kill()
        proc.wait()
    return proc


@pytest.mark.slow
def test_ctrl_c_stops_after_a_step_and_resumes(tmp_path, twelve_steps):
    """SIGINT (Ctrl-C): the step in progress ends, the run stops with it on disk, says so in
    one line and in summary.json, exits with 130; --resume gives the uninterrupted answer."""
    out = tmp_path / "run"
    proc = signal_after(out, signal.SIGINT, 1, output=subprocess.PIPE)
    assert proc.returncode == 130, proc.stdout_text[-3000:] + proc.stderr_text[-3000:]
    assert "Traceback" not in proc.stderr_text
    summary, rows, _ = read(out)
    done = summary["completed_steps"]
    assert summary["status"] == "interrupted" and summary["interrupted_by"] == "SIGINT"
    assert 1 <= done < 13 and sorted({int(r["step"]) for r in rows})[-1] == done
    assert f"interrupted (SIGINT) after step {done}; continue with --resume {out}" in (
        proc.stdout_text
    )
    with np.load(out / "restart.npz") as f:
        assert json.loads(str(f["state"]))["step"] == done
    demo("--resume", str(out), "--no-figure")
    assert_same_run(twelve_steps, read(out), 1e-12)


@pytest.mark.slow
def test_sigterm_under_mpi_marks_the_run_interrupted_and_resumes(tmp_path):
    """SIGTERM to the MPI launcher (Open MPI's mpirun passes SIGTERM on to the ranks and kills
    them a second later, when it may no longer pass their output on; MPICH's mpiexec passes it
    on and waits): summary.json says interrupted at once, and the run resumes to the same
    answer."""
    # 48 footing steps: the signal, passed on by the launcher, lands long before the end even
    # on a loaded machine (the 12 of the other tests were once all done first)
    out, reference = tmp_path / "run", tmp_path / "reference"
    proc = signal_after(out, signal.SIGTERM, 1, ranks=2, output=subprocess.PIPE, total=48)
    log = proc.stdout_text[-3000:] + proc.stderr_text[-3000:]
    assert "Traceback" not in proc.stderr_text, log
    summary, _, _ = read(out)
    assert summary["status"] == "interrupted" and summary["interrupted_by"] == "SIGTERM", log
    assert 1 <= summary["completed_steps"] < 49
    demo("--resume", str(out), "--no-figure", ranks=2)
    demo(*SMALL, "--out", str(reference), "--steps", "48", ranks=2)
    assert_same_run(read(reference), read(out), 1e-10)


@pytest.mark.slow
def test_ctrl_c_while_the_packing_is_generated(tmp_path):
    """SIGINT before any load step (rank 0 generating 20000 disks: 11200 take 21 s, so the
    signal lands during generation even on a loaded machine, where with 5000 it once came
    after): one line, no traceback, exit status 130, nothing written."""
    out = tmp_path / "run"
    proc = subprocess.Popen(
        slope_command("--particles", "20000", "--out", str(out)),
        cwd=ROOT,
        env=MPI_ENV,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.time() + 120
        while time.time() < deadline and proc.poll() is None and not out.exists():
            time.sleep(0.005)  # the folder is made just before the packing
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == 130 and "Traceback" not in stderr, stderr[-3000:]
    assert "slope: SIGINT: stopping before the first load step; nothing is lost" in stdout
    assert list(out.iterdir()) == []


@pytest.mark.slow
def test_killed_run_keeps_its_converged_steps_and_resumes(tmp_path, twelve_steps):
    """SIGKILL once two steps are on disk: the files describe the converged steps exactly
    (summary.json and restart.npz are replaced atomically), and the run resumes from them."""
    out = tmp_path / "run"
    proc = signal_after(out, signal.SIGKILL, 2)
    summary, rows, xdmf = read(out)
    with np.load(out / "restart.npz") as f:
        state = json.loads(str(f["state"]))
        n_history = f["u_history"].shape[0]
    done = summary["completed_steps"]
    assert done >= 2 and state["step"] >= done and n_history == state["step"]
    if proc.returncode == -signal.SIGKILL:  # (a fast machine may have finished first)
        assert summary["status"] == "running"
    # written in this order each step: convergence.csv, restart.npz, summary.json
    steps = sorted({int(r["step"]) for r in rows})
    assert steps == list(range(1, len(steps) + 1)) and len(steps) >= state["step"]
    assert all(np.isfinite(float(r["residual_norm"])) for r in rows)
    for step in range(1, done + 1):
        assert xdmf.count(f'<Time Value="{step}"') == XDMF_FIELDS
    demo("--resume", str(out), "--no-figure")
    assert_same_run(twelve_steps, read(out), 1e-12)


@pytest.mark.slow
def test_resume_on_two_ranks(tmp_path, uninterrupted):
    """Stopped on one rank, resumed on two (and stopped and resumed on two): the restart file
    keys u by node coordinates, so any partition can read it."""
    out = str(tmp_path / "one_then_two")
    demo(*SMALL, "--out", out, "--stop-after", "3")
    demo("--resume", out, "--no-figure", ranks=2)
    resumed = read(out)
    assert resumed[0]["ranks"] == 2
    assert_same_run(uninterrupted, resumed, 1e-10)
    out = str(tmp_path / "two")
    demo(*SMALL, "--out", out, "--stop-after", "2", ranks=2)
    demo("--resume", out, "--no-figure", ranks=2)
    straight = str(tmp_path / "two_straight")
    demo(*SMALL, "--out", straight, ranks=2)
    # parallel MUMPS is not bitwise reproducible from run to run (nor are two straight runs):
    # a round-off-level tolerance, as in test_slope's serial/parallel comparison
    assert_same_run(read(straight), read(out), 1e-10)


def test_resume_errors(tmp_path):
    for folder, words in (
        (tmp_path / "empty", "does not exist"),
        (tmp_path / "bad", "not a usable"),
    ):
        folder.mkdir()
        if folder.name == "bad":
            (folder / "restart.npz").write_bytes(b"PK\x03\x04 truncated")
        proc, _ = run_slope_demo(None, "--resume", str(folder), timeout=300, check=False)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr
        assert proc.stderr.startswith("error: --resume") and words in proc.stderr


def test_resume_of_a_finished_run_changes_nothing(tmp_path, uninterrupted_out):
    """--resume on a run that completed every step says so and leaves its files as they are."""
    out = tmp_path / "done"
    shutil.copytree(uninterrupted_out, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    stdout = demo("--resume", str(out), "--no-figure")
    steps = int(SMALL[SMALL.index("--steps") + 1]) + 1  # gravity, then the footing's steps
    assert f"completed all {steps} load steps; nothing to resume" in stdout
    assert "t = 0" not in stdout
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
