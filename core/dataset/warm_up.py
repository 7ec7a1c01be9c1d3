"""An open's dataset kernels run once on tiny arrays of the types an open passes: loaded from
numba's cache at start-up (or compiled there, on a fresh install), in groups that
:mod:`ringlight.core.compile_ahead` can compile side by side.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from .disc import disc_offsets
from .frame_batch import owners
from .impulse_dataset import ImpulseDataset
from .manifest import Manifest
from .scatter import _offset_order, _offset_order_rows, _scatter_batch, _scatter_frames, _scatter_rows


def warm_up_assembly() -> None:
    """Load the kernels of an open's assembly (:mod:`.assembly`: the scatter's, the frames'
    batches', the others its frames and files need) on tiny arrays of the types an open passes,
    so that a first open in a worker does not hold the GIL while numba loads them (see
    :func:`ringlight.core.rings.stacks.warm_up_kernels`)."""
    warm_up_scatter()
    warm_up_batches()
    warm_up_frames()


def warm_up_scatter() -> None:
    """Load the kernels that place decoded frames' radiance into the responses (for both owner
    types), and put them in offset order."""
    one = np.zeros(1, np.int64)
    for owner_type in (np.int16, np.int32):
        owner, radiance = np.full((1, 1), -1, owner_type), np.zeros((1, 1, 3), np.float32)
        owners(owner, radiance, np.zeros((1, 2), np.int64), one, one, one, np.ones((1, 1), np.float32), 0)
        _scatter_batch(np.zeros((1, 1, 1, 3), np.float32), np.zeros((1, 1, 3)), radiance[None], owner[None], 1)
        _scatter_rows(np.zeros((1, 1, 1, 3), np.float32), np.zeros((1, 1, 3)), radiance[None], owner[None], 1, 0, 1)
        _scatter_frames(np.zeros((1, 1, 1, 3), np.float32), np.zeros((1, 1, 3)), radiance[None], owner[None], 1)
    _offset_order(np.zeros((1, 1, 1, 3), np.float32), one)
    _offset_order_rows(np.zeros((1, 1, 1, 3), np.float32), one, 0, 1)


def warm_up_batches() -> None:
    """Load the native inflater's batch read of frames (the longest of an open's kernels to
    compile), for both owner types."""
    from .exr import _HALF_TO_FLOAT
    from .exr_small import LAYOUT_FIELDS, LENGTH_TYPE, NATIVE_INFLATE
    from .frame_batch import _load_frames

    if not NATIVE_INFLATE:
        return
    one = np.zeros(1, np.int64)
    for owner_type in (np.int16, np.int32):
        owner, radiance = np.full((1, 1), -1, owner_type), np.zeros((1, 1, 3), np.float32)
        # one frame, marked to be read alone: loads the kernel, runs nothing
        _load_frames(np.frombuffer(b"", np.uint8), one, np.full(1, -1, np.int64), np.zeros(LAYOUT_FIELDS, np.int64),
                     1, one, np.ones(1, np.bool_), one, _HALF_TO_FLOAT, np.zeros((1, 1, 3), np.float32),
                     np.zeros(2, LENGTH_TYPE), np.ones(1, np.float32), np.zeros((0, 0, 3), np.float32), False,
                     radiance[None], owner[None], 0, np.zeros((1, 2), np.int64), np.zeros(2, np.int64), one, one,
                     one, np.ones((1, 1), np.float32), 0, np.zeros(1, np.int64), np.zeros(1, np.int64))


def warm_up_frames() -> None:
    """Load the kernels that convert half floats and radiance, unpack a frame read alone, check
    the lit points' spacing, read a run of files, and stat the frames' files (the response cache's
    identities)."""
    from .cache import _identities
    from .exr import _HALF_TO_FLOAT, _put_half
    from .exr_small import _unpack
    from .file_batch import read_run
    from .file_paths import FileResolver
    from .frames import _radiance
    from .spacing import close_pair

    one = np.zeros(1, np.int64)
    _put_half(np.zeros((1, 1), np.uint16), _HALF_TO_FLOAT, np.zeros((1, 1, 3), np.float32), 0)
    _radiance(np.zeros((1, 1, 3), np.float32), np.float32(1.0), np.zeros((1, 1, 3), np.float32), True,
              np.zeros((1, 1, 3), np.float32))
    close_pair(np.array([[0, 0], [5, 5]], np.int64), 2.0, np.zeros(2, np.int64))
    close_pair(np.array([[0, 0], [5, 5]], np.int64), 2.0, np.zeros(2, np.int64), first=False)
    _unpack(np.zeros(2, np.uint8), True, 1, 0, 1, one, np.ones(1, np.bool_), np.zeros(1, np.int64),
            _HALF_TO_FLOAT, np.zeros((1, 1, 1), np.float32))
    with tempfile.TemporaryDirectory() as folder:
        Path(folder, "frame.exr").write_bytes(b"frame")
        _identities(Path(folder), ["frame.exr"])
        read_run(FileResolver(Path(folder)), ["frame.exr"], b"fr")


def warm_up_dataset() -> ImpulseDataset:
    """A 2 x 1 dataset of max_radius 2, its points lit and observed, on which the warm-ups run
    their kernels."""
    offsets = disc_offsets(2.0)
    manifest = Manifest(
        folder=Path("."), height=2, width=1, pitch_mm=None, colorspace="sRGB", frame_space="grid", mapping=None,
        max_radius=2.0, frames=(), dark=None, ground_truth=None, notes=None,
    )
    return ImpulseDataset(manifest, 2.0, offsets, np.zeros((2, 1, len(offsets), 3), np.float32),
                          np.ones((2, 1), np.int32), np.ones((2, 1), bool))
