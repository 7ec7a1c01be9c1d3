"""How much memory opening a dataset may use: a budget, not a fixed limit.

The budget is :data:`BUDGET_FRACTION` of the memory available now (psutil's ``available``: free
plus reclaimable page cache), or ``$RINGLIGHT_MEMORY_BUDGET`` (bytes, or with a K, M, G or T
suffix: ``4G``). A dataset whose response array fits the budget is assembled in memory; a larger
one is assembled band by band into its store and read from it lazily (:mod:`.response_store`).
"""

from __future__ import annotations

import os
import re

import numpy as np
import psutil

from ..errors import RinglightError

BUDGET_FRACTION = 0.25
"""Share of the available memory a dataset open may fill: an out-of-core open assembles bands of
half the budget (with batches of frames of at most an eighth) and keeps decoded bands up to half
of it, so that it stays within the budget, beside whatever else the machine runs."""
MIN_BUDGET = 64 * 2**20
"""Smallest budget taken (bytes): below it a band holds too few rows to be worth a pass."""
_SIZE = re.compile(r"\s*(\d+(?:\.\d+)?)\s*([KMGT]?)i?B?\s*", re.IGNORECASE)


def memory_budget() -> int:
    """Bytes a dataset open may use (module docstring); at least :data:`MIN_BUDGET`."""
    text = os.environ.get("RINGLIGHT_MEMORY_BUDGET")
    if text:
        return max(parse_size(text, "$RINGLIGHT_MEMORY_BUDGET"), MIN_BUDGET)
    return max(int(BUDGET_FRACTION * psutil.virtual_memory().available), MIN_BUDGET)


def parse_size(text: str, what: str) -> int:
    """``"4G"``, ``"512M"``, ``"1.5GiB"`` or plain bytes -> bytes (powers of 1024)."""
    match = _SIZE.fullmatch(text)
    if not match:
        raise RinglightError(f"{what}: {text!r} is not a size (bytes, or a number with K, M, G or T)")
    size = float(match.group(1)) * 1024 ** " KMGT".index(match.group(2).upper() or " ")
    if not size < 2**63:  # infinity too: "1" and 400 zeros
        raise RinglightError(f"{what}: {text[:40]!r} is not a size (over 8 EiB)")
    return int(size)


def size_setting(variable: str, default: int) -> int:
    """Bytes the environment variable ``variable`` sets (:func:`parse_size`), else ``default``.
    Raises RinglightError naming the variable when it is not a size."""
    text = os.environ.get(variable)
    return parse_size(text, f"${variable}") if text else default


def format_bytes(count: float) -> str:
    """``count`` bytes in the largest binary unit that keeps it at least 1, e.g. ``"3.2 MiB"``."""
    for unit in ("B", "KiB", "MiB"):
        if abs(count) < 1024:
            return f"{count:.0f} {unit}" if unit == "B" else f"{count:.1f} {unit}"
        count /= 1024
    return f"{count:.1f} GiB"


def zeroed(shape: tuple[int, ...], dtype) -> np.ndarray:
    """A zero array of ``shape`` whose pages are all faulted in up front by this thread
    (``np.empty``, then filled) rather than lazily by whichever threads first write to it
    (``np.zeros``). Measured in a 256 px first open (1.3 GiB of responses, three runs each,
    alternated): the compiled scatter's threads writing into ``np.zeros`` took 2.8-3.2 s, into
    this 1.7-1.9 s after a fill of 0.15-0.27 s."""
    array = np.empty(shape, dtype)
    array.fill(0)
    return array
