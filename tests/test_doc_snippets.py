"""Every command and Python block of README.md and docs/ runs as written (issue 39).

A document's fenced blocks (a numbered list item's indented block too) run in the order they
appear, in one fresh folder per document (so a page's first block can write a sample there with
``ringlight demo --sample NAME --out NAME`` and the next ones use it), with the ``ringlight``
command of this environment and a private user cache: those marked ``shell`` in bash, those
marked ``python`` as ``python -c`` would run them but in this process (a fresh ``__main__``
namespace, a plain interpreter's warnings; a process of their own paid about 3 s of CPU again for
the imports made here). Every page but README.md runs its ``ringlight`` commands through
tests/command_server.py (a process forked from one that imported numpy, numba, SciPy, OpenCV,
OpenEXR and ringlight's core once, with the block's folder, environment and streams); README's
quick start runs the console script itself, as a new user does. Every page but README.md finds the
bundled samples it writes out already in its user cache, as after an earlier ``ringlight demo``
(:data:`COLD`). A block must exit 0 (a Python block: raise nothing), unless the comment
line before it says otherwise:

- ``<!-- snippet: exit N -->``: the shell block must exit N and print one line on stderr (a refusal
  the page shows);
- ``<!-- snippet: skip (REASON) -->``: not run (installs, the test suite, the documentation's
  build); the reason is required and the skipped blocks are few.

Blocks in other languages (``text``, ``json``, ``toml``) are shown, not run; a command left in an
unmarked indented block would escape this test, so none may be.
"""

import contextlib
import io
import os
import re
import shutil
import subprocess
import sys
import tempfile
import traceback
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from command_server import CommandServer
from reference import random_impulses, write_dataset

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = [ROOT / "README.md", *sorted(
    path for path in (ROOT / "docs").rglob("*.md") if "_build" not in path.parts)]
RUN = {"shell", "python"}
SHOWN = {"text", "json", "toml"}
MARKER = re.compile(r"<!-- snippet: (skip \((?P<reason>[^)]+)\)|exit (?P<status>\d+)) -->")
FENCE = re.compile(r"^(?P<indent> {0,3})(?P<fence>`{3,})(?P<language>\{[\w-]+\}|[\w-]*)\s*$")
"""A fence at the start of a line or indented by up to 3 spaces (a numbered list item's block);
``{name}`` is a MyST directive (a note, a toctree, a table)."""
MAX_SKIPPED = 8
HANG_S = 900
"""A shell block still running after this long is taken for hung (a Python block, in this
process, has the suite's faulthandler_timeout, which prints where it is). It is no measure of
speed: optics.md's first block (a sample written, then a white run and the fits with numba's cache
empty: 97 s at load 3 on two cores) ran over 300 s once in CI at load 5-8, with four test workers
and the documentation's build sharing the two cores."""


@dataclass
class Block:
    document: Path
    line: int
    language: str
    code: str
    skip: str | None = None
    status: int = 0

    def __str__(self):
        return f"{self.document.relative_to(ROOT)}:{self.line} ({self.language})"


def blocks(document: Path) -> list[Block]:
    """The fenced code blocks of a Markdown document, with the marker before each."""
    found, lines, index = [], document.read_text("utf-8").splitlines(), 0
    while index < len(lines):
        opening = FENCE.match(lines[index])
        if opening is None:
            index += 1
            continue
        end = next(at for at in range(index + 1, len(lines)) if lines[at].strip() == opening["fence"])
        previous = next((lines[at] for at in range(index - 1, -1, -1) if lines[at].strip()), "")
        marker = MARKER.fullmatch(previous.strip())
        # CommonMark: a fence indented by N spaces takes up to N spaces off each of its lines.
        indent = len(opening["indent"])
        code = "\n".join(line[:indent].lstrip(" ") + line[indent:] for line in lines[index + 1:end])
        found.append(Block(document, index + 1, opening["language"], code + "\n",
                           skip=marker["reason"] if marker and marker["reason"] else None,
                           status=int(marker["status"]) if marker and marker["status"] else 0))
        index = end + 1
    return found


ALL_BLOCKS = [block for document in DOCUMENTS for block in blocks(document)]


def test_every_block_is_run_or_shown_and_few_are_skipped():
    unknown = [str(block) for block in ALL_BLOCKS
               if block.language not in RUN | SHOWN and not block.language.startswith("{")]
    assert not unknown, f"blocks neither run nor shown (tag them shell, python, text, json or toml): {unknown}"
    skipped = [f"{block}: {block.skip}" for block in ALL_BLOCKS if block.skip]
    assert len(skipped) <= MAX_SKIPPED, skipped
    assert all(block.language == "shell" for block in ALL_BLOCKS if block.status), "exit markers are for shell blocks"
    assert sum(block.language in RUN and not block.skip for block in ALL_BLOCKS) >= 20


def test_a_list_items_block_is_found_with_its_indent_taken_off(tmp_path):
    """optics.md's calibration steps: fences indented 3 spaces in a numbered list, which the
    runner once passed over (CommonMark: up to the fence's indent comes off each line)."""
    page = tmp_path / "page.md"
    page.write_text("1. **Calibrate.**\n\n   ```shell\n   ringlight optics a \\\n     --json b\n  echo c\n   ```\n\n"
                    "```python\nprint(1)\n```\n", "utf-8")
    assert [(block.line, block.language, block.code) for block in blocks(page)] == [
        (3, "shell", "ringlight optics a \\\n  --json b\necho c\n"), (9, "python", "print(1)\n")]


@pytest.mark.parametrize("document", DOCUMENTS, ids=lambda path: str(path.relative_to(ROOT)))
def test_no_command_hides_in_an_indented_block(document):
    """README's old layout: commands in 4-space indented blocks, which no test could find."""
    inside, hidden = False, []
    for number, line in enumerate(document.read_text("utf-8").splitlines(), 1):
        if FENCE.match(line):
            inside = not inside
        elif not inside and re.match(r" {4,}(ringlight|python|from ringlight|import )", line):
            hidden.append(f"{number}: {line.strip()}")
    assert not hidden, hidden


DEMO_OUT = re.compile(r"^ringlight demo --sample (?P<name>[\w-]+) --out ", re.MULTILINE)
COLD = ROOT / "README.md"
"""The page whose samples are written as a new user's first run writes them: every other page
finds the samples its ``ringlight demo --sample NAME --out DIR`` commands name already in its
user cache (links to the ones the suite writes once), as after an earlier ``ringlight demo``,
so the command copies them (1 CPU-s) instead of writing 5000 frames anew (10 CPU-s)."""


def samples_written_out(document: Path) -> list[str]:
    """The samples a document's shell blocks write with ``ringlight demo --sample NAME --out``."""
    return [found["name"] for block in blocks(document) if block.language == "shell" and not block.skip
            for found in DEMO_OUT.finditer(block.code)]


def test_the_pages_demo_commands_are_found_and_one_page_writes_them_cold():
    """What the seeding below depends on: the pattern finds the pages' sample writes (optics.md:
    skin1, layers.md: layers3), and README's quick start still writes its two from nothing."""
    assert samples_written_out(ROOT / "docs" / "guide" / "optics.md") == ["skin1"]
    assert samples_written_out(ROOT / "docs" / "guide" / "layers.md") == ["layers3"]
    assert samples_written_out(COLD) == ["red-bead", "layers3"]


RUNNABLE = [document for document in DOCUMENTS
            if any(block.language in RUN and not block.skip for block in blocks(document))]


def run_python(block: Block) -> None:
    """Run a Python block as ``python -c`` would (the caller has set the folder and environment);
    its exception fails the test with the block's place and code."""
    output = io.StringIO()
    try:
        with warnings.catch_warnings(), contextlib.redirect_stdout(output), contextlib.redirect_stderr(output):
            warnings.resetwarnings()  # a plain interpreter's: shown, not raised as the suite's are
            warnings.simplefilter("default")
            exec(compile(block.code, str(block), "exec"), {"__name__": "__main__"})
    except BaseException:  # SystemExit too: python -c would have exited
        pytest.fail(f"{block} failed:\n{block.code}\n{output.getvalue()[-3000:]}{traceback.format_exc()[-3000:]}")


@pytest.fixture(scope="session")
def command_server():
    """One :class:`command_server.CommandServer` for the session's pages (in a short folder: a Unix
    socket's path holds at most 107 bytes)."""
    server = CommandServer(Path(tempfile.mkdtemp(prefix="rl-")))
    yield server
    server.close()
    shutil.rmtree(server.folder, ignore_errors=True)


def command_path(first: list[str]) -> str:
    """PATH for a page's shell blocks: the folders ``first``, then this environment's ``ringlight``
    (the console script), then the inherited PATH."""
    return os.pathsep.join([*first, str(Path(sys.executable).parent), os.environ.get("PATH", "")])


def shell(code: str, work: Path, environment: dict) -> subprocess.CompletedProcess:
    """Run a shell block as the page's reader would (bash, strict), within :data:`HANG_S`."""
    return subprocess.run(["bash", "-euo", "pipefail", "-c", code], cwd=work, env=environment,
                          capture_output=True, text=True, timeout=HANG_S)


def test_a_served_command_prints_and_exits_as_the_console_script(tmp_path, command_server):
    """What a page's block sees of tests/command_server.py's ``ringlight`` is what it sees of the
    console script: its folder and environment (relative paths, the memory budget ``info`` prints),
    both streams byte for byte and the exit status, of a dataset's summary and of a refusal."""
    write_dataset(tmp_path / "ds", 6, 5, random_impulses(np.random.default_rng(0), 6, 5, support=10))
    (tmp_path / "not-a-dataset").mkdir()
    code = "RINGLIGHT_MEMORY_BUDGET=300M ringlight info ds\nringlight info not-a-dataset || echo refused $?\n"
    runs = {}
    for name, first in (("console script", []), ("served", [str(command_server.bin)])):
        runs[name] = shell(code, tmp_path, dict(os.environ, PATH=command_path(first)))
    served, real = runs["served"], runs["console script"]
    assert "refused 2" in real.stdout and "not-a-dataset" in real.stderr
    assert "memory budget 300.0 MiB" in real.stdout
    assert (served.returncode, served.stdout, served.stderr) == (real.returncode, real.stdout, real.stderr)


@pytest.mark.parametrize("document", RUNNABLE, ids=lambda path: str(path.relative_to(ROOT)))
def test_every_command_and_snippet_runs_as_written(document, tmp_path, private_cache, monkeypatch, link_sample,
                                                   command_server):
    work = tmp_path / "work"
    work.mkdir()
    (tmp_path / "tmp").mkdir()
    # The shell blocks' environment; the Python blocks see it in this process.
    # Every page but README finds the server's ringlight before the console script.
    monkeypatch.setenv("PATH", command_path([] if document == COLD else [str(command_server.bin)]))
    monkeypatch.setenv("QT_QPA_PLATFORM", "offscreen")
    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    monkeypatch.delenv("RINGLIGHT_LOG", raising=False)
    monkeypatch.chdir(work)
    environment = dict(os.environ)  # RINGLIGHT_CACHE_DIR: private_cache's
    if document != COLD:
        for name in samples_written_out(document):
            link_sample(name)  # into private_cache, where the page's demo command copies it from
    for block in blocks(document):
        if block.language not in RUN or block.skip:
            continue
        if block.language == "python":
            run_python(block)
            continue
        try:
            result = shell(block.code, work, environment)
        except subprocess.TimeoutExpired as expired:
            stderr = (expired.stderr or b"").decode(errors="replace")  # bytes, whatever text= says
            pytest.fail(f"{block} still ran after {HANG_S} s (hung?):\n{block.code}\n{stderr[-3000:]}")
        assert result.returncode == block.status, f"{block} exited {result.returncode}:\n{block.code}\n{result.stderr[-3000:]}"
        if block.status:
            assert len(result.stderr.strip().splitlines()) == 1, f"{block}: not one line:\n{result.stderr}"
