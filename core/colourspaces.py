"""Access to colour-science's RGB colourspaces without its optional-dependency chatter, and the
manifest's ``colorspace`` (docs/format/dataset.md): a colour-science name, primaries and a white point, or a
3 x 3 matrix to CIE XYZ.

A colourspace given by primaries or a matrix becomes a colour-science ``RGB_Colourspace``
registered in ``colour.RGB_COLOURSPACES`` under a name derived from its numbers (see
:func:`parse_colourspace`), so every tool that takes a colourspace name (display, chromaticity,
layer recovery, exports) uses it unchanged.

colour-science takes about a second to import (2 s on a busy machine), and most commands only
check the manifest's colourspace name or weigh the channels by luminance. Those answers come from
:mod:`.colourspace_table`, colour-science's own names and numbers written out, while the installed
colour-science is the version it was made from; any other name (another spelling, a custom
colourspace, an unknown name) and every conversion asks colour-science itself.
"""

from __future__ import annotations

import functools
import json
import math
import warnings

import numpy as np

from .colourspace_table import COLOUR_VERSION, COLOURSPACES

CUSTOM_PREFIX = "ringlight custom "
"""Start of the registered names of colourspaces given by primaries or a matrix."""
_CUSTOM_SOURCES: dict[str, dict] = {}
"""Registered custom name -> the manifest value it was built from (for stack.json)."""


@functools.cache
def colour_module():
    """Import and return the ``colour`` package.

    colour-science warns at import that SciPy and Matplotlib features are unavailable; ringlight
    uses neither, so those two usage warnings are silenced here and only here.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings(
            "ignore", message=r'"(SciPy|Matplotlib)" related API features are not available'
        )
        import colour
    return colour


@functools.cache
def _table_applies() -> bool:
    """Whether the installed colour-science is the version :mod:`.colourspace_table` was made
    from (read from its metadata, about 5 ms, without importing it)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("colour-science") == COLOUR_VERSION
    except PackageNotFoundError:
        return False


def _tabled(name: str) -> tuple | None:
    """The table's entry of ``name`` spelled as colour-science names it; None: ask colour-science."""
    return COLOURSPACES.get(name) if _table_applies() else None


def is_known_colourspace(name: str) -> bool:
    """True when ``name`` is an RGB colourspace colour-science knows (case-insensitive)."""
    if _tabled(name) is not None:
        return True
    return name in colour_module().RGB_COLOURSPACES and not name.startswith(CUSTOM_PREFIX)


def _numbers(value: object, shape: tuple[int, ...], what: str) -> np.ndarray:
    """``value`` (nested JSON lists) as a float64 array of ``shape`` with finite entries, else
    ValueError (strings and booleans are not numbers, though numpy would convert them)."""
    def flat(item):
        return [v for inner in item for v in flat(inner)] if isinstance(item, list) else [item]

    array = None
    if isinstance(value, list) and all(type(v) in (int, float) for v in flat(value)):
        try:
            array = np.array(value, dtype=np.float64)
        except (ValueError, OverflowError):  # ragged lists, integers beyond float64
            array = None
    if array is None or array.shape != shape or not np.isfinite(array).all():
        raise ValueError(f"{what} must be {' x '.join(map(str, shape))} finite numbers, got {_short(value)}")
    return array


def _short(value: object) -> str:
    text = json.dumps(value) if not isinstance(value, float) else repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def parse_colourspace(value: object) -> str:
    """The colourspace name for a manifest's ``colorspace`` value.

    Parameters
    ----------
    value
        A colour-science name (``"sRGB"``, ``"ACEScg"``), ``{"primaries": [[xR, yR], [xG, yG],
        [xB, yB]], "whitepoint": [xW, yW]}`` (CIE 1931 xy), or ``{"matrix": M}`` with M the
        3 x 3 matrix from linear RGB to CIE XYZ (rows X, Y, Z).

    Returns
    -------
    A name in ``colour.RGB_COLOURSPACES``: ``value`` itself for a name; for primaries or a matrix,
    a name starting with :data:`CUSTOM_PREFIX` that holds the numbers, under which an
    ``RGB_Colourspace`` is registered (a matrix's primaries and white point are the xy of its
    columns and of its row sums).

    Raises
    ------
    ValueError
        With one line saying what is wrong (unknown name, wrong keys, shape, a singular matrix).

    Examples
    --------
    >>> parse_colourspace("sRGB")
    'sRGB'
    >>> parse_colourspace({"matrix": [[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722],
    ...                               [0.0193, 0.1192, 0.9505]]})[:26]
    'ringlight custom matrix [['
    """
    if isinstance(value, str):
        if not is_known_colourspace(value):
            raise ValueError(f"{value!r} is not a colour-science RGB colourspace")
        return value
    colour = colour_module()
    if isinstance(value, dict) and set(value) == {"primaries", "whitepoint"}:
        primaries = _numbers(value["primaries"], (3, 2), "'colorspace.primaries'")
        whitepoint = _numbers(value["whitepoint"], (2,), "'colorspace.whitepoint'")
        if whitepoint[1] <= 0:
            raise ValueError(f"'colorspace.whitepoint' {_short(value['whitepoint'])} needs y > 0")
        name = (CUSTOM_PREFIX + "primaries " + " ".join(
            f"{label} ({x:.9g}, {y:.9g})" for label, (x, y) in zip("RGBW", [*primaries, whitepoint])))
        with np.errstate(all="ignore"):
            space = colour.RGB_Colourspace(name, primaries, whitepoint, use_derived_matrix_RGB_to_XYZ=True,
                                           use_derived_matrix_XYZ_to_RGB=True)
        if not np.isfinite(space.matrix_RGB_to_XYZ).all() or abs(np.linalg.det(space.matrix_RGB_to_XYZ)) < 1e-12:
            raise ValueError(f"'colorspace.primaries' {_short(value['primaries'])} do not span a colour space "
                             "(collinear, or a primary with y = 0)")
    elif isinstance(value, dict) and set(value) == {"matrix"}:
        matrix = _numbers(value["matrix"], (3, 3), "'colorspace.matrix'")
        column_sums, white = matrix.sum(axis=0), matrix.sum(axis=1)
        if abs(np.linalg.det(matrix)) < 1e-12 or (column_sums <= 0).any() or white[1] <= 0:
            raise ValueError(f"'colorspace.matrix' {_short(value['matrix'])} is not an RGB to XYZ matrix "
                             "(singular, or a primary or the white without positive X + Y + Z)")
        name = CUSTOM_PREFIX + "matrix " + json.dumps([[float(f"{v:.9g}") for v in row] for row in matrix])
        space = colour.RGB_Colourspace(name, colour.XYZ_to_xy(matrix.T), colour.XYZ_to_xy(white), None,
                                       matrix, np.linalg.inv(matrix))
    else:
        raise ValueError(f"must be a colourspace name, {{\"primaries\", \"whitepoint\"}} or {{\"matrix\"}}, "
                         f"got {_short(value)}")
    colour.RGB_COLOURSPACES[name] = space
    _CUSTOM_SOURCES[name] = value
    return name


def colourspace_json(name: str) -> str | dict:
    """The manifest value a colourspace name came from: the name itself, or the primaries or
    matrix of a custom one (what ``stack.json`` writes)."""
    return _CUSTOM_SOURCES.get(name, name)


def colourspace_chromaticities(name: str) -> np.ndarray:
    """(4, 2) float64 CIE 1931 xy of the colourspace's R, G, B primaries and white point."""
    if (entry := _tabled(name)) is not None:
        primaries, whitepoint, _ = entry
        return np.array(primaries + whitepoint, np.float64).reshape(4, 2)
    space = colour_module().RGB_COLOURSPACES[name]
    return np.vstack([np.asarray(space.primaries, np.float64), np.asarray(space.whitepoint, np.float64)])


def colourspace_luminance(name: str) -> np.ndarray:
    """(3,) float64 relative luminance weights: Y = weights @ RGB for linear RGB in the colourspace
    (the Y row of colour-science's RGB -> XYZ matrix, no chromatic adaptation).

    Examples
    --------
    >>> colourspace_luminance("sRGB").round(4).tolist()
    [0.2126, 0.7152, 0.0722]
    """
    if (entry := _tabled(name)) is not None:
        return np.array(entry[2], np.float64)
    return np.asarray(colour_module().RGB_COLOURSPACES[name].matrix_RGB_to_XYZ[1], np.float64)


def chromaticities_differ(file_xy, name: str, tolerance: float = 1e-3) -> bool:
    """True when a file's ``chromaticities`` (8 numbers: xy of R, G, B and white) differ from the
    colourspace's by more than ``tolerance`` in x or y (docs/format/dataset.md, "Frame files")."""
    file_xy = np.asarray(file_xy, np.float64).reshape(4, 2)
    return not bool(np.all(np.abs(file_xy - colourspace_chromaticities(name)) <= tolerance))


def describe_chromaticities(xy) -> str:
    """``"R (0.64, 0.33) G (0.3, 0.6) B (0.15, 0.06) W (0.3127, 0.329)"`` for (4, 2) or (8,) xy."""
    xy = np.asarray(xy, np.float64).reshape(4, 2)
    return " ".join(f"{label} ({x:.4g}, {y:.4g})" for label, (x, y) in zip("RGBW", xy) if math.isfinite(x + y))
