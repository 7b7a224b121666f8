"""Command line ``python -m dolfinx_granular generate``: output file, one-line errors, --debug."""

import os
import subprocess
import sys

from dolfinx_granular import Packing, generate_packing
from dolfinx_granular.__main__ import main

import numpy as np
import pytest

from helpers import ROOT


def run_module(*args, cwd):
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run(
        [sys.executable, "-m", "dolfinx_granular", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_generate_writes_the_packing_of_generate_packing(tmp_path):
    res = run_module("generate", "70", "--seed", "3", "-o", "packing.npz", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert "volume fraction" in res.stdout
    p = Packing.load(tmp_path / "packing.npz")
    assert p == generate_packing(70, seed=3)


def test_user_errors_are_one_line_exit_2(tmp_path):
    res = run_module("generate", "1", "-o", "p.npz", cwd=tmp_path)
    assert res.returncode == 2
    assert res.stderr.strip().startswith("error: n_particles")
    assert len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr
    assert not (tmp_path / "p.npz").exists()


def test_debug_shows_the_traceback(tmp_path):
    res = run_module("--debug", "generate", "1", cwd=tmp_path)
    assert res.returncode != 0 and "Traceback" in res.stderr and "ValueError" in res.stderr


@pytest.mark.parametrize(
    "argv, message",
    [
        (["generate", "many"], "expected an integer"),
        (["generate"], "required"),
        (["generate", "70", "--bogus"], "unrecognized"),
        (["frobnicate"], "invalid choice"),
        (["generate", "70", "-o", "packing.txt"], ".npz"),
        (["generate", "70", "--d-min", "abc"], "size in mm"),
        (["generate", "70", "--d-min", "5"], "d_min"),
        (["generate", "70", "--aspect", "0"], "aspect"),
        (["generate", "70", "--sieve-curve", "missing.csv"], "missing.csv"),
        (["generate", "70", "--sieve-curve", "bad.csv"], "must not decrease"),
        (["generate", "70", "-o", "no/such/dir/p.npz"], "no/such/dir"),
    ],
)
def test_bad_arguments(tmp_path, monkeypatch, capsys, argv, message):
    (tmp_path / "bad.csv").write_text("aperture,passing\n0.3,40\n0.6,20\n1.2,100\n")
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and len(err.splitlines()) == 1
    assert message in err


def test_user_sieve_curve_and_options(tmp_path, monkeypatch, capsys):
    (tmp_path / "sand.csv").write_text("# test sand\naperture,passing\n0.3,0\n0.6,50\n1.18,100\n")
    monkeypatch.chdir(tmp_path)
    assert (
        main(
            [
                "generate",
                "80",
                "--seed",
                "2",
                "--sieve-curve",
                "sand.csv",
                "--aspect",
                "1.5",
                "-o",
                "s.npz",
                "--quiet",
            ]
        )
        == 0
    )
    p = Packing.load(tmp_path / "s.npz")
    assert p == generate_packing(
        80, ([0.3, 0.6, 1.18], [0, 50, 100]), seed=2, d_min=None, aspect=1.5
    )
    assert np.isclose(p.box[1] / p.box[0], 1.5)
    assert "wrote s.npz" in capsys.readouterr().out


def test_no_command_prints_help(capsys):
    assert main([]) == 2
    assert "generate" in capsys.readouterr().err


def test_existing_output_is_kept_unless_forced(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    generate_packing(20, seed=1).save("packing.npz")
    before = (tmp_path / "packing.npz").read_bytes()
    assert main(["generate", "30", "--quiet"]) == 2  # the default name exists already
    err = capsys.readouterr().err
    assert "'packing.npz' exists" in err and "--force" in err
    assert (tmp_path / "packing.npz").read_bytes() == before
    assert main(["generate", "30", "--quiet", "--force"]) == 0
    assert Packing.load(tmp_path / "packing.npz").n_particles == 30


def test_progress_prints_every_stage_event_and_spaces_the_heartbeats(tmp_path, monkeypatch, capsys):
    from dolfinx_granular import __main__ as cli
    from dolfinx_granular.packings import generation

    lines = []
    generate_packing(350, seed=1, progress=lines.append)
    expected = [line.strip() for line in lines if not line.heartbeat]
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(generation, "PROGRESS_INTERVAL", 0.0)  # a heartbeat after every chunk
    monkeypatch.setattr(cli, "PROGRESS_AFTER", 0.0)  # a fast run prints too
    monkeypatch.setattr(cli, "PROGRESS_EVERY", 3600.0)
    assert main(["generate", "350", "--seed", "1"]) == 0
    printed = [line.split("] ", 1)[1] for line in capsys.readouterr().err.splitlines()]
    running = ("jamming:", "stress-free", "checking the contact network")  # heartbeats
    events = [line for line in printed if not line.startswith(running)]

    def text(line):  # without the elapsed time and the percentage, which differ between runs
        return line.split(" [")[0].split(" (")[0]

    # every minimisation's result, the jammed state and the end, in order
    assert [text(line) for line in events] == [text(line) for line in expected]
    assert sum("FIRE steps" in line for line in events) >= 3
    assert len(printed) - len(events) == 1  # the first heartbeat; the next within PROGRESS_EVERY


def test_help_is_plain_text_and_names_the_default_file(capsys):
    for argv in (["--help"], ["generate", "--help"]):
        with pytest.raises(SystemExit):
            main(argv)
        out = capsys.readouterr().out
        assert "``" not in out and ":func:" not in out, out
    assert "default packing.npz" in " ".join(out.split())


def test_relax_command_makes_a_packing_stress_free(tmp_path, monkeypatch, capsys):
    import warnings

    from dolfinx_granular import TaylorRVE

    monkeypatch.chdir(tmp_path)
    p = generate_packing(40, seed=2)
    Packing(p.centers, 1.02 * p.radii, p.box).save("swollen.npz")
    assert main(["relax", "swollen.npz", "-o", "relaxed.npz"]) == 0
    assert "|P(I)| / |C| = " in capsys.readouterr().out
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert TaylorRVE(Packing.load("relaxed.npz"), 2.8e7).prestress_ratio < 1e-9
    assert main(["relax", "swollen.npz", "-o", "relaxed.npz"]) == 2  # kept unless --force


@pytest.mark.parametrize(
    "argv, message",
    [
        (["generate", "1"], "n_particles must be an integer >= 2"),
        (["generate", "70", "--d-min", "5"], "d_min = 5.0 mm cuts off"),
        (["generate", "70", "--aspect", "0"], "aspect"),
        (["generate", "70", "--seed", "-1"], "seed must be an integer >= 0"),
    ],
)
def test_bad_arguments_are_named_before_an_existing_output_file(
    tmp_path, monkeypatch, capsys, argv, message
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "existing.npz").write_bytes(b"kept")
    assert main([*argv, "-o", "existing.npz"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and len(err.splitlines()) == 1
    assert message in err and "exists" not in err
    assert (tmp_path / "existing.npz").read_bytes() == b"kept"


def test_relax_command_relaxes_radii_swollen_by_a_fifth(tmp_path):
    """The issue's reproduction: radii x 1.2 (beyond TaylorRVE's overlap limit); some disks
    cross the cell boundary on the way, and the reported moves are the nearest-image ones."""
    import re
    import warnings

    from dolfinx_granular import TaylorRVE

    p = generate_packing(70, seed=4)
    Packing(p.centers, 1.2 * p.radii, p.box).save(tmp_path / "in.npz")
    res = run_module("relax", "in.npz", "-o", "out.npz", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    moved = float(re.search(r"centres moved up to ([0-9.e+-]+) %", res.stdout).group(1))
    assert 0 < moved < 100  # % of the mean radius
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert TaylorRVE(Packing.load(tmp_path / "out.npz"), 2.8e7).prestress_ratio < 1e-9


def test_relax_command_errors_are_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    Packing([[0.2, 0.2], [0.2, 0.2], [0.6, 0.6]], [0.2, 0.2, 0.2], [1, 1]).save("same.npz")
    for argv, message in [
        (["relax", "missing.npz", "-o", "out.npz"], "does not exist"),
        (["relax", "same.npz", "-o", "out.npz"], "same centre"),
    ]:
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("error: ") and len(err.splitlines()) == 1 and message in err
