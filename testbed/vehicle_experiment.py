"""Assemble the vehicle roll experiment: rig + manoeuvre + sensors + estimator in the loop.

:func:`build_vehicle_roll` returns a :class:`testbed.experiment.Experiment` that
:func:`testbed.experiment.run_episode` runs unchanged::

    from testbed.experiment import run_episode
    from testbed.vehicle_experiment import build_vehicle_roll

    trajectory, summary = run_episode(build_vehicle_roll("kalman"), duration_s=10.0, seed=0)

Estimator design (physical model, nominal parameters)
-----------------------------------------------------
The filter's model is the PHYSICAL linearization about ``roll = 0``
(:func:`testbed.rigs.vehicle_roll.physical_model`, with ``g``; not the paper's ``A``)::

    x' = A x + B a_y + noise,   A = [[0, 1], [(m_s g h_cr - K_R)/I_xx, -C_R/I_xx]],
                                B = [[0], [m_s h_cr / I_xx]]

discretized at the control period with :meth:`filters.LinearSystem.discretize` (exact ZOH,
Van Loan for the noise). Its input ``u`` is the lateral acceleration actually applied over the
step: the environment reports it as ``info["action_applied"]`` (manoeuvre + perturbation,
after clipping), which :class:`~testbed.wrappers.FilterInLoop` passes to the filter, so no
``input_transform`` is needed. The policy returns a zero perturbation: the manoeuvre drives
``a_y``.

Process noise (continuous intensity ``Q``, only on the roll-rate row), two independent parts:

- Multiplicative damping noise. Over one control step ``T`` the damping torque
  ``-D_n w_k roll_rate`` is held, so the roll rate receives
  ``-(D_n T / I_xx) roll_rate w_k`` (the paper's ``C x_k w_k``), of variance
  ``(D_n T / I_xx)^2 roll_rate^2`` per step. The state-dependent ``roll_rate^2`` is replaced
  by a design value ``design_roll_rate^2``; as an intensity (variance / T):
  ``q_damp = D_n^2 T design_roll_rate^2 / I_xx^2`` (5.5e-8 rad^2/s^3 at 0.2 rad/s: the
  damping noise is tiny next to ``C_R``).
- Uncertainty of ``a_y``: a white error of standard deviation ``a_y_std`` per step (held over
  the step) changes the roll rate by ``(m_s h_cr T / I_xx) a_y_std``, so
  ``q_ay = (m_s h_cr / I_xx)^2 a_y_std^2 T`` (6.25e-6 rad^2/s^3 at 0.1 m/s^2). It also
  covers what the linear model leaves out: ``m_s h_cr a_y (1 - cos roll)`` and
  ``m_s g h_cr (sin roll - roll)``, below 5e-4 rad/s^2 (0.002 m/s^2 of ``a_y``) in the
  default double lane change (1.4 deg peak roll).

Measurement model: ``C``, ``R`` from the suite's ``linear_model`` (the accelerometer
linearized about ``roll = 0``: ``a_y + g roll``) and ``D`` from its ``feedthrough_matrix``
(the accelerometer's ``a_y``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from filters import DiscreteLinearSystem, KalmanBucyFilter, KalmanFilter, LinearSystem
from testbed.envs.vehicle_roll import VehicleRollEnv
from testbed.experiment import Experiment
from testbed.rigs.vehicle_roll import VehicleRollParams, paper_model, physical_model
from testbed.wrappers import FilterInLoop

FILTERS = ("kalman", "kalman-bucy", "lmi-hinf")


def process_noise_intensity(params: VehicleRollParams, dt_s: float, a_y_std: float,
                            design_roll_rate: float) -> np.ndarray:
    """Process-noise intensity ``Q`` of the filter model (see the module docstring).

    Parameters
    ----------
    params : VehicleRollParams
        The designer's (nominal) parameters.
    dt_s : float
        Control period ``T``, s.
    a_y_std : float
        Standard deviation of the ``a_y`` error per step, m/s^2.
    design_roll_rate : float
        Roll rate standing in for ``roll_rate`` in the damping noise, rad/s.

    Returns
    -------
    ndarray, shape (2, 2)
        ``diag(0, q_damp + q_ay)``, rad^2/s^3 on the roll-rate row.
    """
    inertia = params.roll_inertia
    q_damp = params.damping_noise**2 * dt_s * design_roll_rate**2 / inertia**2
    q_ay = (params.sprung_mass_kg * params.com_height_m / inertia) ** 2 * a_y_std**2 * dt_s
    return np.diag([0.0, q_damp + q_ay])


def build_vehicle_roll(filter_name: str = "kalman", *,
                       manoeuvre: str | None = "double-lane-change",
                       manoeuvre_params: dict[str, Any] | None = None,
                       sensors: str = "imu", sensor_kwargs: dict[str, Any] | None = None,
                       params: dict[str, float] | None = None, a_y_std: float = 0.1,
                       design_roll_rate: float = 0.2, P0: np.ndarray | None = None,
                       physics_dt_s: float = 0.001, frame_skip: int = 10,
                       kalman_bucy_substeps: int | str = "auto") -> Experiment:
    """The vehicle roll rig driven by a manoeuvre, with an estimator on the physical model.

    Parameters
    ----------
    filter_name : {"kalman", "kalman-bucy"}
    manoeuvre : str or None
        Name in :data:`testbed.manoeuvres.MANOEUVRES` (None: ``a_y`` stays 0 since the
        policy's action is zero).
    manoeuvre_params : dict, optional
        Parameters of the manoeuvre.
    sensors : {"imu", "paper"}
    sensor_kwargs : dict, optional
        Passed to the suite (e.g. ``{"roll_sensor": True}``).
    params : dict, optional
        Scale factors of the simulated rig's parameters (the filter keeps the nominal ones:
        model mismatch).
    a_y_std : float
        Design standard deviation of the ``a_y`` error per step, m/s^2.
    design_roll_rate : float
        Design roll rate for the damping-noise term, rad/s.
    P0 : ndarray, shape (2, 2), optional
        Prior covariance (default ``diag((0.5 deg)^2, (1 deg/s)^2)``); the prior mean is 0.
    physics_dt_s, frame_skip : float, int
        MuJoCo step and control period = ``physics_dt_s * frame_skip``.
    kalman_bucy_substeps : int or "auto"
        RK4 substeps per sample for ``kalman-bucy``.

    Returns
    -------
    Experiment
        ``env`` (a :class:`FilterInLoop` around :class:`VehicleRollEnv`), a zero policy and
        ``meta`` for the JSON output.

    Raises
    ------
    ValueError
        Unknown filter, manoeuvre or sensor suite names (listing the valid ones), bad
        design values.
    """
    if filter_name not in FILTERS:
        raise ValueError(f"unknown filter {filter_name!r}; expected one of {FILTERS}")
    for key, value in (("a_y_std", a_y_std), ("design_roll_rate", design_roll_rate)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{key} must be finite and >= 0, got {value}")
    env = VehicleRollEnv(physics_dt_s=physics_dt_s, frame_skip=frame_skip, sensors=sensors,
                         sensor_kwargs=sensor_kwargs, manoeuvre=manoeuvre,
                         manoeuvre_params=manoeuvre_params, params=params)
    nominal = VehicleRollParams()  # what the designer knows: never the scaled truth
    dt_s = env.dt_s
    A, B = physical_model(nominal)
    C, R_sample = env.sensors.linear_model(dt_s)
    D = env.sensors.feedthrough_matrix()
    Q = process_noise_intensity(nominal, dt_s, a_y_std, design_roll_rate)
    plant = LinearSystem(A=A, B=B, C=C, Q=Q, R=R_sample * dt_s, D=D)
    x0 = np.zeros(2)
    P0 = np.diag(np.deg2rad([0.5, 1.0]) ** 2) if P0 is None else np.asarray(P0, dtype=float)
    design_meta: dict[str, Any] = {}
    if filter_name == "kalman":
        discrete: DiscreteLinearSystem = plant.discretize(dt_s)
        estimator = KalmanFilter(discrete, x0, P0)
    elif filter_name == "kalman-bucy":
        estimator = KalmanBucyFilter(plant, x0, P0, dt_s=dt_s, substeps=kalman_bucy_substeps)
    else:  # seed-002 Theorem 4 design on the physical model; the known a_y is its input
        from testbed.scenarios.seed002 import vehicle_lmi_estimator

        estimator, design_meta = vehicle_lmi_estimator(env.sensors, dt_s, params=nominal,
                                                       a_y_std=a_y_std)
    wrapped = FilterInLoop(env, estimator, measurement_index=range(C.shape[0]),
                           output_matrix=paper_model().M)

    zero = np.zeros(1)

    def policy(x_hat: np.ndarray) -> np.ndarray:
        return zero

    def reset_policy() -> None:
        return None

    meta = {
        "rig": "vehicle-roll",
        "filter": filter_name,
        "controller": "manoeuvre",
        "manoeuvre": manoeuvre,
        "manoeuvre_params": dict(manoeuvre_params or {}),
        "sensors": sensors,
        "sensor_kwargs": dict(sensor_kwargs or {}),
        "params": dict(params or {}),
        "a_y_std": a_y_std,
        "design_roll_rate": design_roll_rate,
        "physics_dt_s": physics_dt_s,
        "control_dt_s": dt_s,
    }
    if design_meta:
        meta["lmi_design"] = design_meta
    return Experiment(wrapped, policy, reset_policy, meta)
