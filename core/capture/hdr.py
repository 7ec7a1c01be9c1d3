"""Merging exposure brackets of a linear camera into radiance.

For raw values v_i (black level b subtracted) at exposures t_i, the samples that are neither
saturated (v_i + b >= saturation level) nor below the noise floor are combined as

    radiance = sum_i v_i / sum_i t_i      (the maximum-likelihood rate for Poisson counts;
                                            equivalently a mean of v_i / t_i weighted by t_i)

in camera counts per second. A pixel saturated in every bracket gets the lower bound
(saturation - b) / t_shortest and is flagged; one below the floor in every bracket gets the
longest exposure's value. OpenCV's Debevec/Robertson merges are not used: they expect 8-bit,
non-linear input, while machine-vision cameras are linear at 12-16 bits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import RinglightError


@dataclass(frozen=True, eq=False)
class MergedFrame:
    """A merged HDR frame.

    Attributes
    ----------
    radiance
        Camera counts per second, black level subtracted, float32, the frames' shape.
    saturated
        bool, same shape: saturated in every bracket (radiance is a lower bound there).
    """

    radiance: np.ndarray
    saturated: np.ndarray

    @property
    def saturated_count(self) -> int:
        return int(np.count_nonzero(self.saturated))


def merge_brackets(frames, exposures, black_level: float, saturation_level: float,
                   noise_floor: float = 0.0) -> MergedFrame:
    """Merge raw ``frames`` (same shape) taken at ``exposures`` seconds (see module docstring).

    ``noise_floor``: counts above black below which a sample is not trusted (e.g. 3x read noise).
    """
    exposures = np.asarray(exposures, np.float64)
    if len(frames) != len(exposures) or len(frames) == 0:
        raise RinglightError(f"HDR merge needs one exposure per frame, got {len(frames)} frames and {len(exposures)} exposures")
    if (exposures <= 0).any():
        raise RinglightError(f"exposures must be > 0 s, got {exposures.tolist()}")
    raw = np.stack([np.asarray(frame, np.float64) for frame in frames])
    signal = raw - black_level
    saturated = raw >= saturation_level - 0.5
    usable = ~saturated & (signal > noise_floor)
    weight = exposures.reshape(-1, *([1] * (raw.ndim - 1)))
    counts = np.where(usable, signal, 0.0).sum(axis=0)
    time = np.where(usable, weight, 0.0).sum(axis=0)
    longest = int(np.argmax(exposures))
    shortest = int(np.argmin(exposures))
    with np.errstate(invalid="ignore", divide="ignore"):
        radiance = np.where(time > 0, counts / time, signal[longest] / exposures[longest])
    all_saturated = saturated.all(axis=0)
    radiance = np.where(all_saturated, (saturation_level - black_level) / exposures[shortest], radiance)
    return MergedFrame(radiance.astype(np.float32), all_saturated)


def bracket_exposures(shortest: float, longest: float, ratio: float = 4.0) -> list[float]:
    """Exposures shortest, shortest * ratio, ... up to and including longest."""
    if not 0 < shortest <= longest:
        raise RinglightError(f"exposure bracket needs 0 < shortest <= longest, got {shortest:g}, {longest:g}")
    exposures = [shortest]
    while exposures[-1] * ratio < longest * (1 - 1e-9):
        exposures.append(exposures[-1] * ratio)
    if exposures[-1] < longest * (1 - 1e-9):
        exposures.append(longest)
    return exposures
