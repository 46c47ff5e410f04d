"""The runner: one scenario executed once (``run``), batched (``mc``) or over a grid (``sweep``).

All three build the same :class:`~testbed.experiment.loop.ClosedLoop` from a
:class:`~testbed.experiment.scenario.Scenario`; ``run`` is a batch of one. Run ``i`` of
``monte_carlo(scenario, runs=R)`` uses the seed ``run_seeds(scenario.seed, R)[i]`` (the
``i``-th word of ``numpy.random.SeedSequence(seed).generate_state(R)``: independent of the
batch size, prefix-stable, no overlap between nearby base seeds) and equals, bitwise,
``run(scenario.replace(seed=that seed))``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import itertools
import os
import shutil
import threading
import time
import zipfile
from collections.abc import Callable
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from filters.kalman import CovarianceMemo
from testbed import estimators
from testbed.estimators.design import DesignModel
from testbed.experiment.backend import check_backend, map_jobs
from testbed.experiment.control import make_controller
from testbed.experiment.envelope import ErrorEnvelope
from testbed.experiment.loop import ClosedLoop, EstimatorStage, Stopped, check_estimate
from testbed.experiment.metrics import EpisodeMetrics
from testbed.experiment.scenario import Scenario, blame
from testbed.experiment.trajectory import Trajectory
from testbed.io import (
    OutputError,
    atomic_path,
    remove_own_temporaries,
    reserve,
    temporary_directory,
)
from testbed.rigs import resolve_rig
from testbed.sim import build_simulator
from testbed.sim.simulator import default_num_threads, positive_int

#: Default number of trajectories stepped together by :func:`monte_carlo`.
DEFAULT_BATCH_SIZE = 1000
#: Keys of a result that measure time, not the estimator.
TIMING_KEYS = ("wall_s", "traj_steps_per_s", "threads")


def run_seeds(seed: int, runs: int) -> np.ndarray:
    """Per-run seeds of ``monte_carlo`` (uint32 words of ``SeedSequence(seed)``), (runs,)."""
    return np.random.SeedSequence(seed).generate_state(runs).astype(np.int64)


@dataclass
class Experiment:
    """A built scenario: the closed loop of N members and its design model."""

    scenario: Scenario
    loop: ClosedLoop
    design: DesignModel
    meta: dict[str, Any]

    def close(self) -> None:
        """Stop the physics threads."""
        self.loop.close()


def _with_defaults(scenario: Scenario) -> Scenario:
    """Fill the fields the user left unset from the rig's and the estimator's defaults."""
    rig = resolve_rig(scenario.rig)
    changes: dict[str, Any] = {}
    for key, value in rig.scenario_defaults.items():
        if getattr(scenario, key) is None:
            changes[key] = value
    name = scenario.estimator if isinstance(scenario.estimator, str) else None
    needs = estimators.SCENARIO_DEFAULTS.get(name, {})
    if needs.get("disturbance") not in rig.disturbance_signals:
        needs = {}  # the rig lacks what the estimator needs: its factory says so
    for key, value in needs.items():
        if key == "disturbance_channel":
            if scenario.sensors is None or isinstance(scenario.sensors, str):
                changes["sensor_options"] = {**scenario.sensor_options, key: value}
        elif getattr(scenario, key) is None:
            changes[key] = value
    return scenario.replace(**changes) if changes else scenario


def described(scenario: Scenario) -> dict[str, Any]:
    """The ``scenario`` block of the outputs: :meth:`Scenario.describe` without the fields
    left at None (TOML has no null; a missing key is the default), so that the block saved
    as TOML or JSON is a scenario file (:mod:`testbed.experiment.scenario_file`)."""
    return {k: v for k, v in scenario.describe().items() if v is not None}


def build(scenario: Scenario, num: int = 1, *, num_threads: int | None = None) -> Experiment:
    """The closed loop of ``num`` members for a scenario (everything validated first).

    Raises
    ------
    ScenarioError
        A bad or inapplicable option (a ``ValueError`` naming the field), before any
        simulation runs.
    """
    resolved = scenario.take_resolved()
    defaulted = _with_defaults(scenario)
    sensors, sensor_kwargs = resolved.sensors, None
    if (defaulted.sensors, defaulted.sensor_options) != (scenario.sensors,
                                                         scenario.sensor_options):
        # a default of the rig or the estimator changed the preset: build that one
        sensors, sensor_kwargs = defaulted.sensors, defaulted.sensor_options or None
    scenario = defaulted
    sim = build_simulator(resolved.rig, num, physics_dt_s=scenario.physics_dt_s,
                          frame_skip=scenario.frame_skip, sensors=sensors,
                          sensor_kwargs=sensor_kwargs,
                          disturbance=scenario.disturbance,
                          process_noise=scenario.process_noise, setpoints=scenario.setpoints,
                          manoeuvre=scenario.manoeuvre,
                          manoeuvre_params=scenario.manoeuvre_params or None,
                          params=scenario.params or None, num_threads=num_threads,
                          profile=scenario.profile, ambient_noise=scenario.ambient_noise,
                          reset_noise_scale=scenario.reset_noise_scale)
    rig = sim.rig
    # the designer's rigs: nominal parameters; the controller's is always the paper
    # profile's (the same controller whatever the estimator's design), the estimator's
    # knows the scenario's profile unless design_profile is "paper"
    control_rig = type(rig)(physics_dt_s=scenario.physics_dt_s)
    matched = scenario.design_profile == "matched" and scenario.profile != "paper"
    design_rig = (type(rig)(physics_dt_s=scenario.physics_dt_s, profile=scenario.profile)
                  if matched else control_rig)
    with blame("design_options"):
        design = design_rig.design_model(sim.sensors, sim.dt_s, sim.known_disturbance,
                                         **scenario.design_options)
        control_design = design
        if design.augmented:
            control_design = design.extras.get("paper_design") or control_rig.design_model(
                sim.sensors, sim.dt_s, sim.known_disturbance, **scenario.design_options)
    name = scenario.estimator if isinstance(scenario.estimator, str) else \
        getattr(scenario.estimator, "__name__", repr(scenario.estimator))
    with blame("estimator"):
        design, fallback = estimators.design_for(scenario.estimator, design)
        est = estimators.build(scenario.estimator, design, **scenario.estimator_options)
        check_estimate(name, est.x, getattr(est, "P", None), design.n, "after the factory")
        if not getattr(est, "batched", False):
            est = estimators.PerMember([est, *(estimators.build(scenario.estimator, design,
                                                                **scenario.estimator_options)
                                               for _ in range(num - 1))])
    P = getattr(est, "P", None)
    prior = (np.array(design.x0, copy=True), None if P is None else np.array(design.P0))
    metrics = EpisodeMetrics(list(rig.state_names), sim.dt_s, list(sim.sensors.measured_state),
                             design.output_matrix[:, design.physical])
    stage = EstimatorStage(est, design.input_transform, metrics, prior,
                           channels=estimators.channels_for(est, design),
                           physical_index=design.physical, name=name)
    controller = make_controller(scenario.controller, control_rig, control_design,
                                 lambda t: sim.setpoints_at(t))
    meta = {"rig": rig.name, "scenario": described(scenario), "sensors": sim.sensors.describe(),
            "control_dt_s": sim.dt_s, "units": sim.units()}
    if matched:
        meta["design_profile"] = "paper (fallback: " + fallback + ")" if fallback else "matched"
        meta["design_states"] = list(design.state_names)
    design_meta = getattr(getattr(est, "inner", est), "design_meta", None)
    if design_meta:
        meta["design"] = design_meta
    return Experiment(scenario, ClosedLoop(sim, stage, controller), design, meta)


def _summary(result, index: int = 0) -> dict[str, Any]:
    return result.summary(index)


#: Most rows :func:`run` records; longer runs keep every k-th step (and the last one), so
#: the memory of ``--plot``/``--rrd`` does not grow with the duration (20,000 rows of the
#: helicopter with body poses: about 10 MB).
RECORD_MAX_ROWS = 20_000


class _DecimatedRows:
    """A recording array ``(N, T, ...)`` for :meth:`ClosedLoop.run` keeping only some rows.

    Keeps rows ``0, every, 2 every, ...`` and the last row written; the loop writes row ``k``
    with ``rows[:, k] = value`` (or into ``rows[:, k]``) and truncates with ``rows[:, :T]``.
    """

    def __init__(self, shape: tuple[int, ...], every: int):
        self.shape, self.every = shape, every
        kept = (shape[1] - 1) // every + 1
        self.data = np.zeros((shape[0], kept + 1, *shape[2:]))  # + the last row written
        self.last = -1

    def _slot(self, key: Any) -> int:
        rows, k = key
        if rows != slice(None) or not isinstance(k, int | np.integer):
            raise IndexError(f"decimated recording supports [:, k] only, got {key!r}")
        self.last = int(k)
        return int(k) // self.every if k % self.every == 0 else -1

    def __setitem__(self, key: Any, value: Any) -> None:
        slot = self._slot(key)
        self.data[:, slot] = value
        if slot != -1:
            self.data[:, -1] = value

    def __getitem__(self, key: Any) -> Any:
        if isinstance(key, tuple) and isinstance(key[1], slice):
            return self  # truncation at an early end: rows are kept by index
        return self.data[:, self._slot(key)]

    def rows(self) -> np.ndarray:
        """Step indices of :meth:`values`, shape (R,)."""
        kept = np.arange(0, self.last + 1, self.every)
        return kept if kept[-1] == self.last else np.append(kept, self.last)

    def values(self) -> np.ndarray:
        """The kept rows, shape (N, R, ...)."""
        n = self.last // self.every + 1
        if self.last % self.every == 0:
            return self.data[:, :n]
        return np.concatenate([self.data[:, :n], self.data[:, -1:]], axis=1)


def run(scenario: Scenario, *, record: bool = True, progress: bool | None = False,
        observe: Callable[[Experiment], Callable[[int, dict[str, Any]], None]] | None = None
        ) -> tuple[Trajectory | None, dict[str, Any]]:
    """One closed-loop episode of ``scenario`` (seed ``scenario.seed``).

    Parameters
    ----------
    scenario : Scenario
    record : bool
        Keep the trajectory (with body poses, for the 3D view).
    progress : bool or None
        Progress bar on stderr: False (default) none, True always, None only when the run
        takes more than two seconds (the CLI's choice on a terminal).
    observe : callable, optional
        Called once with the built :class:`Experiment` before the episode starts; returns
        the per-step observer ``on_step(k, row)`` of :meth:`ClosedLoop.run` (e.g.
        :meth:`testbed.outputs.live.LiveView.attach`, logging to a live viewer). Body poses are
        recorded
        for it. The run is the same with or without it.

    Returns
    -------
    trajectory : Trajectory or None
        With ``record`` (body poses included, for the 3D view). At most
        :data:`RECORD_MAX_ROWS` rows: a longer run keeps every k-th step and the last one
        (``t_s`` gives the time of each row). Without ``record`` nothing per step is kept,
        so memory does not grow with the duration.
    summary : dict
        ``steps``, ``rmse``, ``measurement_rmse``, ``nees_mean``, ``T_final``,
        ``clipped_fraction``, ``units``, ``meta`` (metrics over every step).
    """
    experiment = build(scenario, 1, num_threads=1)
    loop = experiment.loop
    n_steps = int(round(scenario.duration_s / loop.sim.dt_s))
    every = -(-(n_steps + 1) // RECORD_MAX_ROWS)  # ceil
    recorder: Any = record
    if record and every > 1:
        shapes = loop.trajectory_shapes(n_steps, poses=True)
        recorder = {k: _DecimatedRows(shape, every) for k, shape in shapes.items()}
    bar = tqdm(total=n_steps, desc=experiment.meta["rig"], unit="step",
               disable=progress is False, delay=0 if progress else 2.0, leave=False)
    try:
        on_step = observe(experiment) if observe is not None else None
        with bar:
            result = loop.run(np.array([scenario.seed]), scenario.duration_s, record=recorder,
                              poses=record or on_step is not None, bar=bar, on_step=on_step)
    finally:
        experiment.close()
    summary = _summary(result)
    summary["units"] = experiment.meta["units"]
    summary["meta"] = experiment.meta
    traj = None
    if record:
        rec = result.trajectory
        if isinstance(recorder, dict):
            rows = recorder["state"].rows()
            rec = {k: v.values() for k, v in recorder.items()}
            rec["t_s"] = rows * result.dt_s
        sim = loop.sim
        traj = Trajectory(
            t_s=rec["t_s"], state=rec["state"][0], state_names=list(sim.rig.state_names),
            measurement=rec["measurement"][0], measurement_names=list(sim.sensors.names),
            measured_state_index=list(sim.sensors.measured_state),
            action=rec["action"][0],
            action_names=[f"{n} [{u}]" for n, u in zip(sim.rig.action_names,
                                                        sim.rig.action_units, strict=True)],
            estimate=rec["estimate"][0],
            covariance=rec["covariance"][0] if "covariance" in rec else None,
            setpoint=rec["setpoint"][0], body_pos=rec["body_pos"][0],
            body_quat_wxyz=rec["body_quat_wxyz"][0],
            meta=dict(experiment.meta, seed=scenario.seed, duration_s=result.steps * result.dt_s,
                      setpoint_names=list(sim.rig.tracked_states), recorded_every_steps=every),
            rig=sim.rig)
    return traj, summary


class _FileRows:
    """Runs ``start:start+size`` of one array of a ``.npy`` file being written, as the loop
    records them (``rows[:, k] = value``): a few steps are buffered, then written with
    ``os.pwrite`` at their place. No memory map (a full disk is an ``OSError``, never a
    SIGBUS); RAM bounded by ``size x chunk`` rows."""

    #: Bytes of a buffer (the chunk of steps is chosen from it).
    BUFFER_BYTES = 8 << 20

    def __init__(self, stream: _NpzStream, key: str, start: int, size: int):
        self.stream, self.key, self.start = stream, key, start
        total = stream.shapes[key]
        self.shape = (size, *total[1:])
        self._row_items = int(np.prod(total[2:], dtype=np.int64))
        steps = total[1]
        per_step = max(1, size * self._row_items * 8)
        self.chunk = int(max(1, min(steps, self.BUFFER_BYTES // per_step)))
        self._buf = np.zeros((size, self.chunk, *total[2:]))
        self._c0, self._top = 0, -1

    def __setitem__(self, key: Any, value: Any) -> None:
        rows, k = key
        if rows != slice(None) or not isinstance(k, int | np.integer):
            raise IndexError(f"a streamed recording supports [:, k] only, got {key!r}")
        k = int(k)
        if not self._c0 <= k < self._c0 + self.chunk:
            self.flush()
            self._c0 = k - k % self.chunk
        self._buf[:, k - self._c0] = value
        self._top = max(self._top, k)

    def __getitem__(self, key: Any) -> Any:
        if isinstance(key, tuple) and isinstance(key[1], slice):
            return self  # truncation at an early end: the rows not written stay zero
        raise IndexError("a streamed recording is write-only")

    def flush(self) -> None:
        """Write the buffered steps to the file."""
        if self._top < self._c0:
            return
        n = self._top - self._c0 + 1
        steps = self.stream.shapes[self.key][1]
        item = self._row_items * 8
        fd, base = self.stream.files[self.key]
        try:
            for i in range(self.shape[0]):
                data = np.ascontiguousarray(self._buf[i, :n]).tobytes()
                offset = base + ((self.start + i) * steps + self._c0) * item
                while data:
                    written = os.pwrite(fd, data, offset)
                    data, offset = data[written:], offset + written
        except OSError as exc:
            raise OutputError(self.stream.path, exc) from None
        self._buf[:, :n] = 0.0
        self._top = self._c0 - 1


class _NpzStream:
    """Trajectories written batch by batch into ``.npy`` files, zipped into one ``.npz``.

    The space is reserved up front (``posix_fallocate``): a full disk fails before the
    simulation starts, as :class:`testbed.io.OutputError` naming the ``.npz``, and every
    temporary is removed. RAM stays bounded by one batch times a few steps; the ``.npz``
    appears atomically.
    """

    def __init__(self, path: str | Path, shapes: dict[str, tuple[int, ...]]):
        self.path = Path(path)
        self.shapes = dict(shapes)
        self.files: dict[str, tuple[int, int]] = {}  # key -> (fd, header bytes)
        self._open: list[_FileRows] = []
        self._dir: Path | None = None
        try:
            self._dir = temporary_directory(self.path)
            for key, shape in shapes.items():
                header = io.BytesIO()
                np.lib.format.write_array_header_1_0(header, {
                    "descr": "<f8", "fortran_order": False, "shape": tuple(shape)})
                fd = os.open(self._dir / f"{key}.npy", os.O_RDWR | os.O_CREAT | os.O_EXCL,
                             0o600)
                self.files[key] = (fd, header.tell())
                size = header.tell() + 8 * int(np.prod(shape, dtype=np.int64))
                reserve(fd, size, self.path)
                os.ftruncate(fd, size)
                os.pwrite(fd, header.getvalue(), 0)
        except BaseException as exc:
            self.abort()
            if isinstance(exc, OSError) and not isinstance(exc, OutputError):
                raise OutputError(self.path, exc) from None
            raise

    def rows(self, start: int, stop: int) -> dict[str, _FileRows]:
        """Writable rows of runs ``start:stop`` of every array (write them with
        :meth:`flush` after the batch)."""
        self.flush()
        self._open = [_FileRows(self, k, start, stop - start) for k in self.shapes]
        return {r.key: r for r in self._open}

    def flush(self) -> None:
        """Write what the rows of the last batch still buffer."""
        for rows in self._open:
            rows.flush()
        self._open = []

    def finish(self, extra: dict[str, np.ndarray]) -> Path:
        """Write the ``.npz`` with the trajectories and the ``extra`` arrays."""
        try:
            self.flush()
            arrays = {k: np.asanyarray(v) for k, v in extra.items()}
            size = sum(os.fstat(fd).st_size for fd, _ in self.files.values())
            size += sum(a.nbytes + 256 for a in arrays.values())
            size += 512 * (len(self.files) + len(arrays)) + 4096  # zip headers
            with atomic_path(self.path) as tmp, open(tmp, "r+b") as f:
                reserve(f, size, self.path)
                with zipfile.ZipFile(f, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
                    for key, (fd, _) in self.files.items():
                        with zf.open(f"{key}.npy", "w", force_zip64=True) as out:
                            os.lseek(fd, 0, os.SEEK_SET)
                            while block := os.read(fd, 1 << 22):
                                out.write(block)
                    for key, value in arrays.items():
                        with zf.open(f"{key}.npy", "w", force_zip64=True) as out:
                            np.lib.format.write_array(out, value, allow_pickle=False)
                f.truncate(f.tell())  # the reserved space beyond the zip's end
        except OutputError:
            raise
        except OSError as exc:
            raise OutputError(self.path, exc) from None
        finally:
            self.abort()
        return self.path

    def abort(self) -> None:
        """Close and remove the temporary files."""
        self._open = []
        for fd, _ in self.files.values():
            with contextlib.suppress(OSError):
                os.close(fd)
        self.files.clear()
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
        remove_own_temporaries(self.path)


class StudyTooLarge(ValueError):
    """A Monte-Carlo study whose per-run results would not fit in memory (refused before
    anything is allocated); ``needed`` and ``available`` in bytes."""

    def __init__(self, message: str, needed: int = 0, available: int = 0):
        super().__init__(message)
        self.needed, self.available = needed, available

    def __reduce__(self) -> tuple[Any, ...]:
        return (type(self), (str(self), self.needed, self.available))


def available_memory() -> int:
    """Bytes of memory available to a new allocation (Linux ``MemAvailable``; otherwise the
    physical memory)."""
    with contextlib.suppress(OSError, ValueError, IndexError):
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    with contextlib.suppress(ValueError, OSError, AttributeError):
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    return 1 << 62


def _size_text(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB", "TB", "PB"):
        if n < 1000 or unit == "PB":
            return f"{n:.3g} {unit}"
        n /= 1000
    return f"{n:.3g} PB"  # pragma: no cover


def study_bytes(n_states: int, n_measured: int, runs: int,
                envelope_points: int | None = None) -> int:
    """Estimated memory of the per-run results of a study of ``runs`` runs: seeds, per-run
    metrics (arrays, the JSON lists and text) and, with an envelope, its errors."""
    per_run = 3 * 8 + 2 * 8 * (n_states + n_measured + 3)  # seeds, metric arrays (+ joins)
    per_run += 64 * (n_states + 1) + 32 * (n_states + 1)    # Python floats in lists, JSON
    if envelope_points is not None:
        per_run += 8 * n_states * int(envelope_points)
    return int(runs) * per_run


def check_study_size(scenario: Scenario, runs: int,
                     envelope_points: int | None = None) -> None:
    """Refuse a study whose per-run results cannot fit in the available memory.

    Raises
    ------
    StudyTooLarge
        With the estimate and what is available (nothing allocated yet).
    """
    resolved = scenario.check()
    n = resolved.rig.n_states
    m = len(getattr(resolved.sensors, "measured_state", None) or []) or n
    needed = study_bytes(n, m, runs, envelope_points)
    available = available_memory()
    if needed > available // 2:
        raise StudyTooLarge(
            f"runs {runs:,} would need about {_size_text(needed)} of memory for the per-run "
            f"results ({_size_text(needed / runs)} per run), more than half of the "
            f"{_size_text(available)} available; use fewer runs (at most about "
            f"{max(1, available // 2 // max(1, needed // runs)):,})", needed, available)


def _stats(values: np.ndarray) -> dict[str, float]:
    q05, q95 = np.quantile(values, [0.05, 0.95])
    return {"mean": float(np.mean(values)), "q05": float(q05), "q95": float(q95)}


def monte_carlo(scenario: Scenario, runs: int = 100, *, batch_size: int | None = None,
                progress: bool = False, save_npz: str | Path | None = None,
                num_threads: int | None = None,
                envelope_points: int | None = None, backend: str | None = None,
                workers: int | None = None, address: str | None = None) -> dict[str, Any]:
    """``runs`` episodes of ``scenario``, stepped in batches.

    Parameters
    ----------
    scenario : Scenario
        ``scenario.seed`` is the base seed; run ``i`` uses ``run_seeds(seed, runs)[i]``.
    runs : int
    batch_size : int, optional
        Members stepped together (default ``min(runs, 1000)``); results do not depend on it.
    progress : bool
        Show a progress bar (on stderr; default off).
    save_npz : path, optional
        Also write every trajectory (``(runs, steps + 1, ...)``) and the per-run metrics.
    num_threads : int, optional
        Threads (default: the CPUs available; with a ``backend``, 1 per job). In one
        process, ``T > 1`` threads run the runs in ``T`` lanes (contiguous parts, each on a
        Python thread of its own with one physics thread), so that one lane's Python overlaps
        the others' physics; without ``save_npz`` and ``envelope_points`` (one lane then, on
        ``T`` physics threads). The results do not depend on it.
    envelope_points : int, optional
        Also gather the error envelope over runs on this many time points
        (:class:`testbed.experiment.envelope.ErrorEnvelope`: streaming, no trajectory kept); the
        result then has ``error_envelope``.
    backend : {None, "local", "ray"}, optional
        None (default): every batch in this process. ``"local"`` / ``"ray"``: the runs in
        ``workers`` contiguous shards, each a job of :func:`~testbed.experiment.backend.
        map_jobs` (local processes, or Ray tasks on the cluster at ``address`` or a local
        instance); each run keeps its seed, so every per-run result equals the in-process
        study's bitwise. Without ``save_npz`` and ``envelope_points``.
    workers, address : optional
        Shards (default the CPUs, at most ``runs``) and the Ray cluster address.

    Returns
    -------
    dict
        JSON-ready: ``runs``, ``seeds`` (the per-run seeds), ``steps_per_run``, ``wall_s``,
        ``traj_steps_per_s``, ``rmse``/``measurement_rmse`` ``{name: {mean, q05, q95}}``,
        ``nees_mean``, ``nees``, ``T_final``, ``clipped_fraction_mean``, ``units``,
        ``scenario`` (every field, the rig's defaults filled in: what ran; a scenario file
        holding it reproduces the study, see :mod:`testbed.experiment.scenario_file`) and
        ``meta`` (rig, sensors, control period, units, design).
    """
    if isinstance(runs, bool) or int(runs) != runs or runs < 1:
        raise ValueError(f"runs must be a positive integer, got {runs}")
    if batch_size is not None and (int(batch_size) != batch_size or batch_size < 1):
        raise ValueError(f"batch_size must be a positive integer, got {batch_size}")
    if envelope_points is not None and (isinstance(envelope_points, bool)
                                        or int(envelope_points) != envelope_points
                                        or envelope_points < 2):
        raise ValueError(f"envelope_points must be an integer >= 2, got {envelope_points}")
    runs = int(runs)
    if backend is not None:
        if save_npz is not None or envelope_points is not None:
            raise ValueError("a sharded Monte Carlo (backend) writes no npz and no envelope")
        return _sharded_monte_carlo(scenario, runs, batch_size, progress, num_threads,
                                    backend, workers, address)
    # BLAS single-threaded for the whole study, its builds included: their products are
    # tiny, and a second BLAS thread only slows them down (by far on a busy machine)
    start_time = time.perf_counter()
    with threadpool_limits(1):
        return _local_monte_carlo(scenario, runs, batch_size, progress, save_npz, num_threads,
                                  envelope_points, start_time)


def _local_monte_carlo(scenario: Scenario, runs: int, batch_size: int | None, progress: bool,
                       save_npz: str | Path | None, num_threads: int | None,
                       envelope_points: int | None, start_time: float) -> dict[str, Any]:
    """:func:`monte_carlo` in this process (its arguments checked; its wall time counted
    from ``start_time``, a ``time.perf_counter()``)."""
    batch_size = min(runs, int(batch_size or DEFAULT_BATCH_SIZE))
    check_study_size(scenario, runs, envelope_points)
    seeds = run_seeds(scenario.seed, runs)
    threads = (default_num_threads() if num_threads is None
               else positive_int(num_threads, "num_threads"))
    # lanes: contiguous parts of the runs stepped in as many Python threads, one physics
    # thread each, so that one lane's Python (sensors, estimator, controller; it holds the
    # GIL) runs while the other lanes' physics runs (MuJoCo releases the GIL); a run's
    # results do not depend on its batch. A stream or an envelope keeps one lane.
    lanes = min(threads, runs) if save_npz is None and envelope_points is None else 1
    if lanes > 1:
        batch_size = min(batch_size, -(-runs // lanes))
    experiments: dict[int, Experiment] = {}
    # the batches of the study (every lane's, one after the other) compute one covariance
    # sequence when their estimator's covariance does not depend on the data: computed once
    # for all of them (the study's own memo, dropped with it; the same values without it)
    memo = CovarianceMemo()

    def experiment_for(size: int) -> Experiment:
        if size not in experiments:
            experiments[size] = _sharing(build(scenario, size,
                                               num_threads=1 if lanes > 1 else num_threads),
                                         memo)
        return experiments[size]

    first = experiment_for(batch_size)
    dt_s = first.loop.sim.dt_s
    n_steps = int(round(scenario.duration_s / dt_s))
    if n_steps < 1:
        raise ValueError(f"duration_s must cover at least one control period ({dt_s} s), "
                         f"got {scenario.duration_s}")
    stream = None
    state_names = list(first.loop.sim.rig.state_names)
    envelope = None
    if envelope_points is not None:
        envelope = ErrorEnvelope(runs, n_steps, dt_s, state_names, envelope_points)
    gathered = RunMetrics(state_names)
    try:
        if save_npz is not None:
            shapes = {k: (runs, *s[1:])
                      for k, s in first.loop.trajectory_shapes(n_steps).items()}
            stream = _NpzStream(save_npz, shapes)
        parts = [part for part in np.array_split(seeds, lanes) if len(part)]
        batches = sum(-(-len(part) // batch_size) for part in parts)
        bar = tqdm(total=batches * n_steps, desc=f"monte carlo ({first.meta['rig']})",
                   unit="step", disable=not progress)
        with bar:
            if lanes > 1:
                gathered = _run_lanes(scenario, parts, batch_size, experiments, bar, memo)
            else:
                for start in range(0, runs, batch_size):
                    size = min(batch_size, runs - start)
                    loop = experiment_for(size).loop
                    record = stream.rows(start, start + size) if stream is not None else False
                    on_step = None if envelope is None else envelope.observer(start)
                    result = loop.run(seeds[start:start + size], scenario.duration_s,
                                      record=record, bar=bar, on_step=on_step)
                    if stream is not None:
                        stream.flush()
                    gathered.add(result)
    except BaseException:
        if stream is not None:
            stream.abort()
        raise
    finally:
        for experiment in experiments.values():
            experiment.close()
    try:
        per_run = gathered.arrays()
    except BaseException:
        if stream is not None:
            stream.abort()
        raise
    if stream is not None:
        stream.finish(_npz_extra(per_run, seeds, n_steps, dt_s, state_names,
                                 list(first.loop.sim.sensors.names)))  # removes temporaries
    wall_s = time.perf_counter() - start_time
    result = {
        "filter": scenario.describe()["estimator"],
        "runs": runs,
        "duration_s": n_steps * dt_s,
        "steps_per_run": n_steps,
        "seed": scenario.seed,
        "seeds": seeds.tolist(),
        "seed_rule": "numpy.random.SeedSequence(seed).generate_state(runs)",
        "batch_size": batch_size,
        "threads": first.loop.sim.physics.num_threads * lanes,
        "wall_s": wall_s,
        "traj_steps_per_s": runs * n_steps / wall_s,
        **per_run_summary(per_run),
        "npz": None if save_npz is None else str(save_npz),
        "units": first.meta["units"],
        "scenario": first.meta["scenario"],
        "meta": {k: v for k, v in first.meta.items() if k != "scenario"},
    }
    if envelope is not None:
        result["error_envelope"] = envelope.result()
    return result


def _sharing(experiment: Experiment, memo: CovarianceMemo) -> Experiment:
    """``experiment``, its estimator given the study's covariance memo if it takes one
    (:meth:`filters.kalman.KalmanFilter.share_covariance_memo`)."""
    share = getattr(experiment.loop.stage.estimator, "share_covariance_memo", None)
    if callable(share):
        share(memo)
    return experiment


def _run_lanes(scenario: Scenario, parts: list[np.ndarray], batch_size: int,
               experiments: dict[int, Experiment], bar: tqdm,
               memo: CovarianceMemo) -> RunMetrics:
    """The runs of ``parts`` (contiguous seeds, in order), each part in batches of at most
    ``batch_size`` on a thread of its own with its own one-thread experiments (the first
    part's are ``experiments``, closed by the caller; the others' are closed here); every
    lane's estimators share ``memo`` (:class:`filters.kalman.CovarianceMemo`).

    A failure or an interrupt stops every lane within a step (:class:`Stopped`) and is
    raised once they have stopped.
    """
    stop = threading.Event()
    own: list[dict[int, Experiment]] = [experiments] + [{} for _ in parts[1:]]

    state_names = list(experiments[batch_size].loop.sim.rig.state_names)

    def lane(j: int) -> RunMetrics:
        gathered = RunMetrics(state_names)
        for start in range(0, len(parts[j]), batch_size):
            size = min(batch_size, len(parts[j]) - start)
            gathered.add(own[j][size].loop.run(parts[j][start:start + size],
                                               scenario.duration_s, bar=bar, stop=stop))
        return gathered

    try:
        # every lane's experiments built here, one after the other: a build takes the
        # scenario's checked rig and sensors (Scenario.take_resolved), not thread-safe
        for j, part in enumerate(parts):
            for size in {min(batch_size, len(part) - start)
                         for start in range(0, len(part), batch_size)}:
                if size not in own[j]:
                    own[j][size] = _sharing(build(scenario, size, num_threads=1), memo)
        with ThreadPoolExecutor(len(parts)) as pool:  # (BLAS limited by the caller)
            futures = [pool.submit(lane, j) for j in range(len(parts))]
            try:
                _, pending = wait(futures, return_when=FIRST_EXCEPTION)
            except BaseException:  # an interrupt: the lanes stop within a step
                stop.set()
                raise
            if pending:  # a lane failed: the others stop within a step
                stop.set()
        failures = [f.exception() for f in futures
                    if f.exception() is not None and not isinstance(f.exception(), Stopped)]
        if failures:
            raise failures[0]
        results = [f.result() for f in futures]
    finally:
        for cache in own[1:]:
            for experiment in cache.values():
                experiment.close()
    gathered = results[0]
    for part in results[1:]:
        gathered.extend(part)
    return gathered


def _mc_shard(scenario: Scenario, seeds: np.ndarray, batch_size: int | None,
              num_threads: int | None) -> dict[str, Any]:
    """The runs of one shard (their own seeds): per-run arrays and what the study reports."""
    batch_size = min(len(seeds), int(batch_size or DEFAULT_BATCH_SIZE))
    experiments: dict[int, Experiment] = {}
    gathered: RunMetrics | None = None
    try:
        for start in range(0, len(seeds), batch_size):
            size = min(batch_size, len(seeds) - start)
            if size not in experiments:
                experiments[size] = build(scenario, size, num_threads=num_threads)
            loop = experiments[size].loop
            if gathered is None:
                gathered = RunMetrics(list(loop.sim.rig.state_names))
                first = experiments[size]
            result = loop.run(seeds[start:start + size], scenario.duration_s, record=False)
            gathered.add(result)
    finally:
        for experiment in experiments.values():
            experiment.close()
    dt_s = first.loop.sim.dt_s
    return {"per_run": gathered.arrays(), "steps": int(round(scenario.duration_s / dt_s)),
            "dt_s": dt_s, "threads": first.loop.sim.physics.num_threads,
            "units": first.meta["units"], "meta": first.meta}


def _sharded_monte_carlo(scenario: Scenario, runs: int, batch_size: int | None,
                         progress: bool, num_threads: int | None, backend: str,
                         workers: int | None, address: str | None) -> dict[str, Any]:
    """:func:`monte_carlo` in contiguous shards of the runs on :func:`map_jobs` (each job
    holds one CPU: its physics runs on ``num_threads``, default 1, threads)."""
    workers = check_backend(backend, workers, address)
    scenario.check()
    start_time = time.perf_counter()
    seeds = run_seeds(scenario.seed, runs)
    shards = [part for part in np.array_split(seeds, min(workers, runs)) if len(part)]
    bar = tqdm(total=len(shards), desc=f"monte carlo ({backend})", unit="shard",
               disable=not progress)
    with bar:
        parts = map_jobs(_mc_shard, [(scenario, part, batch_size, num_threads or 1)
                                     for part in shards], backend=backend, workers=workers,
                         address=address, on_done=lambda _: bar.update())

    def joined(values: list) -> np.ndarray | None:
        return None if values[0] is None else np.concatenate(values)

    arrays = [p["per_run"] for p in parts]
    per_run = {"rmse": {k: np.concatenate([a["rmse"][k] for a in arrays])
                        for k in arrays[0]["rmse"]},
               "measurement_rmse": {k: np.concatenate([a["measurement_rmse"][k]
                                                       for a in arrays])
                                    for k in arrays[0]["measurement_rmse"]},
               "nees": joined([a["nees"] for a in arrays]),
               "T": joined([a["T"] for a in arrays]),
               "clipped": np.concatenate([a["clipped"] for a in arrays])}
    first = parts[0]
    wall_s = time.perf_counter() - start_time
    n_steps = first["steps"]
    return {
        "filter": scenario.describe()["estimator"],
        "runs": runs,
        "duration_s": n_steps * first["dt_s"],
        "steps_per_run": n_steps,
        "seed": scenario.seed,
        "seeds": seeds.tolist(),
        "seed_rule": "numpy.random.SeedSequence(seed).generate_state(runs)",
        "batch_size": min(len(shards[0]), int(batch_size or DEFAULT_BATCH_SIZE)),
        "threads": first["threads"],
        "backend": backend,
        "workers": workers,
        "wall_s": wall_s,
        "traj_steps_per_s": runs * n_steps / wall_s,
        **per_run_summary(per_run),
        "npz": None,
        "units": first["units"],
        "scenario": first["meta"]["scenario"],
        "meta": {k: v for k, v in first["meta"].items() if k != "scenario"},
    }


class RunMetrics:
    """Per-run metrics of a Monte-Carlo study, gathered batch by batch.

    Parameters
    ----------
    state_names : list of str
    """

    def __init__(self, state_names: list[str]):
        self.rmse: dict[str, list[np.ndarray]] = {k: [] for k in state_names}
        self.measurement_rmse: dict[str, list[np.ndarray]] = {}
        self.nees: list[np.ndarray | None] = []
        self.T: list[np.ndarray | None] = []
        self.clipped: list[np.ndarray] = []

    def add(self, result: Any) -> None:
        """The runs of one batch (a :meth:`ClosedLoop.run` result)."""
        for k, v in result.metrics.rmse().items():
            self.rmse[k].append(v)
        for k, v in result.metrics.measurement_rmse().items():
            self.measurement_rmse.setdefault(k, []).append(v)
        self.nees.append(result.metrics.nees_mean())
        self.T.append(result.metrics.noise_output_ratio())
        self.clipped.append(result.clipped_fraction)

    def extend(self, other: RunMetrics) -> None:
        """The runs of ``other`` after this one's."""
        for k, v in other.rmse.items():
            self.rmse[k].extend(v)
        for k, v in other.measurement_rmse.items():
            self.measurement_rmse.setdefault(k, []).extend(v)
        self.nees.extend(other.nees)
        self.T.extend(other.T)
        self.clipped.extend(other.clipped)

    def arrays(self) -> dict[str, Any]:
        """``rmse``/``measurement_rmse`` ``{name: (runs,)}``, ``nees``, ``T`` ((runs,) or
        None when the estimator has no covariance / the rig no ratio), ``clipped`` (runs,)."""
        def joined(parts: list) -> np.ndarray | None:
            return None if not parts or parts[0] is None else np.concatenate(parts)

        return {"rmse": {k: np.concatenate(v) for k, v in self.rmse.items()},
                "measurement_rmse": {k: np.concatenate(v)
                                     for k, v in self.measurement_rmse.items()},
                "nees": joined(self.nees), "T": joined(self.T),
                "clipped": np.concatenate(self.clipped)}


def per_run_summary(per_run: dict[str, Any]) -> dict[str, Any]:
    """The JSON summary of :meth:`RunMetrics.arrays`: mean and 5/95 % quantiles."""
    nees, T = per_run["nees"], per_run["T"]
    return {
        "rmse": {k: _stats(v) for k, v in per_run["rmse"].items()},
        "rmse_per_run": {k: v.tolist() for k, v in per_run["rmse"].items()},
        "measurement_rmse": {k: _stats(v) for k, v in per_run["measurement_rmse"].items()},
        "nees_mean": None if nees is None else float(np.mean(nees)),
        "nees": None if nees is None else _stats(nees),
        "T_final": None if T is None else _stats(T),
        "clipped_fraction_mean": float(np.mean(per_run["clipped"])),
    }


def _npz_extra(per_run: dict[str, Any], seeds: np.ndarray, n_steps: int, dt_s: float,
               state_names: list[str], measurement_names: list[str]) -> dict[str, np.ndarray]:
    """The per-run metrics and names stored beside the trajectories of ``--save-npz``."""
    extra: dict[str, np.ndarray] = {
        "t_s": np.arange(n_steps + 1) * dt_s, "seeds": seeds,
        "state_names": np.array(state_names), "measurement_names": np.array(measurement_names),
        "rmse": np.stack([per_run["rmse"][k] for k in state_names], axis=1),
        "clipped_fraction": per_run["clipped"]}
    if per_run["nees"] is not None:
        extra["nees_mean"] = per_run["nees"]
    if per_run["T"] is not None:
        extra["T_final"] = per_run["T"]
    return extra


# ---------------------------------------------------------------------------- sweeps
def grid_points(grid: dict[str, list]) -> list[dict[str, Any]]:
    """The Cartesian product of ``grid`` as a list of ``{name: value}`` points."""
    if not grid:
        raise ValueError("grid must name at least one parameter")
    for name, values in grid.items():
        if len(values) == 0:
            raise ValueError(f"grid[{name!r}] has no values")
    names = list(grid)
    return [dict(zip(names, combo, strict=True))
            for combo in itertools.product(*(grid[n] for n in names))]


#: Scenario fields a grid may sweep directly (numbers).
GRID_FIELDS = ("process_noise", "duration_s", "seed", "physics_dt_s", "frame_skip")
_GRID_GROUPS = {"params": "params", "estimator": "estimator_options",
                "design": "design_options", "sensors": "sensor_options"}


def check_grid_name(scenario: Scenario, name: str) -> None:
    """Raise ``ValueError`` listing the valid names unless ``name`` can be swept.

    Valid: :data:`GRID_FIELDS`, ``params.<field>`` (a parameter of the rig, scaled),
    ``design.<option>`` (the rig's design options), ``estimator.<option>`` and
    ``sensors.<option>`` (options of the estimator factory and of the sensor preset, checked
    when the point is built).
    """
    rig = resolve_rig(scenario.rig)
    params = sorted(f.name for f in dataclasses.fields(rig.params_type))
    prefix, dot, key = name.partition(".")
    if (not dot and name in GRID_FIELDS) or (dot and key and (
            (prefix == "params" and key in params)
            or (prefix == "design" and key in rig.scenario_options)
            or prefix in ("estimator", "sensors"))):
        return
    hint = f" (did you mean 'params.{name}'?)" if not dot and name in params else ""
    design = "|".join(sorted(rig.scenario_options)) or "none"
    raise ValueError(f"unknown grid name {name!r}{hint}; valid names: "
                     f"{', '.join(GRID_FIELDS)}, params.<{'|'.join(params)}>, "
                     f"design.<{design}>, estimator.<option>, sensors.<option>")


def point_scenario(scenario: Scenario, point: dict[str, Any]) -> Scenario:
    """The scenario of one grid point.

    Names: see :func:`check_grid_name`.
    """
    changes: dict[str, Any] = {}
    groups = _GRID_GROUPS
    for name, value in point.items():
        check_grid_name(scenario, name)
        if name in ("seed", "frame_skip") and float(value).is_integer():
            value = int(value)
        prefix, dot, key = name.partition(".")
        if dot:
            field_name = groups[prefix]
            merged = dict(changes.get(field_name, getattr(scenario, field_name)))
            merged[key] = value
            changes[field_name] = merged
        else:
            changes[name] = value
    return scenario.replace(**changes)


def _run_point(scenario: Scenario, runs: int) -> dict[str, Any]:
    # one physics thread per point: the pool supplies the parallelism
    return monte_carlo(scenario, runs, progress=False, num_threads=1)


def sweep(scenario: Scenario, grid: dict[str, list], *, runs: int = 100,
          backend: str = "local", workers: int | None = None, address: str | None = None,
          progress: bool = False) -> dict[str, Any]:
    """One Monte-Carlo study per grid point (common random numbers: one base seed).

    Parameters
    ----------
    scenario : Scenario
    grid : dict of str to list
        Swept names (see :func:`point_scenario`) and their values.
    runs : int
    backend : {"local", "ray"}
        Local processes or Ray tasks (a cluster at ``address`` or a local instance).
    address : str, optional
        Ray cluster (``host:port``, ``ray://host:port`` or ``"auto"``); unreachable within
        :data:`RAY_CONNECT_TIMEOUT_S` seconds: ``ConnectionError`` before any work.
    workers : int, optional
        Processes or local Ray CPUs (default ``os.cpu_count()``).
    progress : bool
        Show a progress bar (on stderr; default off).

    Returns
    -------
    dict
        ``backend``, ``workers``, ``wall_s``, ``scenario`` (the base scenario, as in
        :func:`monte_carlo`), ``grid``, ``runs``, ``units``, ``points`` (list of ``{"point",
        "result"}``).
    """
    workers = check_backend(backend, workers, address)
    points = grid_points(grid)
    scenarios = [point_scenario(scenario, p) for p in points]
    for s in scenarios:  # fail fast on a bad name or value, before any work starts
        build(s, 1, num_threads=1).close()
    start = time.perf_counter()
    bar = tqdm(total=len(points), desc=f"sweep ({backend})", unit="point", disable=not progress)
    with bar:
        results = map_jobs(_run_point, [(s, runs) for s in scenarios], backend=backend,
                           workers=workers, address=address, on_done=lambda _: bar.update())
    return {"backend": backend, "workers": workers, "wall_s": time.perf_counter() - start,
            "scenario": described(_with_defaults(scenario)), "grid": dict(grid), "runs": runs,
            "units": results[0]["units"],
            "points": [{"point": p, "result": r} for p, r in zip(points, results, strict=True)]}


def without_timings(result: dict[str, Any]) -> dict[str, Any]:
    """A sweep result with the timing keys removed (for comparing back-ends)."""
    return {
        **{k: v for k, v in result.items() if k not in ("wall_s", "backend", "workers")},
        "points": [{"point": p["point"],
                    "result": {k: v for k, v in p["result"].items() if k not in TIMING_KEYS}}
                   for p in result["points"]],
    }
