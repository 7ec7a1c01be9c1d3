"""Numbers as text with how sure we are of them: a value and its standard error, the value given
to the digit its error allows (the usual rule: the error to two significant digits)."""

from __future__ import annotations

import math

FREE_DIGITS = 4
"""Significant digits of a value shown without an error (none estimated yet, or none defined)."""
SIGNIFICANT_LIMIT = 7
"""Most significant digits a value is given to (float32 holds about 7)."""


def with_error(value: float, error: float | None) -> str:
    """``value`` and its standard error ``error`` as ``0.1912±0.0031``: the error to two
    significant digits and the value to the same decimal; in a shared power of ten
    (``(2.48±0.13)e-05``) when plain decimals would need more than six places or the value is
    10^6 or more. Without a finite error, the value to :data:`FREE_DIGITS` significant digits; an
    error of 0 (ring members all alike: a laterally uniform simulation) is shown as ``±0``; a
    value that is not finite is ``undefined``."""
    if not math.isfinite(value):
        return "undefined"
    if error is None or not math.isfinite(error) or error < 0:
        return f"{value:.{FREE_DIGITS}g}"
    if error == 0:
        return f"{value:.{FREE_DIGITS}g}±0"
    last = math.floor(math.log10(error)) - 1  # the power of ten of the error's second digit
    if round(error, -last) >= 10.0 ** (last + 2):  # 0.0996 rounds to 0.100: two digits are 0.10
        last += 1
    exponent = math.floor(math.log10(max(abs(value), error)))
    if exponent - last > SIGNIFICANT_LIMIT:  # an error below the value's float32 precision
        return f"{value:.{SIGNIFICANT_LIMIT}g}±{error:.2g}"
    if -6 <= last and abs(value) < 1e6:
        decimals = max(0, -last)
        return f"{round(value, -last) + 0.0:.{decimals}f}±{round(error, -last):.{decimals}f}"
    scale = 10.0 ** exponent
    decimals = max(0, exponent - last)
    return f"({value / scale + 0.0:.{decimals}f}±{error / scale:.{decimals}f})e{exponent:+03d}"


def with_errors(values, errors, separator: str = " / ") -> str:
    """Each of ``values`` with its standard error (:func:`with_error`), joined by ``separator``:
    ``0.03228±0.00017 / 0.1709±0.0003 / 0.4794±0.0006`` for three channels."""
    return separator.join(with_error(float(value), float(error)) for value, error in zip(values, errors))
