"""Access to colour-science's RGB colourspaces without its optional-dependency chatter."""

from __future__ import annotations

import functools
import warnings


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


def is_known_colourspace(name: str) -> bool:
    """True when ``name`` is an RGB colourspace colour-science knows (case-insensitive)."""
    return name in colour_module().RGB_COLOURSPACES
