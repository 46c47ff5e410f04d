"""Old names kept for one release (filters._deprecated): a call warns, then runs the new one."""

from __future__ import annotations

import pytest

from filters import variance_continuous
from filters._deprecated import deprecated_alias


def test_an_alias_warns_and_returns_what_the_renamed_function_returns():
    def renamed(a: float, *, b: float = 2.0) -> float:
        """Doc."""
        return a * b

    old = deprecated_alias(renamed, "old_name")
    with pytest.warns(DeprecationWarning, match="old_name is deprecated.*renamed"):
        assert old(3.0, b=4.0) == 12.0
    assert old.__name__ == "old_name" and old.__wrapped__ is renamed


@pytest.mark.parametrize("old, new", [
    (variance_continuous.solve_equation16, variance_continuous.solve_state_bound),
    (variance_continuous.solve_equation17, variance_continuous.solve_error_bound),
])
def test_the_documented_old_names_point_at_the_renamed_functions(old, new):
    assert old.__wrapped__ is new
