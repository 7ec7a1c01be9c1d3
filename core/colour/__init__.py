"""Colour: chromaticity and layer colour recovery, regions, the display pipeline, PNG/movie export.

Uses ``ringlight.core.rings``, ``ringlight.core.dataset`` and the shared basics.
"""
