"""Checking parameters where they enter: a bad value is a ``ValueError`` that names it, never a silent NaN later.

Every float parameter must be a finite number (``inf`` and ``nan`` compare in surprising ways: ``inf > 0`` is
True, so a plain positivity test lets ``workspace_range=inf`` through to an all-zero observation).
"""

from __future__ import annotations

import math
from numbers import Integral, Real

__all__ = ["check_number", "check_vector", "check_integer"]


def check_number(owner: str, key: str, value, *, low: float | None = None, high: float | None = None,
                 low_open: bool = False) -> float:
    """``value`` as a float, finite and within ``[low, high]`` (``(low, high]`` with ``low_open``)."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ValueError(f"{owner}: {key} must be a number, got {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"{owner}: {key} must be finite, got {value!r}")
    if low is not None and (number <= low if low_open else number < low):
        raise ValueError(f"{owner}: {key} must be {'>' if low_open else '>='} {low:g}, got {value!r}")
    if high is not None and number > high:
        raise ValueError(f"{owner}: {key} must be <= {high:g}, got {value!r}")
    return number


def check_integer(owner: str, key: str, value, *, low: int | None = None, high: int | None = None) -> int:
    """``value`` as an int (an integral number: 3 or 3.0, not 3.5 or True) within ``[low, high]``."""
    if isinstance(value, bool) or not (isinstance(value, Integral) or (isinstance(value, Real) and float(value).is_integer())):
        raise ValueError(f"{owner}: {key} must be an integer, got {value!r}")
    number = int(value)
    if (low is not None and number < low) or (high is not None and number > high):
        bounds = f"in {low}..{high}" if low is not None and high is not None else (
            f">= {low}" if low is not None else f"<= {high}")
        raise ValueError(f"{owner}: {key} must be {bounds}, got {value!r}")
    return number


def check_vector(owner: str, key: str, values, length: int | None = None, **bounds) -> tuple[float, ...]:
    """A sequence of finite numbers (of ``length`` when given), each checked as :func:`check_number`."""
    try:
        items = list(values)
    except TypeError:
        raise ValueError(f"{owner}: {key} must be a sequence of numbers, got {values!r}") from None
    if length is not None and len(items) != length:
        raise ValueError(f"{owner}: {key} needs {length} values, got {values!r}")
    return tuple(check_number(owner, f"{key}[{index}]", item, **bounds) for index, item in enumerate(items))
