"""Value parsers of the command line's options: one ``argparse`` type per kind of value.

Each turns the text typed into a checked value or raises ``argparse.ArgumentTypeError`` with
a one-line message (the parser prefixes the flag).
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable

#: The largest seed (a seed is an integer in ``[0, 2**63)``, as the scenario checks).
MAX_SEED = 2**63 - 1


#: A plain decimal number in ASCII (no ``1_0``, no ``0x10``, no other scripts' digits).
_DECIMAL = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?", re.ASCII)


_INTEGER = re.compile(r"[+-]?[0-9]+", re.ASCII)


def plain_float(text: str) -> float:
    """``float(text)`` of a plain ASCII decimal number; NaN for anything else."""
    text = text.strip()
    return float(text) if _DECIMAL.fullmatch(text) else float("nan")


def name_value(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    number = plain_float(value)
    if not math.isfinite(number):
        raise argparse.ArgumentTypeError(f"{name}: value must be a finite number, got "
                                         f"{value!r}")
    return name.strip(), number


def name_setting(text: str) -> tuple[str, float | bool | str]:
    """``NAME=VALUE`` with a number, ``true``/``false`` or a word as the value (the options a
    rig, its sensors or its design declare: the receiver checks the value's type)."""
    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    value = value.strip()
    if value.lower() in ("true", "false"):
        return name.strip(), value.lower() == "true"
    if _DECIMAL.fullmatch(value):
        number = float(value)
        if not math.isfinite(number):
            raise argparse.ArgumentTypeError(f"{name}: value must be finite, got {value!r}")
        return name.strip(), number
    return name.strip(), value


def number(text: str, ok: Callable[[float], bool], what: str) -> float:
    value = plain_float(text)
    if not (math.isfinite(value) and ok(value)):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return value


def positive(text: str) -> float:
    return number(text, lambda v: v > 0, "a finite number > 0")


def non_negative(text: str) -> float:
    return number(text, lambda v: v >= 0, "a finite number >= 0")


def integer(text: str, low: int, high: int | None, what: str) -> int:
    if not _INTEGER.fullmatch(text.strip()):
        raise argparse.ArgumentTypeError(f"expected {what} (plain decimal digits), got "
                                         f"{text!r}")
    value = int(text)
    if value < low or (high is not None and value > high):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return value


def finite(text: str) -> float:
    return number(text, lambda v: True, "a finite number")


def port(text: str) -> int:
    return integer(text, 1, 65535, "a port number in 1-65535")


def seed(text: str) -> int:
    return integer(text, 0, MAX_SEED, "an integer in [0, 2**63)")


def positive_int(text: str) -> int:
    return integer(text, 1, None, "a positive integer")


def grid_axis(text: str) -> tuple[str, list[float]]:
    name, sep, values = text.partition("=")
    if not sep or not name.strip() or not values:
        raise argparse.ArgumentTypeError(f"expected NAME=V1,V2,..., got {text!r}")
    numbers = [number(v, lambda _: True, f"finite numbers for {name.strip()}")
               for v in values.split(",")]
    return name.strip(), numbers
