"""A fresh install's kernels compiled side by side, one process a core
(:mod:`ringlight.core.compile_ahead`)."""

import os
import subprocess
import sys
from concurrent.futures import Future
from concurrent.futures.process import BrokenProcessPool

from ringlight.core import compile_ahead as ahead

# Run as a file: the pool's processes are spawned, and import the main script again (guarded).
# Two small groups (about 10 CPU-s to compile), so that the run stays short; which kernels all
# the groups hold is the next test's.
CHILD = """
from numba.core import event

from ringlight.core import compile_ahead as ahead
from ringlight.core.rings.stacks import kernels_compiled


class Compiles(event.Listener):
    names = set()

    def on_start(self, ev):
        dispatcher = ev.data["dispatcher"]
        self.names.add(dispatcher.py_func.__module__ + "." + dispatcher.__name__)

    def on_end(self, ev):
        pass


if __name__ == "__main__":
    ahead.GROUPS = ("ringlight.core.rings.coverage:warm_up_coverage", "ringlight.core.colour.display:warm_up_display")
    before = kernels_compiled()
    compiled = ahead.compile_ahead(workers=2)
    event.register("numba:compile", Compiles())
    for group in ahead.GROUPS:
        ahead._run_group(group)
    print(before, compiled)
    print(sorted(name for name in Compiles.names if name.startswith("ringlight")))
"""


def test_groups_compiled_in_processes_are_loaded_from_numbas_cache_here(tmp_path):
    # numba's cache in an empty folder, as on a fresh install: the groups compile in two spawned
    # processes, and then run here without compiling any of ringlight's kernels.
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    result = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600,
                            env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")})
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines() == ["False True", "[]"]


OPEN = """
import sys

from numba.core.registry import CPUDispatcher

from ringlight.app.session import load_for_viewing
from ringlight.core import compile_ahead as ahead
from ringlight.core.colour.display import warm_up_display
from ringlight.core.rings.stacks import warm_up_kernels


def signatures():
    found = set()
    for name, module in list(sys.modules.items()):
        if name.startswith("ringlight.") and module is not None:
            for value in vars(module).values():
                if isinstance(value, CPUDispatcher) and value.py_func.__module__ == name:
                    found.update((name + "." + value.__name__, str(signature)) for signature in value.signatures)
    return found


if __name__ == "__main__":
    for group in ahead.GROUPS:
        ahead._run_group(group)
    after_groups = signatures()
    loaded = load_for_viewing(None, None, lambda fraction: None)
    warm_up_kernels()
    warm_up_display()
    print(loaded.stacks.pair.radii.size, " ".join(sorted({name for name, _ in after_groups})))
    print(sorted(signatures() - after_groups))
"""


def test_the_groups_hold_every_kernel_and_type_the_demos_first_open_and_the_warm_ups_load(tmp_path):
    # In a process of its own (one whose earlier work had loaded a kernel would hide it): the groups
    # run (from the cache the test run's start filled), then what a first start runs once they are
    # compiled: the demo's open (its sample written into this test's user cache first), and the
    # warm-ups the window runs at start-up. They add no kernel, and no argument types (a band's
    # slices are not contiguous), that the groups lacked.
    script = tmp_path / "open.py"
    script.write_text(OPEN)
    result = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    first, added = result.stdout.splitlines()
    radii, *kernels = first.split()
    assert int(radii) > 1
    assert {"ringlight.core.rings.stacks._ring_sums", "ringlight.core.dataset.frame_batch._load_frames",
            "ringlight.core.rings.coverage._band_coverage"} <= set(kernels)
    assert added == "[]"


def test_one_core_compiles_in_process_as_before(monkeypatch):
    monkeypatch.setattr(ahead, "kernels_compiled", lambda: False)
    monkeypatch.setattr(ahead, "ProcessPoolExecutor", _no_pool)
    assert ahead.compile_ahead(workers=1) is False


def test_processes_that_cannot_start_or_die_leave_the_compiling_to_the_caller(monkeypatch):
    monkeypatch.setattr(ahead, "kernels_compiled", lambda: False)
    monkeypatch.setattr(ahead, "ProcessPoolExecutor", _pool_refused)
    assert ahead.compile_ahead(workers=2) is False
    monkeypatch.setattr(ahead, "ProcessPoolExecutor", _BrokenPool)
    assert ahead.compile_ahead(workers=2) is False
    assert _BrokenPool.shut_down  # and the pool is let go


def _no_pool(*args, **kwargs):
    raise AssertionError("no process pool with one core")


def _pool_refused(*args, **kwargs):
    raise OSError(24, "Too many open files")


class _BrokenPool:
    """A pool whose processes died (the OS killed them, or they could not import ringlight)."""

    shut_down = False

    def __init__(self, *args, **kwargs):
        pass

    def submit(self, function, *args):
        future = Future()
        future.set_exception(BrokenProcessPool("a child process terminated abruptly"))
        return future

    def shutdown(self, wait=True, cancel_futures=False):
        type(self).shut_down = True


class _Compiling:
    """A compilation that records how it was waited for."""

    def __init__(self):
        self.progress = None

    def wait(self, progress=None):
        self.progress = [0.0, 0.5, 1.0]
        for fraction in self.progress:
            progress(fraction)
        return True


def test_a_first_open_reads_its_manifest_then_waits_for_the_kernels_with_its_phase_named(tmp_path, monkeypatch):
    import numpy as np
    import pytest

    from ringlight.app import session
    from ringlight.core.errors import RinglightError
    from ringlight.core.phases import reporting_phases

    from reference import random_impulses, write_dataset

    compiling = _Compiling()
    monkeypatch.setattr(session, "start_compiling", lambda: compiling)
    # A folder without a manifest: its error at once, nothing waited for.
    with pytest.raises(RinglightError, match="manifest"):
        session.load_for_viewing(tmp_path, None, lambda fraction: None)
    assert compiling.progress is None
    write_dataset(tmp_path / "ds", 6, 6, random_impulses(np.random.default_rng(2), 6, 6, support=2.0), max_radius=2.0)
    phases, fractions = [], []
    with reporting_phases(phases.append):
        loaded = session.load_for_viewing(tmp_path / "ds", None, fractions.append)
    assert loaded.dataset.grid_shape == (6, 6)
    assert compiling.progress == [0.0, 0.5, 1.0]
    assert phases[0] == "compiling ringlight's kernels (first start after an install or update)"
    # The compilation's progress is the open's first half; the open's own follows it.
    assert fractions[:3] == [0.0, 0.25, 0.5]
    assert all(0.5 <= fraction <= 1.0 for fraction in fractions[3:]) and fractions == sorted(fractions)


def test_a_many_core_machine_compiles_in_four_processes(monkeypatch):
    # From four on the longest group bounds the time; each process holds about 290 MB.
    made = []

    def pool(workers, mp_context):
        made.append((workers, mp_context.get_start_method()))
        return _BrokenPool()

    monkeypatch.setattr(ahead, "kernels_compiled", lambda: False)
    monkeypatch.setattr(ahead, "_cores", lambda: 16)
    monkeypatch.setattr(ahead, "ProcessPoolExecutor", pool)
    assert ahead.compile_ahead() is False  # the stand-in pool's processes die
    monkeypatch.setattr(ahead, "_cores", lambda: 3)
    ahead.compile_ahead()
    assert made == [(4, "spawn"), (3, "spawn")]
