"""Bundled sample datasets (see ringlight.core.simulate.samples)."""
