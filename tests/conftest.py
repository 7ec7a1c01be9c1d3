"""Test setup: offscreen Qt, a private cache folder, and helpers shared by the tests."""

import os

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

import pytest


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    """Point ringlight's user cache at a fresh folder for every test."""
    folder = tmp_path_factory.mktemp("user-cache")
    monkeypatch.setenv("RINGLIGHT_CACHE_DIR", str(folder))
    return folder
