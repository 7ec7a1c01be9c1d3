"""Fuzzing the input side: hostile manifests and mutated EXR files against the contract.

The contract (issue 11): whatever the bytes on disk, ``read_manifest``, ``open_dataset`` and
``check_files`` either succeed or raise a :class:`RinglightError` whose message is one line; no
case allocates over 256 MiB (tracemalloc's peak) or grows the process by 1 GiB. Time is not
asserted (a loaded machine is slow at anything): ``benchmarks/bench_manifest.py --hostile`` times
the hostile manifests. A few hundred cases run in CI; for the long campaign set
``RINGLIGHT_FUZZ_CASES`` (manifests, e.g. 10000) and ``RINGLIGHT_FUZZ_EXR_CASES`` (EXR files,
e.g. 2000). With ``RINGLIGHT_FUZZ_REPORT=FILE`` each test appends its counts (cases, errors of
ours, largest allocation peak per case, growth of the peak resident memory) to FILE.
"""

import json
import os
import resource
import shutil
import tempfile
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from reference import write_dataset, write_exr, write_rgb
from ringlight.core import RinglightError, open_dataset
from ringlight.core.dataset.checks import check_files
from ringlight.core.dataset.manifest import read_manifest

MANIFEST_CASES = int(os.environ.get("RINGLIGHT_FUZZ_CASES", "250"))
EXR_CASES = int(os.environ.get("RINGLIGHT_FUZZ_EXR_CASES", "150"))
MAX_PEAK_BYTES = 1024 * 2**20
"""A case's traced peak: a 4 x 3 grid may state a max_radius up to the format's 1024, whose
responses (3.3 million offsets per point) take 475 MiB by design; a blow-up is far beyond."""
MAX_GROWTH_BYTES = 2**30

HEIGHT, WIDTH = 4, 3


def maxrss_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux reports KiB


class Campaign:
    """Runs cases under the contract and keeps the counts the issue asks for."""

    def __init__(self, name):
        self.name = name
        self.cases = self.ours = 0
        self.largest = 0
        self.baseline = maxrss_bytes()

    def run(self, action):
        # Anything but our error escapes and fails the test: hypothesis then shrinks and reports it.
        tracemalloc.start()
        try:
            action()
        except RinglightError as error:
            self.ours += 1
            message = str(error)
            assert message and "\n" not in message, repr(message)
        finally:
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        self.cases += 1
        self.largest = max(self.largest, peak)
        assert peak < MAX_PEAK_BYTES, f"a case allocated {peak / 2**20:.0f} MiB at its peak"
        assert maxrss_bytes() - self.baseline < MAX_GROWTH_BYTES, "a case grew the process by over 1 GiB"

    def report(self):
        line = (f"{self.name}: {self.cases} cases, {self.ours} refused with RinglightError, 0 other "
                f"exceptions, largest allocation peak {self.largest / 2**20:.1f} MiB, peak RSS growth "
                f"{(maxrss_bytes() - self.baseline) / 2**20:.0f} MiB\n")
        if os.environ.get("RINGLIGHT_FUZZ_REPORT"):
            with open(os.environ["RINGLIGHT_FUZZ_REPORT"], "a") as handle:
                handle.write(line)


@pytest.fixture(scope="module")
def workspace():
    """A valid 4 x 3 dataset (12 frames, a dark frame, a camera mapping) to break, and a scratch
    folder per case; module-scoped because hypothesis runs many cases per test."""
    root = Path(tempfile.mkdtemp(prefix="ringlight-fuzz-"))
    rng = np.random.default_rng(0)
    impulses = {(y, x): rng.random((HEIGHT, WIDTH, 3)).astype(np.float32)
                for y in range(HEIGHT) for x in range(WIDTH)}
    manifest = write_dataset(root / "valid", HEIGHT, WIDTH, impulses)
    write_rgb(root / "valid" / "dark.exr", np.full((HEIGHT, WIDTH, 3), 0.01, np.float32))
    y, x = np.mgrid[:HEIGHT, :WIDTH].astype(np.float32)
    write_exr(root / "valid" / "mapping.exr", {"y": y, "x": x})
    yield root, manifest
    shutil.rmtree(root, ignore_errors=True)


def fresh_copy(root: Path) -> Path:
    case = root / "case"
    shutil.rmtree(case, ignore_errors=True)
    shutil.copytree(root / "valid", case)
    return case


# Hostile manifests ----------------------------------------------------------------------------

class ManifestText(str):
    """A manifest's text whose repr stays short in hypothesis's reports."""

    def __repr__(self):
        return f"ManifestText({str.__repr__(self[:300])}{' ...' if len(self) > 300 else ''}, {len(self)} chars)"


RAW = "\0raw\0"
"""Marks a string to be written as raw JSON text (what json.dumps cannot produce)."""

hostile_raw = st.sampled_from([
    "NaN", "Infinity", "-Infinity", "1e999", "-1e999", "1e-320", "4.9e-324", "1e39", "-0.0",
    "9" * 31, "9" * 401, "9" * 5000, "-" + "9" * 40, "[" * 5000 + "]" * 5000,
    '{"a":' * 3000 + "1" + "}" * 3000, '"\\ud800"', '"\\udc80x"', '"a\\u0000b"',
])
hostile_strings = st.one_of(
    st.text(max_size=12),
    st.sampled_from(["", "/", "..", "../x.exr", "/etc/passwd", "frames/../../x", "a" * 300,
                     "/".join(["b" * 200] * 8), "frames\\00000.exr", "frames/00000.exr",
                     "dark.exr", "mapping.exr", "dataset.json", ".", "frames", "sRGB", "camera",
                     "grid", "ringlight-impulse"]),
)
hostile_numbers = st.one_of(
    st.integers(-3, 20), st.integers(-2**70, 2**70), st.floats(allow_nan=False),
    st.sampled_from([0, 1, 2**31, 2**63, 8192, 8193, 1e-38, 1e-45, 3.4e38, 1e300, 0.5, 1024, 1025]),
)
hostile_values = st.recursive(
    st.none() | st.booleans() | hostile_numbers | hostile_strings | hostile_raw.map(lambda s: RAW + s),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(hostile_strings, inner, max_size=4),
    max_leaves=10,
)


def paths_of(document, prefix=()):
    """Every path (tuple of keys and indexes) into a JSON document."""
    yield prefix
    if isinstance(document, dict):
        for key, value in document.items():
            yield from paths_of(value, (*prefix, key))
    elif isinstance(document, list):
        for index, value in enumerate(document):
            yield from paths_of(value, (*prefix, index))


def set_at(document, path, value):
    if not path:
        return value
    target = document
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    return document


def dumps(document) -> str:
    """json.dumps, with RAW-marked strings written as their raw text."""
    text = json.dumps(document, allow_nan=True)
    for raw in sorted(set(_raw_strings(document)), key=len, reverse=True):
        text = text.replace(json.dumps(raw), raw[len(RAW):])
    return text


def _raw_strings(value):
    if isinstance(value, str) and value.startswith(RAW):
        yield value
    elif isinstance(value, dict):
        for item in value.values():
            yield from _raw_strings(item)
    elif isinstance(value, list):
        for item in value:
            yield from _raw_strings(item)


@st.composite
def hostile_manifests(draw, valid):
    """A valid manifest with 1 to 4 mutations: a value replaced by a hostile one, a key removed
    or added, multiplexing and camera options switched on, frames multiplied."""
    document = json.loads(json.dumps(valid))
    for option in draw(st.lists(st.sampled_from(
            ["dark", "camera", "max_radius", "multiplex", "many-frames", "ground-truth", "big-grid"]),
            max_size=3, unique=True)):
        if option == "dark":
            document["dark"] = "dark.exr"
        elif option == "camera":
            document.update(frame_space="camera", mapping="mapping.exr")
        elif option == "max_radius":
            document["max_radius"] = draw(st.sampled_from([0.5, 1.0, 1.5, 1024, 1e-300]))
        elif option == "multiplex":
            document["frames"][0]["lit"] = [[0, 0], [HEIGHT - 1, WIDTH - 1]]
        elif option == "many-frames":
            document["frames"] = document["frames"] * draw(st.integers(2, 200))
        elif option == "ground-truth":
            document["ground_truth"] = {"path_length_images": [{"file": "frames/00000.exr", "min": 0, "max": 1}],
                                        "layers": [{"name": "a", "depth": [0, 1], "rgb": [0.1, 0.2, 0.3]}]}
        else:
            document["grid"] = {"height": draw(st.sampled_from([1, 4096, 8192, 2**26, 10**6])),
                                "width": draw(st.sampled_from([1, 3, 4096, 8192]))}
    for _ in range(draw(st.integers(1, 4))):
        paths = list(paths_of(document))
        path = draw(st.sampled_from(paths))
        action = draw(st.sampled_from(["replace", "replace", "delete", "add"]))
        if action == "replace":
            document = set_at(document, path, draw(hostile_values))
        elif action == "delete" and path:
            parent = document
            for key in path[:-1]:
                parent = parent[key]
            del parent[path[-1]]
        elif action == "add":
            parent = document
            for key in path:
                parent = parent[key]
            if isinstance(parent, dict):
                parent[draw(hostile_strings)] = draw(hostile_values)
            elif isinstance(parent, list):
                parent.append(draw(hostile_values))
        if not isinstance(document, (dict, list)):
            break
    return ManifestText(dumps(document))


def test_hostile_manifests_give_our_error_or_a_dataset(workspace):
    root, valid = workspace
    campaign = Campaign("manifests")

    @settings(max_examples=MANIFEST_CASES, deadline=None, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(hostile_manifests(valid))
    def case(text):
        folder = root / "valid"
        (folder / "dataset.json").write_text(text, encoding="utf-8", errors="surrogatepass")

        def action():
            manifest = read_manifest(folder)
            check_files(manifest)
            open_dataset(manifest, use_cache=False)

        campaign.run(action)

    try:
        case()
    finally:
        (root / "valid" / "dataset.json").write_text(json.dumps(valid))
        campaign.report()
    assert campaign.cases >= MANIFEST_CASES // 2


# Mutated EXR files ----------------------------------------------------------------------------

@st.composite
def mutations(draw, size):
    """A list of byte edits of a file of ``size`` bytes, most of them in the header, where a
    mutation changes what the library believes about the file."""
    edits = []
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "flip", "byte", "int32", "truncate", "insert", "delete"]))
        head = draw(st.booleans())
        at = draw(st.integers(0, min(size, 400) - 1 if head else size - 1))
        if kind == "flip":
            edits.append(("flip", at, 1 << draw(st.integers(0, 7))))
        elif kind == "byte":
            edits.append(("byte", at, draw(st.sampled_from([0, 1, 0x7F, 0x80, 0xFF]))))
        elif kind == "int32":
            edits.append(("int32", at, draw(st.sampled_from(
                [0, 1, -1, 2**31 - 1, -2**31, 8191, 65535, 10**6]))))
        elif kind == "truncate":
            edits.append(("truncate", at, 0))
        elif kind == "insert":
            edits.append(("insert", at, draw(st.binary(min_size=1, max_size=16))))
        else:
            edits.append(("delete", at, draw(st.integers(1, 64))))
    return edits


def mutate(data: bytes, edits) -> bytes:
    data = bytearray(data)
    for kind, at, value in edits:
        at = min(at, max(len(data) - 1, 0))
        if kind == "flip" and data:
            data[at] ^= value
        elif kind == "byte" and data:
            data[at] = value
        elif kind == "int32":
            data[at:at + 4] = int(value).to_bytes(4, "little", signed=True)
        elif kind == "truncate":
            del data[at:]
        elif kind == "insert":
            data[at:at] = value
        else:
            del data[at:at + value]
    return bytes(data)


TARGETS = ["frames/00005.exr", "frames/00000.exr", "dark.exr", "mapping.exr"]


def test_mutated_exr_files_give_our_error_or_a_dataset(workspace):
    root, valid = workspace
    campaign = Campaign("EXR files")
    originals = {name: (root / "valid" / name).read_bytes() for name in TARGETS}

    @settings(max_examples=EXR_CASES, deadline=None, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(st.sampled_from(TARGETS), st.data())
    def case(target, data):
        edits = data.draw(mutations(len(originals[target])))
        case_folder = fresh_copy(root)
        (case_folder / target).write_bytes(mutate(originals[target], edits))
        document = dict(valid)
        if target == "dark.exr":
            document["dark"] = "dark.exr"
        elif target == "mapping.exr":
            document.update(frame_space="camera", mapping="mapping.exr")
        (case_folder / "dataset.json").write_text(json.dumps(document))

        def action():
            manifest = read_manifest(case_folder)
            problems = check_files(manifest)
            assert all(problem and "\n" not in problem for problem in problems)
            opened = open_dataset(manifest, use_cache=False)
            # A file that opens must have passed the header checks as well.
            assert problems == [], problems
            assert opened.responses.shape[:2] == (HEIGHT, WIDTH)

        campaign.run(action)

    try:
        case()
    finally:
        campaign.report()
    assert campaign.cases >= EXR_CASES // 2
