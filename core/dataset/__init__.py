"""Impulse datasets on disk and in memory: manifest, EXR frames, the response model, cache, writer.

Uses only the shared basics of ``ringlight.core`` (errors, atomic, validation, colourspaces).
"""
