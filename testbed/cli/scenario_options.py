"""The options every scenario command shares (``run``, ``mc``, ``sweep``) and the scenario
they make: the command's defaults, then a ``--scenario`` file's fields, then what was typed
(:mod:`testbed.experiment.scenario_file`)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from testbed.cli import deferred, values
from testbed.cli.outputs import wrote
from testbed.estimators import ESTIMATORS
from testbed.experiment import scenario_file
from testbed.experiment.control import CONTROLLERS
from testbed.experiment.scenario import Scenario, ScenarioError
from testbed.rigs import RIGS, resolve_rig

#: Longest ``--duration`` (simulated seconds) accepted without ``--allow-long``.
#: Longest ``--duration`` (simulated seconds) accepted without ``--allow-long``.
MAX_DURATION_S = 3600.0


#: Command-line flag of each scenario field (error messages name the flag).
FLAGS = {"rig": "rig", "estimator": "--filter", "estimator_options": "--filter-option",
         "controller": "--controller", "duration_s": "--duration", "seed": "--seed",
         "sensors": "--sensors", "sensor_options": "--sensor-option",
         "rig_options": "--rig-option", "nominal_params": "--twin",
         "manoeuvre": "--manoeuvre", "manoeuvre_params": "--manoeuvre-param",
         "disturbance": "--disturbance", "process_noise": "--process-noise",
         "design_options": "--design-option", "params": "--param", "profile": "--profile",
         "design_profile": "--design-profile",
         "ambient_noise": "--ambient-noise", "reset_noise_scale": "--reset-noise-scale"}


def add_scenario_options(p: argparse.ArgumentParser, duration_s: float) -> None:
    p.add_argument("rig", nargs="?", default=None,
                   help=f"one of {', '.join(RIGS)}, an installed package's (entry points "
                   "testbed.rigs) or package.module:RigClass (default: the --scenario file's)")
    p.add_argument("--scenario", metavar="FILE", default=None,
                   help="read the scenario from a TOML or JSON file; the options given beside "
                   "it override its fields (docs/examples/*.toml)")
    p.add_argument("--save-scenario", metavar="FILE", default=None,
                   help="write the effective scenario (.toml or .json) and exit without running")
    p.add_argument("--profile", default="paper", choices=("paper", "hardware"),
                   help="paper: the papers' idealizations; hardware: motor lag, amplifier "
                   "limits, deadband, IMU and sensor timing of the real rig (see docs)")
    p.add_argument("--design-profile", default="matched", choices=("matched", "paper"),
                   help="matched: the filter designs from the rig as its profile declares it "
                   "(hardware: motor, bias and delay states); paper: from the papers' model "
                   "(model-mismatch study)")
    p.add_argument("--filter", default="kalman",
                   help=f"{', '.join(ESTIMATORS)}, an installed package's (entry points "
                   "testbed.estimators) or package.module:factory")
    p.add_argument("--filter-option", type=values.name_setting, action="append", default=[],
                   metavar="NAME=VALUE",
                   help="keyword option of the filter factory (a number, true/false or a word)")
    p.add_argument("--controller", default=None, choices=CONTROLLERS,
                   help="default: the rig's (helicopter lqr, vehicle-roll open-loop)")
    p.add_argument("--duration", type=values.positive, default=duration_s,
                   help=f"simulated seconds (at most {MAX_DURATION_S:g} without --allow-long)")
    p.add_argument("--allow-long", action="store_true",
                   help=f"accept a --duration above {MAX_DURATION_S:g} s")
    p.add_argument("--seed", type=values.seed, default=0, help="integer in [0, 2**63)")
    p.add_argument("--sensors", default=None, help="a sensor preset of the rig")
    p.add_argument("--sensor-option", type=values.name_setting, action="append", default=[],
                   metavar="NAME=VALUE", help="option of the sensor preset (e.g. the "
                   "helicopter's noise_std_rad); repeatable (testbed describe RIG)")
    p.add_argument("--rig-option", type=values.name_setting, action="append", default=[],
                   metavar="NAME=VALUE", help="construction option the rig declares (e.g. the "
                   "Aero's yaw_locked=true); repeatable (testbed describe RIG)")
    p.add_argument("--manoeuvre", default=None,
                   help="vehicle-roll: lateral-acceleration profile (or 'none')")
    p.add_argument("--manoeuvre-param", type=values.name_value, action="append", default=[],
                   metavar="NAME=VALUE", help="manoeuvre parameter, repeatable")
    p.add_argument("--disturbance", default=None,
                   help="a named disturbance of the rig (helicopter: basin-helicopter)")
    p.add_argument("--process-noise", type=values.non_negative, default=None,
                   help="scale of the rig's white process noise (helicopter)")
    p.add_argument("--ambient-noise", type=values.finite, default=1.0,
                   help="scale of the rig's small ambient disturbance (air turbulence, gusts; "
                   "default 1, 0: none)")
    p.add_argument("--reset-noise-scale", type=values.finite, default=1.0,
                   help="scale of the rig's initial-state distribution (default 1; 0: the "
                   "fixed initial state of the papers)")
    p.add_argument("--design-option", type=values.name_setting, action="append", default=[],
                   metavar="NAME=VALUE", help="design option the rig declares (e.g. "
                   "process_noise_floor=0.05); repeatable (testbed describe RIG)")
    p.add_argument("--twin", metavar="FILE.toml", default=None,
                   help="a twin of a real unit (testbed identify --twin): its rig, profile, "
                   "options and identified parameters become the nominal ones of the "
                   "simulated rig and of the designer (--param scales on top)")
    p.add_argument("--param", type=values.name_value, action="append", default=[],
                   metavar="NAME=SCALE", help="scale a physical parameter of the simulated "
                   "rig (model mismatch), e.g. --param mass_kg=1.1; repeatable")
    p.add_argument("--no-progress", action="store_true", help="never show a progress bar")


#: ``run``/``mc``/``sweep`` options that set one scenario field (others: _cli_fields).
ARG_FIELDS = {"rig": "rig", "profile": "profile", "design_profile": "design_profile",
              "filter": "estimator",
              "controller": "controller", "duration": "duration_s", "seed": "seed",
              "sensors": "sensors", "manoeuvre": "manoeuvre", "disturbance": "disturbance",
              "process_noise": "process_noise", "ambient_noise": "ambient_noise",
              "reset_noise_scale": "reset_noise_scale", "filter_option": "estimator_options",
              "manoeuvre_param": "manoeuvre_params", "design_option": "design_options",
              "param": "params", "sensor_option": "sensor_options",
              "rig_option": "rig_options"}


def _cli_fields(args: argparse.Namespace, rig: Any, dests: set[str]) -> dict[str, Any]:
    """The scenario fields set by the options ``dests`` (unset ones, None, left out)."""
    out: dict[str, Any] = {}
    for dest, name in ARG_FIELDS.items():
        value = getattr(args, dest, None)
        if dest in dests and value is not None:
            out[name] = dict(value) if isinstance(value, list) else value
    return out


def scenario_and_file(args: argparse.Namespace
                      ) -> tuple[Scenario, scenario_file.ScenarioFile | None]:
    """The checked :class:`Scenario` of ``run``/``mc``/``sweep`` arguments and the
    ``--scenario`` file read (or None): the command's defaults, then the file's fields, then
    the options typed on the command line (testbed.experiment.scenario_file).

    Raises
    ------
    ValueError
        A bad value or an option the rig does not have, the message starting with the flag
        (or with the file and its key).
    """
    source = scenario_file.read(args.scenario) if args.scenario else None
    every = set(ARG_FIELDS)
    given = deferred.given_options(args, every) if source is not None else every
    from_file = source.fields if source is not None else {}
    twin = None
    if args.twin is not None:
        from testbed.identify.twin import read_twin

        twin = read_twin(args.twin)
        if args.rig is not None and resolve_rig(args.rig).name != twin.rig:
            raise ValueError(f"--twin {args.twin}: a twin of rig {twin.rig!r}, not "
                             f"{args.rig!r}")
    rig_name = args.rig if args.rig is not None else twin.rig if twin is not None else \
        from_file.get("rig")
    if rig_name is None:
        raise ValueError(f"rig: give a rig ({', '.join(RIGS)} or package.module:RigClass) "
                         "or --scenario FILE")
    try:
        rig = resolve_rig(rig_name)
    except ValueError as exc:
        where = f"{source.path}: rig" if args.rig is None and source else "rig"
        raise ValueError(f"{where}: {exc}") from None
    typed = _cli_fields(args, rig, given)
    defaults = {k: v for k, v in _cli_fields(args, rig, every).items() if k not in from_file}
    values = scenario_file.merge(scenario_file.merge(defaults, from_file), typed)
    if twin is not None:
        values.update(twin_fields(twin, values, deferred.given_options(args, every)))
    scenario = Scenario(**values)

    def message(field: str, text: str) -> str:
        return scenario_file.scenario_error(source, set(typed), field, text,
                                            FLAGS.get(field, field))

    if scenario.duration_s > MAX_DURATION_S and not args.allow_long:
        raise ValueError(message("duration_s", f"{scenario.duration_s:g} s is above the limit "
                                 f"of {MAX_DURATION_S:g} s; add --allow-long to run it anyway"))
    try:
        scenario.check()
    except ScenarioError as exc:
        raise ValueError(message(exc.field, str(exc))) from None
    return scenario, source


def twin_fields(twin: Any, values: dict[str, Any], typed: set[str]) -> dict[str, Any]:
    """The scenario fields a twin sets: its rig, its options (under those typed), its
    identified parameters as the nominal ones, and its profile and sensor preset unless
    ``--profile`` / ``--sensors`` were typed."""
    fields: dict[str, Any] = {
        "rig": twin.rig,
        "rig_options": {**twin.options, **values.get("rig_options", {})},
        "nominal_params": {name: p.value for name, p in twin.parameters.items()
                           if p.identifiable}}
    if "profile" not in typed:
        fields["profile"] = twin.profile
    if "sensors" not in typed and twin.sensor_preset:
        fields["sensors"] = twin.sensor_preset
    return fields


def scenario_from_args(args: argparse.Namespace) -> Scenario:
    """The checked :class:`Scenario` of ``run``/``mc``/``sweep`` arguments
    (:func:`scenario_and_file`)."""
    return scenario_and_file(args)[0]


def study_value(args: argparse.Namespace, source: scenario_file.ScenarioFile | None,
           name: str) -> Any:
    """``--runs``/``--grid`` if typed, else the ``--scenario`` file's ``[study]`` value, else
    the option's default."""
    if source is None or name in deferred.given_options(args, {name}):
        return getattr(args, name)
    return source.study.get(name, getattr(args, name))


def save_scenario(args: argparse.Namespace, scenario: Scenario, **study: Any) -> int:
    """``--save-scenario FILE``: write the effective scenario, run nothing."""
    path = scenario_file.write(args.save_scenario, scenario_file.block(scenario), study)
    wrote(path)
    return 0


def show_progress(args: argparse.Namespace) -> bool:
    """Progress bars only on a terminal, and never with --no-progress."""
    return not args.no_progress and sys.stderr.isatty()
