"""Layer inversion: a white Monte Carlo forward model of layered slabs, fitted to a region's
ring-light profiles for each layer's absorption, colour and uncertainty.

Uses ``simulate`` (its optics and thick-slab colours), ``colour``, ``rings``, ``dataset`` and the
shared basics; never capture.
"""
