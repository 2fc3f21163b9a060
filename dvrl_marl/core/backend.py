"""The core's arithmetic on any array library: numpy (the default), or another that follows the array API standard
(torch, JAX; ``array_api_compat`` gives each its namespace).

The step is written once. Where numpy runs it eagerly it may skip work no world needs and compute a rule on the rows
that need it only; elsewhere (a GPU, or JAX under ``jax.jit``, where a shape cannot depend on the data) the same rule
runs on every row and the rows that need it keep its result. These helpers say which, so that each rule is written
once for both: ``rows = rows_of(mask)``, compute on ``take(x, rows)``, then ``put(x, rows, mask, values)``.
"""

from __future__ import annotations

import numpy as np
from array_api_compat import array_namespace

__all__ = ["namespace", "needed", "rows_of", "take", "put", "columns", "join", "repeat", "scan"]

_NUMPY = array_namespace(np.empty(0))


def namespace(*arrays):
    """The arrays' namespace: that of those not numpy's (numpy arrays beside them are constants, such as an arm's
    base, which JAX takes as they are), else numpy's own (its functions, without the compatibility layer's calls)."""
    others = [array for array in arrays if not isinstance(array, (np.ndarray, np.generic, float, int))]
    if not others:  # (the default, asked on every call: no lookup)
        return np
    xp = array_namespace(*others)
    return np if xp is _NUMPY else xp


def needed(mask) -> bool:
    """Whether any row needs a rule: ``mask.any()`` where that can be known now, True where it cannot (a traced
    array: the rule then runs on every row, masked)."""
    if isinstance(mask, np.ndarray):
        return bool(mask.any())
    try:
        return bool(namespace(mask).any(mask))
    except Exception:  # noqa: BLE001  (a tracer under jax.jit has no value yet)
        return True


def rows_of(mask):
    """The rows a rule runs on: numpy, the indices where ``mask`` holds; another library, None (every row)."""
    return np.flatnonzero(mask) if isinstance(mask, np.ndarray) else None


def take(x, rows):
    """``x``'s rows ``rows`` (every row for None)."""
    return x if rows is None else x[rows]


def put(x, rows, mask, values):
    """``x`` with ``values`` in the rows the rule ran on: numpy, a copy with rows ``rows`` set; another library, the
    rows where ``mask`` holds taken from ``values`` (computed for every row)."""
    if rows is not None:
        out = x.copy()
        out[rows] = values
        return out
    xp = namespace(x, values)
    return xp.where(xp.reshape(mask, mask.shape + (1,) * (x.ndim - mask.ndim)), values, x)


def columns(parts, xp):
    """``(M, k)`` from ``k`` columns of ``M`` values (numpy: filled in place, cheaper than stacking on a step's path)."""
    if xp is not np:
        return xp.stack(parts, axis=1)
    out = np.empty((len(parts[0]), len(parts)))
    for index, part in enumerate(parts):
        out[:, index] = part
    return out


def join(parts, xp):
    """``(M, k1 + k2 + ...)`` from blocks ``(M, k_i)`` side by side (numpy: float64)."""
    if xp is not np:
        return xp.concat(parts, axis=1)
    return np.concatenate(parts, axis=1, dtype=np.float64)


def _traced(tree) -> bool:
    """Whether a (nested) value holds JAX arrays (under ``jax.jit``: tracers), whose loops JAX should compile once."""
    if isinstance(tree, (tuple, list)):
        return any(_traced(item) for item in tree)
    return type(tree).__module__.startswith("jax")


def repeat(count: int, body, carry, until=None):
    """``carry = body(carry)``, ``count`` times. numpy (and torch): a Python loop that stops early once
    ``until(carry)`` says no row needs more; JAX: ``lax.fori_loop``, the body traced and compiled once (an unrolled
    loop costs its length in compile time)."""
    if _traced(carry):
        from jax import lax

        return lax.fori_loop(0, count, lambda _, value: body(value), carry)
    for _ in range(count):
        if until is not None and until(carry):
            break
        carry = body(carry)
    return carry


def scan(body, carry, items, until=None):
    """``carry = body(carry, item)`` for each item in turn; ``items``: a tuple of arrays stacked along their first
    axis (one row per item). numpy: a Python loop that stops early once ``until(carry)`` holds; JAX: ``lax.scan``."""
    if _traced(carry) or _traced(items):
        from jax import lax

        return lax.scan(lambda value, item: (body(value, item), None), carry, items)[0]
    for index in range(len(items[0])):
        if until is not None and until(carry):
            break
        carry = body(carry, tuple(item[index] for item in items))
    return carry
