"""Ring geometry and the ring light / transient stacks computed from a dataset's responses.

Uses ``ringlight.core.dataset`` and the shared basics; never colour, simulation or capture.
"""
