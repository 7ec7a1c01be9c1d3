"""How the Explore view draws values: the levels of stack images (kept until the stacks change),
the levels histogram, manual levels, and the colour map and colour bar of scalar views.

A mixin of :class:`ringlight.app.window.MainWindow` (beside :class:`~.explore_view.ExploreView`).
"""

from __future__ import annotations

import numpy as np
from ringlight.core.colour.display import DisplaySettings, display_levels, value_histogram
from ringlight.widgets.colormaps import bar_colormap, lut


class ViewLevels:
    """Levels, histograms and colour maps of the shown image (mixed into MainWindow)."""

    def _forget_levels(self) -> None:
        """New stacks or a new dataset: the kept levels and histograms are of other images."""
        self._levels_cache.clear()
        self._histograms.clear()

    def current_levels(self) -> tuple[float, float]:
        return self._levels

    def _levels_for(self, image: np.ndarray, settings: DisplaySettings, source: str) -> tuple[float, float]:
        """The levels of ``image`` from ``source`` (a view key, or "truth"). Those of stack
        images are kept until the stacks change (a percentile of a 1024 x 1024 image is 30 ms a
        scrub step): per image for each radius, or over the whole stack."""
        colorspace = self.loaded.dataset.colorspace
        if settings.normalisation == "manual" or source in ("impulse", "steady", "difference", "snr"):
            return display_levels(image, settings, colorspace)
        per_image = settings.normalisation != "global"
        key = (source, id(self.stacks), self.radius_index() if per_image else None, settings.normalisation,
               settings.percentile, settings.log_decades, settings.diverging, settings.channel)
        if key not in self._levels_cache:
            if per_image:
                values = image
            elif source == "truth":
                values = self.loaded.truth.images
            else:
                values = self.stacks.pair.transient.images if source == "transient" else self.stacks.pair.ring.images
            self._levels_cache[key] = display_levels(values, settings, colorspace)
        return self._levels_cache[key]

    def _histogram_of(self, shown: np.ndarray, settings: DisplaySettings, view: str) -> tuple[np.ndarray, np.ndarray]:
        """``value_histogram`` of the shown values, kept per stack image until the stacks change."""
        if view not in ("ring", "transient"):
            return value_histogram(shown)
        key = (view, id(self.stacks), self.radius_index(), settings.diverging, settings.channel)
        if key not in self._histograms:
            self._histograms[key] = value_histogram(shown)
        return self._histograms[key]

    def shown_settings(self) -> DisplaySettings:
        """The display settings the current view is drawn with: the user's, except that a
        difference is always signed."""
        settings = self.display_settings()
        return settings.with_changes(diverging=True) if self.view() == "difference" else settings

    def _scalar_map(self, settings: DisplaySettings) -> tuple[str | None, np.ndarray | None]:
        """Name and table of the colour map a scalar view is drawn with ((None, None) for colour)."""
        if not settings.scalar:
            return None, None
        name = self.display_controls.colormap_name("signed" if settings.diverging else "channel")
        return name, lut(name)

    def _show_colour_bar(self, settings: DisplaySettings, name: str | None) -> None:
        """The colour bar of a scalar view: the data values at the two levels (before exposure;
        log10 of them on the log scale)."""
        if name is None:
            self.image_panel.set_colour_bar(None)
            return
        gain = 2.0 ** settings.exposure_stops
        low, high = (level / gain for level in self._levels)
        quantity = "Y" if settings.diverging or settings.channel == "Y" else settings.channel
        if settings.diverging:
            low, high = -max(abs(low), abs(high)), max(abs(low), abs(high))
        if settings.normalisation == "log" and not settings.diverging:
            low, high = np.log10(max(low, high * 1e-12)), np.log10(high)
            quantity = f"log10 {quantity}"
        self.image_panel.set_colour_bar((float(low), float(high)), bar_colormap(name, settings), quantity)

    def set_manual_levels(self, low: float, high: float) -> None:
        """Switch to manual levels ``(low, high)`` (linear values after exposure), as dragged."""
        if high <= low:
            return
        settings = self.display_settings().with_changes(normalisation="manual", manual_levels=(low, high))
        self.display_controls.set_settings(settings)
        self._refresh_image()
