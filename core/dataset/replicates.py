"""Independent replicates of a capture (the frames' ``replicate`` labels): each replicate as a
manifest of its own, so that anything computed from the responses can be computed per replicate
and its spread give the noise of the whole.

A dataset whose frames carry two or more replicate labels (each lighting the same points) is
``K`` independent measurements of the same impulse responses: a rig's repeated scans, or a
simulator's independent batches. The dataset's responses are the mean of a point's frames
(docs/format/dataset.md), so for every quantity ``Q`` linear in the responses (ring light and transient
images, a region's ring profile), ``Q`` of the dataset is the mean of the ``Q_k`` of its replicates
(exactly when each replicate lights every point once at one exposure), and its standard error is
``std_k(Q_k) / sqrt(K)``, ddof 1: noise shared by lit points (one simulated kernel, a projector's
flicker) included, which the spread of a ring's members cannot show.
"""

from __future__ import annotations

from dataclasses import replace

from .manifest import Manifest


def replicate_manifests(manifest: Manifest) -> list[Manifest]:
    """One manifest per replicate label of ``manifest`` (sorted), holding that replicate's frames
    only; built in memory (no ``source_sha256``): open each with ``use_cache=False``."""
    return [replace(manifest, frames=tuple(frame for frame in manifest.frames if frame.replicate == label),
                    source_sha256=None)
            for label in manifest.replicates]
