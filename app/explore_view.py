"""The Explore view's behaviour: picking, the radius, and drawing the image, truth, ring and profiles.

A mixin of :class:`ringlight.app.window.MainWindow`: it reads the window's state (``loaded``,
``stacks``, ``noise``, ``picked``) and widgets, and keeps the numbers it shows (``_shown_image``,
``profile``, ``truth_correlation``) for the hover readout and the exports. Levels and colour maps
are :mod:`.view_levels`'s, the noise and the SNR map :mod:`.noise_view`'s.
"""

from __future__ import annotations

import numpy as np
from ringlight.core import ImpulseDataset, ring_geometry
from ringlight.core.colour.display import (
    DisplaySettings,
    display_levels,
    negative_fraction,
    render,
    shown_values,
)
from ringlight.core.colour.regions import region_statistics
from ringlight.core.dataset.ground_truth import normalised_cross_correlation, scaled_difference
from ringlight.core.rings.noise import smoothed
from ringlight.core.rings.profiles import pixel_profile, stack_profile
from ringlight.core.uncertainty_text import with_error
from ringlight.widgets.snr_colours import SNR_LEVELS, snr_colormap_name


class ExploreView:
    """Picking, scrubbing and drawing of the Explore tab (mixed into MainWindow)."""

    def pick(self, y: int, x: int) -> None:
        """Mark grid point (y, x): ring overlay, profiles and (for the impulse view) the image."""
        if self.loaded is None:
            if self.load_jobs.busy:  # a click on the steady state's preview
                self.statusBar().showMessage("Still opening: points can be picked once the stacks are ready", 5000)
            return
        self.picked = (int(y), int(x))
        if self.view() == "impulse":
            self._refresh_image()
        self._refresh_ring()
        self._refresh_profiles()

    def set_radius(self, radius: float) -> None:
        """Show the stack radius nearest ``radius`` (grid steps)."""
        self.scrub_bar.set_index(self.scrub_bar.nearest_index(radius))

    def radius_index(self) -> int:
        return self.scrub_bar.index()

    def view(self) -> str:
        return self.display_controls.view()

    def display_settings(self) -> DisplaySettings:
        return self.display_controls.settings()

    def _on_index_changed(self, _index: int) -> None:
        self._refresh_image()
        self._refresh_ring()
        self._mark_radius()

    def _on_display_settings(self, settings: DisplaySettings) -> None:
        self._refresh_image()

    def _on_denoise_changed(self, _sigma: float, in_exports: bool) -> None:
        self.image_panel.set_display_in_exports(in_exports)
        self._refresh_image()

    def _on_hover(self, y: int, x: int) -> None:
        self._hovered = (y, x) if y >= 0 else None
        self._refresh_hover()

    def _refresh_hover(self) -> None:
        """The readout of the hovered pixel, again: the image under it changes with the radius,
        the view and the noise estimate (it kept the last image's numbers)."""
        hovered = self._hovered
        shape = None if self._shown_image is None else self._shown_image.shape
        inside = hovered is not None and shape is not None and hovered[0] < shape[0] and hovered[1] < shape[1]
        self.hover_label.setText(self.describe_pixel(*hovered) if inside else "")

    def describe_pixel(self, y: int, x: int) -> str:
        """The shown image's value at (y, x), with its standard error once the noise is estimated
        (ring and transient views; the value then to the digit the error allows), and the ring
        points behind it."""
        if self._shown_image is None or self.stacks is None:
            return ""
        index = self.radius_index()
        view = self.view()
        if view == "snr":
            if self.noise is None:
                return ""
            se = float(self.noise.noise.transient_luminance[index, y, x])
            stack = self.stacks.pair.transient
            return (f"y {y}  x {x}   SNR {float(self._shown_image[y, x]):.4g}  (SE of Y(T_r) {se:.4g})   "
                    f"ring points: {int(stack.counts[index, y, x])} at r, "
                    f"{int(stack.outer_counts[index, y, x])} at r+dr")
        value = self._shown_image[y, x]
        errors = self._pixel_errors(view, index, y, x)
        text = f"y {y}  x {x}   RGB " + " ".join(
            with_error(float(channel), None if errors is None else float(error))
            for channel, error in zip(value, errors if errors is not None else value))
        if errors is not None:
            text += " (±1 SE)"
        elif view in ("ring", "transient"):
            text += " (SE: estimating the noise)" if self.noise is None else ""
        if view in ("ring", "transient"):
            stack = self.stacks.pair.transient
            text += f"   ring points: {int(stack.counts[index, y, x])} at r"
            if view == "transient":
                text += f", {int(stack.outer_counts[index, y, x])} at r+dr"
        return text

    def _pixel_errors(self, view: str, index: int, y: int, x: int) -> np.ndarray | None:
        """(3,) standard error of the shown ring or transient image at (y, x), or None (another
        view, or no noise estimate of these stacks yet)."""
        if view not in ("ring", "transient") or self.noise is None or self.noise.pair is not self.stacks.pair:
            return None
        noise = self.noise.noise.transient if view == "transient" else self.noise.noise.ring
        return noise[index, y, x]

    def cancel_all(self) -> None:
        for slot in (self.load_jobs, self.stack_jobs, self.noise_jobs, self.fit_jobs, self.export_jobs,
                     self.impulse_jobs):
            slot.cancel()
        self.cancel_optics()
        self.scrub_bar.play_button.setChecked(False)

    def show_steady_preview(self, steady: np.ndarray, rows: int, colorspace: str) -> None:
        """While a dataset opens with none on screen: its steady state as far as it is built
        (``rows`` of its (H, W, 3) rows; the rest NaN, drawn undefined grey), per-image levels."""
        if self.loaded is not None:
            return  # another dataset is on screen and stays usable until this one is open
        settings = DisplaySettings()
        levels = display_levels(steady[:rows], settings, colorspace)
        self.image_panel.set_pixels(render(steady, levels, settings, colorspace))
        height = steady.shape[0]
        self.image_panel.set_title(f"steady state: rows 0..{rows} of {height} built, opening ..." if rows < height
                                   else "steady state: computing the stacks ...")

    def _reset_zoom(self) -> None:
        for panel in (self.image_panel, self.truth_panel):
            panel.view.autoRange(padding=0.02)

    # ----------------------------------------------------------------- drawing
    def current_image(self) -> np.ndarray | None:
        """The (H, W, 3) linear image of the current view and radius."""
        if self.loaded is None or self.stacks is None:
            return None
        view = self.view()
        if view == "steady":
            return self.loaded.steady_state
        if view == "impulse":
            if self._impulse_cache is None or self._impulse_cache[0] != self.picked:
                dataset = self.loaded.dataset
                if not dataset.in_memory:  # read from the store: in a worker, the view waits for it
                    self._request_impulse(dataset, self.picked)
                    return None
                self._impulse_cache = (self.picked, dataset.impulse_image(*self.picked))
            return self._impulse_cache[1]
        if view == "snr":
            return None if self.noise is None else self.noise.snr[self.radius_index()]
        if view == "difference":
            return self._difference_image()
        stack = self.stacks.pair.transient if view == "transient" else self.stacks.pair.ring
        return stack.images[self.radius_index()]

    def _difference_image(self) -> np.ndarray | None:
        """T_r minus the least-squares multiple of its ground-truth bin (None without truth);
        keeps the scale in ``_difference_scale`` for the title."""
        truth = self.loaded.truth
        if truth is None:
            return None
        index = self.radius_index()
        bin_index = truth.nearest_bin(float(self.stacks.pair.radii[index]), self.stacks.pair.request.dr)
        transient = self.stacks.pair.transient.images[index]
        difference, self._difference_scale = scaled_difference(transient, truth.images[bin_index])
        finite = np.isfinite(difference)
        energy = float(np.sqrt(np.mean(np.square(transient[finite], dtype=np.float64)))) if finite.any() else 0.0
        rms = float(np.sqrt(np.mean(np.square(difference[finite], dtype=np.float64)))) if finite.any() else float("nan")
        self._difference_rms = rms / energy if energy > 0 else float("nan")
        return difference

    def _request_impulse(self, dataset: ImpulseDataset, point: tuple[int, int]) -> None:
        """Read the impulse image of ``point`` from the store in a worker (one at a time; the
        newest pick wins), showing that it is under way."""
        if self._impulse_wanted == point and self.impulse_jobs.busy:
            return
        self._impulse_wanted = point
        self.image_panel.set_title(f"reading the impulse image of y {point[0]} x {point[1]} from the store ...")
        self.impulse_jobs.start(f"Reading the impulse image at y {point[0]} x {point[1]}",
                                lambda progress: (point, dataset.impulse_image(*point)))

    def _on_impulse_ready(self, result) -> None:
        point, image = result
        if self.loaded is None or point != self.picked:
            return  # picked elsewhere, or another dataset, meanwhile
        self._impulse_cache = (point, image)
        if self.view() == "impulse":
            self._refresh_image()

    def _refresh_all(self) -> None:
        self.request_noise()  # again after a cancel (Esc): any change of view brings it back
        self._refresh_image()
        self._refresh_ring()
        self._refresh_profiles()

    def _refresh_image(self) -> None:
        self._draw_image()
        self._refresh_hover()

    def _draw_image(self) -> None:
        if self.view() == "snr":
            self._refresh_snr_image()
            return
        image = self.current_image()
        if image is None:
            if self.view() == "difference" and self.loaded is not None and self.loaded.truth is None:
                self._shown_image = None
                self.image_panel.set_title("T_r minus ground truth: this dataset has no ground truth\n"
                                           "(simulated datasets carry it)")
            return
        settings = self.shown_settings()
        view = self.view()
        colorspace = self.loaded.dataset.colorspace
        self._levels = self._levels_for(image, settings, view)
        self._shown_image = image
        name, table = self._scalar_map(settings)
        pixels = render(image, self._levels, settings, colorspace, table)
        sigma = self.display_controls.denoise_sigma()
        if sigma > 0 and view in ("ring", "transient"):
            # Display only: the levels and the hover readout stay those of the data.
            exports = "exports denoised too" if self.display_controls.denoise_exports() else "exports raw"
            self.image_panel.set_pixels(pixels, render(smoothed(image, sigma), self._levels, settings, colorspace, table),
                                        f"denoised for display:\nGaussian sigma {sigma:g} grid steps\n{exports}")
        else:
            self.image_panel.set_pixels(pixels)
        self._show_colour_bar(settings, name)
        self.image_panel.set_title(self._image_title())
        shown = shown_values(image, settings, colorspace) if settings.scalar else image
        self.display_controls.show_levels(self._levels, 0.0 if settings.diverging else negative_fraction(shown))
        self.levels_histogram.set_image(shown, self._levels, 2.0 ** settings.exposure_stops,
                                        self._histogram_of(shown, settings, view))
        self._refresh_truth(self.display_settings(), colorspace)
        self.show_region_statistics()
        self.image_shown.emit()

    def show_region_statistics(self) -> None:
        """Count, mean and std of the shown image over the Layers tab's region (when one is drawn),
        in the Layers tab under the region's controls (hidden without a region)."""
        region = self.layer_tab.region
        if self._shown_image is None or region.shape != self._shown_image.shape[:2] or region.all():
            text = ""
        elif self._shown_image.ndim == 2:  # the SNR map
            count, mean, std = region_statistics(self._shown_image[..., None], region)
            text = f"region: {count} px, mean SNR {mean[0]:.3g}, std {std[0]:.3g}"
        else:
            count, mean, std = region_statistics(self._shown_image, region)
            text = (f"region: {count} px, mean RGB {' '.join(f'{m:.4g}' for m in mean)}, "
                    f"std {' '.join(f'{s:.3g}' for s in std)}")
        self.region_label.setText(text)
        self.region_label.setVisible(bool(text))

    def _image_title(self) -> str:
        view = self.view()
        if view == "impulse":
            return f"impulse image of lit point y {self.picked[0]} x {self.picked[1]}"
        if view == "steady":
            return "steady state: all points lit"
        request = self.stacks.pair.request
        radius = self.stacks.pair.radii[self.radius_index()]
        if view == "ring":
            return f"E_r  r = {radius:g}  w = {request.thickness:g}"
        if view == "difference":
            truth = self.loaded.truth
            low, high = truth.bounds[truth.nearest_bin(radius, request.dr)]
            return (f"T_r - a truth  r = {radius:g}  dr = {request.dr:g}  truth [{low:g}, {high:g})\n"
                    f"a = {self._difference_scale:.4g}  RMS diff / RMS T_r {self._difference_rms:.3f}")
        if view == "snr":
            return (f"SNR of T_r  r = {radius:g}  dr = {request.dr:g}\n"
                    f"{snr_colormap_name()} {SNR_LEVELS[0]:g}..{SNR_LEVELS[1]:g} (above: {SNR_LEVELS[1]:g})\n"
                    f"grey: < 2 ring members")
        return f"T_r  r = {radius:g}  dr = {request.dr:g}  w = {request.thickness:g}"

    def _refresh_truth(self, settings: DisplaySettings, colorspace: str) -> None:
        truth = self.loaded.truth
        if truth is None:
            return
        index = self.radius_index()
        radius = float(self.stacks.pair.radii[index])
        step = self.stacks.pair.request.dr
        bin_index = truth.nearest_bin(radius, step)
        image = truth.images[bin_index]
        truth_settings = settings if settings.normalisation != "manual" else settings.with_changes(normalisation="per-image")
        levels = self._levels_for(image, truth_settings, "truth")
        self.truth_panel.set_pixels(render(image, levels, truth_settings, colorspace, self._scalar_map(truth_settings)[1]))
        low, high = truth.bounds[bin_index]
        current = normalised_cross_correlation(self.stacks.pair.transient.images[index], image)
        mean = float(np.nanmean(self.stacks.correlations)) if np.isfinite(self.stacks.correlations).any() else float("nan")
        self.truth_panel.set_title(f"truth: path length [{low:g}, {high:g})\nNCC with T_r {current:.3f}, stack mean {mean:.3f}")
        self.truth_correlation = current

    def _refresh_ring(self) -> None:
        if self.loaded is None or self.stacks is None or self.picked is None:
            return
        request = self.stacks.pair.request
        radius = float(self.stacks.pair.radii[self.radius_index()])
        dataset = self.loaded.dataset
        ring = ring_geometry(radius, request.thickness, request.antialias)
        positions, weights = ring.around(self.picked, dataset.grid_shape)
        missing = dataset.lit_counts[positions[:, 0], positions[:, 1]] == 0
        outer = radius + request.dr if self.view() == "transient" else None
        self.image_panel.show_ring(self.picked, positions, weights, missing, radius, outer)

    def _refresh_profiles(self) -> None:
        if self.loaded is None or self.stacks is None or self.picked is None:
            return
        if self.loaded.dataset.in_memory:
            self.profile = pixel_profile(self.loaded.dataset, self.stacks.rings, self.picked)
        else:  # read from its store: the stacks on screen hold the profile, and a click reads nothing
            self.profile = stack_profile(self.stacks.pair.ring, self.stacks.pair.transient, self.picked)
        ring_se = transient_se = None
        if self.noise is not None:
            y, x = self.picked
            ring_se, transient_se = self.noise.noise.ring[:, y, x], self.noise.noise.transient[:, y, x]
        self.profile_plot.set_profiles(self.profile.radii, self.profile.ring, self.profile.transient,
                                       ring_se, transient_se)
        self.profile_plot.set_point(f"at y {self.picked[0]} x {self.picked[1]}")
        self._refresh_optics_model()
        self._mark_radius()

    def _mark_radius(self) -> None:
        if self.stacks is not None:
            self.profile_plot.set_radius(float(self.stacks.pair.radii[self.radius_index()]))
