"""The vehicle roll rig: the :class:`~testbed.rigs.base.Rig` of ``vehicle_roll.xml``.

Parameters, Zhang et al.'s model and the physical one are in
:mod:`testbed.rigs.vehicle_roll.model`, the channels in :mod:`testbed.rigs.vehicle_roll.sensors`,
the LMI design system in :mod:`testbed.rigs.vehicle_roll.stochastic_system`.
"""

from __future__ import annotations

import functools

import mujoco
import numpy as np

from testbed.rigs.base import GRAVITY_M_S2, Rig
from testbed.rigs.vehicle_roll.model import (
    A_Y_LIMIT_M_S2,
    ACTION_NAMES,
    PAPER_PERIOD_S,
    STATE_NAMES,
    VehicleRollParams,
    paper_model,
    physical_model,
)

#: Roll angle beyond which the vehicle has rolled over (episode terminates), rad.
ROLLOVER_RAD = float(np.pi / 2)
SENSOR_PRESETS = ("imu", "paper", "hardware")
#: Where the estimator's input ``a_y`` comes from (see :meth:`VehicleRollRig.design_model`).
A_Y_SOURCES = ("auto", "measured", "oracle")
#: Initial-state spread of the default scenario: roll (rad) and roll-rate (rad/s) standard
#: deviations, the design prior's (0.5 deg, 1 deg/s).
X0_STD = (float(np.deg2rad(0.5)), float(np.deg2rad(1.0)))
#: Ambient disturbance of the default scenario (crosswind gusts): white-noise roll
#: acceleration, rad/s^(3/2). From a lateral gust force of 250 N rms acting 0.6 m above the
#: roll axis (0.088 rad/s^2 rms) with a 0.1 s correlation time: intensity
#: 2 sigma^2 tau_c = 1.6e-3 rad^2/s^3, b = 0.04 (assumption, docs/vehicle_roll.md).
AMBIENT_NOISE_RAD_S15 = 0.04
#: Matched ``hardware`` design: a typical lateral acceleration for the sensitivity errors
#: of the accelerometer and the speed in ``R``, m/s^2 (the double lane change's rms at
#: 80 km/h is about 2 m/s^2; assumption).
DESIGN_A_Y_M_S2 = 2.0


def process_noise_intensity(params: VehicleRollParams, dt_s: float, a_y_std: float,
                            design_roll_rate: float) -> np.ndarray:
    """Process-noise intensity ``Q`` of the design model, shape (2, 2), rad^2/s^3.

    Two independent parts on the roll-rate row:

    - the multiplicative damping noise: over one step ``T`` the torque ``-D_n w_k roll_rate``
      changes the roll rate by ``-(D_n T / I_xx) roll_rate w_k``; with a design value for
      ``roll_rate`` its intensity is ``D_n^2 T design_roll_rate^2 / I_xx^2``;
    - the ``a_y`` error (std ``a_y_std`` per step, held): ``(m_s h_cr / I_xx)^2 a_y_std^2 T``.
      It also covers what the linear model leaves out (``1 - cos roll``, ``sin roll - roll``).
    """
    inertia = params.roll_inertia
    q_damp = params.damping_noise**2 * dt_s * design_roll_rate**2 / inertia**2
    q_ay = (params.sprung_mass_kg * params.com_height_m / inertia) ** 2 * a_y_std**2 * dt_s
    return np.diag([0.0, q_damp + q_ay])


def _zhang_decay(t_s: float) -> np.ndarray:
    """Zhang et al.'s ``v = 0.01 * 0.9^(t / T)`` as a measurement disturbance, shape (1,)."""
    return np.array([0.01 * 0.9 ** (max(t_s, 0.0) / PAPER_PERIOD_S)])


class VehicleRollRig(Rig):
    """The sprung mass of a light commercial vehicle rolling about its roll axis.

    Action: the lateral acceleration ``a_y`` (m/s^2, + left), applied as the d'Alembert force
    ``-m_s a_y`` at the centre of mass (``xfrc_applied``); clipped at +-8 m/s^2. With a
    manoeuvre (``reset(options={"manoeuvre": name})``) the action is added to the profile.
    Step noise: the damping is ``C_R + D_n w_k`` over each control step (``w_k ~ N(0, 1)``).
    The episode terminates past 90 deg of roll.
    """

    name = "vehicle-roll"
    sensor_presets = SENSOR_PRESETS
    xml_path = "models/vehicle_roll.xml"
    params_type = VehicleRollParams
    joints = ("roll",)
    state_names = STATE_NAMES
    state_units = ("rad", "rad/s")
    action_names = ACTION_NAMES
    action_units = ("m/s^2",)
    action_low = (-A_Y_LIMIT_M_S2,)
    action_high = (A_Y_LIMIT_M_S2,)
    tracked_states = ("roll",)
    step_noise_dim = 1
    disturbance_signals = {"zhang-decay": lambda: (None, _zhang_decay)}
    scenario_options = {"a_y_std": 0.1, "design_roll_rate": 0.2, "a_y_source": "auto",
                        "process_noise_model": "auto"}
    scenario_defaults = {"controller": "open-loop", "manoeuvre": "double-lane-change"}
    #: +-20 % on the suspension's roll stiffness and damping (worn dampers, spring
    #: tolerances, temperature): the least known parameters of the roll model. Mass and
    #: centre-of-mass height (load) also scale the input ``m_s h_cr / I_xx``, which a
    #: norm-bounded ``Delta A`` does not cover, so they are not in the range.
    mismatch_range = {"roll_stiffness": 0.2, "roll_damping": 0.2}
    #: What a recording identifies (``testbed identify``), bounds as factors of nominal. The
    #: roll dynamics divided by ``I_xx`` see ``m_s h_cr / I_xx``, ``K_R / I_xx`` and
    #: ``C_R / I_xx`` only: the mass and the height enter as their product, and scaling
    #: ``m_s h_cr``, ``I_xx``, ``K_R`` and ``C_R`` together changes nothing. Weigh the
    #: vehicle (``sprung_mass_kg``) and free at most three of the other four, or the
    #: identifiability check holds the undetermined ones at nominal.
    identifiable = {"sprung_mass_kg": (0.5, 2.0), "com_height_m": (0.4, 2.5),
                    "roll_inertia": (0.4, 2.5), "roll_stiffness": (0.2, 5.0),
                    "roll_damping": (0.2, 5.0)}
    #: ``hardware`` changes the default sensors only (the input is a physical acceleration,
    #: there is no actuator): the ``hardware`` preset with offsets, sensitivity errors and
    #: CAN latency.
    profiles = ("paper", "hardware")
    render_camera = "rear"
    #: Upside down (the episode already ended at 90 deg); the saturated lateral acceleration
    #: rolls the body at about 0.06 rad/s and falling over from 86 deg at 1.4 rad/s, so
    #: 50 rad/s is far outside anything the rig does.
    state_envelope = (np.pi, 50.0)

    def __init__(self, params: VehicleRollParams | None = None, physics_dt_s: float = 0.001,
                 profile: str = "paper", options: dict | None = None):
        super().__init__(params, physics_dt_s, profile, options)
        self.model.opt.gravity[:] = [0.0, 0.0, -GRAVITY_M_S2]
        self._body_id = self.body_id("sprung_mass")
        self._nbody, self._damping_dof = self.model.nbody, int(self.dof_adr[0])
        from testbed.rigs.vehicle_roll.manoeuvres import MANOEUVRES

        self.manoeuvres = MANOEUVRES

    def apply_params(self, model: mujoco.MjModel, params: VehicleRollParams) -> None:
        """Mass, inertia, centre of mass, stiffness and damping from ``params``."""
        b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "sprung_mass")
        joint = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "roll")
        model.body_mass[b] = params.sprung_mass_kg
        model.body_ipos[b] = [0.0, 0.0, params.com_height_m]
        inertia = model.body_inertia[b].copy()
        inertia[0] = params.inertia_com
        model.body_inertia[b] = inertia
        model.jnt_stiffness[joint] = params.roll_stiffness
        model.qpos_spring[self.qpos_adr[0]] = 0.0
        model.dof_damping[self.dof_adr[0]] = params.roll_damping

    def member_constants(self, params: VehicleRollParams) -> np.ndarray:
        """``[m_s, C_R, D_n]`` for :meth:`actuation` and :meth:`apply_step_noise`."""
        return np.array([params.sprung_mass_kg, params.roll_damping, params.damping_noise])

    def actuation(self, u: np.ndarray, constants: np.ndarray) -> dict[str, np.ndarray]:
        """``xfrc_applied[sprung_mass] = [0, -m_s a_y, 0, 0, 0, 0]`` for each member."""
        xfrc = np.zeros((len(u), self._nbody, 6))
        np.multiply(-constants[:, 0], u[:, 0], out=xfrc[:, self._body_id, 1])
        return {"xfrc": xfrc}

    def physics_inputs(self, u: np.ndarray, constants: np.ndarray) -> dict[str, np.ndarray]:
        """:meth:`actuation` as gravity: ``opt.gravity = [0, -a_y, -g]`` for each member.

        The sprung mass is the model's only massive body, so the uniform field ``-a_y``
        along world y puts exactly the force ``-m_s a_y`` at its centre of mass, as the
        ``xfrc_applied`` of :meth:`actuation` does (the same torque ``m_s h_cr a_y
        cos(roll)``; equal up to rounding, tested), without ``xfrc_applied``'s Jacobian
        every physics step (about 5 % of a step of this one-hinge model)."""
        gravity = np.zeros((len(u), 3))
        np.negative(u[:, 0], out=gravity[:, 1])
        gravity[:, 2] = -GRAVITY_M_S2
        return {"gravity": gravity}

    def step_noise_model(self, constants: np.ndarray,
                         xi: np.ndarray) -> dict[str, tuple[int, np.ndarray]]:
        """Damping ``C_R + D_n w_k`` for the next step, shape (k,)."""
        damping = np.multiply(constants[:, 2], xi[:, 0])
        np.add(constants[:, 1], damping, out=damping)  # (the sum into the new product)
        return {"dof_damping": (self._damping_dof, damping)}

    x0_draws = 2

    def random_x0(self, xi: np.ndarray) -> np.ndarray:
        """``roll ~ N(0, (0.5 deg)^2)``, ``roll_rate ~ N(0, (1 deg/s)^2)`` (the design
        prior): shape (k, 2) from ``xi`` (k, 2)."""
        return np.asarray(xi, float) * np.array(X0_STD)

    def ambient_noise_matrix(self) -> np.ndarray:
        """Crosswind gusts: ``b = [[0], [0.04]]`` (roll acceleration)."""
        return np.array([[0.0], [AMBIENT_NOISE_RAD_S15]])

    def validate_x0(self, x0) -> np.ndarray:
        """Shape (2,), finite, roll short of rollover."""
        x = super().validate_x0(x0)
        if abs(x[0]) >= ROLLOVER_RAD:
            raise ValueError(f"options['x0'] roll {x[0]:.4f} rad is beyond rollover "
                             f"(+-{ROLLOVER_RAD:.4f} rad)")
        return x

    def terminated(self, x: np.ndarray) -> np.ndarray:
        """Rolled over: ``|roll| > 90 deg``."""
        return np.abs(x[:, 0]) > ROLLOVER_RAD

    def terminated_row(self, x: list[float]) -> bool:
        """:meth:`terminated` of one state on Python floats."""
        return abs(x[0]) > ROLLOVER_RAD

    def sensors(self, preset: str | None = None, *, dt_s: float = 0.01, **options):
        """``imu`` (gyro, lateral accelerometer, optional roll sensor), ``hardware`` (the
        same with offsets, sensitivity errors and latency) or ``paper`` channels.

        Default: ``imu`` in the ``paper`` profile, ``hardware`` in the ``hardware`` profile.
        See :func:`testbed.rigs.vehicle_roll.sensors.imu`,
        :func:`testbed.rigs.vehicle_roll.sensors.hardware` and
        :class:`testbed.rigs.vehicle_roll.sensors.PaperRollChannel` for the options.
        """
        from testbed.rigs.vehicle_roll import sensors

        preset = preset or ("imu" if self.profile == "paper" else "hardware")
        if preset not in SENSOR_PRESETS:
            raise ValueError(f"unknown vehicle-roll sensor preset {preset!r}; expected one of "
                             f"{SENSOR_PRESETS}")
        try:
            if preset == "imu":
                return sensors.imu(dt_s=dt_s, **options)
            if preset == "hardware":
                return sensors.hardware(dt_s=dt_s, **options)
            return sensors.PaperRollChannel(**options)
        except TypeError as err:
            raise ValueError(f"bad option for sensor preset {preset!r}: {err}") from None

    @classmethod
    def cubic_model(cls, design):
        """Third-order expansion of the gravity torque ``m_s g h_cr sin(roll)`` (nominal).

        ``sin(roll) ~ roll - roll^3 / 6`` about ``roll = 0`` (the design model's point): the
        design's linear ``A`` (which holds ``m_s g h_cr roll / I_xx``) plus
        ``roll_rate' += -(m_s g h_cr / (6 I_xx)) roll^3`` (-1.60 rad^-2 s^-2 nominal). The
        input term ``m_s h_cr a_y cos(roll) / I_xx`` is bilinear in ``a_y`` and ``roll``
        (not a polynomial of the state with a constant input matrix): it stays linear,
        ``cos(roll) ~ 1`` (0.2 % of the input torque at 4 deg). The sensors stay linear
        (the design's ``C``: the accelerometer's ``g sin(roll)`` is ``g roll``).

        Returns
        -------
        testbed.design.cubic.CubicExpansion
        """
        from testbed.design.cubic import CubicExpansion

        nominal = VehicleRollParams()
        a3 = np.zeros((2, 2, 2, 2))
        a3[1, 0, 0, 0] = -nominal.gravity_stiffness / (6.0 * nominal.roll_inertia)
        return CubicExpansion(
            a0=np.zeros(2), a1=np.array(design.continuous.A, float), a2=None, a3=a3,
            E=np.array(design.continuous.B, float),
            description="gravity torque m_s g h_cr sin(roll) / I_xx to third order about "
                        "roll = 0; a_y cos(roll) kept linear")

    def design_model(self, sensors, dt_s: float, disturbance=None, *, a_y_std: float = 0.1,
                     design_roll_rate: float = 0.2, a_y_source: str = "auto",
                     process_noise_model: str = "auto"):
        """The physical linearization (with ``g``), nominal parameters, exact ZOH.

        ``Q`` from :func:`process_noise_intensity`; prior ``0``,
        ``diag((0.5 deg)^2, (1 deg/s)^2)``. ``extras["lmi_system"]`` holds the system of
        the LMI design (Zhang et al.'s Theorem 4 with the multiplicative damping noise).

        Parameters
        ----------
        a_y_source : {"auto", "measured", "oracle"}
            The estimator's input ``a_y``: ``measured`` = speed times yaw rate of the
            sensors' tapped input channels (:func:`~testbed.rigs.vehicle_roll.sensors.
            measured_lateral_acceleration`, the ``imu`` and ``hardware`` presets have them);
            ``oracle`` = the applied ``a_y`` exactly; ``auto`` = measured when the sensors
            have the channels, else oracle. ``extras["a_y_source"]`` records the choice.
        process_noise_model : {"auto", "held", "continuous"}
            How ``Q`` is discretized (:func:`testbed.design.held_noise.uses_held_noise`).
        """
        from testbed.design import build_design
        from testbed.design.held_noise import uses_held_noise
        from testbed.rigs.vehicle_roll.sensors import PaperRollChannel, find_tap

        for key, value in (("a_y_std", a_y_std), ("design_roll_rate", design_roll_rate)):
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"{key} must be finite and >= 0, got {value}")
        if a_y_source not in A_Y_SOURCES:
            raise ValueError(f"a_y_source must be one of {A_Y_SOURCES}, got {a_y_source!r}")
        tap = find_tap(sensors)
        if a_y_source == "measured" and tap is None:
            raise ValueError("a_y_source 'measured' needs the speed and yaw_rate channels "
                             "(sensor presets 'imu' or 'hardware' with speed_yaw_rate=True); "
                             "use a_y_source 'oracle' for the exact a_y")
        source = "measured" if (a_y_source != "oracle" and tap is not None) else "oracle"
        from testbed.rigs.vehicle_roll.sensors import measured_a_y_variance
        transform = None
        if source == "measured":
            transform = functools.partial(_measured_a_y_input, tap)  # pickles
        nominal = self.params  # the designer's (nominal or a twin's), never the truth
        A, B = physical_model(nominal)
        Q = process_noise_intensity(nominal, dt_s, a_y_std, design_roll_rate)
        if disturbance is not None and disturbance.intensity is not None:
            Q = Q + disturbance.intensity
        input_noise_cov = measured_a_y_variance(tap) if transform else None
        design = build_design(self, sensors, dt_s, A, B, Q, np.zeros(2),
                              np.diag(np.deg2rad([0.5, 1.0]) ** 2),
                              output_matrix=paper_model().M, input_transform=transform,
                              input_noise_cov=input_noise_cov,
                              held_noise=uses_held_noise(process_noise_model,
                                                         self.profile == "paper"))
        design.extras["input_noise_cov"] = input_noise_cov
        from testbed.rigs.vehicle_roll.stochastic_system import vehicle_lmi_system

        design.extras.update(paper_model=paper_model(), a_y_std=a_y_std, a_y_source=source,
                             lmi_system=vehicle_lmi_system,
                             lmi_amplitude=(sensors.lmi_amplitude
                                            if isinstance(sensors, PaperRollChannel) else None))
        if self.profile == "paper":
            return design
        return self._matched_design(design, sensors, dt_s, A, B, Q, tap if transform else None,
                                    design_roll_rate, a_y_std)

    def _matched_design(self, paper, sensors, dt_s: float, A: np.ndarray, B: np.ndarray,
                        Q: np.ndarray, tap, design_roll_rate: float, a_y_std: float):
        """The ``hardware`` profile's design: the paper design plus what the sensors declare.

        State ``[roll, roll_rate, (bias_a_y), biases..., delays...]``
        (:func:`testbed.design.build_matched_design`):

        - the measured input's bias ``bias_a_y = v b_r`` (the yaw-rate gyro's declared bias
          times the speed; random walk ``v q_r``): the roll dynamics see ``a_y - bias_a_y``
          and so does the lateral accelerometer (with the measured input only);
        - bias states of the roll-rate gyro (declared random walk and reset offset) and of
          the lateral accelerometer (declared reset offset, constant);
        - delay states for each channel's declared whole-sample CAN latency. The measured
          input arrives as late as the accelerometer it feeds through: the delay state's
          ``s <- g roll + a_y`` uses the input of the same sample. The oracle input is on
          time: an input-memory state ``a_y_prev <- a_y`` (prior std ``a_y_std``) holds the
          sample the delayed accelerometer sees;
        - the sensitivity errors' variances in ``R``: the gyro's at ``design_roll_rate``,
          the accelerometer's and the speed scale's at :data:`DESIGN_A_Y_M_S2`.
        """
        from scipy.linalg import block_diag

        from testbed.design import InputStates, build_matched_design, channel_effects

        names = tuple(sensors.names)
        effects = channel_effects(sensors)
        index = paper.measurement_index
        extra: tuple[tuple[str, str], ...] = ()
        A0, B0, Q0, P0 = A, B, Q, paper.P0
        x0 = np.zeros(2)
        rows: dict[int, np.ndarray] = {}
        speed_scale = 0.0
        if tap is not None and "yaw_rate" in names and "speed" in names:
            gyro = effects[names.index("yaw_rate")]
            speed = 1.0 / tap.linear_model().D[1, 0]
            speed_scale = effects[names.index("speed")].scale_std
            if gyro.bias_walk > 0 or gyro.bias0_std > 0:
                extra = (("bias_a_y", "m/s^2"),)
                A0 = np.block([[A, -B], [np.zeros((1, 3))]])
                B0 = np.vstack([B, np.zeros((1, 1))])
                Q0 = block_diag(Q, [[(speed * gyro.bias_walk) ** 2]])
                P0 = block_diag(paper.P0, [[(speed * gyro.bias0_std) ** 2]])
                x0 = np.zeros(3)
                model = sensors.linear_model()
                for ch in index:
                    rows[int(ch)] = np.concatenate([model.C[ch], -model.D[ch]])
        extra_R = {}
        for ch in index:
            e = effects[ch]
            if names[ch] == "roll_rate":
                extra_R[int(ch)] = (e.scale_std * design_roll_rate) ** 2
            elif names[ch] == "lateral_accel":
                extra_R[int(ch)] = (e.scale_std**2 + speed_scale**2) * DESIGN_A_Y_M_S2**2
        return build_matched_design(
            self, sensors, dt_s, A0, B0, Q0, x0, P0, extra_states=extra, channels=index,
            rows=rows, scale_R=extra_R, effects=effects, paper_design=paper,
            input_scales={0: speed_scale} if tap is not None else None,
            input_memory_std=None if tap is not None else np.array([a_y_std]),
            input_transform=paper.input_transform, output_matrix=paper.output_matrix,
            input_noise_cov=(paper.extras.get("input_noise_cov")),
            extras={**{k: paper.extras[k] for k in ("paper_model", "a_y_std", "a_y_source")},
                    # the nonlinear filters: the roll dynamics see a_y - bias_a_y
                    "input_states": InputStates(from_input=np.eye(1),
                                                from_states=-np.ones((1, len(extra))),
                                                relative=np.zeros((len(extra), 1)))})


def _measured_a_y_input(tap: object, u: np.ndarray, x_hat: np.ndarray) -> np.ndarray:
    """The design's input transform with a measured a_y: speed x yaw rate of the sensors."""
    from testbed.rigs.vehicle_roll.sensors import measured_lateral_acceleration

    a_y = measured_lateral_acceleration(tap)
    if len(a_y) != len(u):
        raise ValueError(f"the measured a_y has {len(a_y)} members, the input "
                         f"{len(u)}: build the design from the simulator's own "
                         "sensors (env.unwrapped.sensors)")
    return a_y
