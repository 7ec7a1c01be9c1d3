"""The noise of the stacks on screen, for the Explore view: estimated in a worker after each new
stack (ring-member spread, :mod:`ringlight.core.rings.noise`), it draws the profile bands, the SNR
map view, the scrub bar's SNR strip and the Layers tab's trusted flags once it arrives.

A mixin of :class:`ringlight.app.window.MainWindow` (beside :class:`~.explore_view.ExploreView`,
whose drawing it calls).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ringlight.core import ImpulseDataset
from ringlight.core.rings.noise import StackNoise, median_snr, transient_snr
from ringlight.core.rings.stack_cache import cached_noise
from ringlight.core.rings.stack_request import StackPair
from ringlight.widgets.snr_colours import SNR_LEVELS, set_snr_colormap, snr_colormap, snr_rgb

SNR_LABEL = "SNR = |Y(T_r)| / SE"


@dataclass(frozen=True, eq=False)
class ViewNoise:
    """The noise of a stack pair on screen.

    Attributes
    ----------
    snr
        (n, H, W) float32 SNR of each T_r's luminance (:func:`transient_snr`).
    image_median_snr
        (n,) median of each SNR image over its defined pixels (:func:`median_snr`): computed
        with the rest in the worker, as on a 1024 x 1024 grid it takes about 0.4 s.
    """

    pair: StackPair
    noise: StackNoise
    snr: np.ndarray
    image_median_snr: np.ndarray


def compute_view_noise(dataset: ImpulseDataset, pair: StackPair, progress) -> ViewNoise:
    """Standard errors and SNR of ``pair``'s stacks (a worker job; the errors from the cache when a
    previous open saved them)."""
    noise = cached_noise(dataset, pair.request, progress)
    snr = transient_snr(pair.transient.images, noise)
    return ViewNoise(pair, noise, snr, median_snr(snr))


class NoiseView:
    """The noise worker and the SNR map (mixed into MainWindow)."""

    def request_noise(self) -> None:
        """Estimate the noise of the shown stacks in a worker, unless known, under way or failed."""
        if (self.loaded is None or self.stacks is None or self.noise is not None or self.noise_jobs.busy
                or self._noise_failed_for is self.stacks.pair):
            return
        dataset, pair = self.loaded.dataset, self.stacks.pair
        self.noise_jobs.start(f"Noise of {len(pair.radii)} radii",
                              lambda progress: compute_view_noise(dataset, pair, progress))

    def _forget_noise(self) -> None:
        """New stacks: their noise is unknown until the worker brings it."""
        self.noise_jobs.cancel()
        self.noise = None
        self.scrub_bar.set_snr(None)

    def _on_noise_failed(self, message: str) -> None:
        self._noise_failed_for = self.stacks.pair if self.stacks is not None else None  # no retry loop
        self.show_error("Could not estimate the noise", message)

    def _on_noise_ready(self, noise: ViewNoise) -> None:
        if self.stacks is None or noise.pair is not self.stacks.pair:
            return  # computed for stacks that were replaced meanwhile
        self.noise = noise
        self.layer_tab.set_noise(noise.noise)
        self.refresh_snr_strip()
        self._refresh_all()

    def refresh_snr_strip(self) -> None:
        """Median SNR of T_r per radius over the Layers tab's region (all pixels when none)."""
        if self.noise is None:
            self.scrub_bar.set_snr(None)
            return
        region = self.layer_tab.region
        whole = region.shape != self.noise.snr.shape[1:] or region.all()
        where = "the image" if whole else "the Layers region"
        medians = self.noise.image_median_snr if whole else median_snr(self.noise.snr, region)
        self.scrub_bar.set_snr(medians, f"median {SNR_LABEL} of T_r over {where}:")

    def _refresh_snr_image(self) -> None:
        """The SNR map of T_r on the shared colour scale, with its colour bar."""
        if self.loaded is None or self.stacks is None:
            return
        if self.noise is None:
            self._shown_image = None
            self.image_panel.set_title("SNR map of T_r: estimating the noise (status bar) ...")
            return
        set_snr_colormap(self.display_controls.colormap_name("snr"))
        self.scrub_bar.snr_strip.update()
        image = self.noise.snr[self.radius_index()]
        self._levels = SNR_LEVELS
        self._shown_image = image
        self.image_panel.set_pixels(snr_rgb(image))
        self.image_panel.set_colour_bar(SNR_LEVELS, snr_colormap(), SNR_LABEL)
        self.image_panel.set_title(self._image_title())
        self.display_controls.show_levels(SNR_LEVELS, 0.0)
        self.levels_histogram.set_image(image, SNR_LEVELS)
        self._refresh_truth(self.display_settings(), self.loaded.dataset.colorspace)
        self.show_region_statistics()
        self.image_shown.emit()
