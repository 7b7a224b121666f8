"""Bad input to the slope demo: one line ``error: ...`` naming the problem and the fix, exit
status 2, no traceback (unless ``--debug``), also under ``mpirun -n 2``; a gmsh model without the
required physical groups."""

from dolfinx_granular import Packing
from dolfinx_granular.packings.packing import FORMAT_NAME, FORMAT_VERSION

import numpy as np
import pytest

from helpers import assert_user_error, run_slope_demo


def demo(*args, ranks=1):
    """The slope demo's process for ``args``, not checked (it is to fail); a failing run ends at
    once, the timeout catches a rank that hangs."""
    return run_slope_demo(None, *args, ranks=ranks, timeout=300, check=False)[0]


def write_npz(path, **fields):
    with open(path, "wb") as f:
        np.savez(f, **fields)
    return str(path)


@pytest.fixture
def packings(tmp_path):
    good = Packing([[0.5, 0.5], [1.5, 1.5]], [0.4, 0.4], (3.0, 3.0))
    base = dict(
        format=np.array(FORMAT_NAME),
        version=np.array(FORMAT_VERSION),
        centers=good.centers,
        radii=good.radii,
        box=good.box,
    )
    files = {"missing": str(tmp_path / "nope.npz")}
    files["truncated"] = str(tmp_path / "truncated.npz")
    good.save(files["truncated"])
    data = open(files["truncated"], "rb").read()
    open(files["truncated"], "wb").write(data[: len(data) // 2])
    files["foreign"] = write_npz(tmp_path / "foreign.npz", weights=np.ones(3))
    files["text"] = str(tmp_path / "text.npz")
    open(files["text"], "w").write("centers,radii\n1,2\n")
    for name, r in (("negative", -0.4), ("zero", 0.0), ("nan", np.nan)):
        files[name] = write_npz(tmp_path / f"{name}.npz", **{**base, "radii": np.array([0.4, r])})
    return files


@pytest.mark.parametrize(
    "args, words",
    [
        (["--particles", "-5"], ["--particles", ">= 2", "-5"]),
        (["--particles", "0"], ["--particles", ">= 2"]),
        (["--particles", "many"], ["--particles", "integer"]),
        (["--steps", "0"], ["--steps", ">= 1"]),
        (["--load-factor", "nan"], ["--load-factor", "finite"]),
        (["--stabilise", "-1"], ["--stabilise", ">= 0"]),
        (["--bogus"], ["unrecognized arguments: --bogus", "--help"]),
        (["--line-search", "magic"], ["--line-search", "invalid choice"]),
        (["--slope-ratio", "0"], ["--slope-ratio", "> 0", "'0'"]),
        (["--slope-ratio", "steep"], ["--slope-ratio", "expected a number"]),
        (["--slope-ratio", "1.5"], ["--slope-ratio 1.5", "multiple of", "0.2", "1.4 or 1.6"]),
    ],
)
def test_invalid_options(args, words):
    assert_user_error(demo(*args), *words)


@pytest.mark.parametrize(
    "kind, words",
    [
        ("missing", ["does not exist"]),
        ("truncated", ["truncated.npz"]),
        ("foreign", ["foreign.npz"]),
        ("text", ["text.npz"]),
        ("negative", ["radii must be > 0"]),
        ("zero", ["radii must be > 0"]),
        ("nan", ["non-finite"]),
    ],
)
def test_invalid_packing_files(packings, kind, words, tmp_path):
    line = assert_user_error(
        demo("--packing", packings[kind], "--out", str(tmp_path / "o")), "--packing", *words
    )
    assert "dolfinx_granular generate" in line  # the fix


def test_unwritable_out(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert_user_error(
        demo("--out", str(blocker / "results"), "--particles", "10"),
        "--out",
        "cannot be written",
        "writable folder",
    )
    assert_user_error(demo("--out", str(blocker), "--particles", "10"), "--out")


def test_debug_shows_the_traceback(tmp_path):
    # its own --out: the default results/slope may hold a user's run, which is refused first
    proc = demo("--packing", str(tmp_path / "nope.npz"), "--out", str(tmp_path / "run"), "--debug")
    assert proc.returncode != 0 and "Traceback" in proc.stderr and "PackingFileError" in proc.stderr


@pytest.mark.slow
def test_error_on_two_ranks_is_one_line_and_no_hang(packings, tmp_path):
    assert_user_error(
        demo("--packing", packings["nan"], "--out", str(tmp_path / "o"), ranks=2),
        "--packing",
        "non-finite",
        mpirun=True,
    )
    assert_user_error(demo("--particles", "-1", ranks=2), "--particles", mpirun=True)


@pytest.mark.mpi
def test_mesh_without_physical_groups():
    pytest.importorskip("dolfinx")
    from dolfinx_granular.slope.geometry import MeshError, build_gmsh_model, model_to_mesh

    import gmsh
    from mpi4py import MPI

    comm = MPI.COMM_WORLD
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    try:
        for removed, words in (
            ([(1, 4)], ["footing (4)"]),
            ([(2, 10)], ["2-D cell group"]),
            (None, ["bottom (1)", "left (2)", "right (3)", "footing (4)"]),
        ):
            if comm.rank == 0:
                build_gmsh_model()
                if removed is None:
                    gmsh.model.removePhysicalGroups()
                else:
                    gmsh.model.removePhysicalGroups(removed)
            with pytest.raises(MeshError) as info:
                model_to_mesh(comm)
            for w in words + ["addPhysicalGroup"]:
                assert w in str(info.value)
            if comm.rank == 0:
                gmsh.model.remove()
    finally:
        gmsh.finalize()
