"""Every command's parsed arguments carry the options the shared code reads
(:data:`testbed.cli.parser.COMMON_DEFAULTS`): a command without an option has its default, a
command with it has its own default or the typed value, and the scenario options' record of
what was typed does not count them."""

from __future__ import annotations

import pytest

from testbed.cli import build_parser
from testbed.cli.deferred import given_options
from testbed.cli.outputs import OUTPUTS
from testbed.cli.parser import COMMANDS, COMMON_DEFAULTS

#: A minimal command line of each command.
LINES = {"run": ["run", "helicopter"], "mc": ["mc", "helicopter"],
         "sweep": ["sweep", "helicopter"], "reproduce": ["reproduce", "all"],
         "score": ["score"], "view": ["view", "a.rrd"], "describe": ["describe", "helicopter"],
         "replay": ["replay", "r.csv"], "identify": ["identify", "r.csv", "--twin", "t.toml"],
         "compare": ["compare", "r.csv"]}


def test_every_output_flag_has_a_common_default():
    assert set(OUTPUTS) <= set(COMMON_DEFAULTS)


@pytest.fixture(scope="module")
def parser():
    return build_parser()


def test_every_command_has_a_line():
    assert set(LINES) == set(COMMANDS)


@pytest.mark.parametrize("command", sorted(LINES))
def test_every_command_namespace_has_the_common_options(parser, command):
    args = parser.parse_args(LINES[command])
    assert args.command == command
    for name in COMMON_DEFAULTS:
        assert hasattr(args, name), name
    assert args.debug is False


def test_a_command_keeps_its_own_defaults_and_values(parser):
    run = parser.parse_args(["run", "helicopter", "--video", "v.mp4"])
    assert run.video == "v.mp4" and run.filter == "kalman" and run.scenario is None
    mc = parser.parse_args(["mc", "helicopter", "--filter", "ukf"])
    assert mc.video is None and mc.filter == "ukf"  # mc has no --video: the common default
    score = parser.parse_args(["score", "--scenario", "a", "--scenario", "b"])
    assert score.scenario == ["a", "b"] and score.filter == ""  # score's is --estimator
    assert parser.parse_args(["describe", "aero"]).filter == ""
    assert parser.parse_args(["run", "helicopter", "--debug"]).debug is True


def test_common_defaults_are_not_typed_options(parser):
    args = parser.parse_args(["run", "helicopter", "--duration", "1"])
    given = given_options(args, set())
    assert "duration" in given
    assert not given & (set(COMMON_DEFAULTS) - {"duration"})
