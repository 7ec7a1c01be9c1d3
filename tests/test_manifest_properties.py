"""Property tests: any manifest either parses or raises DatasetError, never anything else."""

import json
from pathlib import Path

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from ringlight.core import DatasetError
from ringlight.core.dataset.manifest import parse_manifest

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-5, 50) | st.floats(allow_nan=False) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=12,
)

points = st.lists(st.tuples(st.integers(0, 9), st.integers(0, 9)), min_size=1, max_size=4, unique=True)


@st.composite
def manifests(draw):
    frames = [
        {"file": f"f{i}.exr", "lit": [list(p) for p in draw(points)]}
        for i in range(draw(st.integers(1, 4)))
    ]
    manifest = {"format": "ringlight-impulse", "version": 1,
                "grid": {"height": 10, "width": 10}, "frames": frames}
    if draw(st.booleans()):
        manifest["max_radius"] = draw(st.floats(0.5, 6))
    key = draw(st.sampled_from([None, "format", "version", "grid", "frames", "max_radius",
                                "colorspace", "dark", "ground_truth", "extra"]))
    if key is not None:
        manifest[key] = draw(json_values)
    return manifest


@settings(max_examples=300, deadline=None)
@given(manifests())
def test_any_manifest_parses_or_raises_a_dataset_error(manifest):
    try:
        parsed = parse_manifest(json.loads(json.dumps(manifest)), Path("ds"))
    except DatasetError as error:
        assert "ds/dataset.json" in str(error)
        return
    # A manifest that parses obeys the multiplexing rule of FORMAT.md.
    if parsed.multiplexed:
        for frame in parsed.frames:
            diff = frame.lit[:, None, :] - frame.lit[None, :, :]
            dist = (diff ** 2).sum(-1) ** 0.5
            dist[range(len(dist)), range(len(dist))] = 1e9
            assert dist.min() > 2 * parsed.max_radius


def test_close_pair_with_groups_agrees_with_brute_force():
    """The all-frames-at-once spacing check: a close pair is found exactly when two points of one
    group (frame) lie within the limit, and what it returns is such a pair."""
    import math

    from ringlight.core.dataset.spacing import close_pair

    rng = np.random.default_rng(0)
    for _ in range(500):
        count = int(rng.integers(2, 30))
        points = rng.integers(0, 60, (count, 2))
        groups = rng.integers(0, 3, count)
        limit = float(rng.uniform(1, 12))
        distance = np.hypot(*(points[:, None] - points[None]).transpose(2, 0, 1))
        np.fill_diagonal(distance, np.inf)
        close = (distance <= limit) & (groups[:, None] == groups[None])
        found = close_pair(points, limit, groups)
        assert (found is not None) == close.any()
        if found is not None:
            a, b = found
            assert groups[a] == groups[b] and math.dist(points[a], points[b]) <= limit


def test_close_pair_in_one_sweep_agrees_with_brute_force_on_whether_there_is_one():
    """The forward sweep (first=False) answers only whether some pair is within the limit: the
    brute force over all pairs of a group says the same, and a pair it returns is one."""
    from ringlight.core.dataset.spacing import close_pair

    rng = np.random.default_rng(7)
    for trial in range(300):
        count = int(rng.integers(2, 40))
        points = rng.integers(0, int(rng.integers(3, 60)), size=(count, 2)).astype(np.int64)
        groups = rng.integers(0, int(rng.integers(1, 4)), size=count).astype(np.int64)
        limit = float(rng.choice([0.0, 1.0, 1.5, 2.0, 4.4, 7.0]))
        distance = np.hypot(*(points[:, None] - points[None]).transpose(2, 0, 1))
        close = (distance <= limit) & (groups[:, None] == groups[None]) & ~np.eye(count, dtype=bool)
        found = close_pair(points, limit, groups, first=False)
        assert (found is not None) == bool(close.any()), (trial, found)
        if found is not None:
            assert close[found[0], found[1]], (trial, found)
