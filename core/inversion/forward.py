"""The forward model of a layered slab: region-mean ring-light profiles E_c(r) for any per-layer
absorption, from a white Monte Carlo database (:mod:`.white_mc`).

A *structure* groups the database's depth bins into layers. With absorption ``mua`` (L,) per layer
(per grid step, one channel), a record's weight is ``v exp(-sum_k mua_k l_k)`` (``l_k`` its path
length in layer ``k``); the impulse response at pixel offset ``d`` is the records' mean per photon
at ``d``, and the ring-light profile is each ring's weighted mean of it (the rings of
:func:`ringlight.core.rings.geometry.ring_geometry`, as the stacks use them): what the region mean
of E_r is over a laterally homogeneous region.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numba
import numpy as np

from ..rings.geometry import ring_geometry
from .vector_exp import vector_exp
from .white_mc import WhiteDatabase


SMALLEST_E = float(np.finfo(np.float64).tiny)
"""Smallest model E a fit takes the log of: absorption at its bound (10 per grid step) makes a
ring's E underflow to 0 over long paths, and a log of 0 stopped the fit (profile likelihoods of a
strongly scattering slab reach that bound). A ring's E is never 0 within :attr:`Forward.reached`
otherwise."""


@dataclass(frozen=True)
class Structure:
    """Layers as runs of depth bins: layer ``k`` covers bins ``[starts[k], starts[k + 1])``, the last
    one down to the base (``starts[0] == 0``). A bin is one grid step deep but the last."""

    starts: tuple[int, ...]

    @property
    def layers(self) -> int:
        return len(self.starts)

    def depth_ranges(self, depth: float) -> list[tuple[float, float]]:
        """Each layer's ``(top, bottom)`` in grid steps; the last one's bottom is ``depth``."""
        bottoms = list(self.starts[1:]) + [depth]
        return [(float(top), float(min(bottom, depth))) for top, bottom in zip(self.starts, bottoms)]


def weights_reach(weights: np.ndarray) -> int:
    """Largest ``max(|dy|, |dx|)`` of an offset that ring weights ``weights`` (R, S, S) (as
    :func:`embedded_rings` takes them) give a weight other than 0."""
    rows, cols = np.nonzero(weights.any(axis=0))
    half = weights.shape[1] // 2
    return int(max(np.abs(rows - half).max(initial=0), np.abs(cols - half).max(initial=0)))


def embedded_rings(weights: np.ndarray, reach: int) -> np.ndarray:
    """(R, (2 reach + 1)^2): ring weights ``weights`` (R, S, S) over pixel offsets
    ``[dy + S // 2, dx + S // 2]`` (:attr:`.measured.MeasuredProfile.ring_weights`) placed on the
    offsets of a database of ``reach``."""
    rows, side, _ = weights.shape
    half = side // 2
    if half > reach:
        if weights_reach(weights) > reach:
            raise ValueError(f"rings reach beyond the database's {reach} pixels")
        weights, half = weights[:, half - reach:half + reach + 1, half - reach:half + reach + 1], reach
    matrix = np.zeros((rows, 2 * reach + 1, 2 * reach + 1))
    matrix[:, reach - half:reach + half + 1, reach - half:reach + half + 1] = weights
    return matrix.reshape(rows, -1)


def ring_matrix(radii, reach: int, thickness: float = 1.0, antialias: bool = False) -> np.ndarray:
    """(R, (2 reach + 1)^2) float64: each ring's member weights over the pixel offsets of a
    database, normalised to sum 1 per ring (rings must lie within ``reach``)."""
    side = 2 * reach + 1
    matrix = np.zeros((len(radii), side * side))
    for row, radius in enumerate(radii):
        ring = ring_geometry(float(radius), thickness, antialias)
        if np.abs(ring.offsets).max(initial=0) > reach:
            raise ValueError(f"ring of radius {radius} reaches beyond the database's {reach} pixels")
        index = (ring.offsets[:, 0] + reach) * side + ring.offsets[:, 1] + reach
        np.add.at(matrix[row], index, ring.weights)
        matrix[row] /= matrix[row].sum()
    return matrix


class Forward:
    """E(r) and its derivatives for one database, structure and set of rings (one channel at a time).

    Parameters
    ----------
    database
        The white run.
    structure
        How its bins form layers.
    radii, thickness, antialias
        The rings, as the stacks take them.
    ring_weights
        (R, S, S) or None: the rings' effective weights per pixel offset, as a measured profile
        averaged them (:attr:`.measured.MeasuredProfile.ring_weights`: rings cut by the grid's
        edge); None for whole rings.
    """

    def __init__(self, database: WhiteDatabase, structure: Structure, radii, thickness: float = 1.0,
                 antialias: bool = False, ring_weights: np.ndarray | None = None):
        self.database = database
        self.structure = structure
        self.radii = np.asarray(radii, np.float64)
        reach = database.optics.reach
        self.rings = (ring_matrix(self.radii, reach, thickness, antialias) if ring_weights is None
                      else embedded_rings(ring_weights, reach))
        used = self.rings.any(axis=0)[database.pixel]
        self.pixel = database.pixel[used]
        self.value = database.value[used].astype(np.float64)
        self.photon = database.photon[used]
        self.lengths = np.add.reduceat(database.lengths[used], np.asarray(structure.starts), axis=1,
                                       dtype=np.float64)
        self._pixels = self.rings.shape[1]

    @functools.cached_property
    def reached(self) -> int:
        """Rings from r = 0 up to (not including) the first that no record of the database reaches
        (light the run's photons never carried that far): the model is 0 there, so no fit uses it."""
        lit = self.profile(np.zeros(self.structure.layers)) > 0
        return int(np.argmin(lit)) if not lit.all() else len(lit)

    @functools.cached_property
    def _ring_records(self) -> list[tuple[np.ndarray, np.ndarray | None]]:
        """Per ring, the records whose pixel lies in it (ascending, int32 where that holds them) and
        that pixel's weight in it (None where every weight is 1, as in a whole ring: 4 bytes a
        record, not 16): :meth:`covariance` then visits each record once per ring it lies in, not
        every record once per ring (a fit asks for the covariance at every step). Ascending, the
        sums per photon add the same terms in the same order as over every record (the others add
        zero)."""
        index = np.int32 if len(self.pixel) < np.iinfo(np.int32).max else np.int64
        members = []
        for ring in self.rings:
            member = ring[self.pixel]
            records = np.flatnonzero(member).astype(index)
            weight = member[records]
            members.append((records, None if np.all(weight == 1.0) else weight))
        return members

    def profile(self, mua: np.ndarray, derivatives: bool = False):
        """E(r) (R,) for absorption ``mua`` (L,) per layer; with ``derivatives``, also
        dE/dmua (R, L)."""
        # Contiguous: a column of a (C, L) table would compile the kernel once more.
        kernel, slopes = _kernel(self.pixel, self.value, self.lengths, np.ascontiguousarray(mua, np.float64),
                                 self._pixels, derivatives)
        scale = 1.0 / self.database.photons
        profile = self.rings @ kernel * scale
        if not derivatives:
            return profile
        return profile, -(self.rings @ slopes.T) * scale

    def variance(self, mua: np.ndarray) -> np.ndarray:
        """(R,) variance of :meth:`profile` from the run's own photons (:meth:`covariance` of one
        channel)."""
        return self.covariance(np.asarray(mua, np.float64)[None])[:, 0, 0]

    def covariance(self, mua: np.ndarray, rings: int | None = None) -> np.ndarray:
        """(rings, C, C) covariance between the channels' :meth:`profile` at absorptions ``mua``
        (C, L), over the first ``rings`` rings (all by default), from the run's own photons: each
        photon's contribution to a ring per channel (independent photons), their covariance over
        the photons, over the photon count. The channels share the photons, so they covary."""
        mua = np.ascontiguousarray(mua, np.float64)
        # The weights :meth:`profile` sums, channel by channel (9.7 -> 6.9 ms for three channels of
        # 410 000 records where numpy's product and exp took them).
        weights = np.stack([_weights(self.value, self.lengths, channel) for channel in mua])  # (C, records)
        photons = self.database.photons
        rings = len(self.radii) if rings is None else rings
        covariance = np.empty((rings, len(mua), len(mua)))
        for row in range(rings):
            records, member = self._ring_records[row]
            per_photon = _per_photon_sums(records, _NO_MEMBER if member is None else member, self.photon, weights,
                                          photons)
            centred = per_photon - per_photon.mean(axis=1, keepdims=True)
            covariance[row] = centred @ centred.T / (photons * photons)
        return covariance


_NO_MEMBER = np.zeros(0)
"""What :func:`_per_photon_sums` takes for a ring whose members all weigh 1."""


@numba.njit(cache=True, nogil=True)
def _per_photon_sums(records, member, photon, weights, photons):
    """(C, photons) each photon's sum of ``weights`` (C, records) over a ring's ``records``
    (ascending), each times its ``member`` weight in the ring (empty: 1). The same sums, added in
    the same order, as ``np.bincount(photon[records], weights[c, records] * member, photons)``
    per channel, in one pass without the gathered copies (a fifth of a covariance's CPU, and a fit
    asks for one at every step)."""
    sums = np.zeros((weights.shape[0], photons))
    weighted = member.shape[0] > 0
    for i in range(records.shape[0]):
        record = records[i]
        p = photon[record]
        for c in range(weights.shape[0]):
            sums[c, p] += weights[c, record] * member[i] if weighted else weights[c, record]
    return sums


@numba.njit(cache=True, nogil=True)
def _kernel(pixel, value, lengths, mua, pixels, derivatives):
    """Sums per pixel of each record's weight ``value exp(-lengths . mua)`` ((P,)) and, with
    ``derivatives``, of the weight times each layer's length ((L, P); else (0, P)). Serial: on
    a busy 2-core machine threads here cost more than they give. The weights are made first, in a
    loop of their own that LLVM vectorises (:func:`.vector_exp.vector_exp`: ``math.exp`` took half
    of a profile's time, one value at a time), then summed per pixel in the records' order."""
    layers = lengths.shape[1]
    kernel = np.zeros(pixels)
    slopes = np.zeros((layers if derivatives else 0, pixels))
    weights = _weights(value, lengths, mua)
    for i in range(pixel.shape[0]):
        kernel[pixel[i]] += weights[i]
        if derivatives:
            for k in range(layers):
                slopes[k, pixel[i]] += weights[i] * lengths[i, k]
    return kernel, slopes


@numba.njit(cache=True, nogil=True, inline="always")
def _weights(value, lengths, mua):
    """(records,) each record's weight ``value exp(-lengths . mua)``, the exponent summed over the
    layers in their order, layer by layer over every record: LLVM vectorises only innermost loops,
    so each loop here runs over the records."""
    exponent = np.zeros(value.shape[0])
    for k in range(lengths.shape[1]):
        absorption = mua[k]
        for i in range(value.shape[0]):
            exponent[i] += lengths[i, k] * absorption
    for i in range(value.shape[0]):
        exponent[i] = value[i] * vector_exp(-exponent[i])
    return exponent
