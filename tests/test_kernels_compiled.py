"""Whether numba's cache holds ringlight's kernels (a fresh install's first start compiles them
first, about half a minute on two cores, and the window says so): :func:`ringlight.core.rings.stacks.kernels_compiled`."""

import os
import subprocess
import sys

from ringlight.core.rings.stacks import kernels_compiled, warm_up_kernels


def test_the_stack_kernel_is_in_numbas_cache_once_it_has_run():
    warm_up_kernels()  # compiles the stack's kernel into numba's cache, or loads it from there
    assert kernels_compiled()


def test_an_empty_cache_is_a_first_start(tmp_path):
    # numba's cache moved to an empty folder, as on a fresh install: nothing compiled yet.
    code = "from ringlight.core.rings.stacks import kernels_compiled; print(kernels_compiled())"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                            env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)})
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "False"
