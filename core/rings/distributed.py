"""Ring light images on a dask cluster: one task per band of the dataset's store.

A point's ring means need only its own responses, so bands of rows are independent. Each task
opens the store (zarr, read-only) at its path, reads its band (every chunk's checksum checked)
and computes its images as the local path does (:func:`ringlight.core.rings.stacks.band_images`), so
the images equal the local ones bit for bit.
The store and the frames' dataset folder must be on a file system every worker sees at the same
path (a shared or network file system); the workers need ringlight installed.

``scheduler`` is a ``dask.distributed.Client`` or the address of a running scheduler
(``tcp://host:8786``), whose client is opened for the call and closed after it.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..dataset.impulse_dataset import ImpulseDataset
from ..errors import Cancelled, StackError

CONNECT_TIMEOUT_S = 10.0
"""Seconds a scheduler given by its address has to answer before the stack is refused."""


def band_ring_sums(store_path: str, row0: int, row1: int, lit: np.ndarray, observed: np.ndarray,
                   offsets: np.ndarray, tables: tuple) -> tuple[np.ndarray, np.ndarray]:
    """One band's ring images and counts: (n, rows, W, 3) float32 and (n, rows, W) int32."""
    import zarr

    from .stacks import band_images

    responses = zarr.open_array(zarr.storage.LocalStore(Path(store_path), read_only=True), path="responses",
                                mode="r")[row0:row1]
    images = np.empty((len(tables[0]), row1 - row0, responses.shape[1], 3), np.float32)
    counts = np.empty((len(tables[0]), row1 - row0, responses.shape[1]), np.int32)
    band_images(responses, lit, observed, offsets, tables, row0, images, counts)
    return images, counts


def distributed_ring_images(dataset: ImpulseDataset, tables: tuple, scheduler,
                            progress: Callable[[float], None] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(n, H, W, 3) images and (n, H, W) counts of the rings in ``tables`` (see
    :func:`ringlight.core.rings.stacks._ring_tables`), one task per store band on ``scheduler``."""
    if dataset.store is None:
        raise StackError(f"{dataset.path}: a stack on a cluster reads the dataset's store; open it with the cache on")
    from dask.distributed import Client, as_completed

    client = scheduler if isinstance(scheduler, Client) else None
    try:
        if client is None:
            try:
                client = _client_class()(str(scheduler), timeout=CONNECT_TIMEOUT_S, set_as_default=False)
            except OSError as error:
                raise StackError(f"cannot reach the dask scheduler at {scheduler} ({error})") from None
            except Exception as error:  # a malformed address, or a service that is not a scheduler
                raise StackError(f"{scheduler!r} is not the address of a dask scheduler "
                                 f"(tcp://HOST:PORT): {type(error).__name__}: {error}") from None
        height, width = dataset.grid_shape
        images = np.empty((len(tables[0]), height, width, 3), np.float32)
        counts = np.empty((len(tables[0]), height, width), np.int32)
        # The small arrays go with each task (a few MB at 800 x 800): no scatter step, which can
        # wait forever on a cluster that another client in the process also holds.
        lit, observed = np.ascontiguousarray(dataset.lit), np.ascontiguousarray(dataset.observed)
        bands = {client.submit(band_ring_sums, str(dataset.store.path), row0, row1, lit, observed, dataset.offsets,
                               tables, pure=False): (row0, row1)
                 for row0, row1 in _store_bands(dataset)}
        done = 0
        try:
            for future in as_completed(bands, loop=client.loop):
                row0, row1 = bands[future]
                images[:, row0:row1], counts[:, row0:row1] = future.result()
                done += 1
                if progress is not None:
                    progress(done / len(bands))
        except (Cancelled, KeyboardInterrupt):
            client.cancel(list(bands))
            raise
        return images, counts
    finally:
        if client is not None and client is not scheduler:
            client.close()


@functools.cache
def _client_class() -> type:
    """A ``dask.distributed.Client`` whose IO loop thread ends when its connection fails.

    A ``Client`` starts a thread for its event loop before it connects; when the connection
    fails (a malformed address, or no scheduler answering in time) the constructor raises and
    that thread runs on for the life of the process, one per failed try (distributed 2026.8).
    """
    from dask.distributed import Client

    class ClosingClient(Client):
        def start(self, **kwargs):
            try:
                super().start(**kwargs)
            except BaseException:
                with contextlib.suppress(Exception):  # the connection's error is the one to tell
                    self.close()  # nothing to do once the failed connection closed it
                runner = getattr(self, "_loop_runner", None)  # distributed's own attribute
                if runner is not None:
                    runner.stop()
                raise

    return ClosingClient


def _store_bands(dataset: ImpulseDataset) -> list[tuple[int, int]]:
    height, tile = dataset.grid_shape[0], dataset.store.tile
    return [(row, min(row + tile, height)) for row in range(0, height, tile)]
