"""Multiplexed impulse codes: Hadamard S-matrices over lattice frames (the paper's future work).

A plain lattice scan captures each lattice frame (a set of lit points more than 2 max_radius apart)
on its own. With an S-matrix code of order n (n = 2^k - 1), a block of n lattice frames is
captured as n frames, frame i lighting the union of the lattice frames j with S[i, j] = 1
((n + 1) / 2 of them); the block's lattice frames are recovered as S^-1 @ captures, pixel by pixel
(the camera is linear). The dataset then holds the recovered lattice frames, as a plain scan would.

Noise (Harwit and Sloane, "Hadamard Transform Optics", 1979): S^-1 = 2 / (n + 1) (2 S^T - J) has
entries +-2 / (n + 1), so a recovered frame's variance is 4 n / (n + 1)^2 times the mean variance
of the captures. Where read noise dominates (the same in every capture), that is an SNR gain of
(n + 1) / (2 sqrt n); where shot noise dominates, each capture holds about (n + 1) / 2 times the
light of one lattice frame, and the gain shrinks below 1 wherever the recovered frame is fainter
than the light the other lattice frames add there (far from the lit points, next to the others'
bright peaks).
"""

from __future__ import annotations

import numpy as np

from ..errors import RinglightError

MAX_ORDER = 1023
"""Largest code order: a block's n captures are held in memory at once (as float64 to
demultiplex), and the noise gain (n + 1) / (2 sqrt n) is already 16 at this order (a block of
65 535 asked for a 32 GiB matrix and 16.5 GB of captures)."""
BLOCK_COPIES = 6
"""Frame-sized float32 arrays a block holds per capture while it is demultiplexed: the merged
radiance, the stacked captures, and the float64 captures and recovered frames (two each)."""


def s_matrix(order: int) -> np.ndarray:
    """(order, order) int S-matrix from Sylvester's Hadamard matrix of size order + 1, which must
    be a power of two: S = (1 - H') / 2 with H' the normalised Hadamard matrix without its first
    row and column.

    >>> s_matrix(3).tolist()
    [[1, 0, 1], [0, 1, 1], [1, 1, 0]]
    """
    size = order + 1
    if order < 3 or size & (size - 1) or order > MAX_ORDER:
        raise RinglightError(f"a Hadamard S-matrix code needs order 2^k - 1 from 3 to {MAX_ORDER} "
                             f"(3, 7, 15, 31, ...), got {order}")
    hadamard = np.ones((1, 1), np.int64)
    while hadamard.shape[0] < size:
        hadamard = np.block([[hadamard, hadamard], [hadamard, -hadamard]])
    return ((1 - hadamard[1:, 1:]) // 2).astype(np.int64)


def block_bytes(order: int, frame_bytes: int) -> int:
    """Bytes a block of ``order`` captures of ``frame_bytes`` (float32 RGB) each holds at once."""
    return max(order, 1) * frame_bytes * BLOCK_COPIES


def s_matrix_inverse(order: int) -> np.ndarray:
    """(order, order) float64 inverse of :func:`s_matrix`: 2 / (n + 1) (2 S^T - J)."""
    s = s_matrix(order)
    return 2.0 / (order + 1) * (2 * s.T - 1)


def code_blocks(frame_count: int, order: int) -> list[tuple[range, np.ndarray | None]]:
    """Split ``frame_count`` lattice frames into consecutive blocks of ``order`` coded by the
    S-matrix (``order`` 0: every frame alone, uncoded); a last block shorter than ``order`` is
    captured uncoded. Returns (frame indices, S or None) per block; the frame count is unchanged."""
    if order == 0:
        return [(range(index, index + 1), None) for index in range(frame_count)]
    code = s_matrix(order)
    blocks = [(range(start, start + order), code) for start in range(0, frame_count - order + 1, order)]
    coded = len(blocks) * order
    return blocks + [(range(index, index + 1), None) for index in range(coded, frame_count)]


def coded_lit(frames: list[np.ndarray], indices: range, code: np.ndarray | None) -> list[np.ndarray]:
    """Lit points (m, 2) of each capture of a block: the union of the lattice frames its code row
    selects (the frame itself when uncoded)."""
    if code is None:
        return [frames[index] for index in indices]
    return [np.concatenate([frames[indices[j]] for j in np.flatnonzero(row)]) for row in code]


def demultiplex(captures: np.ndarray, code: np.ndarray | None) -> np.ndarray:
    """Recovered lattice frames (n, ...) from the block's captures (n, ...) (float, linear, black
    subtracted): S^-1 @ captures along the first axis; the captures themselves when uncoded."""
    captures = np.asarray(captures, np.float64)
    if code is None:
        return captures
    inverse = s_matrix_inverse(code.shape[0])
    return np.tensordot(inverse, captures, axes=1)


def predicted_variance(capture_variances: np.ndarray, code: np.ndarray | None) -> np.ndarray:
    """Variance (n, ...) of the recovered frames from the captures' variances (n, ...), the
    captures' noise being independent: sum_i (S^-1)[j, i]^2 var_i."""
    capture_variances = np.asarray(capture_variances, np.float64)
    if code is None:
        return capture_variances
    return np.tensordot(s_matrix_inverse(code.shape[0]) ** 2, capture_variances, axes=1)
