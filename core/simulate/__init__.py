"""The Monte Carlo simulator: scenes, the photon kernel, transport into datasets, presets, lattices.

Uses ``colour``, ``rings``, ``dataset`` and the shared basics; never capture.
"""
