"""Estimators by name or by import path: ``name -> factory(design, **options) -> Estimator``.

The protocol is :mod:`filters.base`: :class:`filters.base.Estimator` (``x``, ``P`` or None,
``reset(x0, P0)``, ``step(y, u)``) and the optional protocols the testbed uses where an
estimator has them: :class:`~filters.base.Innovations` (``testbed score``'s NIS, ANIS and
whiteness), :class:`~filters.base.Batched`, :class:`~filters.base.Primed`,
:class:`~filters.base.ChannelRequest`, :class:`~filters.base.DesignFacts` and
:class:`~filters.base.Named` (the label in ``testbed score``). What the testbed adds:

- ``y``: the channels ``design.discrete``'s ``H`` (with ``D``) describes
  (``design.measurement_index``), measured at the end of the step (or the estimator's own
  ``channels``); ``u``: the input applied over it, in the design model's coordinates (the
  loop applies ``design.input_transform(u_applied, x_hat)`` with ``x_hat`` the estimator's
  ``x`` before the step). Channels an input is computed from go to the input transform,
  not to the estimator: a Kalman filter written from ``F, B, H, D, Q, R`` alone works on
  every rig. The nonlinear model in the same input is :func:`nonlinear_model`.
- An estimator without ``batched = True`` runs in ``mc`` and ``score`` as one instance per
  run (:class:`PerMember`, each from its own factory call or a copy).
- Physical states: a design may be augmented (the ``hardware`` profile's matched design:
  actuator, sensor-bias and delay states after the rig's physical ones). The estimator
  keeps its whole state; the loop reports ``x[..., physical_index]`` and the marginal block
  ``P[..., physical_index, physical_index]`` (``design.physical_index``).
- Checks: after the factory and after the first step the loop checks ``x`` ((n,) or
  (N, n)) and ``P`` ((n, n) or (N, n, n)): finite, symmetric and positive semidefinite to a
  relative tolerance (:func:`testbed.experiment.loop.check_estimate`); otherwise one line
  names the estimator and the expected shape.
- Design profiles: a family whose theory needs the paper's model declares why
  (:attr:`FamilySpec.paper_design_only` in :data:`FAMILIES`; a plug-in factory sets
  ``factory.paper_design_only = "why"``); it then receives ``design.extras["paper_design"]``
  instead of an augmented design (:func:`design_for`). Built in: ``kalman``,
  ``kalman-bucy``, ``lmi-hinf``, ``ekf`` and ``ukf`` design from the matched model;
  ``ms-hinf``, ``poly-hinf`` and ``vc-discrete`` fall back to the paper design (their
  reasons at the bottom of this module; ``testbed score`` notes the pair "paper design").

A user's estimator is named ``package.module:factory`` or ``path/to/file.py:factory``
anywhere a filter name is accepted (``testbed run RIG --filter mymodule:make``), or by the
name of an installed package's ``testbed.estimators`` entry point (:mod:`testbed.discovery`;
:func:`names` lists them with the built-ins); the factory receives the
:class:`~testbed.design.DesignModel` and keyword options. Its label
(:func:`label`): ``LABEL=spec`` when given, else the factory's ``name`` attribute (a class's
:class:`~filters.base.Named` ``name``), else ``file:factory`` without the directories.
"""

from __future__ import annotations

import copy
import inspect
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from filters import DiscreteLinearSystem, KalmanBucyFilter, KalmanFilter, MeanSquareHInfFilter
from testbed import plugins
from testbed.design import DesignModel
from testbed.estimators import optional
from testbed.estimators.wrappers import (  # noqa: F401 - the public names stay here
    ChannelSelect,
    EstimatorWrapper,
    channels_for,
)

Factory = Callable[..., Any]


def _select(estimator: Any, design: DesignModel) -> Any:
    if len(design.measurement_index) == len(design.measurement_names):
        return estimator
    return ChannelSelect(estimator, design.measurement_index, len(design.measurement_names))


def paper_design_only(name: str | Factory) -> str | None:
    """Why an estimator family designs from the paper model only (None: it takes the
    matched, possibly augmented design): a built-in family's
    :attr:`FamilySpec.paper_design_only`, else the plug-in factory's ``paper_design_only``
    attribute (its own declaration)."""
    spec = family(name)
    if spec is not None:
        return spec.paper_design_only
    try:
        factory = resolve(name)
    except ValueError:
        return None
    reason = getattr(factory, "paper_design_only", None)
    return None if reason is None else str(reason)


def design_for(name: str | Factory, design: DesignModel) -> tuple[DesignModel, str | None]:
    """The design an estimator family is built from, and why it is not ``design``.

    An augmented (matched) design goes to every family except those declaring
    ``paper_design_only`` (their reason returned), which get ``design.extras["paper_design"]``.

    Raises
    ------
    ValueError
        The family needs the paper design and the design does not carry one.
    """
    reason = paper_design_only(name) if design.augmented else None
    if reason is None:
        return design, None
    paper = design.extras.get("paper_design")
    if paper is None:
        raise ValueError(f"filter {name!r} designs from the rig's paper model only ({reason}); "
                         "this augmented design carries none (extras['paper_design'])")
    return paper, reason


def kalman(design: DesignModel, constants: str = "consider") -> Any:
    """Discrete Kalman filter on ``design.discrete`` (exact ZOH at the control period).

    A design that declares constant errors (``design.extras["consider"]``: the hardware
    profiles' per-run sensitivity and speed-scale errors) gets a Schmidt-Kalman filter
    (:class:`filters.schmidt.SchmidtKalmanFilter`) that considers them, with ``R`` without
    their white-noise stand-in; ``constants="white"``: the Kalman filter with the stand-in.
    """
    if constants not in ("consider", "white"):
        raise ValueError(f"constants must be 'consider' or 'white', got {constants!r}")
    consider = design.extras.get("consider")
    if consider and constants == "consider":
        from filters.schmidt import SchmidtKalmanFilter

        d = design.discrete
        system = DiscreteLinearSystem(F=d.F, B=d.B, H=d.H, D=d.D, Q=d.Q, R=consider["R"],
                                      dt_s=d.dt_s)
        est = SchmidtKalmanFilter(system, design.x0, design.P0, consider["parameters"])
    else:
        est = KalmanFilter(design.discrete, design.x0, design.P0)
    return _select(est, design)


def kalman_bucy(design: DesignModel, substeps: int | str = "auto") -> Any:
    """Continuous Kalman-Bucy filter on ``design.continuous`` (RK4, ``substeps`` per sample)."""
    est = KalmanBucyFilter(design.continuous, design.x0, design.P0, dt_s=design.dt_s,
                           substeps=substeps)
    return _select(est, design)


def ms_hinf(design: DesignModel, gamma: float | None = None,
            initial_weight: np.ndarray | None = None, sampled: bool = False,
            gamma_factor: float = 5.0) -> Any:
    """Basin et al.'s mean-square H-infinity filter (Theorem 1).

    ``sampled=True``: its sampled-data counterpart instead, a discrete H-infinity filter for
    the same two-channel problem on the hold-equivalent (ZOH) model, with a discrete gamma
    (``gamma_factor`` times the smallest level, on the 1-2-5 grid, unless ``gamma`` is given;
    :func:`testbed.estimators.lmi.sampled_ms_hinf_estimator`).

    Needs deterministic channels ``y2 = C2 x + H w`` in the sensors and the disturbance
    matrix ``G`` in the design (helicopter: ``--disturbance basin-helicopter``, which the
    scenario adds by default for this filter). ``gamma`` defaults to
    ``design.extras["gamma"]`` (the paper's 1.1), ``initial_weight`` (``R`` of (6)) to
    ``design.extras["initial_weight"]`` or the identity.
    """
    det = design.deterministic_index
    if sampled:
        from testbed.estimators.stochastic_system import (
            sampled_ms_hinf_estimator,
            sampled_two_channel_system,
        )

        est, meta = sampled_ms_hinf_estimator(design, gamma=gamma, gamma_factor=gamma_factor)
        est.design_meta = meta
        index = sampled_two_channel_system(design)[2]
        if np.array_equal(index, np.arange(len(design.measurement_names))):
            est.channels = "all"
            return est
        return ChannelSelect(est, index, len(design.measurement_names), request=True)
    if len(det) == 0 or design.disturbance_matrix is None:
        raise ValueError("filter 'ms-hinf' needs a deterministic channel y2 = C2 x + H w and "
                         "the disturbance G w(t) (helicopter: disturbance 'basin-helicopter')")
    gamma = design.extras.get("gamma", 1.1) if gamma is None else float(gamma)
    R0 = design.extras.get("initial_weight", np.eye(design.n)) if initial_weight is None \
        else np.asarray(initial_weight, float)
    plant = design.continuous
    est = MeanSquareHInfFilter(plant.A, plant.B, plant.C, plant.R, design.sensors.C[det],
                               design.sensors.Hw[det], design.disturbance_matrix, plant.Q,
                               design.output_matrix, gamma, R0, design.x0, design.P0,
                               design.dt_s, substeps="auto", noise_intensities=True,
                               method="auto")
    # gamma bounds the gain from the scenario's w (G in the state, Hw in y2) to z = L x
    est.design_meta = {"gamma": gamma, "gamma_channel": "scenario",
                       "gamma_kind": "continuous-observation",
                       "certificate": "Basin et al. Theorem 1 on the design model"}
    index = np.concatenate([design.measurement_index, det])
    if np.array_equal(index, np.arange(len(design.measurement_names))):
        est.channels = "all"  # the deterministic channels too
        return est
    return ChannelSelect(est, index, len(design.measurement_names), request=True)


def lmi_hinf(design: DesignModel, gamma: float | None = None, gamma_factor: float = 5.0,
             objective: str = "h2-unique", plant_block: bool | None = None) -> Any:
    """Zhang et al.'s LMI-designed H-infinity filter (Theorem 4): the rig's LMI design system
    (``design.extras["lmi_system"]``: the vehicle roll rig) or, without one, the system built
    from the discrete design model (:mod:`testbed.estimators.lmi`: the full LMI (48) on a
    stable plant, its error block on a plant with free integrators; ``plant_block`` forces
    either)."""
    from testbed.estimators.stochastic_system import lmi_estimator, verified_estimator

    rig_system = design.extras.get("lmi_system")
    if rig_system is None:
        extra = {} if plant_block is None else {"plant_block": bool(plant_block)}
        est, meta = lmi_estimator(design, gamma=gamma, gamma_factor=gamma_factor,
                                  objective=objective, **extra)
    else:
        if plant_block is not None:
            raise ValueError("filter 'lmi-hinf': option plant_block applies to the generic "
                             "design (testbed.estimators.lmi), not to this rig's own LMI "
                             "system")
        system, B_u, D_u = rig_system(design)
        est, meta = verified_estimator(system, design, gamma=gamma, gamma_factor=gamma_factor,
                                       objective=objective, input_matrix=B_u, feedthrough=D_u)
        meta["a_y_std"] = design.extras.get("a_y_std", 0.1)
    est.design_meta = meta
    return _select(est, design)


def poly_hinf(design: DesignModel, gamma: float | None = None, gamma_factor: float = 1.5,
              substeps: int | None = None) -> Any:
    """Basin et al.'s central polynomial H-infinity filter (Theorem 1) on the rig's cubic
    expansion (``design.extras["cubic_model"]``, :meth:`testbed.rigs.base.Rig.cubic_model`;
    :mod:`testbed.estimators.poly`). ``gamma`` defaults to ``gamma_factor`` times the linear
    part's smallest level."""
    cubic = design.extras.get("cubic_model")
    if cubic is None:
        raise ValueError("filter 'poly-hinf' needs the rig's cubic expansion "
                         "(design.extras['cubic_model']); this design has none")
    from testbed.estimators.poly import poly_hinf_estimator

    est = poly_hinf_estimator(design, cubic(design), gamma=gamma, gamma_factor=gamma_factor,
                              substeps=substeps)
    est.channels = "all"  # it keeps design.measurement_index itself
    return est


def vc_discrete(design: DesignModel, gamma: float | None = None, gamma_factor: float = 2.0,
                sigma_factor: float | None = None, max_evaluations: int = 120,
                output_injection: bool | None = None) -> Any:
    """The discrete variance-constrained H2/H-infinity predictor (Liu, Deng & Wang) on the
    discrete design model with the rig's parameter-mismatch range as norm-bounded
    uncertainty ``M F N`` (:mod:`testbed.estimators.vc`; a design model with free integrators
    is designed in its output-injection loop ``F - L0 H``, or as ``output_injection`` says).
    ``gamma`` defaults to ``gamma_factor`` times the smallest solvable level, the variance
    bounds to the smallest power of two (or ``sigma_factor``) times the nominal Kalman
    predictor's variances that the design meets."""
    from testbed.estimators.vc import vc_discrete_estimator

    est, _ = vc_discrete_estimator(design, gamma=gamma, gamma_factor=gamma_factor,
                                   sigma_factor=sigma_factor, max_evaluations=max_evaluations,
                                   output_injection=output_injection)
    return _select(est, design)


def ekf(design: DesignModel, eps: float = 1e-6, centered: bool = False,
        jacobian: str = "step", jacobian_points: int = 1, nthread: int = 0) -> Any:
    """Extended Kalman filter on the rig's nominal MuJoCo model, composed with a matched
    design's actuator, bias and delay states (Jacobians from one-physics-step derivatives
    at ``jacobian_points`` points per period, or ``jacobian="rollout"``: finite differences
    of the control-period map over one batched rollout; step ``eps``, forward or
    ``centered``; ``nthread`` rollout threads), ``Q``/``R`` of ``design.discrete``
    (:mod:`testbed.estimators.nonlinear`)."""
    from testbed.estimators.nonlinear import nonlinear_estimator

    return _select(nonlinear_estimator(design, "ekf", eps=eps, centered=centered,
                                       jacobian=jacobian, jacobian_points=jacobian_points,
                                       nthread=nthread), design)


def ukf(design: DesignModel, alpha: float = 1e-3, beta: float = 2.0,
        kappa: float = 0.0, sigma_points: str = "simplex", w0: float = 0.0,
        nthread: int = 0) -> Any:
    """Unscented Kalman filter on the rig's nominal MuJoCo model (with a matched design's
    extra states, as :func:`ekf`), ``Q``/``R`` of ``design.discrete``
    (:mod:`testbed.estimators.nonlinear`).

    Its sigma points are Julier's ``n + 2`` spherical simplex points (default,
    ``sigma_points="simplex"``, centre weight ``w0``, scaled by ``alpha, beta``), or the
    ``2n + 1`` scaled points of Wan & van der Merwe (``sigma_points="scaled"``, ``alpha,
    beta, kappa``). The simplex set needs about 0.6 of the standard set's physics for the
    same accuracy (docs/scoring.md, "The ukf's sigma points")."""
    from testbed.estimators.nonlinear import nonlinear_estimator

    return _select(nonlinear_estimator(design, "ukf", alpha=alpha, beta=beta, kappa=kappa,
                                       sigma_points=sigma_points, w0=w0, nthread=nthread),
                   design)

@dataclass(frozen=True)
class FamilySpec:
    """A built-in estimator family as the registry holds it (:data:`FAMILIES`).

    Attributes
    ----------
    factory : callable
        ``factory(design, **options) -> Estimator``.
    paper_design_only : str, optional
        Why the family designs from the paper model only (None: it takes the matched,
        possibly augmented design); :func:`design_for` then gives it
        ``design.extras["paper_design"]``.
    scenario_defaults : dict
        Scenario fields the family needs, applied where the user set nothing
        (:func:`testbed.experiment.scenario.with_defaults`).
    """

    factory: Factory
    paper_design_only: str | None = None
    scenario_defaults: Mapping[str, Any] = field(default_factory=dict)


_CONTINUOUS_DELAYS = "the whole-sample IMU delays have no continuous-time form"

#: Built-in estimator families: name -> :class:`FamilySpec`.
FAMILIES: dict[str, FamilySpec] = {
    "kalman": FamilySpec(kalman),
    "kalman-bucy": FamilySpec(kalman_bucy),
    "ms-hinf": FamilySpec(
        ms_hinf,
        paper_design_only=("Basin et al.'s Theorem 1 is stated for the paper's continuous "
                           f"model with the deterministic channel y2; {_CONTINUOUS_DELAYS}"),
        scenario_defaults={"disturbance": "basin-helicopter", "disturbance_channel": True}),
    "lmi-hinf": FamilySpec(lmi_hinf),
    "poly-hinf": FamilySpec(
        poly_hinf,
        paper_design_only=("a continuous-time filter on the rig's cubic expansion, written in "
                           f"the paper's states; {_CONTINUOUS_DELAYS}")),
    "vc-discrete": FamilySpec(
        vc_discrete,
        paper_design_only=("its variance bounds are stationary covariances of a plant with a "
                           "known exogenous input: the matched designs' constant offsets have "
                           "none (vehicle: undetectable, Aero: no stabilizing Riccati "
                           "solution) and the helicopter's input is computed from the "
                           "estimated rotor speed; designed there by "
                           "testbed.estimators.vc:vc_discrete_matched")),
    "ekf": FamilySpec(ekf),
    "ukf": FamilySpec(ukf),
}
#: Built-in estimators: name -> ``factory(design, **options)`` (the families' factories).
ESTIMATORS: dict[str, Factory] = {name: spec.factory for name, spec in FAMILIES.items()}


def family(name: str | Factory) -> FamilySpec | None:
    """The :class:`FamilySpec` of a built-in name or factory, also under a label
    (:func:`labelled`); None: not a built-in."""
    if isinstance(name, plugins.LabelledFactory):
        name = name.spec
    if isinstance(name, str):
        return FAMILIES.get(name)
    return next((spec for spec in FAMILIES.values() if spec.factory is name), None)


def resolve(name: str | Factory) -> Factory:
    """A factory from a registered name, ``package.module:factory`` or a callable.

    Raises
    ------
    ValueError
        Unknown name (the registered ones listed) or an import path that does not load.
    """
    if callable(name):
        return name
    if not isinstance(name, str):
        raise ValueError(f"filter must be a name or 'module:factory', got {name!r}")
    if name in ESTIMATORS:
        return ESTIMATORS[name]
    module, sep, attr = name.rpartition(":")
    if not sep:  # an installed package's entry point (testbed.discovery)
        installed = _installed(name)
        if installed is not None:
            return installed
    if not sep or not module or not attr:
        raise ValueError(f"unknown filter {name!r}; expected one of {sorted(names())}, "
                         "'package.module:factory' or 'path/to/file.py:factory'")
    factory = plugins.load(name, f"filter {name!r}")
    if not callable(factory):
        raise ValueError(f"filter {name!r}: {attr!r} is not callable")
    return factory


def names() -> list[str]:
    """The estimator names :func:`resolve` accepts: the built-in ones (:data:`ESTIMATORS`),
    then those of installed packages' ``testbed.estimators`` entry points (nothing is
    imported; a built-in name wins)."""
    from testbed import discovery

    return [*ESTIMATORS, *(n for n in discovery.names("estimator") if n not in ESTIMATORS)]


def _installed(name: str) -> Factory | None:
    """The factory of an installed package's entry point ``name`` (None: there is none)."""
    from testbed import discovery

    factory = discovery.load("estimator", name)
    if factory is not None and not callable(factory):
        raise ValueError(f"{discovery.describe(discovery.find('estimator', name))}: "
                         f"{factory!r} is not callable")
    return factory


def labelled(spec: str | Factory) -> str | Factory:
    """An estimator as ``testbed score`` takes it, with a short label.

    A registered name stays a name; ``LABEL=spec`` and a plug-in spec become a
    :class:`testbed.plugins.LabelledFactory` whose ``__name__`` is ``LABEL`` or
    :func:`testbed.plugins.default_label` (the plug-in's ``name``, else ``file:factory``
    without directories); a callable is returned as it is.

    Raises
    ------
    ValueError
        Unknown name, a plug-in that does not load, or a malformed ``LABEL=``.
    """
    if callable(spec):
        return spec
    label, rest = plugins.split_label(spec)
    factory = resolve(rest)  # loads (and names the failure of) a plug-in here
    if label is None and rest in ESTIMATORS:
        return rest
    return plugins.LabelledFactory(rest, label or plugins.default_label(rest, factory),
                                   resolve)


def label(spec: str | Factory) -> str:
    """The label of an estimator (see :func:`labelled`)."""
    out = labelled(spec)
    return plugins.factory_name(out)


def check_options(factory: Factory, name: Any, options: dict[str, Any]) -> None:
    """Refuse option names a factory does not accept (when its signature declares them).

    Raises
    ------
    ValueError
        An unknown option, with the factory's options listed.
    """
    try:
        params = list(inspect.signature(factory).parameters.values())[1:]  # after design
    except (TypeError, ValueError):  # no introspectable signature: the call decides
        return
    if any(p.kind is p.VAR_KEYWORD for p in params):
        return
    names = {p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
    unknown = set(options) - names
    if unknown:
        label = plugins.factory_name(name)
        raise ValueError(f"filter {label!r} has no option(s) {sorted(unknown)}; its options: "
                         f"{sorted(names) or 'none'}")


def build(name: str | Factory, design: DesignModel, **options: Any) -> Any:
    """``resolve(name)(design, **options)``, checked against the protocol."""
    factory = resolve(name)
    label = plugins.factory_name(name)
    try:
        est = factory(design, **options)
    except TypeError as err:
        if name in ESTIMATORS:
            raise ValueError(f"filter {name!r}: bad options {sorted(options)} ({err})") from None
        raise plugins.PluginError(f"filter {label!r}", "build", err) from None
    except ValueError:
        if name in ESTIMATORS:  # a bad option value, named by the built-in factory
            raise
        raise plugins.PluginError(f"filter {label!r}", "build", sys.exc_info()[1]) from None
    except plugins.PLUGIN_FAILURES as err:
        raise plugins.PluginError(f"filter {label!r}", "build", err) from None
    lacking = optional.lacks(est)
    if lacking:
        raise ValueError(f"filter {name!r}: the factory returned {type(est).__name__}, "
                         f"which has no {lacking[0]!r} (see testbed.estimators)")
    return est


def nonlinear_model(design: DesignModel, **options: Any) -> Any:
    """The nonlinear model ``f, F, h, H`` of ``design`` in the loop's input, for plug-ins
    (:class:`testbed.estimators.model.NonlinearModel`; ``docs/extending.md``)."""
    from testbed.estimators.model import nonlinear_model as make

    return make(design, **options)


class PerMember:
    """N instances of a non-batched estimator presented as one batched estimator.

    Parameters
    ----------
    instances : list of estimators
        One per member, each in the single-run form (``x`` (n,)).
    """

    batched = True

    def __init__(self, instances: list[Any]):
        self.instances = instances
        channels = optional.requested_channels(instances[0])
        if channels is not None:
            self.channels = channels

    @classmethod
    def build(cls, name: str | Factory, design: DesignModel, num: int,
              **options: Any) -> PerMember:
        """``num`` instances from ``num`` factory calls (the first one copied when cheap)."""
        first = build(name, design, **options)
        rest = [copy.deepcopy(first) for _ in range(num - 1)]
        return cls([first, *rest])

    @property
    def x(self) -> np.ndarray:
        """Estimates, shape (N, n)."""
        return np.stack([np.asarray(e.x, float) for e in self.instances])

    @property
    def P(self) -> np.ndarray | None:
        """Covariances (N, n, n), or None when the estimator has none."""
        Ps = [optional.covariance(e) for e in self.instances]
        return None if any(P is None for P in Ps) else np.stack([np.asarray(P) for P in Ps])

    def reset(self, x0: np.ndarray, P0: np.ndarray | None) -> None:
        """Reset member ``i`` from ``x0[i]``, ``P0[i]`` (or a shared ``P0`` (n, n))."""
        x0 = np.asarray(x0, float)
        for i, e in enumerate(self.instances):
            P = None if P0 is None else (P0 if np.ndim(P0) == 2 else P0[i])
            e.reset(x0[i], P)

    def prime(self, y: np.ndarray) -> None:
        """Prime the instances that use the first sample."""
        for e, yi in zip(self.instances, y, strict=True):
            prime = optional.primer(e)
            if prime is not None:
                prime(yi)

    @property
    def innovation(self) -> np.ndarray | None:
        """The instances' innovations (N, m), or None when one has none
        (:class:`filters.base.Innovations`)."""
        values = [optional.innovations(e)[0] for e in self.instances]
        if any(v is None for v in values):
            return None
        return np.stack([np.asarray(v, float).reshape(-1) for v in values])

    @property
    def innovation_cov(self) -> np.ndarray | None:
        """The instances' innovation covariances (N, m, m), or None when one has none."""
        values = [optional.innovations(e)[1] for e in self.instances]
        if any(v is None for v in values):
            return None
        return np.stack([np.atleast_2d(np.asarray(v, float)) for v in values])

    def step(self, y: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """Step every instance on its row."""
        for i, e in enumerate(self.instances):
            e.step(y[i], None if u is None else u[i])
        return self.x
