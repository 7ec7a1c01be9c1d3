"""Silencing the OpenEXR library while reader threads decode side by side."""

import subprocess
import sys

SCRIPT = """
import os, sys, threading
from ringlight.core.dataset.exr_header import quiet_library

first_in, second_in, second_out = threading.Event(), threading.Event(), threading.Event()
overlapped = []

def first():
    with quiet_library():
        first_in.set()
        os.write(1, b"lost 1 ")
        second_out.wait(5)  # still inside while the second reader comes and goes
        overlapped.append(second_in.is_set())

def second():
    first_in.wait(30)
    with quiet_library():
        second_in.set()
        os.write(2, b"lost 2 ")
        print("lost 3")
    second_out.set()

threads = [threading.Thread(target=first), threading.Thread(target=second)]
for thread in threads:
    thread.start()
for thread in threads:
    thread.join(60)
os.write(1, b"overlapped " if overlapped == [True] else b"serialised ")
print("after", flush=True)
os.write(2, b"stderr back")
"""


def test_readers_are_silenced_together_and_the_descriptors_come_back_after_the_last():
    """A second reader enters while the first is inside (one at a time, the reader threads of an
    open decoded a frame each in turn); nothing either writes reaches descriptors 1 and 2, and
    both point at the terminal again once the last has left."""
    result = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=120, check=True)
    assert result.stdout == "overlapped after\n"
    assert result.stderr == "stderr back"


FIRST_OUT_FIRST = """
import os, threading
from ringlight.core.dataset.exr_header import _Silence, quiet_library

first_in, first_out = threading.Event(), threading.Event()

def first():
    with quiet_library():
        first_in.set()
    first_out.set()

def second():
    first_in.wait(30)
    with quiet_library():
        first_out.wait(30)  # the first has left: this one is still inside
        os.write(1, b"lost after the first left ")
        os.write(2, b"lost too ")

threads = [threading.Thread(target=first), threading.Thread(target=second)]
for thread in threads:
    thread.start()
for thread in threads:
    thread.join(60)
print(f"after, depth {_Silence.depth}", flush=True)
os.write(2, b"stderr back")
"""


def test_a_reader_leaving_first_keeps_the_others_silenced():
    """The first reader in leaves while the second is still inside: the library stays silenced until
    the second leaves (a reader restoring the descriptors it found would let the second's output
    through, and the last one out would restore /dev/null for good)."""
    result = subprocess.run([sys.executable, "-c", FIRST_OUT_FIRST], capture_output=True, text=True, timeout=120,
                            check=True)
    assert result.stdout == "after, depth 0\n"
    assert result.stderr == "stderr back"
