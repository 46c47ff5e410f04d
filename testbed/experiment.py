"""Assemble and run an experiment: rig environment + estimator in the loop + controller.

:func:`build_helicopter` wires the pieces the way the CLI's ``testbed run helicopter`` does;
:func:`run_episode` steps any :class:`~testbed.wrappers.FilterInLoop` with a policy and
returns the :class:`~testbed.trajectory.Trajectory` and the metrics summary.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from tqdm import tqdm

from filters import (
    DiscreteLinearSystem,
    KalmanBucyFilter,
    KalmanFilter,
    LinearSystem,
    MeanSquareHInfFilter,
)
from testbed.control import LQRTracker
from testbed.disturbances import Disturbance, seed000_disturbance
from testbed.envs.helicopter import Helicopter2DOFEnv
from testbed.rigs.helicopter import (
    PITCH_LIMIT_RAD,
    HelicopterParams,
    gravity_voltage,
    paper_model,
)
from testbed.scenarios.seed000 import MsHinfHelicopterScenario
from testbed.sensors import DisturbanceChannel, make_sensor_suite
from testbed.trajectory import Trajectory
from testbed.wrappers import FilterInLoop

FILTERS = ("kalman", "kalman-bucy", "ms-hinf")
CONTROLLERS = ("lqr", "open-loop")
DISTURBANCES = ("none", "seed000")


@dataclass
class Experiment:
    """A ready-to-run closed loop.

    Attributes
    ----------
    env : FilterInLoop
        The rig environment with the estimator in the loop.
    policy : callable ``x_hat (n,) -> action (k,)``
    reset_policy : callable
        Called at every reset (clears integrators and clocks).
    meta : dict
        Description written into JSON outputs.
    """

    env: FilterInLoop
    policy: Callable[[np.ndarray], np.ndarray]
    reset_policy: Callable[[], None]
    meta: dict[str, Any]


def build_helicopter(filter_name: str = "kalman", controller: str = "lqr", *,
                     sensors: str = "encoders", sensor_kwargs: dict | None = None,
                     disturbance: str = "none", process_noise_scale: float = 0.0,
                     process_noise_floor: float = 0.05, params: dict[str, float] | None = None,
                     physics_dt_s: float = 0.001, frame_skip: int = 10,
                     kalman_bucy_substeps: int | str = "auto",
                     gamma: float | None = None) -> Experiment:
    """The helicopter with an estimator designed on seed-000's linear model and an LQR.

    The estimator's model is the paper's ``(A, B)`` (the rig is its nonlinear truth); its
    input is the applied voltage minus the gravity-compensating voltage at the estimated
    pitch (nominal parameters), so the linear model sees only the unbalanced torque. Its
    process noise is the disturbance's ``b b^T`` plus ``process_noise_floor`` on the
    acceleration rows (unmodelled dynamics); its measurement noise is the sensor suite's.

    Parameters
    ----------
    filter_name : {"kalman", "kalman-bucy", "ms-hinf"}
        ``ms-hinf``: seed-000's mean-square H-infinity filter, designed on the paper's model
        with its ``G``, ``H``, ``L``, ``R`` and ``gamma = 1.1``; the sensors get the
        deterministic channel ``y2 = C2 x + H w`` (requires ``disturbance="seed000"``).
    controller : {"lqr", "open-loop"}
        ``open-loop`` applies the level-pitch gravity voltage only.
    sensors : str
        Sensor suite name (see :func:`testbed.sensors.make_sensor_suite`).
    sensor_kwargs : dict, optional
    disturbance : {"none", "seed000"}
        ``seed000``: the paper's ``G w(t)``.
    process_noise_scale : float
        Multiplies the paper's white-noise matrix ``b`` (0: no process noise).
    process_noise_floor : float
        Extra process-noise intensity (rad^2/s^3) on each acceleration row of the filter.
    params : dict, optional
        Scale factors of the simulated rig's parameters (the filter and controller keep the
        nominal ones: model mismatch).
    physics_dt_s, frame_skip : float, int
        MuJoCo step and control period = ``physics_dt_s * frame_skip``.
    gamma : float, optional
        Attenuation level of ``ms-hinf`` (default: the paper's 1.1).
    kalman_bucy_substeps : int or "auto"
        RK4 substeps per sample for ``kalman-bucy`` (``"auto"``: enough for stability at
        the current covariance; quantized encoders make the Riccati equation stiff).

    Returns
    -------
    Experiment
    """
    if filter_name not in FILTERS:
        raise ValueError(f"unknown filter {filter_name!r}; expected one of {FILTERS}")
    if controller not in CONTROLLERS:
        raise ValueError(f"unknown controller {controller!r}; expected one of {CONTROLLERS}")
    if disturbance not in DISTURBANCES:
        raise ValueError(f"unknown disturbance {disturbance!r}; expected one of {DISTURBANCES}")
    if not (np.isfinite(process_noise_floor) and process_noise_floor >= 0):
        raise ValueError(f"process_noise_floor must be finite and >= 0, got {process_noise_floor}")
    if gamma is not None and filter_name != "ms-hinf":
        raise ValueError(f"gamma applies to the 'ms-hinf' filter only, not {filter_name!r}")
    if filter_name == "ms-hinf" and disturbance != "seed000":
        raise ValueError("filter 'ms-hinf' needs the deterministic disturbance channel "
                         "y2 = C2 x + H w: use disturbance='seed000'")
    dist: Disturbance | None = None
    if disturbance == "seed000" or process_noise_scale > 0:
        dist = seed000_disturbance(noise_scale=process_noise_scale,
                                   deterministic=disturbance == "seed000")
    dt_s = physics_dt_s * frame_skip
    suite = make_sensor_suite(sensors, dt_s, **(sensor_kwargs or {}))
    model = paper_model()
    if filter_name == "ms-hinf":
        suite = DisturbanceChannel(suite, model.C2, model.H)
    env = Helicopter2DOFEnv(physics_dt_s=physics_dt_s, frame_skip=frame_skip, sensors=suite,
                            disturbance=dist, params=params)
    nominal = HelicopterParams()  # what the designer knows: never the scaled truth

    C, R_sample = env.sensors.linear_model(dt_s)
    Q = np.zeros((4, 4))
    Q[2:, 2:] += process_noise_floor * np.eye(2)
    if env.disturbance.intensity is not None:
        Q += env.disturbance.intensity
    plant = LinearSystem(A=model.A, B=model.B, C=C, Q=Q, R=R_sample * dt_s)
    x0 = np.array([-PITCH_LIMIT_RAD, 0.0, 0.0, 0.0])
    P0 = np.diag([1e-4, 1e-4, 1e-4, 1e-4])
    measurement_index = range(C.shape[0])
    if filter_name == "kalman":
        discrete: DiscreteLinearSystem = plant.discretize(dt_s)
        estimator = KalmanFilter(discrete, x0, P0)
    elif filter_name == "kalman-bucy":
        estimator = KalmanBucyFilter(plant, x0, P0, dt_s=dt_s, substeps=kalman_bucy_substeps)
    else:
        paper = MsHinfHelicopterScenario()
        gamma = paper.gamma if gamma is None else gamma
        estimator = MeanSquareHInfFilter(model.A, model.B, C, plant.R, model.C2, model.H,
                                         model.G, plant.Q, model.L, gamma, paper.R, x0,
                                         P0, dt_s, substeps="auto", noise_intensities=True)
        measurement_index = range(suite.dim)

    def unbalanced_input(u: np.ndarray, x_hat: np.ndarray) -> np.ndarray:
        return u - gravity_voltage(nominal, x_hat[0])

    wrapped = FilterInLoop(env, estimator, input_transform=unbalanced_input,
                           measurement_index=measurement_index)
    if controller == "lqr":
        lqr = LQRTracker(model.A, model.B, dt_s,
                         feedforward=lambda pitch: gravity_voltage(nominal, pitch),
                         setpoint=env.setpoint)
        policy, reset_policy = lqr, lqr.reset
    else:
        hover = gravity_voltage(nominal, 0.0)

        def policy(x_hat: np.ndarray) -> np.ndarray:
            return hover

        def reset_policy() -> None:
            return None

    meta = {
        "rig": "helicopter",
        "filter": filter_name,
        "controller": controller,
        "sensors": sensors,
        "disturbance": disturbance,
        "process_noise_scale": process_noise_scale,
        "gamma": gamma,
        "params": dict(params or {}),
        "physics_dt_s": physics_dt_s,
        "control_dt_s": dt_s,
    }
    return Experiment(wrapped, policy, reset_policy, meta)


def run_episode(experiment: Experiment, duration_s: float, seed: int | None = None,
                options: dict[str, Any] | None = None, *, record: bool = True,
                progress: bool | None = None) -> tuple[Trajectory | None, dict[str, Any]]:
    """Run one closed-loop episode.

    Parameters
    ----------
    experiment : Experiment
    duration_s : float
        Simulated time; rounded to whole control periods.
    seed : int, optional
        Seed of the environment's random generator (noise, disturbances).
    options : dict, optional
        Reset options (``x0``, ``params``, ``estimator``...).
    record : bool
        Keep the full :class:`Trajectory` (with body poses for the 3D view).
    progress : bool, optional
        Show a progress bar; default: only for runs longer than a few seconds of wall time
        (tqdm's ``delay``).

    Returns
    -------
    trajectory : Trajectory or None
    summary : dict
        ``steps``, ``rmse``, ``measurement_rmse``, ``nees_mean``, ``T_final``,
        ``clipped_fraction``.
    """
    env = experiment.env
    inner = env.unwrapped
    dt_s = float(inner.dt_s)
    if not (np.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"duration_s must be a positive finite time in s, got {duration_s}")
    n_steps = int(round(duration_s / dt_s))
    experiment.reset_policy()
    x_hat, info = env.reset(seed=seed, options=options)

    rows: dict[str, list] = {k: [] for k in ("t", "state", "est", "cov", "meas", "act", "ref",
                                             "pos", "quat")}

    def keep(info: dict[str, Any]) -> None:
        rows["t"].append(info["t"])
        rows["state"].append(info["state"])
        rows["est"].append(info["estimate"])
        rows["cov"].append(info["covariance"])
        rows["meas"].append(info["measurement"])
        rows["act"].append(info["action_applied"])
        rows["ref"].append(info["setpoint"])
        pos, quat = inner.body_poses()
        rows["pos"].append(pos)
        rows["quat"].append(quat)

    if record:
        keep(info)
    clipped_steps = 0
    show = True if progress else None if progress is None else False
    bar = tqdm(total=n_steps, desc=experiment.meta.get("rig", "run"), unit="step",
               disable=show is False, delay=0 if progress else 2.0, leave=False)
    with bar:
        for _ in range(n_steps):
            action = experiment.policy(x_hat)
            x_hat, _, terminated, truncated, info = env.step(action)
            clipped_steps += bool(np.any(info["action_clipped"]))
            if record:
                keep(info)
            bar.update()
            if terminated:
                break

    summary = env.metrics().summary()
    summary["clipped_fraction"] = clipped_steps / max(summary["steps"], 1)
    if not record:
        return None, summary
    has_cov = all(c is not None for c in rows["cov"])
    traj = Trajectory(
        t_s=np.asarray(rows["t"]),
        state=np.asarray(rows["state"]),
        state_names=list(inner.state_names),
        measurement=np.asarray(rows["meas"]),
        measurement_names=list(inner.sensors.names),
        measured_state_index=list(inner.sensors.measured_state_index),
        action=np.asarray(rows["act"]),
        action_names=list(inner.action_names),
        estimate=np.asarray(rows["est"]),
        covariance=np.asarray(rows["cov"]) if has_cov else None,
        setpoint=np.asarray(rows["ref"]),
        body_pos=np.asarray(rows["pos"]),
        body_quat_wxyz=np.asarray(rows["quat"]),
        meta=dict(experiment.meta, seed=seed, duration_s=n_steps * dt_s),
    )
    return traj, summary
