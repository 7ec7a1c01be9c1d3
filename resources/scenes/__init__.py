"""Simulator scene presets (FORMAT.md scene description v1), one JSON file each."""
