"""Sphinx extension: screenshots of the explorer window, made at build time by the app's own
``ringlight DATASET --screenshot FILE.png`` (offscreen), one per bundled sample.

The pages show them from ``_generated/screenshots/`` (not kept in git). The samples are written
into the build's cache folder first (``conf.py`` sets ``RINGLIGHT_CACHE_DIR``), then the windows
are rendered: the first alone, which compiles the kernels a window needs into numba's cache on a
fresh install (two windows at once compiled each of them twice: 10 s of CPU for the noise's kernel
alone), then the others two at a time, loading them from there.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from sphinx.util import logging

SHOTS = {
    # file name: (sample, extra arguments)
    "explorer-red-bead.png": ("red-bead", ["--radius", "2", "--pick", "24,24"]),
    "explorer-star.png": ("star", ["--radius", "3", "--pick", "24,24"]),
    "explorer-layers3.png": ("layers3", ["--radius", "4", "--pick", "24,24"]),
    "explorer-skin1.png": ("skin1", ["--radius", "2", "--pick", "24,24"]),
}
PARALLEL = 2

logger = logging.getLogger(__name__)


def make_screenshots(app) -> None:
    from ringlight.core.simulate.samples import sample_dataset

    folder = Path(app.srcdir) / "_generated" / "screenshots"
    folder.mkdir(parents=True, exist_ok=True)
    environment = {**os.environ, "QT_QPA_PLATFORM": "offscreen"}
    commands = []
    for name, (sample, extra) in SHOTS.items():
        dataset = sample_dataset(sample)
        commands.append([sys.executable, "-m", "ringlight.app", str(dataset), "--screenshot", str(folder / name),
                         "--overwrite", *extra])
    _finish(commands[0], _start(commands[0], environment))
    running = []
    for command in commands[1:]:
        running.append((command, _start(command, environment)))
        if len(running) >= PARALLEL:
            _finish(*running.pop(0))
    for command, process in running:
        _finish(command, process)


def _start(command, environment) -> subprocess.Popen:
    return subprocess.Popen(command, env=environment, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _finish(command, process) -> None:
    output, _ = process.communicate(timeout=300)
    if process.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} exited {process.returncode}: {output.strip()}")
    logger.info(output.strip())


def setup(app):
    app.connect("builder-inited", make_screenshots)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
