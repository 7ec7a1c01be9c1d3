"""An interoperability corpus of OpenEXR frame files, written with the OpenEXR Python API.

Each :class:`CorpusFile` says what reading it must give (FORMAT.md "Frame files"): the exact
array written (or, for a lossy compression, what the OpenEXR library itself decodes), or a
refusal whose one line holds ``refusal``. Nothing here imports ringlight.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenEXR

HEIGHT, WIDTH = 37, 23
"""Sizes that are no multiple of any tile or chunk, so partial tiles and chunks are exercised."""
RGB = ("R", "G", "B")
LOSSY = {"PXR24_COMPRESSION", "B44_COMPRESSION", "B44A_COMPRESSION", "DWAA_COMPRESSION", "DWAB_COMPRESSION",
         "LJ2K_COMPRESSION"}
"""Compressions that may change FLOAT or HALF values (LJ2K: FLOAT R, G, B, not a lone channel):
their reference is the library's own decode."""
ACES_AP0 = (0.7347, 0.2653, 0.0, 1.0, 0.0001, -0.077, 0.32168, 0.33767)
SRGB = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)


@dataclass(frozen=True)
class CorpusFile:
    """One file: read ``channels`` (from ``part``, for ``colorspace``) must give ``expected``
    ((H, W, len(channels)) float32) or be refused with a line holding ``refusal``."""

    name: str
    path: Path
    channels: tuple[str, ...] = RGB
    expected: np.ndarray | None = None
    refusal: str | None = None
    part: str | None = None
    colorspace: str = "sRGB"


def compressions() -> list[str]:
    """Every compression the installed OpenEXR library writes."""
    return [name for name in OpenEXR.Compression.__members__ if not name.startswith("NUM_")]


def planes(seed: int, dtype, count: int = 3) -> list[np.ndarray]:
    """``count`` (HEIGHT, WIDTH) planes of ``dtype`` (UINT values below 2**24: exact in float32)."""
    rng = np.random.default_rng(seed)
    if dtype == np.uint32:
        return [rng.integers(0, 2**24, (HEIGHT, WIDTH)).astype(np.uint32) for _ in range(count)]
    return [rng.uniform(-2, 60, (HEIGHT, WIDTH)).astype(dtype) for _ in range(count)]


def write(path: Path, channels: dict[str, np.ndarray], **header) -> Path:
    """A single-part file (ZIP scanline unless ``header`` says otherwise)."""
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, **header}
    with OpenEXR.File(header, {name: np.ascontiguousarray(plane) for name, plane in channels.items()}) as exr:
        exr.write(str(path))
    return path


def library_decode(path: Path, names: tuple[str, ...], part: int = 0) -> np.ndarray:
    """What the OpenEXR library's own File reader decodes, as float32 (the reference for lossy files)."""
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        return np.stack([np.asarray(exr.parts[part].channels[name].pixels, np.float32) for name in names], -1)


def tiles(mode, x_size: int = 8, y_size: int = 4):
    description = OpenEXR.TileDescription()
    description.xSize, description.ySize, description.mode = x_size, y_size, mode
    return description


def complete_mipmap(path: Path, planes_by_name: dict[str, np.ndarray], x_size: int, y_size: int) -> None:
    """Write the lower levels of a NO_COMPRESSION mip-mapped FLOAT file.

    The Python API writes only level 0 and leaves the other levels' offsets 0, which the library
    then refuses as a damaged chunk table. Each lower level (its pixels: every 2**l-th pixel,
    ROUND_DOWN sizes) is appended as raw tiles (OpenEXR file layout: tile x, y, level x, level y,
    data size, then per scanline every channel's values in name order) and its offsets filled in.
    """
    data = bytearray(path.read_bytes())
    at = 8
    while data[at] != 0:  # attributes: name, type, size, value
        type_end = data.index(b"\0", data.index(b"\0", at) + 1)
        at = type_end + 5 + int.from_bytes(data[type_end + 1:type_end + 5], "little")
    table = at + 1
    names = sorted(planes_by_name)
    full_height, full_width = planes_by_name[names[0]].shape
    entry = 0
    for level in range(max(full_height, full_width).bit_length()):
        height, width = max(full_height >> level, 1), max(full_width >> level, 1)
        for tile_y in range(-(-height // y_size)):
            for tile_x in range(-(-width // x_size)):
                if level > 0:
                    rows = slice(tile_y * y_size, min((tile_y + 1) * y_size, height))
                    cols = slice(tile_x * x_size, min((tile_x + 1) * x_size, width))
                    level_planes = [planes_by_name[n][::1 << level, ::1 << level][:height, :width] for n in names]
                    pixels = b"".join(plane[row, cols].astype("<f4").tobytes()
                                      for row in range(rows.start, rows.stop) for plane in level_planes)
                    chunk = np.array([tile_x, tile_y, level, level, len(pixels)], "<i4").tobytes() + pixels
                    data[table + 8 * entry:table + 8 * entry + 8] = len(data).to_bytes(8, "little")
                    data += chunk
                entry += 1
    path.write_bytes(bytes(data))


def write_corpus(folder: Path) -> list[CorpusFile]:
    """Write every file kind into ``folder`` and return what each must read as."""
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for compression in compressions():
        for dtype, label in ((np.float16, "HALF"), (np.float32, "FLOAT"), (np.uint32, "UINT")):
            written = planes(len(files), dtype)
            path = write(folder / f"{compression}_{label}.exr", dict(zip(RGB, written)),
                         compression=getattr(OpenEXR, compression))
            exact = compression not in LOSSY or dtype == np.uint32
            expected = np.stack(written, -1).astype(np.float32) if exact else library_decode(path, RGB)
            files.append(CorpusFile(f"{compression} {label}", path, expected=expected))
    written = planes(100, np.float32)
    rgb = np.stack(written, -1)
    for mode, label in ((OpenEXR.ONE_LEVEL, "one level"), (OpenEXR.MIPMAP_LEVELS, "mip-mapped"),
                        (OpenEXR.RIPMAP_LEVELS, "rip-mapped, level 0 only")):
        for compression in (OpenEXR.NO_COMPRESSION, OpenEXR.PIZ_COMPRESSION):
            path = write(folder / f"tiled {label} {compression.name}.exr", dict(zip(RGB, written)),
                         type=OpenEXR.tiledimage, tiles=tiles(mode), compression=compression)
            if mode == OpenEXR.ONE_LEVEL:
                files.append(CorpusFile(f"tiled {compression.name}", path, expected=rgb))
            elif mode == OpenEXR.MIPMAP_LEVELS and compression == OpenEXR.NO_COMPRESSION:
                complete_mipmap(path, dict(zip(RGB, written)), 8, 4)
                files.append(CorpusFile("tiled mip-mapped", path, expected=rgb))
            else:  # the Python API leaves the lower levels unwritten: a damaged file
                files.append(CorpusFile(f"tiled {label} {compression.name}", path,
                                        refusal="truncated or corrupt OpenEXR file"))
    extra = dict(zip(RGB, written)) | {f"extra{k}": written[0] for k in range(15)}
    files.append(CorpusFile("15 extra channels", write(folder / "extra.exr", extra), expected=rgb))
    files.append(CorpusFile("monochrome Y", write(folder / "mono.exr", {"Y": written[1]}), ("Y",),
                            expected=written[1][..., None]))
    for prefix in ("camera.", "ViewLayer.Combined."):
        names = tuple(prefix + c for c in RGB)
        path = write(folder / f"{prefix}exr", dict(zip(names, written)) | {prefix + "A": written[0]})
        files.append(CorpusFile(f"prefixed {prefix}", path, names, expected=rgb))
    files.append(CorpusFile("prefixed read as R, G, B", folder / "camera.exr",
                            refusal='missing channel(s) R, G, B (found: camera.A, camera.B, camera.G, camera.R)'))
    files += _parts_and_windows(folder, written, rgb)
    return files


def _parts_and_windows(folder: Path, written, rgb) -> list[CorpusFile]:
    files = []
    def part(name, channels):  # a new Part per file: older APIs change a Part's header as they write it
        return OpenEXR.Part({"type": OpenEXR.scanlineimage}, channels, name)

    with OpenEXR.File([part("depth", {"Z": written[0]}), part("left", dict(zip(RGB, written)))]) as exr:
        exr.write(str(folder / "parts_one_rgb.exr"))
    with OpenEXR.File([part("left", dict(zip(RGB, written))), part("right", dict(zip(RGB, written[::-1])))]) as exr:
        exr.write(str(folder / "parts_two_rgb.exr"))
    files += [
        CorpusFile("multi-part, one RGB part", folder / "parts_one_rgb.exr", expected=rgb),
        CorpusFile("multi-part, two RGB parts", folder / "parts_two_rgb.exr",
                   refusal="2 parts hold channels R, G, B ('left', 'right'); name one with 'part'"),
        CorpusFile("multi-part, part named", folder / "parts_two_rgb.exr", part="right", expected=rgb[..., ::-1]),
        CorpusFile("multi-part, no such part", folder / "parts_two_rgb.exr", part="centre",
                   refusal="no part named 'centre' (parts: 'left', 'right')"),
    ]
    data = ((3, 2), (3 + WIDTH - 1, 2 + HEIGHT - 1))
    display = ((0, 0), (WIDTH - 1, HEIGHT - 1))
    files.append(CorpusFile("offset data window", write(folder / "offset.exr", dict(zip(RGB, written)),
                                                        dataWindow=data, displayWindow=display),
                            refusal=f"data window (3, 2)-({3 + WIDTH - 1}, {2 + HEIGHT - 1}) differs from display "
                                    f"window (0, 0)-({WIDTH - 1}, {HEIGHT - 1})"))
    small = ((0, 0), (WIDTH - 2, HEIGHT - 1))
    files.append(CorpusFile("data window inside the display window",
                            write(folder / "smaller.exr", {c: p[:, :-1] for c, p in zip(RGB, written)},
                                  dataWindow=small, displayWindow=display),
                            refusal=f"data window (0, 0)-({WIDTH - 2}, {HEIGHT - 1}) differs from display window"))
    files.append(CorpusFile("both windows offset alike", write(folder / "shifted.exr", dict(zip(RGB, written)),
                                                               dataWindow=data, displayWindow=data), expected=rgb))
    files.append(CorpusFile("sRGB chromaticities", write(folder / "srgb.exr", dict(zip(RGB, written)),
                                                         chromaticities=SRGB), expected=rgb))
    files.append(CorpusFile("ACES AP0 chromaticities", write(folder / "aces.exr", dict(zip(RGB, written)),
                                                             chromaticities=ACES_AP0),
                            refusal="chromaticities R (0.7347, 0.2653) G (0, 1) B (0.0001, -0.077) W (0.3217, 0.3377) "
                                    "differ from the dataset's colorspace sRGB (R (0.64, 0.33)"))
    files.append(CorpusFile("ACES AP0 chromaticities, ACES2065-1 dataset", folder / "aces.exr",
                            colorspace="ACES2065-1", expected=rgb))
    files.append(CorpusFile("deep scanline", write_deep(folder / "deep.exr", HEIGHT, WIDTH),
                            refusal="deep (per-sample) OpenEXR files are not supported"))
    return files


def write_deep(path: Path, height: int, width: int) -> Path:
    """A valid deep scanline file: 0 to 2 samples a pixel of R, G, B."""
    channels = {name: np.empty((height, width), dtype=object) for name in RGB}
    for y in range(height):
        for x in range(width):
            for name in RGB:
                channels[name][y, x] = np.arange((y + x) % 3, dtype=np.float32) if (y + x) % 3 else None
    header = {"compression": OpenEXR.ZIPS_COMPRESSION, "type": OpenEXR.deepscanline}
    with OpenEXR.File(header, channels) as exr:
        exr.write(str(path))
    return path
