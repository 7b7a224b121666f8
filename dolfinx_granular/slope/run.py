"""The slope benchmark's load path: gravity, then the footing in steps, every step on disk.

:class:`SlopeRun` drives a :class:`~dolfinx_granular.slope.model.SlopeModel` through its load
phases with a :class:`~dolfinx_granular.LoadStepper` (cut-backs, limit loads), records
every converged step (Newton history, settlement, diagnostics) and writes through a
:class:`~dolfinx_granular.RunWriter` after each of them: ``slope.xdmf`` (+ ``.h5``:
displacement and cell-mean von Mises per step, appended), ``convergence.csv``, ``summary.json``
and ``restart.npz``, so that a killed run loses nothing and :func:`load_restart` continues it on
any number of ranks with the same answer.

``convergence.csv`` has one row per Newton iterate of every converged step: the residual norm
there, the relative energy norm of the Newton step that led to it (table 2 of the paper), and, on
the last row of each step, the test that ended it (``energy norm``, ``round-off``).
"""

from __future__ import annotations

import json
import os
import time
from typing import TYPE_CHECKING, Any

import numpy as np
from mpi4py import MPI

from ..drivers.loading import Cutback, LoadStepper
from ..drivers.protocol import ASKED_TO_STOP, failure
from ..fem import compat as dfx
from ..fem.fields import cauchy_output
from ..io.postprocess import cell_function, gather_mesh
from ..io.runwriter import NodeOrder, PointOrder, RestartError, RunWriter, read_npz
from ..laws.validity import OVERLAP_THRESHOLD, OverlapMonitor
from ..packings.packing import Packing
from .geometry import SlopeGeometry as SlopeGeometry  # (found here too, as before)
from .interrupt import SIGNALS, signal_name
from .model import SlopeModel, granular_material, newton_solver
from .options import K_N as K_N
from .options import PHASES as PHASES
from .options import SlopeOptions
from .path import last_increment, load_path, path_failure, path_summary
from .summary import draw_figure, draw_load_settlement, report_stop, summarise

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping

    from dolfinx.fem import Function

    from ..drivers.newton import NewtonSolver
    from ..drivers.protocol import Driver, IncrementRecord
    from ..fem.quadrature import QuadratureMaterial
    from .interrupt import StopRequest


RESTART_FORMAT = "dolfinx_granular.slope_restart"
CONVERGENCE_HEADER = ["step", "iterate", "residual_norm", "energy_norm_rel", "converged_by"]
#: every file a slope run writes in its folder (``--force`` removes these, and nothing else)
RUN_FILES = (
    "summary.json",
    "restart.npz",
    "convergence.csv",
    "slope.xdmf",
    "slope.h5",
    "slope.png",
    "load_settlement.png",
)
#: the figures, drawn at the end of a run (stale once a run continues)
FIGURES = ("slope.png", "load_settlement.png")


def convergence_rows(
    step: int, result: IncrementRecord
) -> list[tuple[int, int, float, float | str, str]]:
    """The convergence.csv rows of one converged increment (an
    :class:`~dolfinx_granular.drivers.protocol.IncrementRecord`, or a converged
    :class:`~dolfinx_granular.SolveResult`), one per Newton iterate."""
    h = result.history
    residuals = [r for _, r, _ in h] + [result.residual_norm]
    energies = [""] + [e for _, _, e in h]
    last = len(residuals) - 1
    return [
        (
            step,
            i,
            float(residuals[i]),
            energies[i],  # "" on the first row: no Newton step led to the start
            result.converged_by if i == last else "",
        )
        for i in range(len(residuals))
    ]


def run_files(folder: str | os.PathLike[str]) -> list[str]:
    """The names of the files in ``folder`` that a slope run writes (:data:`RUN_FILES`, and the
    temporary files of an atomic write that a killed run left), sorted; [] if there is none."""
    try:
        names = os.listdir(folder)
    except (FileNotFoundError, NotADirectoryError):
        return []
    return sorted(
        n for n in names if n in RUN_FILES or any(n.startswith(f + ".tmp") for f in RUN_FILES)
    )


def converged_steps(folder: str | os.PathLike[str]) -> int:
    """The load steps that the run in ``folder`` has on disk: 0 if it has no restart file and
    its ``summary.json`` (if any) counts none; 1 where the count cannot be read."""
    if os.path.exists(os.path.join(folder, "restart.npz")):
        return max(1, _summary_steps(folder))
    return _summary_steps(folder)


def _summary_steps(folder):
    try:
        with open(os.path.join(folder, "summary.json")) as f:
            return int(json.load(f).get("completed_steps") or 0)
    except FileNotFoundError:
        return 0
    except (OSError, ValueError, TypeError, AttributeError):
        return 1  # (a summary that cannot be read: keep the run)


def clear_run(folder: str | os.PathLike[str], names: tuple[str, ...] | None = None) -> None:
    """Remove the files of a slope run from ``folder`` (only ``names`` among them if given); the
    folder's other files stay."""
    for name in run_files(folder):
        if names is None or name in names:
            os.remove(os.path.join(folder, name))


def load_restart(folder: str | os.PathLike[str]) -> dict:
    """``folder/restart.npz`` as a dict: ``options`` (SlopeOptions), ``state`` (dict),
    ``packing``, ``nodes`` (n, 2), ``u_history`` (steps, n, 2), ``path``; raises
    :class:`~dolfinx_granular.io.runwriter.RestartError` if unusable."""
    path = os.path.join(folder, "restart.npz")
    if not os.path.exists(path) and run_files(folder) and not converged_steps(folder):
        raise RestartError(
            f"{folder} holds a run that stopped before its first load step converged: nothing "
            "to resume; run the same command again without --resume (no --force needed)"
        )
    f = read_npz(path, RESTART_FORMAT)
    try:
        return {
            "options": SlopeOptions.from_dict(json.loads(str(f["options"]))),
            "state": json.loads(str(f["state"])),
            "packing": Packing(f["centers"], f["radii"], f["box"]),
            "nodes": f["nodes"],
            "u_history": f["u_history"],
            "path": path,
            "history": {k[len("history_") :]: v for k, v in f.items() if k.startswith("history_")},
        }
    except Exception as err:  # JSON or packing errors
        raise RestartError(
            f"{path!r} is not a usable restart file ({err}); start the run again without resuming"
        ) from err


class SlopeRun:
    """One run of the slope benchmark, written to ``out``.

    Args:
        packing: the RVE microstructure (the same on every rank).
        options: :class:`SlopeOptions`.
        out: output folder.
        comm: MPI communicator.
        verbose: progress lines on rank 0 (and one line per Newton step).
        restart: the dict of :func:`load_restart` to continue from (its options are used).
        stop_after: stop after this many converged load steps (all phases).
        started: ``time.perf_counter()`` when the run began (``wall_time``), default now.
        law_factory: ``law_factory(packing, normal_stiffness)`` -> the material-point law
            (default: :meth:`SlopeOptions.law`).
        material_factory, solver_factory: see :class:`~dolfinx_granular.slope.model.SlopeModel`.
        stop_request: a :class:`~dolfinx_granular.slope.interrupt.StopRequest` whose signals
            stop the run after the load step in progress (on every rank alike), or None.

    Attributes:
        interrupted: the signal that stopped the run (0: none).
        step: converged load steps so far (all phases, load control and path following).
        failed: None, or the :func:`~dolfinx_granular.drivers.protocol.failure` dict of the
            phase that failed (its ``t`` that of the phase: lam / load_factor on the path).
        stopped: None, or :data:`~dolfinx_granular.drivers.protocol.ASKED_TO_STOP` (``stop_after``,
            a signal).
        arclength: the :class:`~dolfinx_granular.ArcLength` of path following, or None.
    """

    def __init__(
        self,
        packing: Packing,
        options: SlopeOptions | None = None,
        out: str | os.PathLike[str] = "results/slope",
        comm: MPI.Comm = MPI.COMM_WORLD,
        verbose: bool = True,
        restart: dict | None = None,
        stop_after: int | None = None,
        started: float | None = None,
        law_factory: Callable[[Packing, float], Any] | None = None,
        material_factory: Callable[[Any, Function], QuadratureMaterial] | None = None,
        solver_factory: Callable[..., NewtonSolver] | None = None,
        stop_request: StopRequest | None = None,
    ) -> None:
        self.t_start = time.perf_counter() if started is None else started
        self.options = o = restart["options"] if restart else (options or SlopeOptions())
        self.packing, self.comm, self.stop_after = packing, comm, stop_after
        self.verbose = verbose and comm.rank == 0
        self.stop_request, self.interrupted = stop_request, 0
        self._step_summary = None  # (summary.json while the run goes on: _write_summary)
        self.say = (
            (lambda *a: print(*a, flush=True))
            if (verbose and comm.rank == 0)
            else (lambda *a: None)
        )
        material_factory = material_factory or (
            lambda law, u: granular_material(law, u, stabilise=o.stabilise)
        )
        solver_factory = solver_factory or (
            lambda *a: newton_solver(
                *a,
                petsc_options=o.petsc_options,
                verbose=verbose,
                linear_solver=o.linear_solver,
                stall_rtol=o.residual_tolerance,
            )
        )
        self.law = law_factory(packing, o.normal_stiffness) if law_factory else o.law(packing)
        self.model = SlopeModel(
            comm,
            self.law,
            o.geometry,
            o.load_factor,
            material_factory,
            solver_factory,
            confined=o.confinement > 0.0,
        )
        self.writer = RunWriter(out, comm)
        if restart is not None and comm.rank == 0:
            clear_run(out, FIGURES)  # the figures of the stored part: drawn anew at the end
        self.nodes = NodeOrder(comm, self.model.V, tolerance=1e-9 * o.geometry.width)
        # the history of a law with it (frictional contacts) travels with the restart, keyed by
        # the quadrature points' coordinates
        self.points = (
            PointOrder(comm, self.model.material.points, 1e-9 * o.geometry.width)
            if self.model.material.has_state
            else None
        )
        self.stepper = LoadStepper(  # (warn=False: the run reports a failure in its log)
            self.model.solver,
            max_cutbacks=o.max_cutbacks,
            log=lambda line: self.say("  " + line),
            warn=False,
        )
        self.rows, self.iterations, self.step_info, self.u_history = [], [], [], []
        self.step, self.failed, self.stopped = 0, None, None
        self.arclength = None  # the path of path_following
        # one ValidityWarning per run, when contact overlaps first pass the threshold
        self.validity = OverlapMonitor()
        self.restart = restart  # the stored run continued here (load_restart), or None
        self.resumed_from, self.time_output = None, 0.0
        self._V0 = dfx.function_space(self.model.mesh, "DG", 0)
        self._start = (0, 0.0, None)  # phase, t, dt
        self._begin_xdmf()
        if restart is not None:
            self._resume(restart)
        if stop_request is not None:
            stop_request.reinstall()  # (meshing with gmsh may have reset the handlers)
        self._step_summary = self._progress({"cutbacks": [], "step": self.step})
        self._write_summary()  # ("running": a run with no converged step is on disk too)
        self.setup_time = time.perf_counter() - self.t_start

    @property
    def n_nominal(self) -> int:
        """Nominal load steps: the gravity steps, the footing steps and as many to unload."""
        o = self.options
        if o.path_following == "gravity":
            return o.max_increments
        if o.path_following:
            return o.gravity_steps + o.max_increments
        if o.reduction is not None:
            return o.gravity_steps + o.steps * (len(o.phases) - 2) + o.reduction_steps
        return o.gravity_steps + o.steps * (len(o.phases) - 1)

    # -- output ----------------------------------------------------------------------------------

    def _begin_xdmf(self):
        from dolfinx import io

        with io.XDMFFile(self.comm, self.writer.path("slope.xdmf"), "w") as xdmf:
            xdmf.write_mesh(self.model.mesh)
        self._repair_xdmf()

    def _append_xdmf(self, step):
        """Append u, the cell-mean von Mises and Cauchy stresses (file closed per step: complete
        on disk)."""
        from dolfinx import io

        m = self.model
        vm = cell_function(self._V0, m.material.cell_average(m.von_mises()))
        vm.name = "von_mises"
        cauchy = cauchy_output(m.material)  # cell means of the Cauchy stress (Pa)
        with io.XDMFFile(self.comm, self.writer.path("slope.xdmf"), "a") as xdmf:
            xdmf.write_function(m.u, float(step))
            xdmf.write_function(vm, float(step))
            xdmf.write_function(cauchy, float(step))
        self._repair_xdmf()

    def _repair_xdmf(self):
        if self.comm.rank == 0:
            dfx.repair_xdmf(self.writer.path("slope.xdmf"))
        self.comm.barrier()  # (the next append reads the file on every rank)

    def _state(self, phase_index, step, t):
        return {
            "step": step,
            "phase": phase_index,
            "t": t,
            "dt": self.stepper.dt,
            "iterations": self.iterations,
            "step_info": self.step_info,
            "rows": self.rows,
            "cutbacks": [c.as_dict() for c in self.stepper.cutbacks],
            "path": self.stepper.path,
            "arclength": self.arclength.state() if self.arclength is not None else None,
        }

    def _write_step(self, phase_index, step, t):
        """Everything of a converged step on disk (XDMF appended, the rest replaced)."""
        t_out = time.perf_counter()
        self._append_xdmf(step)
        values = self.nodes.gather_function(self.model.u)
        if self.comm.rank == 0:
            self.u_history.append(values)
        state = self._state(phase_index, step, t)
        history = {}
        if self.points is not None:
            gathered = self.points.gather_material(self.model.material)
            if self.comm.rank == 0:
                history = {f"history_{k}": v for k, v in gathered.to_arrays().items()}
                history["history_points"] = self.points.X
        self.writer.csv("convergence.csv", CONVERGENCE_HEADER, self.rows)
        self.writer.npz(
            "restart.npz",
            format=np.array(RESTART_FORMAT),
            version=np.array(2),
            options=np.array(json.dumps(self.options.as_dict())),
            state=np.array(json.dumps(state)),
            centers=self.packing.centers,
            radii=self.packing.radii,
            box=self.packing.box,
            nodes=self.nodes.X,
            u_history=np.asarray(self.u_history),
            **history,
        )
        self._step_summary = self._progress(state)
        self._write_summary()
        self.time_output += time.perf_counter() - t_out

    def _progress(self, state):
        """summary.json's fields while the run goes on (rank 0; None elsewhere)."""
        if self.comm.rank != 0:
            return None
        return {
            "ranks": self.comm.size,
            "steps": self.n_nominal,
            "completed_steps": state["step"],
            "resumed_from": self.resumed_from,
            "cutbacks": state["cutbacks"],
            "iterations": list(self.iterations),
            "footing_settlement": self.step_info[-1]["settlement"] if self.step_info else None,
            "load_factor": self.options.load_factor,
            "slope_ratio": self.options.geometry.slope_ratio,
            "slope_angle": self.options.geometry.slope_angle,
            "stabilise": self.options.stabilise,
            "step_info": list(self.step_info),
        }

    def _signalled(self) -> int:
        """The signal this rank has received (0: none); not collective."""
        return self.stop_request.signum if self.stop_request is not None else 0

    def _write_summary(self):
        """summary.json of the last step on disk, ``running`` (``interrupted`` once a signal
        has come), and the interrupted one that a signal writes at once (rank 0)."""
        if self.comm.rank != 0:
            return
        stop, path = self.stop_request, self.writer.path("summary.json")

        def body(signum):
            by = signal_name(signum) if signum else None
            status = "interrupted" if signum else "running"
            return {"status": status, "interrupted_by": by, **self._step_summary}

        if stop is not None:
            stop.keep(None)  # (no signal writes it while this does)
        self.writer.json("summary.json", body(self._signalled()))
        if stop is None:
            return
        stop.keep(path, {s: json.dumps(body(s), indent=1) for s in SIGNALS})
        stop.announce({s: self._stop_line(s) for s in SIGNALS} if self.verbose else None)
        if self._signalled():  # (one that came while the file was being written)
            self.writer.json("summary.json", body(self._signalled()))

    def _stop_line(self, signum):
        """What a first signal puts on the console at once."""
        name, step = signal_name(signum), self._step_summary["completed_steps"]
        if not step:
            return (
                f"slope: {name}: stopping; no load step has converged yet, so nothing is lost: "
                "run the same command again (no --force needed)"
            )
        return (
            f"slope: {name}: stopping after the load step in progress (again: at once); "
            f"step {step} is on disk: continue with --resume {self.writer.out}"
        )

    def _stop_agreed(self) -> bool:
        """Collective: True once any rank has received a signal (sets :attr:`interrupted`)."""
        if self.stop_request is not None:
            self.interrupted = self.stop_request.agreed(self.comm)
        return bool(self.interrupted)

    # -- the load path ---------------------------------------------------------------------------

    def _resume(self, restart):
        """Continue from a restart: records, stepper state, and the XDMF file rewritten from the
        stored displacements (valid whatever the partition was)."""
        state = restart["state"]
        self.resumed_from = self.step = state["step"]
        self.rows = [tuple(r) for r in state["rows"]]
        self.iterations, self.step_info = list(state["iterations"]), list(state["step_info"])
        self.validity.warned = any(s.get("overlap_points_above") for s in self.step_info)
        self.stepper.step = state["step"]
        self.stepper.cutbacks = [Cutback(**c) for c in state["cutbacks"]]
        self.stepper.path = list(state.get("path", []))
        for k, values in enumerate(restart["u_history"], start=1):
            self.nodes.scatter_function(values, restart["nodes"], self.model.u)
            self.model.material.update(tangent=False)
            self.model.material.commit()
            self._append_xdmf(k)
        self.u_history = list(restart["u_history"]) if self.comm.rank == 0 else []
        if self.points is not None:  # the stored history, not the replay's (any partition)
            material = self.model.material
            stored = dict(restart["history"])
            points = stored.pop("points")
            self.points.restore_material(material, stored, points)
            material.update(tangent=False)
            material.commit()
        phase, t, dt = state["phase"], state["t"], state["dt"]
        if t >= 1.0:  # the stored step ended a phase: go on with the next one
            phase, t, dt = phase + 1, 0.0, None
        self._start = (phase, t, dt)
        self.say(
            f"slope: resumed from {restart['path']} after step {self.resumed_from} "
            f"({self.options.phases[min(phase, len(self.options.phases) - 1)]}, t = {t:.6g})"
        )

    def _record(self, phase_index, step, t, result, elapsed):
        m = self.model
        lam_g = t if phase_index == 0 else 1.0
        footing = m.footing_load()  # 0 in the gravity phase: set_gravity zeroes the footing
        self.iterations.append(result.iterations)
        self.rows.extend(convergence_rows(step, result))
        self.step_info.append(
            {
                "step": step,
                "phase": self.options.phases[phase_index],
                "t": t,
                "gravity": lam_g,
                "footing_load": footing,
                "iterations": result.iterations,
                "converged": True,
                "residual_norm": result.residual_norm,
                "converged_by": result.converged_by,
                "reason": result.reason_name,
                "open_points": m.open_points(),
                "non_elliptic_points": m.non_elliptic_points(),
                "settlement": m.settlement(),
                "stabiliser_force": m.stabiliser_share(),
                "dissipated_energy": m.material.dissipated_energy(),
                **self._friction(phase_index, t),
                "time": elapsed,
                **self._overlaps(step),
            }
        )
        # (no "of n": cut-backs and path following take more steps than the nominal ones)
        self.say(
            f"step {step:2d} ({self.options.phases[phase_index]}, t = {t:.4g}): gravity "
            f"x{lam_g:.2f}, footing "
            f"{footing:.3e} N/m{_friction_note(self.step_info[-1])}, {result.iterations} "
            "iterations, "
            f"{elapsed:.2f} s{_tolerated_note(self.step_info[-1])}"
            f"{_overlap_note(self.step_info[-1])}{self._time_left(step)}"
        )

    def _friction(self, phase_index, t):
        """The step's contact friction for ``step_info`` where the run reduces it."""
        o = self.options
        if o.reduction is None:
            return {}
        reducing = o.phases[phase_index] == "reduction"
        return {"friction": o.reduced_friction(t if reducing else 0.0)[0]}

    def _time_left(self, step):
        """``; ~3.2 min left`` for a step's log line (see :func:`time_left_note`)."""
        elapsed = time.perf_counter() - self._path_started
        left = self.n_nominal - step
        return time_left_note(elapsed, step - self._steps_before, left, self.options.path_following)

    def _overlaps(self, step):
        """The step's validity measure for ``step_info`` (collective); warns once per run."""
        summary = self.model.overlap_summary()
        if summary is None:
            return {}
        if self.comm.rank == 0:
            self.validity.check(summary, f"step {step}")
        else:
            self.validity.warned = self.validity.warned or summary.exceeded
        return {
            "overlap_max_ratio": summary.max_ratio,
            "overlap_points_above": summary.points_above,
            "overlap_fraction_above": summary.fraction_above,
        }

    def run(self) -> bool:
        """Take the load phases from where the run stands; True if every phase completed."""
        clock = [time.perf_counter()]

        def converged(phase_index, t, inc):
            self.step += 1
            self._record(phase_index, self.step, t, inc, time.perf_counter() - clock[0])
            self._write_step(phase_index, self.step, t)
            clock[0] = time.perf_counter()
            if self._stop_agreed():
                return False
            return not (self.stop_after is not None and self.step >= self.stop_after)

        if self._stop_agreed():  # (a signal during the set-up)
            return False
        self._path_started, self._steps_before = time.perf_counter(), self.step
        start_phase, start_t, start_dt = self._start
        for i in range(start_phase, len(self.options.phases)):
            resumed = i == start_phase
            driver, t_of = self._driver(
                i, start_t if resumed else 0.0, start_dt if resumed else None
            )
            driver.run(on_converged=lambda inc, i=i, t_of=t_of: converged(i, t_of(inc), inc))
            if driver.failed is not None:
                self.failed = self._failure(i, driver)
                return False
            if driver.stopped == ASKED_TO_STOP:  # (--stop-after, a signal): not complete
                self.stopped = ASKED_TO_STOP
                return False
        return True

    def _driver(self, i: int, t0: float, dt: float | None) -> tuple[Driver, Callable[[Any], float]]:
        """The driver of phase i from the converged state at t0 (its loads set), and the map
        from its increments to the phase's t."""
        o, m = self.options, self.model
        setter = {
            "gravity": m.set_gravity,
            "footing": m.set_footing,
            "unloading": lambda t: m.set_footing(1.0 - t),
            "reduction": self._set_friction,
        }[o.phases[i]]
        setter(t0)  # the loads of the converged state the phase starts from
        if o.phases[i] == o.path_following:
            stored = None
            if self.restart is not None and i == self._start[0]:
                stored = self.restart["state"].get("arclength")
            self.arclength = load_path(
                m,
                o,
                self.say,
                stored,
                None if stored is None else last_increment(self.restart, self.nodes, m.V),
            )
            return self.arclength, lambda inc: inc.lam / o.path_full_load
        steps = {"gravity": o.gravity_steps, "reduction": o.reduction_steps}
        increment = 1.0 / steps.get(o.phases[i], o.steps)
        return self.stepper.phase(o.phases[i], setter, increment, t0, dt), lambda inc: inc.t

    def _set_friction(self, t: float) -> None:
        """The friction (and rolling friction) of every RVE at t of the reduction phase,
        under the whole load."""
        m = self.model
        if "footing" in self.options.phases:
            m.set_footing(1.0)
        else:
            m.set_gravity(1.0)
        self.law.set_friction(*self.options.reduced_friction(t))

    def _failure(self, i, driver):
        """The run's ``failed`` record of phase i's driver."""
        if driver is not self.arclength:
            return driver.failed
        lam = self.arclength.lam / self.options.path_full_load
        return failure(
            self.options.phases[i], self.step + 1, lam, path_failure(self.model, driver.failed)
        )


def time_left_note(elapsed: float, done: int, left: int, bound: bool = False) -> str:
    """``; ~3.2 min left``: the mean time of the ``done`` steps so far (``elapsed`` seconds)
    times the ``left`` nominal steps to come ('' under 10 s, or with none done or left);
    ``bound``: "at most" (path following may stop at its peak earlier). Cut-backs add steps."""
    if done <= 0 or left <= 0:
        return ""
    seconds = elapsed / done * left
    if seconds < 10:
        return ""
    return f"; {'at most ' if bound else ''}~{_duration(seconds)} left"


def _duration(seconds):
    """``42 s``, ``3.2 min`` or ``1.5 h``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    return f"{seconds / 60:.1f} min" if seconds < 5400 else f"{seconds / 3600:.1f} h"


def _friction_note(info):
    """``, mu 0.125`` for a step's log line where the run reduces the friction ('' without)."""
    return f", mu {info['friction']:.5g}" if "friction" in info else ""


def _tolerated_note(info):
    """``, out of balance by 4.7e+03 N (--residual-tolerance)`` for a step's log line where the
    step was accepted within the residual tolerance, not at round-off ('' otherwise)."""
    if info["converged_by"] != "tolerance":
        return ""
    return f", out of balance by {info['residual_norm']:.3g} N (--residual-tolerance)"


def _overlap_note(info):
    """``, overlaps <= 55 % of r (89 % of points > 10 %)`` for a step's log line ('' without)."""
    if "overlap_max_ratio" not in info:
        return ""
    return (
        f", overlaps <= {100 * info['overlap_max_ratio']:.3g} % of r "
        f"({100 * info['overlap_fraction_above']:.3g} % of points > {100 * OVERLAP_THRESHOLD:g} %)"
    )


def is_complete(restart: Mapping[str, Any]) -> bool:
    """True if the run of ``restart`` (:func:`load_restart`) had completed every load phase."""
    state = restart["state"]
    path = state.get("arclength") or {}
    if path.get("stopped") and path["stopped"] != ASKED_TO_STOP:
        return True  # a path that reached its end (past the peak, or the full load)
    return state["phase"] == len(restart["options"].phases) - 1 and state["t"] >= 1.0


def run_slope(
    packing: Packing,
    options: SlopeOptions | None = None,
    out: str | os.PathLike[str] = "results/slope",
    comm: MPI.Comm = MPI.COMM_WORLD,
    figure: bool = True,
    **kwargs: Any,
) -> dict:
    """Run the slope benchmark (or continue it: ``restart=``) and write its results to ``out``;
    returns the summary dict (also in ``out/summary.json``). Keyword arguments as
    :class:`SlopeRun`; ``figure`` draws ``out/slope.png``."""
    run = SlopeRun(packing, options, out, comm, **kwargs)
    o, m = run.options, run.model
    run.say(
        f"slope: 1:{o.geometry.slope_ratio:g} slope ({o.geometry.slope_angle:.1f}°), "
        f"{m.mesh.topology.index_map(2).size_global} cells, "
        f"{comm.allreduce(m.material.n_points)} {'' if o.rve == 'taylor' else o.rve + ' '}RVEs "
        f"of {packing.n_particles} particles"
        + (f" confined at {o.confinement:g} Pa" if o.confinement else "")
        + f", {comm.size} rank(s), {run.n_nominal} load steps"
        + (f", footing load x{o.load_factor:g}" if "footing" in o.phases else "")
        + (f", the {o.path_following} by path following" if o.path_following else "")
        + (f", stabiliser {o.stabilise:g}" if o.stabilise else "")
        + (
            f", out-of-balance force tolerated: {o.residual_tolerance:g} of the force scale"
            if o.residual_tolerance > 0.0
            else ""
        )
    )
    if getattr(run.law, "prestress", None) is not None:
        run.say(
            f"slope: reference state of the RVE: P(I) = "
            f"{np.array2string(run.law.prestress, precision=3)} Pa "
            f"({run.law.prestress_ratio:.2g} of its modulus)"
        )
    run.run()
    if run.stop_request is not None:  # the load path is done: a signal now changes nothing
        run.stop_request.announce(None)
        run.stop_request.keep(None)
    figure = figure and not run.interrupted  # (asked to stop: no figure of a partial run)
    path = path_summary(run.arclength, run.step_info, o.geometry.footing_load, o.path_following)
    report_stop(run, path)
    extremes = m.extremes()
    probes = m.probes(extremes[1][1])
    # the mesh, displacement and cell-mean von Mises stress gathered on rank 0 (collective)
    data = gather_mesh(m.V, m.u, m.material.cell_average(extremes[0])) if figure else None
    m.solver.destroy()  # collective PETSc clean-up while all ranks are here (rank 0 draws next)
    seconds, colour_range = 0.0, None
    if figure and comm.rank == 0:
        seconds, colour_range = draw_figure(
            run, run.writer.path("slope.png"), data, extremes, probes
        )
        draw_load_settlement(run, run.writer.path("load_settlement.png"))
    summary = summarise(run, extremes, probes, seconds, colour_range, path)
    run.writer.csv("convergence.csv", CONVERGENCE_HEADER, run.rows)
    run.writer.json("summary.json", summary)
    t = summary
    ended = {"converged": "done", "stopped": "stopped as asked"}.get(t["status"], t["status"])
    run.say(
        f"slope: {ended} after {t['wall_time']:.1f} s (set-up {t['time_setup']:.1f} s, RVE "
        f"{t['time_rve']:.1f} s, assembly {t['time_assembly']:.1f} s, solve "
        f"{t['time_solve']:.1f} s, output {t['time_output']:.1f} s); settlement "
        f"{t['footing_settlement']:.4f} m; von Mises {t['min_von_mises']:.4g} .. "
        f"{t['max_von_mises']:.4g} Pa; results in {run.writer.out}"
    )
    if comm.size > 1:
        run.say(
            "slope: RVE seconds per rank "
            + ", ".join(f"{s:.1f}" for s in t["time_rve_ranks"])
            + f" (max / mean {t['rve_imbalance']:.2f}"
            + (
                f"; summed over the evaluations, slowest / mean {per_update:.2f})"
                if (per_update := t["rve_imbalance_per_update"]) is not None
                else ")"
            )
            + "; CPU "
            + ", ".join(f"{s:.1f}" for s in t["time_rve_ranks_cpu"])
            + f" (max / mean {t['rve_imbalance_cpu']:.2f})"
        )
    return summary
