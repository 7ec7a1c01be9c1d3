"""The JSON Schemas shipped in ``ringlight.resources.schemas`` against ringlight's own checks.

Agreement (issue 39): every manifest ringlight's parser accepts validates against the dataset
schema, on the hostile-input corpus (the fuzz campaign's mutations of a valid manifest, the
property tests' manifests, the refusals the bad-input tests name and the keys a rig's frames
use), and every dataset, scene and stack export the project writes validates against its schema.
The schemas cannot see the files, nor compare one value with another (a lit point with the
grid); what they leave to the code is listed in their descriptions and in docs/format. So the
converse is checked as a floor, not an equality: of the manifests the parser refuses, the schema
must refuse those whose fault is one of structure or type.
"""

import json
from dataclasses import replace
from importlib import resources
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from reference import random_impulses, write_dataset
from ringlight.app.main import main
from ringlight.core import DatasetError, open_dataset, radius_range, ring_stack, transient_stack, write_stack
from ringlight.core.dataset.manifest import MANIFEST_NAME, parse_manifest
from ringlight.core.rings.coverage import ring_coverage
from ringlight.core.simulate.presets import load_scene
from ringlight.core.simulate.replicates import simulate_replicates
from ringlight.core.simulate.samples import sample_dataset, sample_names
from ringlight.core.simulate.scene import SceneError, parse_scene
from ringlight.core.simulate.transport import simulate_transport, write_transport
from ringlight.core.validation import decode_json
from test_fuzz_input import HEIGHT, MANIFEST_CASES, WIDTH, hostile_manifests
from test_manifest_properties import manifests as property_manifests

SCHEMAS = ("dataset", "scene", "stack")


def schema(name: str) -> jsonschema.Draft202012Validator:
    """The installed package's schema ``name`` (package data, as a user of the wheel gets it)."""
    text = resources.files("ringlight.resources.schemas").joinpath(f"{name}.schema.json").read_text("utf-8")
    document = json.loads(text)
    jsonschema.Draft202012Validator.check_schema(document)
    return jsonschema.Draft202012Validator(document)


DATASET, SCENE, STACK = (schema(name) for name in SCHEMAS)


def parser_accepts(document) -> bool:
    try:
        parse_manifest(document, Path("ds"))
    except DatasetError:
        return False
    return True


def schema_errors(validator, document) -> list[str]:
    return [f"{'/'.join(map(str, error.absolute_path))}: {error.message[:200]}"
            for error in validator.iter_errors(document)]


def assert_accepted_validates(document) -> bool:
    """The agreement: a manifest the parser accepts is valid under the schema. Returns whether
    the parser accepted it."""
    if not parser_accepts(document):
        return False
    assert not (errors := schema_errors(DATASET, document)), errors
    return True


@pytest.mark.parametrize("name", SCHEMAS)
def test_the_schemas_are_draft_2020_12_and_name_their_format(name):
    document = schema(name).schema
    assert document["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert document["properties"]["format"] == {"const": f"ringlight-{'impulse' if name == 'dataset' else name}"}
    assert document["properties"]["version"] == {"const": 1}


def valid_manifest() -> dict:
    """The fuzz campaign's starting point: a 4 x 3 dataset lit one point per frame."""
    return {"format": "ringlight-impulse", "version": 1, "grid": {"height": HEIGHT, "width": WIDTH},
            "frames": [{"file": f"frames/{index:05d}.exr", "lit": [[y, x]]}
                       for index, (y, x) in enumerate((y, x) for y in range(HEIGHT) for x in range(WIDTH))]}


def test_hostile_manifests_the_parser_accepts_validate_against_the_schema():
    """The fuzz campaign's generator (tests/test_fuzz_input.py): hostile values, removed and added
    keys, multiplexing, camera frames, huge grids. Each text is decoded by ringlight's bounded
    reader (NaN, huge integers and deep nesting are refused there, before any schema)."""
    counts = {"accepted": 0, "refused": 0, "refused by the schema too": 0}

    @settings(max_examples=MANIFEST_CASES, deadline=None, database=None, derandomize=True,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(hostile_manifests(valid_manifest()))
    def case(text):
        try:
            document = decode_json(text.encode("utf-8", "surrogatepass"), MANIFEST_NAME, DatasetError, "manifest")
        except DatasetError:
            counts["refused"] += 1
            return
        if assert_accepted_validates(document):
            counts["accepted"] += 1
        else:
            counts["refused"] += 1
            counts["refused by the schema too"] += not DATASET.is_valid(document)

    case()
    # Both kinds occur (derandomized: the same cases every run); most refusals are structural,
    # and the schema refuses those too (212 of 243 when written).
    assert counts["accepted"] >= 3 and counts["refused"] >= MANIFEST_CASES // 4, counts
    assert counts["refused by the schema too"] >= counts["refused"] // 2, counts


@settings(max_examples=300, deadline=None, derandomize=True)
@given(property_manifests())
def test_the_property_tests_manifests_the_parser_accepts_validate(manifest):
    assert_accepted_validates(json.loads(json.dumps(manifest)))


def refusals():
    """Manifests the parser refuses for their structure or types (the bad-input tests' cases and
    more): the schema refuses each of them too."""
    def changed(change):
        document = valid_manifest()
        change(document)
        return document

    yield "wrong format", changed(lambda m: m.update(format="something-else"))
    yield "version 2", changed(lambda m: m.update(version=2))
    yield "version true", changed(lambda m: m.update(version=True))
    yield "height a string", changed(lambda m: m["grid"].update(height="6"))
    yield "height 0", changed(lambda m: m["grid"].update(height=0))
    yield "frames an object", changed(lambda m: m.update(frames={}))
    yield "no frames", changed(lambda m: m.update(frames=[]))
    yield "negative exposure", changed(lambda m: m["frames"][0].update(exposure=-1))
    yield "exposure beyond float32", changed(lambda m: m["frames"][0].update(exposure=1e39))
    yield "max_radius true", changed(lambda m: m.update(max_radius=True))
    yield "max_radius over 1024", changed(lambda m: m.update(max_radius=1025))
    yield "a lit point of halves", changed(lambda m: m["frames"][1].update(lit=[[0.5, 1]]))
    yield "a lit point of three", changed(lambda m: m["frames"][1].update(lit=[[0, 1, 2]]))
    yield "no lit point", changed(lambda m: m["frames"][1].update(lit=[]))
    yield "a negative lit point", changed(lambda m: m["frames"][1].update(lit=[[-1, 0]]))
    yield "unknown key", changed(lambda m: m.update(max_raduis=3))
    yield "unknown frame key", changed(lambda m: m["frames"][0].update(exposre=1))
    yield "a path outside", changed(lambda m: m["frames"][0].update(file="../outside.exr"))
    yield "an absolute path", changed(lambda m: m["frames"][0].update(file="/etc/passwd"))
    yield "a backslash", changed(lambda m: m["frames"][0].update(file="frames\\0.exr"))
    yield "a NUL", changed(lambda m: m["frames"][0].update(file="a\0b.exr"))
    yield "camera without mapping", changed(lambda m: m.update(frame_space="camera"))
    yield "mapping without camera", changed(lambda m: m.update(mapping="mapping.exr"))
    yield "frame space sideways", changed(lambda m: m.update(frame_space="sideways"))
    yield "multiplexed without max_radius", changed(lambda m: m["frames"][0].update(lit=[[0, 0], [3, 2]]))
    yield "two channels", changed(lambda m: m.update(channels=["R", "G"]))
    yield "repeated channels", changed(lambda m: m.update(channels=["R", "R", "B"]))
    yield "an empty channel name", changed(lambda m: m.update(channels=[""]))
    yield "colorspace a number", changed(lambda m: m.update(colorspace=3))
    yield "colorspace of two keys", changed(lambda m: m.update(colorspace={"matrix": [[1, 0, 0]] * 3, "x": 1}))
    yield "a 2 x 3 matrix", changed(lambda m: m.update(colorspace={"matrix": [[1, 0, 0], [0, 1, 0]]}))
    yield "a white point at y 0", changed(lambda m: m.update(colorspace={
        "primaries": [[0.64, 0.33], [0.3, 0.6], [0.15, 0.06]], "whitepoint": [0.3, 0]}))
    yield "a truth image without max", changed(lambda m: m.update(
        ground_truth={"path_length_images": [{"file": "t.exr", "min": 0}]}))
    yield "a truth layer of two colours", changed(lambda m: m.update(
        ground_truth={"layers": [{"name": "a", "depth": [0, 1], "rgb": [0.1, 0.2]}]}))
    yield "notes a list", changed(lambda m: m.update(notes=["a"]))
    yield "a manifest that is a list", []


@pytest.mark.parametrize("why, document", list(refusals()), ids=[why for why, _ in refusals()])
def test_manifests_refused_for_their_structure_are_refused_by_both(why, document):
    assert not parser_accepts(document), why
    assert not DATASET.is_valid(document), why


def rig_manifests():
    """The keys a rig's frames use (tests/exr_corpus.py's cases: channels, parts, colourspaces),
    a camera dataset, a dark frame, ground truth and max_radius: each accepted and valid."""
    base = valid_manifest()
    yield {**base, "channels": ["Y"]}
    yield {**base, "channels": ["camera.R", "camera.G", "camera.B"], "part": "right"}
    yield {**base, "colorspace": "ACES2065-1", "notes": "a note", "dark": "dark.exr"}
    yield {**base, "colorspace": {"primaries": [[0.64, 0.33], [0.3, 0.6], [0.15, 0.06]],
                                  "whitepoint": [0.3127, 0.329]}}
    yield {**base, "colorspace": {"matrix": [[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722],
                                             [0.0193, 0.1192, 0.9505]]}}
    yield {**base, "frame_space": "camera", "mapping": "mapping.exr", "grid": {"height": 4, "width": 3, "pitch_mm": 0.1}}
    yield {**base, "max_radius": 1.5, "frames": [{"file": "f.exr", "lit": [[0, 0], [3, 2]], "exposure": 2}]}
    yield {**base, "ground_truth": {"path_length_images": [{"file": "t/0.exr", "min": 0, "max": 1.5}],
                                    "layers": [{"name": "top", "depth": [0, 2], "rgb": [0.8, 0.2, 0.1]}]}}


@pytest.mark.parametrize("document", list(rig_manifests()))
def test_manifests_of_every_rig_option_are_accepted_and_valid(document):
    assert assert_accepted_validates(document)


def test_the_sample_key_of_the_2026_11_26_revision_is_in_the_schema():
    """``sample``: n in [1, 3], g in (-1, 1), both optional; nothing else."""
    base = valid_manifest()
    for sample in ({"n": 1.4, "g": 0.8}, {"n": 1}, {"g": -0.99}, {}):
        assert DATASET.is_valid({**base, "sample": sample}), sample
    for sample in ({"n": 0.9}, {"n": 3.5}, {"g": 1}, {"g": -1}, {"n": "1.4"}, {"k": 1}, [1.4, 0.8]):
        assert not DATASET.is_valid({**base, "sample": sample}), sample


def test_the_replicate_key_of_the_2026_11_26_revision_is_in_the_schema_and_the_parser():
    """A frame's ``replicate``: a whole number from 0, accepted and valid; anything else refused by
    both. That every replicate lights the same points is the reader's check alone."""
    base = valid_manifest()
    labelled = {**base, "frames": [{**frame, "replicate": 0} for frame in base["frames"]]
                + [{**frame, "file": "again/" + frame["file"], "replicate": 3} for frame in base["frames"]]}
    assert assert_accepted_validates(labelled)
    for label in (-1, 1.5, "0", True, 2**31):
        bad = {**base, "frames": [{**base["frames"][0], "replicate": label}, *base["frames"][1:]]}
        assert not parser_accepts(bad) and not DATASET.is_valid(bad), label
    uneven = {**base, "frames": [*labelled["frames"][:-1]]}
    assert DATASET.is_valid(uneven) and not parser_accepts(uneven)


# Every dataset, scene and stack the project writes ------------------------------------------------

def manifest_of(folder: Path) -> dict:
    return json.loads((Path(folder) / MANIFEST_NAME).read_text("utf-8"))


@pytest.mark.parametrize("name", sample_names())
def test_every_bundled_sample_validates(name, link_sample):
    link_sample(name)  # as sample_dataset writes it, written once for the whole run
    document = manifest_of(sample_dataset(name))
    assert assert_accepted_validates(document)


def test_simulator_outputs_validate(tmp_path):
    for preset, measure in (("layers3", "camera"), ("red-bead", "exitance")):
        scene = load_scene(preset, size=(6, 6))
        scene = replace(scene, measure=measure, max_radius=2.0)
        folder = write_transport(simulate_transport(scene, photons=20, seed=1), tmp_path / preset)
        assert assert_accepted_validates(manifest_of(folder)), preset
    scene = replace(load_scene("layers3", size=(6, 6)), max_radius=2.0)
    folder = write_transport(simulate_replicates(scene, 8, 2, seed=1), tmp_path / "replicates")
    assert assert_accepted_validates(manifest_of(folder))


def test_a_simulated_capture_validates(tmp_path, capsys):
    """``ringlight capture`` with the simulated rig: a camera-space dataset with a mapping."""
    assert main(["capture", "--camera", "simulated", "--projector", "simulated", "--option", "size=6x6",
                 "--option", "photons=50", "--max-radius", "2", "--out", str(tmp_path / "scan")]) == 0
    document = manifest_of(tmp_path / "scan")
    assert document["frame_space"] == "camera" and assert_accepted_validates(document)


def test_stack_exports_validate(tmp_path):
    impulses = random_impulses(np.random.default_rng(3), 7, 6, support=2)
    write_dataset(tmp_path / "ds", 7, 6, impulses, max_radius=3)
    dataset = open_dataset(tmp_path / "ds")
    radii = radius_range(0, 1, 0.5)
    stacks = {"ring": ring_stack(dataset, radii), "transient": transient_stack(dataset, radii, step=0.5)}
    for kind, stack in stacks.items():
        for coverage in (None, ring_coverage(dataset, radii)):
            folder = write_stack(stack, tmp_path / f"{kind}-{coverage is None}", coverage=coverage)
            document = json.loads((folder / "stack.json").read_text())
            assert not (errors := schema_errors(STACK, document)), errors
            assert document["kind"] == kind and len(document["images"]) == len(radii)
    broken = {**document, "step": 0}
    assert not STACK.is_valid(broken) and not STACK.is_valid({**document, "images": ["../x.exr"]})


def bundled_scenes() -> list[Path]:
    return sorted(Path(str(resources.files("ringlight.resources.scenes"))).glob("*.json"))


@pytest.mark.parametrize("path", bundled_scenes(), ids=lambda path: path.stem)
def test_every_bundled_scene_validates_and_parses(path):
    document = json.loads(path.read_text("utf-8"))
    parse_scene(document, where=str(path))
    assert not (errors := schema_errors(SCENE, document)), errors


@pytest.mark.parametrize("change", [
    lambda s: s.update(format="ringlight-impulse"),
    lambda s: s.update(version=True),
    lambda s: s.update(n=3.5),
    lambda s: s.update(depth=0),
    lambda s: s["materials"]["clay"].update(g=1.0),
    lambda s: s["materials"]["clay"].update(mus=[1, 1]),
    lambda s: s["materials"]["clay"].update(mua=[-1, 0, 0]),
    lambda s: s.update(camera={"direction": [90, 0]}),
    lambda s: s.update(measure="radiance"),
    lambda s: s.update(seed=-1),
    lambda s: s.update(shapes=[{"type": "cube", "material": "bead"}]),
    lambda s: s.update(shapes=[{"type": "sphere", "material": "bead", "center": [1, 2, 3]}]),
    lambda s: s.update(path_length_bins={"step": 1}),
    lambda s: s.update(colour="red"),
    lambda s: s.update(notes=None),
])
def test_scenes_refused_for_their_structure_are_refused_by_both(change):
    document = json.loads((bundled_scenes()[0].parent / "red-bead.json").read_text("utf-8"))
    change(document)
    with pytest.raises(SceneError):
        parse_scene(document)
    assert not SCENE.is_valid(document)


@settings(max_examples=150, deadline=None, derandomize=True)
@given(st.data())
def test_scenes_the_parser_accepts_validate(data):
    """Bundled scenes with one key replaced by a small JSON value: whenever the simulator's parser
    accepts the result, so does the schema."""
    path = data.draw(st.sampled_from(bundled_scenes()))
    document = json.loads(path.read_text("utf-8"))
    key = data.draw(st.sampled_from(sorted(document) + ["seed", "n", "measure", "camera", "layers"]))
    document[key] = data.draw(st.none() | st.booleans() | st.integers(-3, 70) | st.floats(-2, 100)
                              | st.sampled_from(["camera", "exitance", "clay", ""])
                              | st.fixed_dictionaries({"direction": st.lists(st.floats(-5, 95), min_size=2, max_size=2)}))
    try:
        parse_scene(document, size=(4, 4))
    except SceneError:
        return
    assert not (errors := schema_errors(SCENE, document)), errors
