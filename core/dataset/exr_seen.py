"""Headers that passed their check, known again by their bytes.

The frames of a dataset mostly share one header, byte for byte (one camera, one size, one
writer): the OpenEXR library's reading of it (a second open of the file, its header parsed into
Python objects, about 100 us a frame) is needed once. A single-part file's header is the bytes
from its start up to its chunk table; a file whose first bytes are those of a header already
checked against the same request (channels, size, part, colourspace) has that header, and only
its chunk table is left to check (:func:`.exr.visit_exr`). Frames whose headers differ (a rig
that stamps each with its time) are read by the library one by one, as before.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

from .exr_chunks import ChunkLayout
from .exr_header import ExrHeader
from .exr_small import SmallLayout

KEPT = 16
"""Headers kept, the most recently matched first."""


@dataclass(frozen=True)
class PassedHeader:
    """A header's bytes, the request it passed (names, expected shape, part, colourspace), what
    the library read from it, where its chunk table is, and how a small file of it is decoded
    without the library (:mod:`.exr_small`; None: by the library)."""

    header_bytes: bytes
    request: tuple
    header: ExrHeader
    layout: ChunkLayout
    small: SmallLayout | None = None


class HeaderCache:
    """The headers of one pass over a dataset's files (an ``info`` check, an open); thread-safe.
    ``library_reads`` counts the headers the library was asked to read."""

    def __init__(self) -> None:
        self._passed: list[PassedHeader] = []
        self._lock = threading.Lock()
        self.library_reads = 0

    def find(self, head: bytes, request: tuple) -> PassedHeader | None:
        """The passed header that ``head`` (a file's first bytes) starts with, for ``request``."""
        with self._lock:
            for index, passed in enumerate(self._passed):
                if passed.request == request and head.startswith(passed.header_bytes):
                    if index:
                        self._passed.insert(0, self._passed.pop(index))
                    return passed
        return None

    def add(self, passed: PassedHeader) -> None:
        with self._lock:
            self._passed.insert(0, passed)
            del self._passed[KEPT:]
