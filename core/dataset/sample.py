"""What a manifest states of the sample's surface (its optional ``sample`` key, revision
2026-11-26 of the dataset format): refractive index and phase function anisotropy."""

from __future__ import annotations

from dataclasses import dataclass

from ..validation import Validator

_SAMPLE_KEYS = {"n", "g"}
INDEX_RANGE = (1.0, 3.0)
"""Refractive indices a manifest's ``sample.n`` may state (air to the densest glasses)."""


@dataclass(frozen=True)
class Sample:
    """What is known of the surface (the manifest's optional ``sample`` key): refractive index ``n``
    in [1, 3] and Henyey-Greenstein anisotropy ``g`` in (-1, 1); None where not stated. The
    simulator writes its scene's; a user may state them for a real capture; tools (the layer
    inversion) take them as defaults."""

    n: float | None = None
    g: float | None = None


def parse_sample(check: Validator, value: object) -> Sample:
    """The ``sample`` key: ``{"n": ..., "g": ...}``, each optional."""
    doc = check.mapping(value, "sample", _SAMPLE_KEYS, set())
    n = check.number(doc["n"], "sample.n") if "n" in doc else None
    if n is not None and not INDEX_RANGE[0] <= n <= INDEX_RANGE[1]:
        raise check.fail("sample.n", f"a refractive index in [{INDEX_RANGE[0]:g}, {INDEX_RANGE[1]:g}]", doc["n"])
    g = check.number(doc["g"], "sample.g") if "g" in doc else None
    if g is not None and not -1.0 < g < 1.0:
        raise check.fail("sample.g", "an anisotropy in (-1, 1)", doc["g"])
    return Sample(n, g)


def sample_json(sample: Sample) -> dict | None:
    """The ``sample`` key of ``sample`` as a manifest writes it; None when nothing is stated."""
    stated = {key: value for key, value in (("n", sample.n), ("g", sample.g)) if value is not None}
    return stated or None
