"""The rig contract: one MuJoCo model, its parameters, names with units, and its design model.

A rig is one folder under ``testbed/rigs/`` (its MJCF file beside its Python, as in
dm_control's suite) holding a :class:`Rig` subclass, plus one registration line in
:mod:`testbed.rigs`. A subclass declares data (class attributes) and overrides a few hooks;
everything else (loading, named state access, finite-difference linearization, the batched
simulator, the Gymnasium environments, the runner) is inherited or generic.

State convention: ``x = [positions of joints..., velocities of joints...]`` for the joints
named in :attr:`Rig.joints` (hinges or slides), in rad or m and rad/s or m/s.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, ClassVar

import mujoco
import numpy as np

from filters import real_array
from testbed.rigs.disturbances import Disturbance, scenario_disturbance
from testbed.rigs.linearize import linearize, steady_act
from testbed.rigs.mjcf import models_dir, read_mjcf
from testbed.rigs.options import RigOption, build_rig
from testbed.rigs.params import ParameterMismatch, Params

__all__ = ["GRAVITY_M_S2", "ParameterMismatch", "Params", "Rig", "RigOption", "build_rig",
           "models_dir"]

#: Standard gravity used by every rig, m/s^2.
GRAVITY_M_S2 = 9.81


class Rig:
    """A MuJoCo rig: model, parameters, named state, actuation, linearization, design model.

    Subclasses set the class attributes and override :meth:`apply_params` (write parameters
    into the model) and, where the rig needs them, :meth:`actuation`, :meth:`operating_input`,
    :meth:`validate_x0`, :meth:`terminated`, :meth:`sensors` and :meth:`design_model`.

    Parameters
    ----------
    params : Params, optional
        Physical parameters (default: the nominal ``params_type()``).
    physics_dt_s : float
        MuJoCo time step, s.
    profile : str
        One of :attr:`profiles` (default ``"paper"``, the MJCF as written).

    Attributes
    ----------
    model : mujoco.MjModel
    data : mujoco.MjData
    params : Params
    """

    #: Registry name (``testbed run NAME``).
    name: ClassVar[str] = ""
    #: MJCF file: ``models/NAME.xml`` (built in, :func:`models_dir`), absolute, or relative
    #: to the module defining the subclass.
    xml_path: ClassVar[Path]
    #: Parameter dataclass.
    params_type: ClassVar[type[Params]] = Params
    #: Joints whose positions then velocities form the state.
    joints: ClassVar[tuple[str, ...]] = ()
    state_names: ClassVar[tuple[str, ...]] = ()
    state_units: ClassVar[tuple[str, ...]] = ()
    action_names: ClassVar[tuple[str, ...]] = ()
    action_units: ClassVar[tuple[str, ...]] = ()
    #: Action limits (the amplifier/actuator saturates there: actions are clipped).
    action_low: ClassVar[tuple[float, ...]] = ()
    action_high: ClassVar[tuple[float, ...]] = ()
    #: States a reference tracks (reward, LQR integrators, output of the T ratio).
    tracked_states: ClassVar[tuple[str, ...]] = ()
    #: Standard normals per member and control step that perturb the model
    #: (:meth:`step_noise_model`); 0 for none.
    step_noise_dim: ClassVar[int] = 0
    #: Standard normals per member that :meth:`random_x0` turns into an initial state.
    x0_draws: ClassVar[int] = 0
    #: Open-loop input profiles by name (``reset(options={"manoeuvre": name})``).
    manoeuvres: ClassVar[dict[str, Callable[..., Any]]] = {}
    #: Default reference schedule ``((t_s, *tracked values), ...)``; empty: zero reference.
    default_setpoints: ClassVar[tuple[tuple[float, ...], ...]] = ()
    #: Named deterministic disturbances: ``name -> () -> (G (n, s) or None, w: t_s -> (s,))``.
    disturbance_signals: ClassVar[dict[str, Callable[[], tuple[Any, Any]]]] = {}
    #: Scenario defaults of this rig (``controller``, ``manoeuvre``...).
    scenario_defaults: ClassVar[dict[str, Any]] = {"controller": "lqr"}
    #: Rig-specific scenario options with their defaults (see :meth:`design_model`).
    scenario_options: ClassVar[dict[str, Any]] = {}
    #: Simulation profiles: ``"paper"`` (the papers' idealizations) first, then e.g.
    #: ``"hardware"`` (actuator and sensor effects of the real rig, :meth:`edit_spec`).
    profiles: ClassVar[tuple[str, ...]] = ("paper",)
    #: Camera of ``render_mode="rgb_array"`` (a camera named in the MJCF; "" = free camera).
    render_camera: ClassVar[str] = ""
    #: Parameter-mismatch range: ``{Params field: relative half-range}`` (0.2: the truth may
    #: have the field scaled by any factor in ``[0.8, 1.2]``). The scoring suite's mismatch
    #: entries scale these fields; robust designs take the range as their uncertainty set
    #: (:class:`ParameterMismatch`). Empty: the rig declares none.
    mismatch_range: ClassVar[dict[str, float]] = {}
    #: Divergence detector: the largest ``|x_i|`` per state (rig units; ``inf``: unbounded)
    #: that the physical rig can reach, with a wide margin. The simulator raises
    #: :class:`~testbed.sim.simulator.SimulationDiverged` for a state past it. Empty: no bound.
    state_envelope: ClassVar[tuple[float, ...]] = ()
    #: Construction options (``--rig-option NAME=VALUE``): ``{name: RigOption}``; the values
    #: are :attr:`options` (validated, defaults filled) when :meth:`edit_spec` and
    #: :meth:`apply_params` run.
    rig_options: ClassVar[dict[str, RigOption]] = {}
    #: Physical parameters a recording can identify (``testbed identify``):
    #: ``{Params field: (low, high)}``, the bounds as factors of the nominal value (wide
    #: enough for real units).
    identifiable: ClassVar[dict[str, tuple[float, float]]] = {}
    #: The LQR tracker's weights (``state_weight``, ``input_weight``, ``integral_weight``);
    #: None: the built-in table's entry of the rig, else ones (an instance may set its own).
    lqr_weights: dict[str, Any] | None = None
    #: The sensor presets :meth:`sensors` takes (empty: the default suite only;
    #: :func:`testbed.rigs.describe.sensor_presets`).
    sensor_presets: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def resolve_options(cls, options: dict[str, Any] | None) -> dict[str, Any]:
        """``options`` checked against :attr:`rig_options`, defaults filled.

        Raises
        ------
        ValueError
            An unknown option (the valid ones listed) or a bad value (named).
        """
        options = dict(options or {})
        unknown = set(options) - set(cls.rig_options)
        if unknown:
            raise ValueError(f"rig {cls.name!r} has no option {sorted(unknown)[0]!r}; expected "
                             f"one of {sorted(cls.rig_options) or 'none'}")
        return {name: opt.parse(name, options[name]) if name in options else opt.default
                for name, opt in cls.rig_options.items()}

    def __init__(self, params: Params | None = None, physics_dt_s: float = 0.001,
                 profile: str = "paper", options: dict[str, Any] | None = None):
        number = isinstance(physics_dt_s, int | float | np.floating) and \
            not isinstance(physics_dt_s, bool)
        if not (number and np.isfinite(physics_dt_s) and physics_dt_s > 0):
            raise ValueError(f"physics_dt_s must be a positive finite time in s, "
                             f"got {physics_dt_s!r}")
        if profile not in self.profiles:
            raise ValueError(f"unknown profile {profile!r} for rig {self.name!r}; expected one "
                             f"of {self.profiles}")
        #: The simulation profile (one of :attr:`profiles`).
        self.profile = profile
        #: The construction options (:attr:`rig_options`, defaults filled).
        self.options = self.resolve_options(options)
        path = self.resolved_xml_path()
        plain = profile == self.profiles[0] and self.options == self.resolve_options(None)
        read = read_mjcf(str(path), path.stat().st_mtime_ns, plain)
        if plain:
            self.model = copy.deepcopy(read)
        else:
            spec = read.copy()
            self.edit_spec(spec)
            self.model = spec.compile()
        self.model.opt.timestep = physics_dt_s
        self.data = mujoco.MjData(self.model)
        ids = [self.joint_id(n) for n in self.joints]
        self.qpos_adr = np.array([self.model.jnt_qposadr[i] for i in ids], dtype=int)
        self.dof_adr = np.array([self.model.jnt_dofadr[i] for i in ids], dtype=int)
        #: Index of the state in ``concatenate(qpos, qvel)``.
        self.state_gather = np.concatenate([self.qpos_adr, self.model.nq + self.dof_adr])
        self._check_declarations()
        self.params = self.params_type()
        self.set_params(params or self.params_type())

    @classmethod
    def resolved_xml_path(cls) -> Path:
        """The MJCF file: a bare ``models/NAME.xml`` is a built-in model (:func:`models_dir`);
        other relative paths resolve beside the subclass's module."""
        import sys

        path = Path(cls.xml_path)
        if path.parts[:1] == ("models",) and len(path.parts) == 2:
            path = models_dir() / path.name
        elif not path.is_absolute():
            path = Path(sys.modules[cls.__module__].__file__).resolve().parent / path
        if not path.is_file():
            raise FileNotFoundError(f"MJCF model of rig {cls.name!r} not found: {path}")
        return path

    def _check_declarations(self) -> None:
        n, k = self.n_states, self.n_actions
        for label, seq, size in (("state_names", self.state_names, n),
                                 ("state_units", self.state_units, n),
                                 ("action_units", self.action_units, k),
                                 ("action_low", self.action_low, k),
                                 ("action_high", self.action_high, k)):
            if len(seq) != size:
                raise TypeError(f"{type(self).__name__}.{label} has {len(seq)} entries, "
                                f"expected {size}")
        if self.state_envelope and (len(self.state_envelope) != n or not all(
                b > 0 for b in self.state_envelope)):
            raise TypeError(f"{type(self).__name__}.state_envelope must have {n} positive "
                            f"entries (inf: unbounded), got {self.state_envelope}")
        fields = {f.name for f in dataclasses.fields(self.params_type)}
        for name, r in self.mismatch_range.items():
            if name not in fields or not (isinstance(r, int | float) and 0.0 < r < 1.0):
                raise TypeError(f"{type(self).__name__}.mismatch_range: {name!r}: {r!r} must "
                                f"name a field of {self.params_type.__name__} with a "
                                "relative range in (0, 1)")
        fields_ok = all(name in fields and 0 < lo < 1 < hi for name, (lo, hi)
                        in self.identifiable.items())
        if not fields_ok:
            raise TypeError(f"{type(self).__name__}.identifiable must map fields of "
                            f"{self.params_type.__name__} to bounds (low < 1 < high)")
        unknown = set(self.tracked_states) - set(self.state_names)
        if unknown:
            raise TypeError(f"{type(self).__name__}.tracked_states {sorted(unknown)} are not "
                            "state names")

    # ------------------------------------------------------------------ declarations
    @property
    def n_states(self) -> int:
        """State dimension ``2 * len(joints)``."""
        return 2 * len(self.joints)

    @property
    def n_actions(self) -> int:
        """Action dimension."""
        return len(self.action_names)

    @property
    def envelope(self) -> np.ndarray:
        """:attr:`state_envelope` as an array, shape (n,) (``inf`` where unbounded)."""
        if not self.state_envelope:
            return np.full(self.n_states, np.inf)
        return np.array(self.state_envelope, dtype=float)

    @property
    def tracked_index(self) -> np.ndarray:
        """Indices of :attr:`tracked_states` in the state, shape (r,)."""
        return np.array([self.state_names.index(s) for s in self.tracked_states], dtype=int)

    def units(self) -> dict[str, str]:
        """``{state or action name: unit}``."""
        return {**dict(zip(self.state_names, self.state_units, strict=True)),
                **dict(zip(self.action_names, self.action_units, strict=True))}

    def joint_id(self, name: str) -> int:
        """MuJoCo id of a joint; ``ValueError`` naming it when the model has none."""
        jid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if jid < 0:
            raise ValueError(f"rig {self.name!r}: the MJCF model has no joint {name!r}")
        return jid

    def body_id(self, name: str) -> int:
        """MuJoCo id of a body; ``ValueError`` naming it when the model has none."""
        bid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, name)
        if bid < 0:
            raise ValueError(f"rig {self.name!r}: the MJCF model has no body {name!r}")
        return bid

    # ------------------------------------------------------------------ parameters
    def set_params(self, params: Params) -> None:
        """Validate and write physical parameters into :attr:`model` (then ``mj_setConst``).

        Raises
        ------
        ValueError
            Unphysical parameter (named); the model is unchanged.
        """
        self._check_params(params)
        self.apply_params(self.model, params)
        mujoco.mj_setConst(self.model, self.data)
        self.params = params

    def model_with(self, params: Params, data: mujoco.MjData | None = None) -> mujoco.MjModel:
        """A copy of :attr:`model` with ``params`` written in; the rig itself is unchanged.

        Parameters
        ----------
        params : Params
        data : mujoco.MjData, optional
            Scratch data of this model for ``mj_setConst`` (default: a new one).
        """
        self._check_params(params)
        model = copy.copy(self.model)  # mj_copyModel
        self.apply_params(model, params)
        mujoco.mj_setConst(model, mujoco.MjData(model) if data is None else data)
        return model

    def _check_params(self, params: Params) -> None:
        if not isinstance(params, self.params_type):
            raise ValueError(f"params must be a {self.params_type.__name__}, got "
                             f"{type(params).__name__}")
        params.validate()

    def apply_params(self, model: mujoco.MjModel, params: Params) -> None:
        """Write ``params`` into ``model`` (masses, inertias, damping, gears...)."""

    def edit_spec(self, spec: mujoco.MjSpec) -> None:
        """Change the MJCF spec for a profile other than the first, before compiling.

        E.g. give the actuators dynamics (``dyntype``) or limits; :attr:`profile` says which.
        """

    def member_constants(self, params: Params) -> np.ndarray:
        """Per-member numbers :meth:`actuation` and :meth:`step_noise_model` need, shape (d,)."""
        return np.zeros(0)

    # ------------------------------------------------------------------ state
    def get_state(self, data: mujoco.MjData | None = None) -> np.ndarray:
        """State of ``data`` (default :attr:`data`), shape (n,)."""
        data = self.data if data is None else data
        return np.concatenate((data.qpos, data.qvel))[self.state_gather]

    def set_state(self, x: np.ndarray, data: mujoco.MjData | None = None,
                  model: mujoco.MjModel | None = None) -> None:
        """Write ``x`` (shape (n,)) into qpos/qvel and run ``mj_forward``."""
        data = self.data if data is None else data
        j = len(self.joints)
        data.qpos[self.qpos_adr] = x[:j]
        data.qvel[self.dof_adr] = x[j:]
        mujoco.mj_forward(self.model if model is None else model, data)

    def default_x0(self) -> np.ndarray:
        """Initial state when a reset gives none, shape (n,) (default: rest at zero)."""
        return np.zeros(self.n_states)

    def random_x0(self, xi: np.ndarray) -> np.ndarray:
        """Initial states from the rig's documented distribution, shape (k, n).

        Parameters
        ----------
        xi : ndarray, shape (k, x0_draws)
            Standard normals (times the scenario's ``reset_noise_scale``), one row per member.

        Default: :meth:`default_x0` for every member (no randomness).
        """
        return np.tile(self.default_x0(), (len(xi), 1))

    def validate_x0(self, x0: Any) -> np.ndarray:
        """``options['x0']`` as a finite real array of shape (n,) within :attr:`envelope`,
        else ``ValueError``."""
        x = real_array(x0, f"options['x0'] {list(self.state_names)}", shape=(self.n_states,))
        outside = np.abs(x) > self.envelope
        if outside.any():
            i = int(np.flatnonzero(outside)[0])
            raise ValueError(f"options['x0'] {self.state_names[i]} = {x[i]:g} "
                             f"{self.state_units[i]} is outside the rig's envelope "
                             f"|{self.state_names[i]}| <= {self.envelope[i]:g}")
        return x

    def validate_setpoints(self, setpoints: Sequence[Sequence[float]]) -> np.ndarray:
        """A reference table ``(t_s, *tracked values)`` rows, checked; shape (rows, 1 + r)."""
        r = len(self.tracked_states)
        table = real_array(setpoints, f"setpoints (rows t_s, {', '.join(self.tracked_states)})",
                           finite=False)
        if table.ndim != 2 or table.shape[1] != 1 + r or len(table) == 0:
            raise ValueError(f"setpoints must be a sequence of (t_s, "
                             f"{', '.join(self.tracked_states)}) rows, got shape {table.shape}")
        if not np.all(np.isfinite(table)) or np.any(np.diff(table[:, 0]) < 0) or table[0, 0] > 0:
            raise ValueError("setpoints must be finite, start at t <= 0 and be sorted by time")
        return table

    def terminated(self, x: np.ndarray) -> np.ndarray:
        """Whether each state ends the episode (e.g. a rollover), shape (k,) bool."""
        return np.zeros(len(x), dtype=bool)

    def terminated_row(self, x: list[float]) -> bool:
        """:meth:`terminated` of one state given as a list of Python floats (a one-member
        simulator's step). Default: :meth:`terminated` of it; a rig may decide it without
        numpy, with the same result."""
        return bool(self.terminated(np.array((x,), dtype=float))[0])

    # ------------------------------------------------------------------ inputs
    def actuation(self, u: np.ndarray, constants: np.ndarray) -> dict[str, np.ndarray]:
        """MuJoCo inputs for applied actions ``u`` (k, nu) (default: ``ctrl = u``).

        Parameters
        ----------
        u : ndarray, shape (k, nu)
            Applied (clipped) actions in the rig's units.
        constants : ndarray, shape (k, d)
            :meth:`member_constants` of each member.

        Returns
        -------
        dict
            ``"ctrl"`` (k, model.nu) and/or ``"xfrc"`` (k, nbody, 6).
        """
        return {"ctrl": u}

    def physics_inputs(self, u: np.ndarray, constants: np.ndarray) -> dict[str, np.ndarray]:
        """What the simulator writes into its members for applied actions ``u`` (k, nu):
        :meth:`actuation` (default), or the same physics through cheaper MuJoCo inputs.

        Besides ``"ctrl"`` and ``"xfrc"``, a rig may give ``"gravity"`` (k, 3): each
        member's ``opt.gravity`` for the step (a per-simulation model field; a member's
        reset restores its model's). A uniform acceleration field is the d'Alembert force
        of an accelerating base on every massive body at its centre of mass, which MuJoCo
        adds with the bias forces at no extra cost; ``xfrc_applied`` costs a Jacobian per
        body and physics step. :meth:`actuation` stays the definition (the nonlinear
        filters' MuJoCo process model and :meth:`linearize` use it), and the two must give
        the same physics up to rounding (tested).

        Parameters
        ----------
        u : ndarray, shape (k, nu)
        constants : ndarray, shape (k, d)

        Returns
        -------
        dict
            ``"ctrl"`` (k, model.nu), ``"xfrc"`` (k, nbody, 6) and/or ``"gravity"`` (k, 3).
        """
        return self.actuation(u, constants)

    #: Whether :meth:`substep_ctrl` runs before every physics step (e.g. a current limit
    #: that depends on the motor state); False keeps MuJoCo's multi-step call.
    needs_substep: bool = False

    def substep_ctrl(self, command: np.ndarray, act: np.ndarray,
                     constants: np.ndarray) -> np.ndarray:
        """MuJoCo ``ctrl`` for the next physics step from the held command (with
        :attr:`needs_substep`), for one member or (leading axis) k members at once.

        Parameters
        ----------
        command : ndarray, shape (nu,) or (k, nu)
            The control step's ``ctrl`` from :meth:`actuation` (held).
        act : ndarray, shape (na,) or (k, na)
            MuJoCo's actuator states now.
        constants : ndarray, shape (d,) or (k, d)
            :meth:`member_constants` of the member(s).
        """
        return command

    def act_window(self, constants: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """When :meth:`substep_ctrl` is ``clip(command, c act - r, c act + r)`` per actuator
        (``act`` its first actuator state), ``(c, r)`` of k members, each (k, nu): the
        simulator then runs it in C (:mod:`testbed.sim.native`; the model needs
        ``nuserdata == 1 + 3 nu``). None (default): :meth:`substep_ctrl` in Python."""
        return None

    def step_noise_model(self, constants: np.ndarray,
                         xi: np.ndarray) -> dict[str, tuple[Any, np.ndarray]]:
        """The model fields the step noise ``xi`` (k, step_noise_dim) sets for the next step
        of k members (with :attr:`step_noise_dim` > 0).

        Returns
        -------
        dict
            ``{field: (index, values)}``: ``model.<field>[index] = values[j]`` for member
            ``j`` (``index`` an int or a tuple of ints into the field; ``values`` (k,)). The
            simulator writes them into its members' per-simulation model fields at once.
        """
        return {}

    def apply_step_noise(self, model: mujoco.MjModel, constants: np.ndarray,
                         xi: np.ndarray) -> None:
        """Perturb one member's ``model`` for the next step from ``xi`` (step_noise_dim,)
        (:meth:`step_noise_model` for one member)."""
        for name, (index, values) in self.step_noise_model(constants[None],
                                                            np.asarray(xi)[None]).items():
            getattr(model, name)[index] = values[0]

    def operating_input(self, params: Params, x: np.ndarray) -> np.ndarray:
        """Input that holds the rig at state ``x`` (e.g. gravity compensation), (k, nu).

        The design model's linear input is ``u - operating_input(x_hat)``; controllers add
        it as feed-forward. Default: zero.
        """
        return np.zeros((len(x), self.n_actions))

    def process_noise_matrix(self) -> np.ndarray | None:
        """White process-noise input ``b`` (n, p) scaled by ``process_noise`` (None: none)."""
        return None

    def ambient_noise_matrix(self) -> np.ndarray | None:
        """White-noise input ``b`` (n, p) of the rig's small ambient disturbance (air
        turbulence, gusts), scaled by ``ambient_noise`` (None: the rig has none)."""
        return None

    def disturbance(self, name: Any = None, process_noise: float = 0.0,
                    ambient_noise: float = 0.0) -> Disturbance | None:
        """The scenario's disturbance: a named signal ``G w(t)``, ``process_noise b dW`` and
        ``ambient_noise b_a dW_a`` (:func:`testbed.rigs.disturbances.scenario_disturbance`)."""
        return scenario_disturbance(self, name, process_noise, ambient_noise)

    # ------------------------------------------------------------------ linearization
    def linearize(self, x_op: np.ndarray | None = None, u_op: np.ndarray | None = None,
                  eps: float = 1e-6, motor_states: bool = False
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Continuous-time ``(A, B)`` of ``x' = f(x, u)`` by central differences of MuJoCo at
        ``x_op`` (default :meth:`linearization_point`) and ``u_op`` (default
        :meth:`operating_input`), optionally with the actuator states:
        :func:`testbed.rigs.linearize.linearize`."""
        return linearize(self, x_op, u_op, eps, motor_states)

    def steady_act(self, ctrl: np.ndarray) -> np.ndarray:
        """MuJoCo actuator states at rest under a constant ``ctrl`` (nu,), shape (na,)
        (:func:`testbed.rigs.linearize.steady_act`)."""
        return steady_act(self, ctrl)

    def parameter_mismatch(self) -> ParameterMismatch | None:
        """:attr:`mismatch_range` about this rig's parameters (None: the rig declares none)."""
        if not self.mismatch_range:
            return None
        return ParameterMismatch(type(self), self.params, dict(self.mismatch_range),
                                 float(self.model.opt.timestep), self.profile,
                                 dict(self.options))

    def linearization_point(self) -> np.ndarray:
        """Default operating state of :meth:`linearize`, shape (n,) (zero)."""
        return np.zeros(self.n_states)

    # ------------------------------------------------------------------ sensors and design
    def sensors(self, preset: str | None = None, **options: Any):
        """A sensor suite by preset name (see the subclass), built from its channels."""
        raise NotImplementedError(f"rig {self.name!r} declares no sensor presets")

    @classmethod
    def cubic_model(cls, design: Any):
        """Third-order expansion of the nominal dynamics for the polynomial H-infinity filter.

        Parameters
        ----------
        design : testbed.design.DesignModel
            The design model the expansion is written in (state, input, ``A``, ``B``).

        Returns
        -------
        testbed.design.cubic.CubicExpansion

        Raises
        ------
        ValueError
            Default: the rig provides no expansion (``testbed score`` lists the reason).
        """
        raise ValueError(f"rig {cls.name!r} provides no cubic expansion")

    def design_model(self, sensors, dt_s: float, disturbance=None, **options: Any):
        """What a filter designer knows for these sensors and control period.

        Default: the MuJoCo linearization at :meth:`linearization_point` (nominal
        parameters), the sensors' linear model, the disturbance's intensity plus
        ``process_noise`` (intensity on each velocity row) as ``Q``, a zero prior mean
        and ``P0 = prior_std**2 I``. Rigs with a paper model override this.

        Returns
        -------
        testbed.design.DesignModel
        """
        from testbed.design import design_from_linearization

        return design_from_linearization(self, sensors, dt_s, disturbance, **options)
