"""The interoperability corpus (tests/exr_corpus.py): every file kind FORMAT.md's "Frame files"
names, written with the OpenEXR Python API, is read bit for bit or refused with its one line, and
nothing the OpenEXR library prints itself reaches the user."""

import numpy as np
import pytest
from exr_corpus import CorpusFile, compressions, write_corpus
from ringlight.core import DatasetError
from ringlight.core.colourspaces import parse_colourspace
from ringlight.core.dataset.exr import check_exr, read_exr_channels, whole_file_reader


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> list[CorpusFile]:
    return write_corpus(tmp_path_factory.mktemp("corpus"))


def outcome(file: CorpusFile) -> str | None:
    """None when ``file`` reads as its CorpusFile says, else what went wrong."""
    colorspace = parse_colourspace(file.colorspace)
    try:
        image = read_exr_channels(file.path, file.channels, part=file.part, colorspace=colorspace)
    except DatasetError as error:
        message = str(error)
        if file.refusal is None:
            return f"refused: {message}"
        if "\n" in message or not message.startswith(f"{file.path}: ") or file.refusal not in message:
            return f"refused with {message!r}, expected one line naming the file and holding {file.refusal!r}"
        return None
    if file.refusal is not None:
        return f"read, expected a refusal holding {file.refusal!r}"
    if image.shape != file.expected.shape or not np.array_equal(image.view(np.uint32), file.expected.view(np.uint32)):
        return "read, but not bit for bit the array written"
    return None


def test_every_corpus_file_reads_bit_exactly_or_is_refused_with_one_line(corpus, capfd):
    problems = [f"{file.name}: {problem}" for file in corpus if (problem := outcome(file)) is not None]
    assert problems == []
    captured = capfd.readouterr()
    assert captured.out == "" and captured.err == "", "the OpenEXR library's own output reached the user"


def test_the_corpus_holds_every_compression_pixel_type_and_layout(corpus):
    names = {file.name for file in corpus}
    for compression in compressions():
        assert {f"{compression} HALF", f"{compression} FLOAT", f"{compression} UINT"} <= names
    assert {"tiled mip-mapped", "monochrome Y", "multi-part, part named", "offset data window",
            "ACES AP0 chromaticities", "deep scanline", "prefixed camera."} <= names
    assert sum(file.refusal is None for file in corpus) > 3 * len(compressions())


def test_only_the_channels_asked_for_are_decoded(corpus, monkeypatch):
    """A single-part file with 15 extra channels: the reader asks the library for R, G, B only
    (OpenEXR's InputFile.channels), so the extra planes are never converted or stored."""
    import OpenEXR

    asked = []
    original = OpenEXR.InputFile

    class Recording:
        def __init__(self, path):
            self.file = original(path)

        def header(self):
            return self.file.header()

        def channels(self, names, pixel_type, *rows):
            asked.append(tuple(names))
            return self.file.channels(names, pixel_type, *rows)

        def close(self):
            self.file.close()

    monkeypatch.setattr(OpenEXR, "InputFile", Recording)
    extra = next(file for file in corpus if file.name == "15 extra channels")
    image = read_exr_channels(extra.path, ("R", "G", "B"))
    assert asked == [("R", "G", "B")]
    np.testing.assert_array_equal(image, extra.expected)


def test_the_reader_the_assembly_plans_for_is_the_one_used(corpus, monkeypatch):
    """``whole_file_reader`` (which sets the library's threads in an open) says which of the
    library's readers decodes: the selecting one (InputFile) exactly where it says not the whole
    file's, for every readable corpus file, read whole and as a band of rows."""
    import OpenEXR

    used = []
    original = OpenEXR.InputFile

    def recording(path):
        used.append(path)
        return original(path)

    monkeypatch.setattr(OpenEXR, "InputFile", recording)
    plans = {}
    for file in corpus:
        if file.refusal is not None:
            continue
        header = check_exr(file.path, file.channels, part=file.part)
        for rows in (None, (0, max(1, header.height // 2))):
            used.clear()
            read_exr_channels(file.path, file.channels, part=file.part, rows=rows)
            whole = whole_file_reader(header, file.channels, None if rows is None else rows[1] - rows[0])
            assert (not used) == whole, (file.name, rows)
            plans[whole] = plans.get(whole, 0) + 1
    assert plans[True] >= 20 and plans[False] >= 20  # both readers exercised


def test_a_band_of_rows_reads_exactly_those_rows_of_every_readable_file(corpus):
    """What a band of an out-of-core open reads: rows 3..9 of each file equal the whole read's."""
    for file in corpus:
        if file.expected is None or file.expected.shape[0] < 10:
            continue
        colorspace = parse_colourspace(file.colorspace)
        band = read_exr_channels(file.path, file.channels, part=file.part, colorspace=colorspace, rows=(3, 9))
        assert np.array_equal(band.view(np.uint32), file.expected[3:9].view(np.uint32)), file.name
