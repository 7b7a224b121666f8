"""The set-up's warm-up (``python -m dolfinx_granular.warmup``): after it, the slope demo, the
relaxed study and the usual API find every Numba kernel and FFCx form in the caches, and a
repeated warm-up is skipped."""

import json
import os
import subprocess
import sys

from dolfinx_granular import warmup

import pytest

from helpers import ROOT

# (in the probes: the compiled specialisations of every Numba kernel of the package)
SIGNATURES = r"""
def signatures():
    found = {}
    for name, module in list(sys.modules.items()):
        if name.startswith("dolfinx_granular"):
            for attr, obj in vars(module).items():
                if isinstance(obj, numba.core.dispatcher.Dispatcher):
                    found[f"{name}.{attr}"] = {str(s) for s in obj.signatures}
    return found
"""

# Run in a fresh interpreter with its own FFCx cache (XDG_CACHE_HOME): warm up, then the demo's
# command line (frictionless with its figure, and with friction) and a GranularMaterial on a mesh
# of the user's; report what they compiled that the warm-up had not.
PROBE = r"""
import json, sys
from pathlib import Path

import numba
import numpy as np

from dolfinx_granular import warmup

tmp = Path(sys.argv[1])
stamp = tmp / "warmup.json"
ran = [warmup.warm_up(force=True, stamp=stamp, say=print), warmup.warm_up(stamp=stamp, say=print)]


{SIGNATURES}

def ffcx_files():
    return {p.name for p in warmup._ffcx_cache_dir().glob("*.so")}


kernels, forms = signatures(), ffcx_files()
from dolfinx_granular.slope import cli

common = ["--particles", "40", "--seed", "1", "--steps", "1", "--stop-after", "1"]
assert cli.main(common + ["--out", str(tmp / "a")]) == 0
assert cli.main(common + ["--out", str(tmp / "b"), "--no-figure", "--friction", "0.3"]) == 0
new_forms = sorted(ffcx_files() - forms)

from dolfinx import fem, mesh
from mpi4py import MPI

from dolfinx_granular import GranularMaterial, TaylorRVE, generate_packing, vector_space

msh = mesh.create_unit_square(MPI.COMM_SELF, 2, 2, mesh.CellType.quadrilateral)
u = fem.Function(vector_space(msh))
material = GranularMaterial(TaylorRVE(generate_packing(40, seed=2), 2.8e7), u)
material.update()
material.update(tangent=False)
after = signatures()
new_kernels = {k: sorted(s - kernels.get(k, set())) for k, s in after.items()}
print("PROBE", json.dumps({
    "ran": ran,
    "new_kernels": {k: s for k, s in new_kernels.items() if s},
    "new_forms": new_forms,
    "compiled": sum(len(s) for s in after.values()),
}))
""".replace("{SIGNATURES}", SIGNATURES)


# In a fresh interpreter: the warm-up's material-point calls, then what the relaxed study does
# (demos/relaxed_study.py: a packing jammed at a pressure, compressed along F = lam I, moduli,
# confined shear, for both laws) and the FIRE fallback of its micro solver (where Newton stalls:
# near jamming, or on a packing that another CPU generated a little differently); the kernel
# specialisations they needed that the warm-up had not compiled.
RELAXED_PROBE = r"""
import importlib.util, json, sys

import numba
import numpy as np

from dolfinx_granular import RelaxedRVE, generate_packing, warmup
from dolfinx_granular.laws.relaxed import RelaxationError, Settings, relax
from dolfinx_granular.laws.relaxed.fire import FIRE_CHUNK, fire_chunk


{SIGNATURES}

warmup.warm_api()
kernels = signatures()
spec = importlib.util.spec_from_file_location("relaxed_study", sys.argv[1])
study = importlib.util.module_from_spec(spec)
spec.loader.exec_module(study)
packing = generate_packing(40, seed=3, pressure=1e-3)
row = study.moduli_row(packing, 3, 1e-3)
study.shear_rows(packing, 2)
relaxed = RelaxedRVE(packing, study.K_N)
settings = Settings(max_iterations=0, fire_steps=FIRE_CHUNK)
try:  # Newton given no step: FIRE takes over at once
    relax(relaxed.cell, np.diag([0.99, 0.995]), np.zeros((40, 2)), True, settings)
except RelaxationError:
    pass
new = {k: sorted(s - kernels.get(k, set())) for k, s in signatures().items()}
print("PROBE", json.dumps({
    "status": row["status"],
    "fire": len(fire_chunk.signatures),
    "new_kernels": {k: s for k, s in new.items() if s},
}))
""".replace("{SIGNATURES}", SIGNATURES)


def probe_report(code, *args, env=None):
    """Run a probe script in a fresh interpreter; its ``PROBE {json}`` line as a dict."""
    proc = subprocess.run(
        [sys.executable, "-c", code, *map(str, args)],
        env=env,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    line = next(x for x in proc.stdout.splitlines() if x.startswith("PROBE "))
    return json.loads(line[len("PROBE ") :])


def test_after_warmup_the_relaxed_study_compiles_nothing():
    report = probe_report(RELAXED_PROBE, os.path.join(ROOT, "demos", "relaxed_study.py"))
    assert report["status"] == "ok" and report["fire"] > 0  # (it did take those paths)
    assert report["new_kernels"] == {}, "specialisations the warm-up does not compile"


@pytest.mark.slow
def test_after_warmup_the_demo_and_the_api_compile_nothing(tmp_path):
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path / "cache"))
    report = probe_report(PROBE, tmp_path, env=env)
    assert report["ran"] == [True, False]  # forced, then skipped as current
    assert report["compiled"] > 0  # the probe did see the package's kernels
    assert report["new_kernels"] == {}, "specialisations the warm-up does not compile"
    assert report["new_forms"] == [], "forms the warm-up does not compile"


def test_the_record_is_current_until_a_source_changes(tmp_path):
    stamp = tmp_path / "warmup.json"
    assert not warmup.is_current(stamp)  # no warm-up recorded yet
    stamp.write_text(json.dumps(warmup.fingerprint()))
    assert warmup.is_current(stamp)
    record = json.loads(stamp.read_text())
    source = sorted(record["sources"])[0]
    record["sources"][source][0] -= 1  # an older modification time of one source
    stamp.write_text(json.dumps(record))
    assert not warmup.is_current(stamp)


def test_the_record_covers_every_kernel_module_and_the_caches():
    record = warmup.fingerprint()
    for source in (
        "laws/taylor_kernel.py",
        "laws/friction_kernel.py",
        "packings/generation.py",
        "warmup.py",
    ):
        assert source in record["sources"]
    assert record["python"] == sys.executable
    assert record["numba_cache_dir"] == os.getenv("NUMBA_CACHE_DIR", "")
    assert warmup.stamp_path().name == f"warmup.{sys.implementation.cache_tag}.json"


def test_a_bad_option_is_refused_in_one_line():
    proc = subprocess.run(
        [sys.executable, "-m", "dolfinx_granular.warmup", "--bogus"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert "unrecognized arguments: --bogus" in proc.stderr


def test_the_first_run_section_is_a_marked_table_of_runs_and_phases():
    import first_run
    from sections import marked_sections

    run = {"setup_s": 2.5, "total_s": 9.0}
    rows = [
        {"stack": "S", "warm_up": False, "load_before": 1.0, "load_after": 2.0, "first": run},
        {"stack": "S", "warm_up": True, "load_before": 1.0, "load_after": 2.0, "first": run},
    ]
    for r, warmup_s in zip(rows, (None, [30.0, 0.5])):
        r["second"] = run
        if warmup_s:
            r["warmup_s"] = warmup_s
    found = [{"stack": "S", "empty": {"a": 3.0, "b": 1.5}, "filled": {"a": 1.0, "b": 0.5}}]
    text = first_run.markdown(rows, found, 700, "python benchmarks/first_run.py", 1.0)
    assert marked_sections(text) == [text.strip()]
    assert text.splitlines()[1] == "## 8. The first run after set-up"
    assert "| S | none | 2.5 / 9.0 | 2.5 / 9.0 | 1.0 .. 2.0 |" in text
    assert "| S | 30.0/0.5 | 2.5 / 9.0 | 2.5 / 9.0 | 1.0 .. 2.0 |" in text
    assert "| a | 3.0 / 1.0 |" in text
    assert "| sum | 4.5 / 1.5 |" in text  # the set-up's phases add up


def test_changed_sources_are_told_from_the_record(tmp_path):
    stamp = tmp_path / "warmup.json"
    assert not warmup.sources_changed(stamp)  # no record: nothing to clear
    record = warmup.fingerprint()
    stamp.write_text(json.dumps(record))
    assert not warmup.sources_changed(stamp)
    record["sources"]["warmup.py"][1] += 1  # another size of one source
    stamp.write_text(json.dumps(record))
    assert warmup.sources_changed(stamp)


CACHED = """
import json
from dolfinx_granular import warmup
from dolfinx_granular.laws.relaxed_friction.rolling import stiffness
stiffness(1.0, 2.0, 3.0)  # (compiled, and cached under $NUMBA_CACHE_DIR)
before = [str(p) for p in warmup.numba_cache_files()]
removed = warmup.clear_numba_cache()
print(json.dumps(dict(before=before, removed=removed, after=len(warmup.numba_cache_files()))))
"""


def test_the_numba_cache_files_are_found_and_cleared(tmp_path):
    """A kernel compiled with $NUMBA_CACHE_DIR set lands where numba_cache_files looks, and
    clear_numba_cache removes it (the warm-up does so where the sources changed: a cached
    caller keeps its callees as they were compiled)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    proc = subprocess.run([sys.executable, "-c", CACHED], env=env, capture_output=True,
                          text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert any("rolling.stiffness" in p for p in report["before"])
    assert all(p.startswith(str(tmp_path)) for p in report["before"])  # (not the checkout's)
    assert report["removed"] == len(report["before"]) and report["after"] == 0
