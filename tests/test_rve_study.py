"""demos/rve_study.py at reduced size: files, tables, and numbers recomputed independently."""

import csv
import json
import shutil
import time

from dolfinx_granular import Packing, TaylorRVE
from dolfinx_granular.cache import PackingCache

import numpy as np
import pytest

from helpers import load_demo


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    mod = load_demo("rve_study")
    out = tmp_path_factory.mktemp("rve_study")
    t0 = time.perf_counter()
    assert mod.main(["--out", str(out), "--small"]) == 0
    return mod, out, time.perf_counter() - t0


def read(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_outputs_exist(study):
    mod, out, runtime = study
    assert runtime > 0
    for name in (
        "fig2_sieve_curve.png",
        "fig3_packings_densities.png",
        "fig4_compression.png",
        "fig5_shear.png",
        "speed_error.png",
    ):
        with open(out / name, "rb") as f:
            assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    summary = json.loads((out / "summary.json").read_text())
    assert [row["n"] for row in summary["speed_error"]] == list(mod.SMALL["speed_sizes"])


def test_stress_curves_are_mean_and_std_over_the_seeds(study):
    mod, out, _ = study
    rows = read(out / "stress_curves.csv")
    steps = mod.SMALL["steps"]
    assert {r["path"] for r in rows} == set(mod.PATHS)
    assert len(rows) == len(mod.PATHS) * len(mod.SMALL["fig_sizes"]) * (steps + 1)
    assert max(float(r["strain"]) for r in rows) >= 0.10
    # recompute one point from the cached packings, independently of the demo's code path
    n = mod.SMALL["fig_sizes"][0]
    packings = [
        Packing.load(out / "packings" / f"n{n}_s{s}.npz") for s in range(mod.SMALL["seeds"])
    ]
    F = np.array([[1.0, 0.0], [0.05, 1.0]])
    sig = np.array([TaylorRVE(p, mod.K_N).cauchy(F) for p in packings])
    row = next(
        r
        for r in rows
        if r["path"] == "shear_21"
        and r["n"] == str(n)
        and float(r["strain"]) == pytest.approx(0.05)
    )
    for key, (a, b) in (("sigma11", (0, 0)), ("sigma22", (1, 1)), ("sigma12", (0, 1))):
        assert float(row[f"{key}_mean_Pa"]) == pytest.approx(sig[:, a, b].mean(), rel=1e-6)
        assert float(row[f"{key}_std_Pa"]) == pytest.approx(
            sig[:, a, b].std(ddof=1), rel=1e-6, abs=1e-3
        )
    # compression loads the compressed direction hardest; unloaded reference is stress-free
    c11 = [r for r in rows if r["path"] == "compression_11" and r["n"] == str(n)]
    s11 = [float(r["sigma11_mean_Pa"]) for r in c11]
    s22 = [float(r["sigma22_mean_Pa"]) for r in c11]
    assert abs(s11[0]) < 1e-6 * abs(s11[-1])
    assert all(np.diff(s11) < 0) and s11[-1] < s22[-1] < 0


def test_speed_error_table(study):
    mod, out, _ = study
    rows = read(out / "speed_error.csv")
    assert [int(r["n"]) for r in rows] == list(mod.SMALL["speed_sizes"])
    for r in rows:
        n = int(r["n"])
        packings = [
            Packing.load(out / "packings" / f"n{n}_s{s}.npz")
            for s in range(mod.SMALL["speed_seeds"])
        ]
        assert int(r["seeds"]) == len(packings)
        sc = np.array([TaylorRVE(p, mod.K_N).cauchy(np.diag([0.95, 1.0]))[0, 0] for p in packings])
        cv = sc.std(ddof=1) / abs(sc.mean())
        assert float(r["cv_compression"]) == pytest.approx(cv, rel=1e-5)
        assert float(r["time_per_point"]) > 0
        assert float(r["cv_shear"]) > 0


def test_packing_table(study):
    mod, out, _ = study
    rows = read(out / "packings.csv")
    sizes = set(mod.SMALL["fig_sizes"]) | set(mod.SMALL["speed_sizes"])
    assert len(rows) == len(sizes) * mod.SMALL["speed_seeds"]
    for r in rows:
        assert float(r["volume_fraction"]) >= 0.82
        assert float(r["prestress_ratio"]) < 1e-6
        assert float(r["rattler_fraction"]) <= 0.15


def test_cache_is_reused(study, tmp_path):
    mod, out, _ = study
    shutil.copytree(out / "packings", tmp_path / "packings")
    p = Packing.load(tmp_path / "packings" / "n70_s0.npz")
    # a marked file in place of the study's: get() returns it, so it read and did not generate
    marked = Packing(p.centers, p.radii * (1 - 1e-6), p.box)
    marked.save(tmp_path / "packings" / "n70_s0.npz")
    cache = PackingCache(str(tmp_path / "packings"))
    assert cache.get(70, 0) == marked
    assert cache.generation_time(70, 0) > 0  # recorded by the study's run, read back here


def test_cache_records_generation_times(tmp_path):
    cache = PackingCache(tmp_path)
    p = cache.get(12, 3)
    assert cache.get(12, 3) is p and cache.path(12, 3) == str(tmp_path / "n12_s3.npz")
    assert cache.generation_time(12, 3) > 0
    again = PackingCache(tmp_path)  # a later process: the file and its time are reused
    assert again.get(12, 3) == p and again.times == cache.times
    fresh = PackingCache(tmp_path, use_cache=False)  # generated anew (deterministic per seed)
    assert fresh.times == {} and fresh.get(12, 3) == p and fresh.generation_time(12, 3) > 0
