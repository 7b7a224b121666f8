"""A signal's last words land at once, whatever the process is doing: the C-level handler of
:mod:`dolfinx_granular.slope.interrupt_native` writes the prepared line and file while the process
is inside a compiled kernel (where a Python handler would wait for it to return), and a second
signal ends the process; a run with no converged step is run again without ``--force``."""

import json
import os
import select
import signal
import subprocess
import sys
import time

from dolfinx_granular.io.runwriter import RestartError
from dolfinx_granular.slope.cli import UserError, _claim_out
from dolfinx_granular.slope.run import converged_steps, load_restart

import pytest

CHILD = """
import sys
import numba
from dolfinx_granular.slope.interrupt import StopRequest

@numba.njit
def spin(n):  # a compiled call of minutes: no Python bytecode runs until it returns
    s = 0.0
    for i in range(n):
        s += (i % 7) * 1e-9
    return s

spin(10)
stop = StopRequest()
with stop.installed():
    stop.announce({2: "stopping on SIGINT", 15: "stopping on SIGTERM"})
    stop.keep(sys.argv[1], {2: '{"by": "SIGINT"}', 15: '{"by": "SIGTERM"}'})
    print("ready", flush=True)
    spin(10**12)
"""


def read_line(proc, timeout):
    """The child's next stdout line within ``timeout`` seconds ('' if none came)."""
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    return proc.stdout.readline().strip() if ready else ""


@pytest.fixture
def spinning(tmp_path):
    """A child inside a long compiled call with its signal handlers installed; (proc, file)."""
    target = tmp_path / "summary.json"
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(target)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert read_line(proc, 120) == "ready"
        yield proc, target
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_inside_a_compiled_call_writes_at_once(spinning, sig):
    proc, target = spinning
    proc.send_signal(sig)
    assert read_line(proc, 10) == f"stopping on {sig.name}"
    deadline = time.time() + 10
    while not target.exists() and time.time() < deadline:
        time.sleep(0.01)
    assert json.loads(target.read_text()) == {"by": sig.name}
    assert proc.poll() is None  # still inside the compiled call: the C handler wrote it
    assert [p.name for p in target.parent.iterdir()] == ["summary.json"]  # no temporary left
    proc.send_signal(sig)  # the second: at once, 128 + its number
    assert proc.wait(timeout=10) == 128 + sig


def test_handlers_are_restored_after_the_run():
    before = [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)]
    code = (
        "import signal\nfrom dolfinx_granular.slope.interrupt import StopRequest\n"
        "with StopRequest().installed():\n    pass\n"
        "signal.raise_signal(signal.SIGINT)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert "KeyboardInterrupt" in proc.stderr  # Python's default SIGINT handler again
    assert [signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)] == before


def write_run(folder, completed, restart):
    folder.mkdir()
    (folder / "slope.xdmf").write_text("<Xdmf/>")
    (folder / "summary.json").write_text(json.dumps({"completed_steps": completed}))
    if restart:
        (folder / "restart.npz").write_bytes(b"...")
    (folder / "notes.txt").write_text("the user's own file")


def test_a_run_with_no_converged_step_is_run_again_without_force(tmp_path):
    out = tmp_path / "run"
    write_run(out, 0, restart=False)
    assert converged_steps(out) == 0
    with pytest.raises(RestartError, match="nothing to resume; run the same command again"):
        load_restart(out)
    _claim_out(str(out), force=False)
    assert sorted(os.listdir(out)) == ["notes.txt"]


@pytest.mark.parametrize("completed,restart", [(2, False), (0, True), (3, True)])
def test_a_run_with_converged_steps_is_kept(tmp_path, completed, restart):
    out = tmp_path / "run"
    write_run(out, completed, restart)
    assert converged_steps(out) >= 1
    with pytest.raises(UserError, match="holds a slope run"):
        _claim_out(str(out), force=False)
    assert (out / "summary.json").exists() and (out / "slope.xdmf").exists()
