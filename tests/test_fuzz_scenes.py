"""Scene files (FORMAT.md "Scene description") with hostile values: every one is a scene whose
simulation fits its limits, or SceneError's one line naming the file, within bounded memory
(issue 40, cases 6 and 10). Hypothesis mutates a small valid scene at one to three places."""

from __future__ import annotations

import copy
import json
import tracemalloc

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from ringlight.app.main import main
from ringlight.core.simulate.scene import (
    MAX_COEFFICIENT,
    MAX_SIMULATION_BYTES,
    SceneError,
    parse_scene,
    read_scene,
    simulation_bytes,
)

BASE = {
    "format": "ringlight-scene", "version": 1, "grid": {"height": 8, "width": 8}, "depth": 10, "n": 1.4,
    "materials": {"skin": {"mus": [1, 1, 1], "mua": [0.1, 0.2, 0.3], "g": 0.5},
                  "base": {"mus": [2, 2, 2], "mua": [0.01, 0.01, 0.01]}},
    "background": "base",
    "layers": [{"material": "skin", "top": 0, "bottom": 2}],
    "shapes": [{"type": "sphere", "material": "skin", "center": [4, 4, 5], "radius": 2},
               {"type": "star", "material": "skin", "center": [4, 4], "top": 1, "bottom": 3, "points": 5,
                "outer": 3, "inner": 1}],
    "photons_per_point": 100, "max_radius": 4, "path_length_bins": {"step": 1, "count": 16}, "seed": 3,
}
PATHS = [
    ("grid", "height"), ("grid", "width"), ("grid", "pitch_mm"), ("depth",), ("n",),
    ("materials", "skin", "mus"), ("materials", "skin", "mua"), ("materials", "skin", "g"),
    ("materials", "skin", "mus", 0), ("materials", "base", "mua", 2), ("background",), ("layers",),
    ("layers", 0, "top"), ("layers", 0, "bottom"), ("shapes", 0, "radius"), ("shapes", 0, "center", 2),
    ("shapes", 1, "points"), ("shapes", 1, "outer"), ("shapes", 1, "inner"), ("shapes", 1, "center"),
    ("photons_per_point",), ("max_radius",), ("path_length_bins", "count"), ("path_length_bins", "step"),
    ("seed",), ("format",), ("version",), ("shapes",), ("materials",),
]
HOSTILE = st.sampled_from([
    0, -1, 1, 3, 255, 256, 2**31, 2**53 + 1, 2**63, 10**400, 1e308, 1e-320, -0.0, 0.5, True, None, "x", "",
    [], {}, [1, 2], [1e308] * 3, [2**53 + 1] * 3, [[1]], "NaN",
]) | st.integers() | st.floats(allow_nan=False, allow_infinity=False)
FUZZ = settings(max_examples=400, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])


def mutated(document, path, value):
    target = document
    for step in path[:-1]:
        if not isinstance(target, (dict, list)):
            return document
        try:
            target = target[step]
        except (KeyError, IndexError, TypeError):
            return document
    if isinstance(target, dict) or (isinstance(target, list) and isinstance(path[-1], int)
                                    and path[-1] < len(target)):
        target[path[-1]] = value
    return document


def parsed_within_memory(document, limit=256 * 2**20):
    """parse_scene's Scene or SceneError, and the peak of the memory Python allocated."""
    tracemalloc.start()
    try:
        try:
            outcome = parse_scene(document, where="hostile.json")
        except SceneError as error:
            outcome = error
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < limit, f"{peak / 2**20:.0f} MiB"
    return outcome


@FUZZ
@given(st.lists(st.tuples(st.sampled_from(PATHS), HOSTILE), min_size=1, max_size=3))
def test_a_hostile_scene_is_a_bounded_scene_or_one_line(mutations):
    document = copy.deepcopy(BASE)
    for path, value in mutations:
        document = mutated(document, path, value)
    outcome = parsed_within_memory(document)
    if isinstance(outcome, SceneError):
        message = str(outcome)
        assert message.startswith("hostile.json: ") and "\n" not in message, message
    else:
        assert simulation_bytes(outcome.height, outcome.width, outcome.max_radius,
                                outcome.bin_count) <= MAX_SIMULATION_BYTES
        assert max(max(m.mus + m.mua) for m in outcome.materials) <= MAX_COEFFICIENT


@pytest.mark.parametrize("change, expected", [
    ({"path_length_bins": {"step": 1, "count": 2**22}}, r"would take .* GiB .*path_length_bins.count 4194304"),
    ({"max_radius": 3e5}, r"would take .* GiB .*max_radius 300000"),
    ({"max_radius": 2.0**53 + 1}, r"would take .* GiB"),
    ({"grid": {"height": 4000, "width": 4000}, "depth": 4}, r"would take .* GiB"),
    ({"materials": {"base": {"mus": [1, 1, 1], "mua": [1e308] * 3}}}, r"'materials.base.mua' is 1e\+308 per grid step"),
    ({"materials": {"base": {"mus": [1, 1, 1], "mua": [2**31] * 3}}}, r"'materials.base.mua' is 2.14748e\+09"),
    ({"materials": {"base": {"mus": [2**53 + 1] * 3, "mua": [2**53 + 1] * 3}}}, r"'materials.base.mus' is 9.0072e\+15"),
    ({"shapes": [{"type": "star", "material": "base", "center": [4, 4], "top": 1, "bottom": 3, "points": 10**9,
                  "outer": 3, "inner": 1}]}, r"'shapes\[0\]' needs 2 <= points <= 360"),
    ({"layers": [{"material": "base", "top": i / 1000, "bottom": (i + 1) / 1000} for i in range(20000)]},
     r"'layers' lists 20000 entries, at most 256"),
])
def test_the_issues_scenes_are_one_line_before_any_allocation(tmp_path, capsys, change, expected):
    """Case 6: MemoryError for 805 GiB of path-length bins and 3 PiB of windows, "array is too big"
    for max_radius 2^53 + 1; case 10: coefficients that spun in the reference kernel, a star with
    a huge ``points``, 20 000 layers."""
    document = {key: value for key, value in copy.deepcopy(BASE).items() if key not in ("layers", "shapes")}
    document["materials"] = {"base": BASE["materials"]["base"]}
    document.update(change)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(document))
    with pytest.raises(SceneError, match=expected):
        read_scene(path)
    assert isinstance(parsed_within_memory(document, limit=64 * 2**20), SceneError)
    status = main(["simulate", str(path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and err[0].startswith(f"ringlight: error: {path}: ")
    assert not (tmp_path / "out").exists()
