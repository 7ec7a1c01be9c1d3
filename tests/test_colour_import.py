"""Commands that convert no colour do not import colour-science (about a second of every start):
the names and numbers they need come from ringlight.core.colourspace_table, which must be
colour-science's own, number for number, and is used only with the colour-science it was made from.

The luminance row is not data but derived by colour-science through numpy's linear algebra, whose last bits
vary between numpy releases (up to 6 units in the last place with numpy 2.4.6, against the table made with an
earlier one): it is compared within LUMINANCE_TOLERANCE, the primaries and white points bit for bit."""

import json
import re
import subprocess
import sys

import numpy as np
import pytest
from reference import edit_manifest, random_impulses, write_dataset
from ringlight.core import colourspaces
from ringlight.core.colourspace_table import COLOUR_VERSION, COLOURSPACES
from ringlight.core.colourspaces import (CUSTOM_PREFIX, colour_module, colourspace_chromaticities,
                                         colourspace_luminance, is_known_colourspace, parse_colourspace)

LUMINANCE_TOLERANCE = 1e-14
"""How far (relative, and absolute for an entry near 0) the table's luminance rows may lie from
colour-science's own (module docstring): 6 units in the last place are 7e-16 at 1."""


def assert_same_luminance(found, name: str) -> None:
    """``found`` is colour-science's luminance row of colourspace ``name``, within :data:`LUMINANCE_TOLERANCE`."""
    expected = np.asarray(colour_module().RGB_COLOURSPACES[name].matrix_RGB_to_XYZ[1], np.float64)
    np.testing.assert_allclose(np.asarray(found, np.float64), expected, rtol=LUMINANCE_TOLERANCE,
                               atol=LUMINANCE_TOLERANCE)


def table_in_use() -> None:
    """Skip unless the installed colour-science is the one the table was made from: with any other
    (a release newer than the table), the table is not used and colour-science answers itself,
    which the other tests check; the table is then out of date, not wrong."""
    installed = colour_module().__version__
    if installed != COLOUR_VERSION:
        pytest.skip(f"the table is colour-science {COLOUR_VERSION}'s, {installed} is installed (unused): "
                    "run python tools/colourspace_table.py")


def test_the_table_is_colour_sciences_own_names_and_numbers():
    table_in_use()
    colour = colour_module()
    regenerate = "run python tools/colourspace_table.py"
    names = [name for name in colour.RGB_COLOURSPACES.keys() if not name.startswith(CUSTOM_PREFIX)]
    assert sorted(COLOURSPACES) == sorted(names), regenerate
    for name in names:
        space = colour.RGB_COLOURSPACES[name]
        primaries, whitepoint, luminance = COLOURSPACES[name]
        assert np.array(primaries).tobytes() == np.asarray(space.primaries, np.float64).ravel().tobytes(), name
        assert np.array(whitepoint).tobytes() == np.asarray(space.whitepoint, np.float64).tobytes(), name
        assert_same_luminance(luminance, name)
        # What the module answers from the table is what colour-science answers.
        expected = np.vstack([np.asarray(space.primaries, np.float64), np.asarray(space.whitepoint, np.float64)])
        assert colourspace_chromaticities(name).tobytes() == expected.tobytes(), name
        assert colourspace_luminance(name).tobytes() == np.array(luminance, np.float64).tobytes(), name


@pytest.mark.parametrize("name", ["sRGB", "srgb", "SRGB", "acescg", "adobergb1998", "s-RGB", "sRGB2", "",
                                  CUSTOM_PREFIX + "matrix [[1.0]]"])
def test_any_spelling_is_known_exactly_when_colour_science_knows_it(name):
    colour = colour_module()
    assert is_known_colourspace(name) == (name in colour.RGB_COLOURSPACES and not name.startswith(CUSTOM_PREFIX))
    if is_known_colourspace(name):
        assert parse_colourspace(name) == name
        assert_same_luminance(colourspace_luminance(name), name)
    else:
        with pytest.raises(ValueError, match=f"^{re.escape(repr(name))} is not a colour-science RGB colourspace$"):
            parse_colourspace(name)


@pytest.fixture
def version_checked_again(monkeypatch):
    """Forget the installed version's check before and after the test (after: before monkeypatch
    restores the module, so that the next check reads the restored version)."""
    colourspaces._table_applies.cache_clear()
    yield monkeypatch
    colourspaces._table_applies.cache_clear()


def test_the_table_is_used_only_with_the_colour_science_it_was_made_from(version_checked_again):
    monkeypatch = version_checked_again
    installed = colour_module().__version__
    monkeypatch.setattr(colourspaces, "COLOUR_VERSION", installed)  # as if the table were this release's
    monkeypatch.setitem(COLOURSPACES, "Not colour-science's", ((0.6, 0.3, 0.3, 0.6, 0.15, 0.06), (0.3, 0.3),
                                                              (0.2, 0.7, 0.1)))
    assert is_known_colourspace("Not colour-science's")  # served from the table
    monkeypatch.setattr(colourspaces, "COLOUR_VERSION", installed + ".other")
    colourspaces._table_applies.cache_clear()
    assert not is_known_colourspace("Not colour-science's")  # colour-science asked
    assert is_known_colourspace("ACEScg")
    assert colourspace_luminance("ACEScg").tolist() == list(COLOURSPACES["ACEScg"][2])


def test_a_dataset_is_described_stacked_and_weighed_without_importing_colour_science(tmp_path):
    table_in_use()
    write_dataset(tmp_path / "ds", 12, 12, random_impulses(np.random.default_rng(2), 12, 12, support=3))
    edit_manifest(tmp_path / "ds", lambda manifest: manifest.update(colorspace="ACEScg"))
    code = f"""if True:
        import contextlib, io, json, sys
        from ringlight.app.main import main
        from ringlight.core import open_dataset
        from ringlight.core.colourspaces import colourspace_chromaticities
        from ringlight.core.rings.noise import luminance_weights, stack_noise
        folder = {str(tmp_path / "ds")!r}
        with contextlib.redirect_stdout(io.StringIO()):
            codes = [main(["info", folder]), main(["stack", folder, "--radii", "0:2:1", "--out", folder + "-stack"])]
        dataset = open_dataset(folder, radius=3)
        noise = stack_noise(dataset, [0.0, 1.0])  # what an optics fit weighs its rings by
        answers = [luminance_weights(dataset.colorspace).tolist(), colourspace_chromaticities("ACEScg").tolist()]
        before = "colour" in sys.modules
        from ringlight.core.colour.chroma import chromaticity
        chromaticity(noise.luminance_weights, dataset.colorspace)  # a conversion imports it
        print(json.dumps({{"codes": codes, "before": before, "after": "colour" in sys.modules, "answers": answers}}))
    """
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    found = json.loads(result.stdout)
    assert found["codes"] == [0, 0] and found["before"] is False and found["after"] is True
    space = colour_module().RGB_COLOURSPACES["ACEScg"]
    assert_same_luminance(found["answers"][0], "ACEScg")
    assert found["answers"][1] == np.vstack([space.primaries, space.whitepoint]).tolist()
    assert json.loads((tmp_path / "ds-stack" / "stack.json").read_text())["colorspace"] == "ACEScg"
