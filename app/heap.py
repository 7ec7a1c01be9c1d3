"""The heap after start-up, out of the cyclic garbage collector's sight (no other import: the tests'
conftest calls it in venvs that hold neither Qt nor OpenCV)."""

from __future__ import annotations

import gc


def settle_heap() -> None:
    """Put what start-up made (modules, Qt wrappers, the window: about 200 000 objects) out of the
    cyclic garbage collector's sight (``gc.freeze``). A full collection otherwise scans them all
    while holding the GIL, about 110 ms here, and one that falls due while a worker parses a
    manifest (which allocates a list per lit point) stalls the event loop as long:
    ``benchmarks/bench_gui.py`` measured 130-170 ms while opening a 128 px dataset, 22 ms after
    this. Frozen objects are still freed by reference counting; only cycles among them stay."""
    gc.collect()
    gc.freeze()
