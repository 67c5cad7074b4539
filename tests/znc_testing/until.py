"""The two ways a test waits: :func:`wait_until` (wall clock, for real processes and threads) and
:func:`step_until` (cycles, for an in-process core or PLC stepped by the test).

Both share one meaning of a predicate's return value: a truthy value that is not a ``str`` means done
(and is returned by :func:`wait_until`); a falsy value means "not yet"; a ``str`` means "not yet, and
this is why" (the last one is quoted on failure). Both fail with :class:`AssertionError` saying what was
awaited and the last value seen.

May import: the standard library only (the core tests use it without zenoh or numpy).
"""
from __future__ import annotations

import time
from typing import Any, Callable, TypeVar

T = TypeVar("T")


def done(value: object) -> bool:
    """Whether a predicate's ``value`` means done (truthy and not a ``str``: a str says why not yet)."""
    return bool(value) and not isinstance(value, str)


def wait_until(predicate: Callable[[], T], timeout: float = 10.0, what: str = "the condition",
               interval: float = 0.005) -> T:
    """Poll ``predicate`` every ``interval`` s until it is :func:`done`; return its value.

    An exception from ``predicate`` counts as "not yet" (the process may still be starting) and is
    reported if it never succeeds.

    Raises:
        AssertionError: ``timeout`` s passed; the message says ``what`` was awaited and the last value
            (or exception) seen.
    """
    deadline = time.monotonic() + timeout
    last: Any = None
    while True:
        try:
            last = predicate()
        except Exception as exc:  # keep polling; report it if it never succeeds
            last = exc
        else:
            if done(last):
                return last
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what} (last: {last!r})")
        time.sleep(interval)


def step_until(step: Callable[[], Any], predicate: Callable[[], Any], max_steps: int = 100_000,
               what: str = "condition") -> int:
    """Call ``step()`` then ``predicate()`` until the predicate is :func:`done`; return the number of
    steps taken (at least 1: the predicate is first asked after a step).

    Raises:
        AssertionError: not done after ``max_steps`` steps (the message says ``what`` and the last value).
    """
    last: Any = None
    for k in range(1, max_steps + 1):
        step()
        last = predicate()
        if done(last):
            return k
    raise AssertionError(f"{what} not reached within {max_steps} cycles (last: {last!r})")
