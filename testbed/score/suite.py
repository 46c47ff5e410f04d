"""The scoring suites as data: which scenarios, how many runs, which disturbance channel.

A :class:`SuiteEntry` is a :class:`~testbed.experiment.scenario.Scenario` (its ``estimator`` field
is
ignored: the harness runs every estimator on it) plus what scoring needs: runs, the rig
profile, the entry it mismatches, whether the initial state is drawn from the design prior,
and the worst-case search settings. ``standard`` holds every entry; ``quick`` a subset with
fewer runs and shorter horizons (under a minute on two cores). Each suite has a version
(:data:`SUITE_VERSIONS`) and a content hash of its definitions (:func:`suite_hash`), written
in every score output.

Profiles: an entry names the rig profile it needs (``"paper"``: the papers' idealizations,
today's rigs; ``"hardware"``). It runs when the profile is available, detected at run time
from the :class:`Scenario` fields or the rig's ``scenario_options`` (never from a version);
``"paper"`` is what rigs without profiles simulate. Otherwise the entry is listed as
skipped with the reason.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from testbed.experiment.scenario import Scenario
from testbed.records import field_values
from testbed.rigs import resolve_rig
from testbed.rigs.helicopter.rig import HelicopterRig
from testbed.rigs.linear_plant.rig import LinearPlantRig
from testbed.rigs.vehicle_roll.model import physical_model

#: Helicopter parameters scaled together for the +-20 % mismatch entries: the rig's declared
#: mismatch range (:attr:`HelicopterRig.mismatch_range`: the moving mass, so the gravity
#: torque the designer compensates is off by 20 %, and the viscous dampings).
HELICOPTER_MISMATCH_KEYS = tuple(HelicopterRig.mismatch_range)
#: Aero worst-case channel: angular accelerations (rad/s^2) on the pitch and yaw rows.
AERO_CHANNEL = ((0.0, 0.0), (0.0, 0.0), (1.0, 0.0), (0.0, 1.0))
#: The pitch stiffness a real Aero unit shows, as a factor of the nominal (more than twice
#: it): the ``aero-hardware-stiff`` entry's truth.
AERO_REAL_STIFFNESS = 2.2
#: Vehicle worst-case channel: a roll moment expressed as an equivalent lateral acceleration
#: (m/s^2), i.e. the rig's input column ``m_s h_cr / I_xx`` (rad/s^2 per m/s^2).
VEHICLE_CHANNEL = tuple(tuple(row) for row in physical_model()[1].tolist())


@dataclass(frozen=True)
class WorstCaseSpec:
    """Settings of the adversarial worst-case disturbance search of one entry.

    Attributes
    ----------
    energy : float
        ``||w||_2^2 = sum_k |w_k|^2 dt`` of every candidate disturbance, in (w units)^2 s
        (the loop is nonlinear: the gain depends on it).
    horizon_s : float, optional
        Horizon of the search (default: the entry's duration).
    channel : tuple of rows, optional
        ``G`` (n, s), velocity rows only, of a disturbance channel for scenarios without a
        named disturbance signal (one with a signal uses that signal's ``G`` and ``Hw``).
    random_draws : int
        White-noise disturbances of the same energy (the random gain is their maximum).
    basis : int
        Right singular vectors of the linearized error system kept as the basis of the
        refinement (the first is the power-iteration direction).
    generations : int
        Generations of the derivative-free refinement on the nonlinear loop.
    """

    energy: float = 1.0
    horizon_s: float | None = None
    channel: tuple[tuple[float, ...], ...] | None = None
    random_draws: int = 4
    basis: int = 4
    generations: int = 2

    def __post_init__(self) -> None:
        if not (np.isfinite(self.energy) and self.energy > 0):
            raise ValueError(f"energy must be positive and finite, got {self.energy}")
        if self.horizon_s is not None and not (np.isfinite(self.horizon_s)
                                               and self.horizon_s > 0):
            raise ValueError(f"horizon_s must be positive, got {self.horizon_s}")
        for name in ("random_draws", "basis", "generations"):
            value = field_values(self)[name]
            if int(value) != value or value < (1 if name != "generations" else 0):
                raise ValueError(f"{name} must be a positive integer, got {value}")


@dataclass(frozen=True)
class SuiteEntry:
    """One scenario of a suite and how to score on it.

    Attributes
    ----------
    name : str
        Unique within the suite (``helicopter``, ``helicopter+20%``...).
    description : str
    scenario : Scenario
        Everything but the estimator.
    runs : int
        Monte-Carlo runs (common random numbers: the same per-run seeds for every estimator).
    profile : str, optional
        Rig profile the entry needs (``"paper"``, ``"hardware"``; None: no profile).
    nominal : str, optional
        The entry this one mismatches: ``mismatch_rmse_ratio`` = RMSE here / RMSE there.
    x0_from_prior : bool
        Draw each run's true initial state from the design prior ``N(x0, P0)`` (seeded by
        the run seed), so that a consistent estimator's prior is right.
    worst_case : WorstCaseSpec, optional
        Run the worst-case search here (None: not on this entry).
    feedback : {"truth", "estimate"}
        What the controller acts on. ``"truth"`` (default): every estimator sees the same
        trajectories (bitwise, with the same seeds); ``"estimate"``: output feedback, the
        trajectories then depend on the estimator.
    """

    name: str
    description: str
    scenario: Scenario
    runs: int
    profile: str | None = "paper"
    nominal: str | None = None
    x0_from_prior: bool = False
    worst_case: WorstCaseSpec | None = None
    feedback: str = "truth"

    def __post_init__(self) -> None:
        if self.feedback not in ("truth", "estimate"):
            raise ValueError(f"entry {self.name!r}: feedback must be 'truth' or 'estimate', "
                             f"got {self.feedback!r}")
        if int(self.runs) != self.runs or self.runs < 2:
            raise ValueError(f"entry {self.name!r}: runs must be an integer >= 2 (confidence "
                             f"intervals), got {self.runs}")
        if self.profile not in (None, "paper", "hardware"):
            raise ValueError(f"entry {self.name!r}: profile must be 'paper', 'hardware' or "
                             f"None, got {self.profile!r}")

    def replace(self, **changes: Any) -> SuiteEntry:
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)

    def unavailable(self) -> str | None:
        """Why this entry cannot run here (None: it can).

        The profile is available when :class:`Scenario` has a ``profile`` field or the rig
        lists ``profile`` in its ``scenario_options``; ``"paper"`` is also what a rig without
        profiles simulates.
        """
        if self.profile is None or self.profile == "paper":
            return None
        if _profile_route(self.scenario) is None:
            return f"profile {self.profile!r} not available"
        return None

    def resolved_scenario(self) -> Scenario:
        """The scenario with the profile applied where the testbed supports profiles."""
        route = _profile_route(self.scenario) if self.profile is not None else None
        if route == "field":
            return self.scenario.replace(profile=self.profile)
        if route == "design":
            return self.scenario.replace(design_options={**self.scenario.design_options,
                                                         "profile": self.profile})
        return self.scenario

    def describe(self) -> dict[str, Any]:
        """JSON-ready description."""
        scenario = self.scenario.describe()
        scenario.pop("estimator", None)
        scenario.pop("estimator_options", None)
        wc = None if self.worst_case is None else dataclasses.asdict(self.worst_case)
        return {"name": self.name, "description": self.description, "runs": self.runs,
                "profile": self.profile, "nominal": self.nominal,
                "x0_from_prior": self.x0_from_prior, "feedback": self.feedback,
                "worst_case": wc,
                "scenario": scenario, "skipped": self.unavailable()}


def _profile_route(scenario: Scenario) -> str | None:
    if "profile" in {f.name for f in dataclasses.fields(Scenario)}:
        return "field"
    if "profile" in resolve_rig(scenario.rig).scenario_options:
        return "design"
    return None


# ---------------------------------------------------------------------------- the entries
def _helicopter(profile: str, scale: float | None, runs: int, duration_s: float,
                worst_case: WorstCaseSpec | None) -> SuiteEntry:
    base = "helicopter" if profile == "paper" else "helicopter-hardware"
    params = {} if scale is None else {k: scale for k in HELICOPTER_MISMATCH_KEYS}
    name = base if scale is None else f"{base}{scale - 1:+.0%}"
    what = "nominal parameters" if scale is None else (
        f"simulated {', '.join(HELICOPTER_MISMATCH_KEYS)} x {scale:g} (designers keep nominal)")
    return SuiteEntry(
        name=name,
        description=(f"2-DOF helicopter ({profile} profile), LQR tracking the default "
                     f"setpoints, encoders + the y2 = C2 x + H w channel, Basin et al.'s "
                     f"disturbance w(t) and white noise b dW; {what}"),
        scenario=Scenario(rig="helicopter", disturbance="basin-helicopter",
                          sensor_options={"disturbance_channel": True}, process_noise=1.0,
                          params=params, duration_s=duration_s),
        runs=runs, profile=profile, nominal=None if scale is None else base,
        worst_case=worst_case if scale is None else None)


def _vehicle(profile: str, manoeuvre: str, runs: int, duration_s: float,
             worst_case: WorstCaseSpec | None) -> SuiteEntry:
    suffix = "" if profile == "paper" else "-hardware"
    title = {"double-lane-change": "dlc", "step-steer": "step-steer"}[manoeuvre]
    return SuiteEntry(
        name=f"vehicle-{title}{suffix}",
        description=(f"vehicle roll ({profile} profile), open-loop {manoeuvre} lateral "
                     "acceleration, IMU (gyro with bias walk, accelerometer), damping noise"),
        scenario=Scenario(rig="vehicle-roll", manoeuvre=manoeuvre, duration_s=duration_s),
        runs=runs, profile=profile, worst_case=worst_case)


def _aero(profile: str, stiffness: float | None, runs: int, duration_s: float,
          worst_case: WorstCaseSpec | None) -> SuiteEntry:
    base = "aero" if profile == "paper" else "aero-hardware"
    what = "nominal parameters" if stiffness is None else (
        f"simulated pitch_stiffness x {stiffness:g}, what a real unit shows (designers keep "
        "nominal)")
    return SuiteEntry(
        name=base if stiffness is None else f"{base}-stiff",
        description=(f"Quanser Aero ({profile} profile), LQR tracking the default pitch and "
                     f"yaw setpoints, the rig's default sensors, white torque noise; {what}"),
        scenario=Scenario(rig="aero", process_noise=1.0, duration_s=duration_s,
                          params={} if stiffness is None else {"pitch_stiffness": stiffness}),
        runs=runs, profile=profile, nominal=None if stiffness is None else base,
        worst_case=worst_case if stiffness is None else None)


def calibration_entry(runs: int, duration_s: float,
                      worst_case: WorstCaseSpec | None) -> SuiteEntry:
    """The linear-Gaussian calibration plant (the Kalman filter is optimal there)."""
    return SuiteEntry(
        name="calibration",
        description=("linear-Gaussian plant (mass-spring-damper, exact discrete model, white "
                     "acceleration noise, noisy position); truth drawn from the prior: the "
                     "Kalman filter is optimal and must be consistent"),
        scenario=Scenario(rig=LinearPlantRig, process_noise=1.0, duration_s=duration_s),
        runs=runs, profile=None, x0_from_prior=True, worst_case=worst_case)


def standard() -> list[SuiteEntry]:
    """Every entry: calibration, helicopter (paper/hardware x nominal/+-20 %), vehicle roll
    (double lane change, step steer; paper/hardware), the Quanser Aero (paper, hardware, and
    hardware with a real unit's pitch stiffness). Basin et al.'s own scenario is
    :func:`basin_ms_hinf_entry`, outside the ranked suite."""
    wc_heli = WorstCaseSpec(energy=1.0, horizon_s=10.0)
    wc_vehicle = WorstCaseSpec(energy=1.0, horizon_s=10.0, channel=VEHICLE_CHANNEL)
    entries = [calibration_entry(100, 20.0, WorstCaseSpec(energy=1.0, horizon_s=30.0,
                                                          channel=((0.0,), (1.0,))))]
    for profile in ("paper", "hardware"):
        for scale in (None, 1.2, 0.8):
            entries.append(_helicopter(profile, scale, 100, 20.0, wc_heli))
    for profile in ("paper", "hardware"):
        for manoeuvre in ("double-lane-change", "step-steer"):
            entries.append(_vehicle(profile, manoeuvre, 100, 10.0, wc_vehicle))
    wc_aero = WorstCaseSpec(energy=0.01, horizon_s=10.0, channel=AERO_CHANNEL)
    entries.append(_aero("paper", None, 100, 20.0, wc_aero))
    entries.append(_aero("hardware", None, 100, 20.0, wc_aero))
    entries.append(_aero("hardware", AERO_REAL_STIFFNESS, 100, 20.0, None))
    return entries


def basin_ms_hinf_entry() -> SuiteEntry:
    """Basin et al.'s mean-square H-infinity example on the rig, as an entry outside the
    ranked suites.

    The paper's per-sample sensor noise (unit intensity over 10 ms: 10 rad standard
    deviation) and the open-loop hover voltage leave the rig on its stops: every filter
    predicts open loop there (the Kalman filter's pitch RMSE 126 deg), which ranks nothing.
    It stays a reproduction (``testbed reproduce basin-ms-hinf-helicopter``) and a
    worst-case test case.
    """
    return SuiteEntry(
        name="basin-ms-hinf",
        description=("Basin et al.'s helicopter example on the rig: the paper's sensors "
                     "(y1 with unit-intensity noise, y2 = C2 x + H w), w(t), b dW, the "
                     "hover voltage open loop; the mean-square H-infinity filter's scenario"),
        scenario=Scenario(rig="helicopter", sensors="paper", controller="open-loop",
                          disturbance="basin-helicopter",
                          sensor_options={"disturbance_channel": True}, process_noise=1.0,
                          duration_s=20.0),
        runs=100, profile="paper", worst_case=WorstCaseSpec(energy=1.0, horizon_s=20.0))


#: Entries of ``quick`` and their overrides (runs, duration, worst-case horizon).
QUICK = {"calibration": (32, 5.0, 5.0), "helicopter": (16, 6.0, 3.0),
         "helicopter+20%": (16, 6.0, None), "vehicle-dlc": (16, 6.0, 3.0),
         "helicopter-hardware": (16, 6.0, 3.0), "vehicle-dlc-hardware": (16, 6.0, 3.0)}


def quick() -> list[SuiteEntry]:
    """The subset of :func:`standard` that runs in under a minute on two cores."""
    out = []
    for entry in standard():
        if entry.name not in QUICK:
            continue
        runs, duration_s, horizon_s = QUICK[entry.name]
        wc = entry.worst_case
        if wc is not None and horizon_s is not None:
            wc = dataclasses.replace(wc, horizon_s=horizon_s, random_draws=3, generations=1)
        out.append(entry.replace(runs=runs, worst_case=wc if horizon_s else None,
                                 scenario=entry.scenario.replace(duration_s=duration_s)))
    return out


#: The suite's declared lineup: the built-in estimators a leaderboard scores. It fixes the
#: family of the paired comparisons' Holm correction (:func:`testbed.score.report.comparisons`)
#: so that a verdict does not depend on which other estimators a run scores.
LINEUP = ("kalman", "kalman-bucy", "ms-hinf", "lmi-hinf", "poly-hinf", "vc-discrete", "ekf",
          "ukf")

SUITES = {"quick": quick, "standard": standard}
#: Version of each suite's definition: bump it whenever :func:`suite_hash` changes (a test pins
#: the hash of the current version), so that scores are compared only within one version.
SUITE_VERSIONS = {"quick": 2, "standard": 4}


def suite_names() -> list[str]:
    """The suites :func:`get_suite` knows: the built-in ones (:data:`SUITES`), then those of
    installed packages' ``testbed.suites`` entry points (nothing is imported)."""
    from testbed import discovery

    return [*SUITES, *(n for n in discovery.names("suite") if n not in SUITES)]


@dataclass(frozen=True)
class SuiteSpec:
    """A suite as the registry knows it: the function making its entries and its version.

    Attributes
    ----------
    function : callable () -> list of SuiteEntry
    version : int
        >= 1; :data:`SUITE_VERSIONS` for a built-in suite, an installed suite's ``version``
        attribute (default 1).
    """

    function: Any
    version: int


def _suite_spec(name: str) -> SuiteSpec:
    """Suite ``name``: a built-in one, or an installed package's ``testbed.suites`` entry
    point (a callable with an optional ``version``, an int >= 1, default 1: read here,
    once)."""
    if name in SUITES:
        return SuiteSpec(SUITES[name], SUITE_VERSIONS[name])
    from testbed import discovery

    function = None if not isinstance(name, str) else discovery.load("suite", name)
    if function is None:
        raise ValueError(f"unknown suite {name!r}; expected one of {sorted(suite_names())}")
    version = getattr(function, "version", 1)  # the plug-in's declaration
    if not callable(function) or isinstance(version, bool) or not isinstance(version, int) \
            or version < 1:
        raise ValueError(f"{discovery.describe(discovery.find('suite', name))}: expected a "
                         "callable () -> list of SuiteEntry with an optional int version >= 1")
    return SuiteSpec(function, version)


def suite_version(name: str) -> int:
    """The version of suite ``name``: :data:`SUITE_VERSIONS`, or an installed suite's
    ``version`` attribute (default 1)."""
    return _suite_spec(name).version


def get_suite(name: str) -> list[SuiteEntry]:
    """The entries of a suite by name (a built-in one or an installed package's).

    Raises
    ------
    ValueError
        Unknown suite (the known ones listed), or an installed suite that does not load or
        does not give a list of :class:`SuiteEntry` (its entry point named).
    """
    function = _suite_spec(name).function
    if function is SUITES.get(name):
        entries = function()
    else:
        from testbed import discovery, plugins

        what = discovery.describe(discovery.find("suite", name))
        try:
            entries = function()
        except plugins.PLUGIN_FAILURES as exc:
            raise plugins.PluginError(what, "build", exc) from None
        if not isinstance(entries, list) or not entries or not all(
                isinstance(e, SuiteEntry) for e in entries):
            raise ValueError(f"{what}: expected a non-empty list of SuiteEntry, got "
                             f"{type(entries).__name__}")
    names = [e.name for e in entries]
    if len(set(names)) != len(names):
        raise ValueError(f"suite {name!r} has duplicate entry names")
    return entries


def suite_hash(name: str) -> str:
    """sha256 of the canonical JSON of the suite's entries (:meth:`SuiteEntry.describe`
    without the run-time ``skipped``; keys sorted, no whitespace), hex."""
    entries = []
    for entry in get_suite(name):
        described = entry.describe()
        described.pop("skipped")
        entries.append(described)
    text = json.dumps(entries, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()


def suite_identity(name: str) -> dict[str, Any]:
    """``{"suite", "version", "hash"}`` of a suite (written in every score output)."""
    get_suite(name)  # unknown names fail here
    return {"suite": name, "version": suite_version(name), "hash": suite_hash(name)}


def describe_suite(name: str) -> list[dict[str, Any]]:
    """JSON-ready descriptions of a suite's entries (``testbed score --list``)."""
    return [e.describe() for e in get_suite(name)]


__all__ = ["AERO_CHANNEL", "AERO_REAL_STIFFNESS", "HELICOPTER_MISMATCH_KEYS", "QUICK",
           "SUITES", "SUITE_VERSIONS", "SuiteEntry", "WorstCaseSpec", "basin_ms_hinf_entry",
           "calibration_entry",
           "describe_suite", "get_suite", "quick", "standard", "suite_hash", "suite_identity",
           "suite_names", "suite_version"]
