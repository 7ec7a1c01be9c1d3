"""Calibrating a rig's scale on a reference, the calibration file (round trip, refusals, its JSON
Schema) and maps of a scaled capture through the calibration."""

import json
from importlib import resources

import jsonschema
import numpy as np
import pytest
from optics_helpers import TEST_PHOTONS, model_dataset
from ringlight.core.atomic import OutputError
from ringlight.core.optics import (
    Calibration,
    CalibrationError,
    calibrate,
    optical_maps,
    radial,
    read_calibration,
    write_calibration,
)
from ringlight.core.optics.calibration import calibration_document


@pytest.fixture(scope="module")
def run():
    return radial.radial_run(1.4, 0.0, TEST_PHOTONS, seed=0)


def schema() -> jsonschema.Draft202012Validator:
    text = resources.files("ringlight.resources.schemas").joinpath("calibration.schema.json").read_text("utf-8")
    document = json.loads(text)
    jsonschema.Draft202012Validator.check_schema(document)
    return jsonschema.Draft202012Validator(document)


def test_calibration_recovers_the_rigs_scale_and_maps_through_it(run):
    # A "rig" reads 250, 300, 350 times the model's E: a reference of known properties gives
    # those scales, and a sample scanned on the same rig is mapped to its true properties.
    scale = np.array([250.0, 300.0, 350.0])
    reference = model_dataset(run, 0.6, 0.03, 24, 8, pitch_mm=0.1, scale=scale, noise=np.full(9, 0.02), seed=1)
    calibration = calibrate(reference, 0.3, 6.0, photons=TEST_PHOTONS, description="phantom")
    np.testing.assert_allclose(calibration.scale, scale, rtol=0.01)
    assert calibration.units == "per_mm" and calibration.reference_musp == (6.0, 6.0, 6.0)
    sample = model_dataset(run, 0.2, 0.01, 22, 8, pitch_mm=0.1, scale=scale, noise=np.full(9, 0.02), seed=2)
    maps = optical_maps(sample, calibration=calibration, photons=TEST_PHOTONS)
    inside = maps.complete
    assert np.median(maps.musp[inside]) == pytest.approx(2.0, rel=0.02)
    assert np.median(maps.mua[inside]) == pytest.approx(0.1, rel=0.03)
    # Without the calibration the scale is read as a medium 250 times brighter: nothing fits.
    assert abs(np.nanmedian(optical_maps(sample, photons=TEST_PHOTONS).mua[inside]) / 0.1 - 1) > 0.5


def test_calibration_file_round_trips_and_validates_against_its_schema(tmp_path):
    calibration = Calibration((1.5, 2.0, 2.5), (0.01, 0.02, 0.03), (0.01, 0.02, 0.03), (1.0, 1.1, 1.2), "per_mm",
                              1.4, 0.8, "phantom", {"dataset": "/data/p", "pitch_mm": 0.1})
    path = tmp_path / "rig.json"
    write_calibration(path, calibration)
    assert read_calibration(path) == calibration
    schema().validate(json.loads(path.read_text()))
    with pytest.raises(OutputError):
        write_calibration(path, calibration)  # exists: not without overwrite
    write_calibration(path, calibration, overwrite=True)
    at_the_bounds = Calibration((1e-30, 1.0, 1e30), (0.0, 0.0, 1e30), (0.01,) * 3, (1.0,) * 3, "per_mm", 1.4, 0.0)
    write_calibration(path, at_the_bounds, overwrite=True)
    assert read_calibration(path) == at_the_bounds
    schema().validate(json.loads(path.read_text()))


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(format="ringlight-stack"), "'format' must be the string 'ringlight-calibration'"),
    (lambda d: d.update(version=2), "'version' must be 1"),
    (lambda d: d.update(scale=[1.0, -1.0, 1.0]), "'scale' must be 3 positive numbers"),
    (lambda d: d.update(scale=[1.0, 1.0]), "'scale' must be a list of 3 numbers"),
    (lambda d: d["reference"].update(units="per_inch"), "'reference.units' must be one of"),
    (lambda d: d["reference"].update(n=0.5), "'reference.n' must be a refractive index"),
    (lambda d: d.pop("reference"), "lacks required key(s) 'reference'"),
    (lambda d: d.update(extra=1), "unknown key(s) 'extra'"),
])
def test_bad_calibration_is_one_line_naming_the_file_and_the_schema_agrees(tmp_path, change, message):
    document = calibration_document(Calibration((1.0, 1.0, 1.0), (0.0, 0.0, 0.0), (0.01,) * 3, (1.0,) * 3,
                                                "per_mm", 1.4, 0.0))
    change(document)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(document))
    with pytest.raises(CalibrationError) as error:
        read_calibration(path)
    text = str(error.value)
    assert text.startswith(str(path)) and message in text and "\n" not in text
    assert not schema().is_valid(document)


def edited_calibration(tmp_path, **changes) -> tuple:
    """A calibration file as ``write_calibration`` writes it, with its top-level keys then set to
    ``changes``; returns its path and the edited document."""
    calibration = Calibration((412.7, 398.2, 405.9), (1.1, 1.0, 1.2), (0.01, 0.012, 0.015), (1.0,) * 3, "per_mm",
                              1.4, 0.0, "phantom")
    path = tmp_path / "cal.json"
    write_calibration(path, calibration)
    document = json.loads(path.read_text())
    document.update(changes)
    path.write_text(json.dumps(document))
    return path, document


@pytest.mark.parametrize("channels", [["X", "Y", "Z"], ["B", "G", "R"], ["R", "G"], ["Y"], "RGB"])
def test_calibration_channels_other_than_r_g_b_in_order_are_one_line_naming_the_file(tmp_path, channels):
    # scale and reference are applied by position to the maps' R, G, B: any other names or order
    # would be applied silently to the wrong channels.
    path, document = edited_calibration(tmp_path, channels=channels)
    with pytest.raises(CalibrationError) as error:
        read_calibration(path)
    assert str(error.value) == (f"{path}: 'channels' must be [\"R\", \"G\", \"B\"] (scale and reference are in that "
                                f"order), got {channels!r}")
    assert not schema().is_valid(document)


@pytest.mark.parametrize("key, values, expected", [
    ("scale", [1e308, 1e308, 1e308], "3 positive numbers within [1e-30, 1e+30]"),  # the fits overflow: maps all NaN
    ("scale", [1.0, 1e31, 1.0], "3 positive numbers within [1e-30, 1e+30]"),
    ("scale", [1e-31, 1.0, 1.0], "3 positive numbers within [1e-30, 1e+30]"),
    ("scale_se", [1e308, 1.0, 1.0], "3 standard errors within [0, 1e+30]"),
    ("scale_se", [1.0, -1.0, 1.0], "3 standard errors within [0, 1e+30]"),
])
def test_scale_out_of_range_is_one_line_naming_the_file(tmp_path, key, values, expected):
    path, document = edited_calibration(tmp_path, **{key: values})
    with pytest.raises(CalibrationError) as error:
        read_calibration(path)
    assert str(error.value) == f"{path}: '{key}' must be {expected}, got {values!r}"
    assert not schema().is_valid(document)


def test_not_json_and_not_a_file_are_refused(tmp_path):
    path = tmp_path / "broken.json"
    path.write_text("{not json")
    with pytest.raises(CalibrationError, match=str(path)):
        read_calibration(path)
    with pytest.raises(CalibrationError, match=str(tmp_path)):
        read_calibration(tmp_path)


def test_a_file_that_is_not_a_calibration_is_never_replaced(tmp_path):
    path = tmp_path / "notes.json"
    path.write_text('{"mine": true}')
    calibration = Calibration((1.0,) * 3, (0.0,) * 3, (0.01,) * 3, (1.0,) * 3, "per_mm", 1.4, 0.0)
    with pytest.raises(CalibrationError):
        write_calibration(path, calibration, overwrite=True)
    assert path.read_text() == '{"mine": true}'


def test_reference_outside_the_table_is_refused(run):
    reference = model_dataset(run, 0.6, 0.03, 16, 6)
    with pytest.raises(CalibrationError, match="outside the model's table"):
        calibrate(reference, 0.03, 100.0, photons=TEST_PHOTONS)
    with pytest.raises(CalibrationError, match="positive numbers"):
        calibrate(reference, -0.03, 1.0, photons=TEST_PHOTONS)
    for mua, musp in (([0.03, 0.04], 1.0), (0.03, "one"), (0.03, [[1.0, 1.0, 1.0]] * 2)):  # numpy's words before
        with pytest.raises(CalibrationError, match=r"each be one number or one per channel \(3\), got"):
            calibrate(reference, mua, musp, photons=TEST_PHOTONS)


def test_a_scan_whose_scale_is_out_of_range_writes_no_calibration(run):
    # A rig reading 1e31 times the model's E: beyond the scales a calibration file may hold.
    reference = model_dataset(run, 0.6, 0.03, 16, 6, scale=1e31)
    with pytest.raises(CalibrationError, match=r"gives no scale within \[1e-30, 1e\+30\]"):
        calibrate(reference, 0.03, 0.6, photons=TEST_PHOTONS)
