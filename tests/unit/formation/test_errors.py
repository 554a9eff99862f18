"""Every error the testbed raises builds its message from named values, so a caller (and a
test) can read the value that broke a rule without parsing the text."""

from __future__ import annotations

import inspect

import pytest

from formation import errors

LEAVES = [
    c
    for c in vars(errors).values()
    if inspect.isclass(c)
    and issubclass(c, errors.TestbedError)
    and c.__module__ == errors.__name__
    and not c.__subclasses__()
]


@pytest.mark.parametrize("cls", LEAVES, ids=lambda c: c.__name__)
def test_every_error_builds_its_message_from_values(cls: type[errors.TestbedError]) -> None:
    own = next(
        (b for b in cls.__mro__ if "__init__" in b.__dict__ and b.__module__ == errors.__name__),
        None,
    )
    assert own is not None, f"{cls.__name__} takes a finished message, not its values"
    params = list(inspect.signature(own.__init__).parameters)[1:]
    assert params, f"{cls.__name__}.__init__ names no value"


def test_the_values_stay_on_the_error() -> None:
    exc = errors.SweepError("--loss '0:1:0'", "step = 0; expected > 0")
    assert (exc.subject, exc.problem) == ("--loss '0:1:0'", "step = 0; expected > 0")
    assert str(exc) == "--loss '0:1:0': step = 0; expected > 0"
    exc2 = errors.ExecutorError("--scheduler", "'local:0'", "local:N needs N ≥ 1 workers")
    assert exc2.value == "'local:0'" and str(exc2).startswith("--scheduler 'local:0': ")
