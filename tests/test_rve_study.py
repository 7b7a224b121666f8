"""demos/rve_study.py at reduced size: files, tables, and numbers recomputed independently."""

import csv
import json
import os
import shutil

from dolfinx_granular import Packing, TaylorRVE, generate_packing
from dolfinx_granular.packings.cache import PackingCache

import numpy as np
import pytest

from helpers import is_png, load_demo


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    mod = load_demo("rve_study")
    out = tmp_path_factory.mktemp("rve_study")
    assert mod.main(["--out", str(out), "--small"]) == 0
    return mod, out


def read(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def expected_packings(cfg):
    """{n: seeds} of the packings a study configuration needs: ``seeds`` of each figure size,
    ``speed_seeds`` of each speed size, the more of the two where a size is both."""
    fig, speed = set(cfg["fig_sizes"]), set(cfg["speed_sizes"])
    return {
        n: max(cfg["seeds"] if n in fig else 0, cfg["speed_seeds"] if n in speed else 0)
        for n in sorted(fig | speed)
    }


def test_outputs_exist(study):
    mod, out = study
    # the cache holds exactly the packings of the configuration, each with its generation time
    cache = PackingCache(str(out / "packings"))
    wanted = [(n, s) for n, seeds in expected_packings(mod.SMALL).items() for s in range(seeds)]
    assert sorted(p.name for p in (out / "packings").glob("*.npz")) == sorted(
        os.path.basename(cache.path(n, s)) for n, s in wanted
    )
    assert len(cache.times) == len(wanted)
    assert all(np.isfinite(cache.generation_time(n, s)) for n, s in wanted)  # (KeyError: none)
    for name in (
        "fig2_sieve_curve.png",
        "fig3_packings_densities.png",
        "fig4_compression.png",
        "fig5_shear.png",
        "speed_error.png",
    ):
        assert is_png(out / name), name
    summary = json.loads((out / "summary.json").read_text())
    assert [row["n"] for row in summary["speed_error"]] == list(mod.SMALL["speed_sizes"])
    assert summary["seeds"] == list(range(mod.SMALL["seeds"]))
    assert summary["fig_sizes"] == list(mod.SMALL["fig_sizes"])


def test_stress_curves_are_mean_and_std_over_the_seeds(study):
    mod, out = study
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
    mod, out = study
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
    mod, out = study
    rows = read(out / "packings.csv")
    assert len(rows) == sum(expected_packings(mod.SMALL).values())
    for r in rows:
        assert float(r["volume_fraction"]) >= 0.82
        assert float(r["prestress_ratio"]) < 1e-6
        assert float(r["rattler_fraction"]) <= 0.15


def test_cache_is_reused(study, tmp_path):
    mod, out = study
    shutil.copytree(out / "packings", tmp_path / "packings")
    cache = PackingCache(str(tmp_path / "packings"))
    n = mod.SMALL["fig_sizes"][0]
    p = Packing.load(cache.path(n, 0))
    # a marked file in place of the study's: get() returns it, so it read and did not generate
    marked = Packing(p.centers, p.radii * (1 - 1e-6), p.box)
    marked.save(cache.path(n, 0))
    assert cache.get(n, 0) == marked
    assert cache.generation_time(n, 0) > 0  # recorded by the study's run, read back here


def test_cache_records_generation_times(tmp_path):
    cache = PackingCache(tmp_path)
    p = cache.get(12, 3)
    assert cache.get(12, 3) is p and cache.path(12, 3) == str(tmp_path / "n12_s3.npz")
    assert cache.generation_time(12, 3) > 0
    again = PackingCache(tmp_path)  # a later process: the file and its time are reused
    assert again.get(12, 3) == p and again.times == cache.times
    fresh = PackingCache(tmp_path, use_cache=False)  # generated anew (deterministic per seed)
    assert fresh.times == {} and fresh.get(12, 3) == p and fresh.generation_time(12, 3) > 0


def test_cache_keeps_packings_jammed_at_a_pressure_apart(tmp_path):
    cache = PackingCache(tmp_path)
    p = cache.get(12, 3, pressure=1e-3)
    assert cache.path(12, 3, 1e-3) == str(tmp_path / "n12_s3_p0.001.npz")
    assert p == generate_packing(12, seed=3, pressure=1e-3) and p != cache.get(12, 3)
    assert cache.get(12, 3, 1e-3) is p and cache.generation_time(12, 3, 1e-3) > 0
    assert PackingCache(tmp_path).get(12, 3, 1e-3) == p  # (read back in a later process)
