"""The output folder of a new scan: what may receive one, checked before the devices open.

A new scan is published onto an absent or empty folder only (:mod:`.scan`); every refusal is one
line naming the folder, and comes before the correspondence is projected, not after it.
"""

from __future__ import annotations

import os
import secrets
from pathlib import Path

from ..atomic import check_output_folder
from ..ownership import Owned, foreign_entry
from .scan_plan import PLAN_NAME, SCAN_FOLDER, ScanError


def check_scan_folder(out: str | os.PathLike) -> None:
    """Raise ScanError (or OutputError) unless a new scan may be written into ``out``.

    :meth:`.scan.Scan.prepare` checks this before it publishes; a caller checks it before the
    devices open, so that a refusal comes before the correspondence is projected, not after.
    Refused: a finished dataset or an unfinished scan, something that is not a folder (at ``out``
    or above it), a folder holding anything, what :func:`..atomic.check_output_folder` refuses,
    and a folder in which the staging folder beside ``out`` cannot be made (read-only, ``/proc``).
    """
    out = Path(out)
    try:
        if (out / "dataset.json").exists():
            raise ScanError(f"{out}: already holds a finished dataset; choose another folder")
        if (out / SCAN_FOLDER / PLAN_NAME).exists():
            raise ScanError(f"{out}: holds an unfinished scan; resume it or choose another folder")
        _check_empty(out)
        check_output_folder(out, lambda folder: None, "scan", replace=False)
        _probe_staging(out)
    except OSError as error:  # a folder that cannot be read or written (OutputError says so itself)
        raise ScanError(f"{out}: cannot prepare the scan: {error.strerror or error}") from error


def _check_empty(out: Path) -> None:
    """Refuse an ``out`` that is not a folder or holds anything: a new scan replaces nothing (one
    under a file is :func:`..atomic.check_output_folder`'s)."""
    if not out.is_dir():
        if os.path.lexists(out):
            raise ScanError(f"{out}: exists and is not a folder; refusing to write a scan into it")
        return
    foreign = foreign_entry(out, Owned())
    if foreign is not None:
        raise ScanError(f"{out}: exists and is not empty (it holds {foreign}); "
                        "refusing to write a scan into it: choose another folder")


def _probe_staging(out: Path) -> None:
    """Make and remove a hidden folder where the scan's staging folder will be (beside ``out``,
    links resolved), where that folder exists: OSError when it cannot be made."""
    real = Path(os.path.realpath(os.path.abspath(out)))
    if real.parent.is_dir():
        probe = real.parent / f".{real.name}.partial-{secrets.token_hex(6)}"
        probe.mkdir()
        probe.rmdir()
