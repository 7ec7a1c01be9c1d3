"""ringlight.core: variable ring light imaging as a numpy library (no Qt).

    from ringlight.core import open_dataset, radius_range, transient_stack
    dataset = open_dataset("red-bead")      # after: ringlight demo --sample red-bead --out red-bead
    stack = transient_stack(dataset, radius_range(0, 10, 1), step=1.0)
    stack.images            # (11, 48, 48, 3) float32, NaN where undefined

(docs/guide/python.md runs the same lines.)

Importing it first checks that numba's cache of ringlight's kernels matches their sources
(:mod:`.kernel_cache`), before any kernel loads.
"""

from .kernel_cache import check_kernel_cache

check_kernel_cache()

from .dataset.exr import read_exr_rgb, write_exr_rgb
from .dataset.disc import disc_offsets, response_memory_bytes
from .dataset.impulse_dataset import ImpulseDataset, effective_max_radius, open_dataset
from .dataset.manifest import Manifest, read_manifest
from .dataset.manifest_copy import load_manifest
from .dataset.writer import DatasetWriter
from .errors import Cancelled, DatasetError, RinglightError, StackError
from .rings.geometry import RingGeometry, annulus_pixel_area, ring_geometry
from .rings.stack_io import read_stack, write_stack
from .rings.radii import needed_radius, parse_radius_range, radius_range
from .rings.stacks import Stack, ring_stack, transient_stack

__all__ = [
    "Cancelled", "DatasetError", "DatasetWriter", "ImpulseDataset", "Manifest", "RingGeometry",
    "RinglightError", "Stack", "StackError", "annulus_pixel_area", "disc_offsets",
    "effective_max_radius", "load_manifest", "needed_radius", "open_dataset", "parse_radius_range",
    "radius_range", "read_exr_rgb", "read_manifest", "read_stack", "response_memory_bytes",
    "ring_geometry", "ring_stack", "transient_stack", "write_exr_rgb", "write_stack",
]
