"""Reading and checking JSON documents (manifests, scenes, stack and cache files).

:func:`read_json` is the one bounded reader every JSON file of ringlight goes through: a size
limit before parsing, integer literals of at most :data:`MAX_INT_DIGITS` digits, no NaN or
Infinity literals, bounded nesting. :class:`Validator` checks the decoded values. Both raise the
caller's error family with one line naming the file (and key).
"""

from __future__ import annotations

import gc
import json
import math
import os
import re
import reprlib
import stat
from collections.abc import Callable
from pathlib import Path

MAX_JSON_BYTES = 256 * 2**20
"""Largest JSON file read (a one-point-per-frame manifest of a 1024 x 1024 grid is ~80 MB)."""
MAX_INT_DIGITS = 30
"""Longest integer literal accepted; Python would otherwise spend quadratic time on huge ones."""
MAX_NAME_BYTES = 255
"""Longest file-name component (bytes, UTF-8) on the file systems ringlight writes to."""
MAX_PATH_BYTES = 1024
"""Longest relative path (bytes, UTF-8) a document may name: with the dataset folder's own path it
stays under the 4096 bytes Linux allows a whole path."""

_LONG_DIGIT_RUN = re.compile(rf"[0-9]{{{MAX_INT_DIGITS + 1}}}")
_SHORT = reprlib.Repr()
_SHORT.maxstring = 60
_SHORT.maxother = 60
_SHORT.maxlist = _SHORT.maxdict = 4
_SHORT.maxlevel = 2


def short_repr(value: object) -> str:
    """A one-line repr of at most about 80 characters, whatever the nesting or length of ``value``."""
    return _SHORT.repr(value).replace("\n", " ")


def _bounded_int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_INT_DIGITS:
        raise ValueError(f"an integer literal of {len(text)} digits (at most {MAX_INT_DIGITS})")
    return int(text)


def _no_constant(name: str):
    raise ValueError(f"{name} is not a JSON number")


def read_json(path: str | os.PathLike, error: type[Exception], what: str = "JSON file",
              max_bytes: int = MAX_JSON_BYTES) -> object:
    """Decode the JSON file ``path``; any problem raises ``error`` with one line naming it.

    Refused: a path that is not a regular file (a FIFO or device would block or never end), a
    file over ``max_bytes``, invalid UTF-8 or JSON, integer literals over :data:`MAX_INT_DIGITS`
    digits, NaN and Infinity literals, and nesting deeper than the interpreter can decode.
    """
    return decode_json(read_bounded(path, error, what, max_bytes), path, error, what)


def read_bounded(path: str | os.PathLike, error: type[Exception], what: str = "JSON file",
                 max_bytes: int = MAX_JSON_BYTES) -> bytes:
    """The bytes of the regular file ``path`` of at most ``max_bytes``; anything else raises
    ``error`` with one line naming it (see :func:`read_json`)."""
    path = Path(path)
    try:
        with open(path, "rb", opener=_nonblocking) as handle:
            info = os.fstat(handle.fileno())
            if not stat.S_ISREG(info.st_mode):
                raise error(f"{path}: the {what} is not a regular file")
            if info.st_size > max_bytes:
                raise error(f"{path}: the {what} is {info.st_size / 2**20:.0f} MiB, over the "
                            f"{max_bytes / 2**20:.0f} MiB a {what} may have")
            # Sized by the file, not the limit: read(n) allocates n bytes before reading.
            data = handle.read(min(info.st_size, max_bytes) + 1)
    except FileNotFoundError:
        raise error(f"{path}: {what} not found") from None
    except IsADirectoryError:
        raise error(f"{path}: the {what} is not a regular file") from None
    except OSError as problem:
        raise error(f"{path}: the {what} cannot be read ({problem.strerror or problem})") from None
    if len(data) > max_bytes:
        raise error(f"{path}: the {what} is over the {max_bytes / 2**20:.0f} MiB a {what} may have")
    return data


def decode_json(data: bytes, path: str | os.PathLike, error: type[Exception], what: str = "JSON file",
                element_hooks: dict[str, Callable[[], Callable[[object], object]]] | None = None) -> object:
    """Decode ``data``, the bytes of the JSON file ``path``, with the limits of :func:`read_json`.

    ``element_hooks``: for a key of the top-level object whose value is an array, a factory of a
    function that each element is passed to as soon as it is decoded, and whose result is kept in
    its place (a long array's elements made compact one by one: see
    :class:`ringlight.core.dataset.frame_table.FrameCollector`); one function per occurrence of
    the key."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as problem:
        raise error(f"{path}: the {what} is not UTF-8 text (byte {problem.start})") from None
    # The bounded integer hook costs a Python call per integer; it is only needed when the text
    # holds a run of digits long enough to be a refused literal (in a string or not).
    parse_int = _bounded_int if _has_long_digit_run(text) else None
    # Decoding makes millions of lists and dicts and no cycle: the collections they set off
    # traverse them all, over half the time (an 800 px manifest: 0.76 s against 0.33 s) and one
    # of them holding the GIL 94 ms.
    collecting = gc.isenabled()
    gc.disable()
    try:
        return _decode_in_pieces(text, json.JSONDecoder(parse_int=parse_int, parse_constant=_no_constant),
                                 element_hooks or {})
    except json.JSONDecodeError as problem:
        raise error(f"{path}: invalid JSON at line {problem.lineno}: {problem.msg}") from None
    except RecursionError:
        raise error(f"{path}: the {what} is nested too deeply") from None
    except ValueError as problem:
        raise error(f"{path}: invalid JSON: {problem}") from None
    finally:
        if collecting:
            gc.enable()


_SPACE = re.compile(r"[ \t\n\r]*")
_PIECE = 2**20
"""Characters the long-digit search looks at in one call (a call holds the GIL: 20 MB at once took
0.2 s)."""


def _has_long_digit_run(text: str) -> bool:
    """Whether ``text`` holds a run of more than :data:`MAX_INT_DIGITS` digits, searched a piece
    at a time (pieces overlapping by that many characters, so no run is split unseen)."""
    return any(_LONG_DIGIT_RUN.search(text, start, start + _PIECE + MAX_INT_DIGITS)
               for start in range(0, max(len(text), 1), _PIECE))


def _decode_in_pieces(text: str, decoder: json.JSONDecoder, element_hooks: dict) -> object:
    """``decoder.decode(text)``, with a top-level object's values and the elements of its arrays
    each decoded by one call of the decoder: a single call holds the GIL for the whole document
    (an 800 px manifest's 20 MB of JSON: 1-2 s in which a window's event loop stood still); between
    pieces other threads run. The same values, duplicate keys (the last wins) and errors."""
    if text.startswith("\ufeff"):
        raise json.JSONDecodeError("Unexpected UTF-8 BOM (decode using utf-8-sig)", text, 0)
    index = _SPACE.match(text).end()
    if not text.startswith("{", index):
        return decoder.decode(text)
    result, index = {}, _SPACE.match(text, index + 1).end()
    if text.startswith("}", index):
        index += 1
    else:
        while True:
            if not text.startswith('"', index):
                raise json.JSONDecodeError("Expecting property name enclosed in double quotes", text, index)
            key, index = json.decoder.scanstring(text, index + 1)
            index = _SPACE.match(text, index).end()
            if not text.startswith(":", index):
                raise json.JSONDecodeError("Expecting ':' delimiter", text, index)
            index = _SPACE.match(text, index + 1).end()
            if text.startswith("[", index):
                hook = element_hooks.get(key)
                result[key], index = _array_in_pieces(text, index, decoder, hook() if hook else None)
            else:
                result[key], index = _one_value(text, index, decoder)
            index = _SPACE.match(text, index).end()
            if text.startswith("}", index):
                index += 1
                break
            if not text.startswith(",", index):
                raise json.JSONDecodeError("Expecting ',' delimiter", text, index)
            index = _SPACE.match(text, index + 1).end()
    end = _SPACE.match(text, index).end()
    if end != len(text):
        raise json.JSONDecodeError("Extra data", text, end)
    return result


def _array_in_pieces(text: str, index: int, decoder: json.JSONDecoder,
                     convert: Callable[[object], object] | None = None) -> tuple[list, int]:
    """The array starting at ``text[index]`` ("["), an element a call (each passed through
    ``convert`` when given); and the index after it."""
    values, index = [], _SPACE.match(text, index + 1).end()
    if text.startswith("]", index):
        return values, index + 1
    while True:
        value, index = _one_value(text, index, decoder)
        values.append(value if convert is None else convert(value))
        index = _SPACE.match(text, index).end()
        if text.startswith("]", index):
            return values, index + 1
        if not text.startswith(",", index):
            raise json.JSONDecodeError("Expecting ',' delimiter", text, index)
        index = _SPACE.match(text, index + 1).end()


def _one_value(text: str, index: int, decoder: json.JSONDecoder) -> tuple[object, int]:
    try:
        return decoder.scan_once(text, index)
    except StopIteration as stop:
        raise json.JSONDecodeError("Expecting value", text, stop.value) from None


def _nonblocking(name, flags):
    # O_NONBLOCK: opening a FIFO must not wait for a writer; regular files are unaffected.
    return os.open(name, flags | os.O_NONBLOCK)


class Validator:
    """Checks values of a decoded JSON document; failures raise ``error`` with a message
    ``"{where}: '{key}' must be ..., got ..."``."""

    def __init__(self, where: object, error: type[Exception]):
        self.where = where
        self.error = error

    def fail(self, key: str, expected: str, value: object) -> Exception:
        return self.error(f"{self.where}: '{key}' must be {expected}, got {short_repr(value)}")

    def mapping(self, value: object, key: str, allowed: set[str] | None, required: set[str]) -> dict:
        """A JSON object with no keys beyond ``allowed`` (None: any) and all of ``required``."""
        if not isinstance(value, dict):
            raise self.fail(key, "an object", value)
        if allowed is not None and (unknown := sorted(set(value) - allowed)):
            raise self.error(
                f"{self.where}: unknown key(s) {', '.join(map(short_repr, unknown[:5]))}{' ...' if len(unknown) > 5 else ''} in {key} "
                f"(allowed: {', '.join(sorted(allowed))})"
            )
        if absent := sorted(required - set(value)):
            raise self.error(f"{self.where}: {key} lacks required key(s) {', '.join(map(repr, absent))}")
        return value

    def sequence(self, value: object, key: str) -> list:
        if not isinstance(value, list):
            raise self.fail(key, "a list", value)
        return value

    def string(self, value: object, key: str) -> str:
        """A string of valid Unicode (JSON's ``\\ud800`` escapes can make lone surrogates, which
        no file name, terminal or file can hold)."""
        if not isinstance(value, str):
            raise self.fail(key, "a string", value)
        if not value.isascii():
            try:
                value.encode("utf-8")
            except UnicodeEncodeError:
                raise self.fail(key, "a string of valid Unicode", value) from None
        return value

    def number(self, value: object, key: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, "a finite number", value)
        try:
            number = float(value)
        except OverflowError:  # an integer of hundreds of digits: math.isfinite overflowed on it
            raise self.fail(key, "a finite number", value) from None
        if not math.isfinite(number):
            raise self.fail(key, "a finite number", value)
        return number

    def positive_number(self, value: object, key: str) -> float:
        number = self.number(value, key)
        if number <= 0:
            raise self.fail(key, "a positive number", value)
        return number

    def positive_int(self, value: object, key: str) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise self.fail(key, "a positive integer", value)
        return value

    def numbers(self, value: object, key: str, count: int) -> tuple[float, ...]:
        items = self.sequence(value, key)
        if len(items) != count:
            raise self.fail(key, f"a list of {count} numbers", value)
        return tuple(self.number(item, key) for item in items)

    def relative_file(self, value: object, key: str) -> str:
        """A '/'-separated relative path that stays inside the document's folder, with a name
        every file system can hold (no NUL, valid Unicode, components of at most
        :data:`MAX_NAME_BYTES` and the whole of at most :data:`MAX_PATH_BYTES` bytes)."""
        if not isinstance(value, str):
            raise self.fail(key, "a string", value)
        name = value
        parts = name.split("/")
        if not name or name.startswith("/") or ".." in parts or "\\" in name:
            raise self.fail(key, "a relative path inside the dataset folder (with '/')", value)
        if "\0" in name:
            raise self.fail(key, "a file name without NUL characters", value)
        try:
            encoded = [part.encode("utf-8") for part in parts]
        except UnicodeEncodeError:
            raise self.fail(key, "a file name in valid Unicode", value) from None
        if max(map(len, encoded)) > MAX_NAME_BYTES:
            raise self.fail(key, f"a file name of at most {MAX_NAME_BYTES} bytes per folder level", value)
        if sum(map(len, encoded)) + len(encoded) - 1 > MAX_PATH_BYTES:
            raise self.fail(key, f"a path of at most {MAX_PATH_BYTES} bytes", value)
        return name
