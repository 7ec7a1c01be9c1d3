"""The bounded JSON reader decodes a top-level object's values and arrays a piece at a time (so
that other threads run meanwhile): the same values and the same errors as one ``json.loads``,
on random documents and random damage to them."""

import gc
import json
import threading
import time

import numpy as np
import pytest
from ringlight.core.errors import DatasetError
from ringlight.core.validation import decode_json


def random_value(rng, depth=0):
    kind = rng.integers(0, 7 if depth < 3 else 4)
    if kind == 0:
        return int(rng.integers(-10**6, 10**6))
    if kind == 1:
        return float(rng.normal()) * 10.0 ** int(rng.integers(-5, 5))
    if kind == 2:
        return "".join(rng.choice(list('ab "\\/é\n\t☃'), int(rng.integers(0, 6))))
    if kind == 3:
        return [None, True, False][int(rng.integers(0, 3))]
    if kind in (4, 5):
        return [random_value(rng, depth + 1) for _ in range(int(rng.integers(0, 4)))]
    return {f"k{int(rng.integers(0, 4))}": random_value(rng, depth + 1) for _ in range(int(rng.integers(0, 4)))}


def random_text(rng):
    document = {f"k{index}": random_value(rng) for index in range(int(rng.integers(0, 5)))}
    text = json.dumps(document, indent=[None, 0, 2][int(rng.integers(0, 3))], ensure_ascii=bool(rng.integers(0, 2)))
    if rng.integers(0, 2):  # spacing json.dumps does not make, and a key given twice
        text = text.replace(":", " :\t").replace(",", " ,\n ")
        text = text[:-1] + (', "k0": 7}' if len(text) > 2 else '"k0": 7}')
    return text


def outcome(decode):
    try:
        return "ok", decode()
    except (json.JSONDecodeError, DatasetError) as error:
        return "error", str(error)


@pytest.mark.parametrize("seed", range(4))
def test_pieces_decode_as_one_call_does_on_random_and_damaged_documents(seed):
    rng = np.random.default_rng(seed)
    for _ in range(250):
        text = random_text(rng)
        if rng.integers(0, 2):  # damage: a character dropped, doubled or replaced
            at = int(rng.integers(0, len(text)))
            change = rng.integers(0, 3)
            junk = "{}[],:\" x0-"[int(rng.integers(0, 11))]
            text = text[:at] + (text[at] * 2 if change == 0 else "" if change == 1 else junk) + text[at + 1:]
        ours = outcome(lambda: decode_json(text.encode(), "doc.json", DatasetError))
        assert gc.isenabled()  # paused while decoding only
        theirs = outcome(lambda: json.loads(text))
        if theirs[0] == "ok":
            assert ours == theirs, text
        else:  # the same place and reason, in the reader's one line
            error = None
            try:
                json.loads(text)
            except json.JSONDecodeError as problem:
                error = problem
            assert ours == ("error", f"doc.json: invalid JSON at line {error.lineno}: {error.msg}"), text


def test_other_threads_run_while_a_large_manifest_is_decoded():
    """A 4225-frame document (one call of the decoder holds the GIL throughout: a thread waiting
    for it then advances once or not at all): a thread that counts while it is decoded counts
    many times."""
    frames = [{"file": f"frames/{index:05d}.exr", "lit": [[y, x] for y in range(0, 1024, 65)
                                                           for x in range(index % 65, 1024, 65)]}
              for index in range(4225)]
    data = json.dumps({"format": "ringlight-impulse", "version": 1, "frames": frames}).encode()
    counts, decoding, done = [0], threading.Event(), threading.Event()

    def count():
        decoding.wait()
        while not done.is_set():
            counts[0] += 1
            time.sleep(0)

    counter = threading.Thread(target=count)
    counter.start()
    try:
        decoding.set()
        decoded = decode_json(data, "dataset.json", DatasetError)
        during = counts[0]
    finally:
        done.set()
        counter.join()
    assert decoded["frames"][-1] == frames[-1]
    assert during >= 10, during


@pytest.mark.parametrize("text", ["\ufeff{}", "\ufeff[1]", " ", "", "{\"a\": [1, {\"b\": []}]} \n", "\"\\ud800\""])
def test_edges_decode_as_one_call_does(text):
    ours = outcome(lambda: decode_json(text.encode("utf-8", "surrogatepass"), "doc.json", DatasetError))
    try:
        theirs = ("ok", json.loads(text))
    except json.JSONDecodeError as error:
        theirs = ("error", f"doc.json: invalid JSON at line {error.lineno}: {error.msg}")
    assert ours == theirs
