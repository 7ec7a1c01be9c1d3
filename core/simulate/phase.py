"""Sampling the Henyey-Greenstein phase function: the scattering step that the simulator's walk
and the layer inversion's white Monte Carlo share (its density is
:func:`ringlight.core.simulate.camera.henyey_greenstein`; the statement itself is
:func:`.steps.scattered_direction`, which the CUDA kernels compile too). Directions are ``(y, x, z)``
unit vectors."""

from __future__ import annotations

from .steps import CPU

scatter_direction = CPU.scatter
"""``scatter_direction(state, uy, ux, uz, g)``: the direction ``(uy, ux, uz)`` after a
Henyey-Greenstein scattering of anisotropy ``g``, from two uniforms of ``state`` (the polar
angle's, then the azimuth's)."""
