"""Type checks for JSON documents (manifests, scenes) that raise one error naming the file and key."""

from __future__ import annotations

import math
from pathlib import PurePosixPath


class Validator:
    """Checks values of a decoded JSON document; failures raise ``error`` with a message
    ``"{where}: '{key}' must be ..., got ..."``."""

    def __init__(self, where: object, error: type[Exception]):
        self.where = where
        self.error = error

    def fail(self, key: str, expected: str, value: object) -> Exception:
        return self.error(f"{self.where}: '{key}' must be {expected}, got {value!r}")

    def mapping(self, value: object, key: str, allowed: set[str] | None, required: set[str]) -> dict:
        """A JSON object with no keys beyond ``allowed`` (None: any) and all of ``required``."""
        if not isinstance(value, dict):
            raise self.fail(key, "an object", value)
        if allowed is not None and (unknown := sorted(set(value) - allowed)):
            raise self.error(
                f"{self.where}: unknown key(s) {', '.join(map(repr, unknown))} in {key} "
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
        if not isinstance(value, str):
            raise self.fail(key, "a string", value)
        return value

    def number(self, value: object, key: str) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(key, "a finite number", value)
        return float(value)

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
        """A '/'-separated relative path that stays inside the document's folder."""
        name = self.string(value, key)
        path = PurePosixPath(name)
        if not name or path.is_absolute() or ".." in path.parts or "\\" in name:
            raise self.fail(key, "a relative path inside the dataset folder (with '/')", value)
        return name
