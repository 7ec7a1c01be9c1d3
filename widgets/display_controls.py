"""Controls for what the image view shows and how: view, channel and colour map, normalisation,
levels, exposure, and a display-only denoise."""

from __future__ import annotations

import math

from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QDoubleValidator
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QSlider,
    QToolButton,
    QWidget,
)
from ringlight.core.colour.display import NORMALISATIONS, DisplaySettings

from .colormaps import MAPS

VIEWS = {
    "transient": "Transient T_r",
    "ring": "Ring light E_r",
    "impulse": "Impulse image of picked point",
    "steady": "Steady state (all lit)",
    "snr": "SNR map of T_r (|T_r| / SE)",
    "difference": "T_r minus ground truth (scaled)",
}
"""View keys and their labels (the window's View menu numbers them Ctrl+1, Ctrl+2, ...)."""

SHOWN = {
    "rgb": "Colour (RGB)",
    "Y": "Luminance Y",
    "signed": "Signed Y (diverging)",
    "R": "Channel R",
    "G": "Channel G",
    "B": "Channel B",
}
"""What of an image is shown (a :data:`~ringlight.core.colour.display.CHANNELS` entry, or signed
luminance on a diverging map, which keeps negative transients visible) and its labels."""

_NORMALISATION_LABELS = {
    "per-image": "Per image (robust max)",
    "range": "Per image (robust min-max)",
    "global": "Global over stack",
    "log": "Log",
    "manual": "Manual levels",
}
_EXPOSURE_TICKS_PER_STOP = 10


class DisplayControls(QWidget):
    """Edits the view key and :class:`DisplaySettings`.

    Signals
    -------
    view_changed(str)
        A key of :data:`VIEWS`.
    settings_changed(object)
        A new :class:`DisplaySettings` (also sent when the colour map changes:
        :meth:`colormap_name` gives it).
    profile_log_changed(bool)
        Whether the profile plots use a log y axis.
    denoise_changed(float, bool)
        Gaussian sigma of the display-only denoise in grid steps (0: off), and whether exports
        get it too (only when the user ticks that).
    """

    view_changed = Signal(str)
    settings_changed = Signal(object)
    profile_log_changed = Signal(bool)
    denoise_changed = Signal(float, bool)

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.view_box = QComboBox()
        for key, label in VIEWS.items():
            self.view_box.addItem(label, key)
        self.view_box.setToolTip(f"Image shown (Ctrl+1 .. Ctrl+{len(VIEWS)})")
        self.normalisation_box = QComboBox()
        for key in NORMALISATIONS:
            self.normalisation_box.addItem(_NORMALISATION_LABELS[key], key)
        self.percentile_box = QDoubleSpinBox()
        self.percentile_box.setRange(50, 100)
        self.percentile_box.setDecimals(2)
        self.percentile_box.setSuffix(" th pct")
        self.percentile_box.setToolTip("Robust maximum: this percentile of the finite values maps to white")
        self.low_edit = QLineEdit()
        self.high_edit = QLineEdit()
        for edit, tip in ((self.low_edit, "Black level (linear radiance)"), (self.high_edit, "White level")):
            edit.setValidator(QDoubleValidator())
            edit.setToolTip(tip)
        self.decades_box = QDoubleSpinBox()
        self.decades_box.setRange(0.5, 12)
        self.decades_box.setSingleStep(0.5)
        self.decades_box.setSuffix(" decades")
        self.decades_box.setToolTip("Log display range below the robust maximum")
        self.exposure_slider = QSlider(Qt.Orientation.Horizontal)
        self.exposure_slider.setRange(-8 * _EXPOSURE_TICKS_PER_STOP, 8 * _EXPOSURE_TICKS_PER_STOP)
        self.exposure_label = QLabel()
        self.exposure_label.setMinimumWidth(64)
        reset = QToolButton(text="0")
        reset.setToolTip("Reset exposure")
        reset.clicked.connect(lambda: self.exposure_slider.setValue(0))
        self.shown_box = QComboBox()
        for key, label in SHOWN.items():
            self.shown_box.addItem(label, key)
        self.shown_box.setToolTip("Colour, one channel or luminance; signed luminance shows negative transients "
                                  "on a diverging map (blue < 0 < red) instead of clipping them to black")
        self.map_box = QComboBox()
        self.map_box.setToolTip("Colour map of one-channel, signed and SNR views (colour views have none)")
        self._maps = {kind: names[0] for kind, names in MAPS.items()}
        self.profile_log_box = QCheckBox("Profiles: log y")
        self.denoise_box = QCheckBox("Denoise display: Gaussian")
        self.denoise_box.setToolTip("Blur E_r and T_r images on screen only (NaN pixels stay undefined); "
                                    "the image is labelled while this is on, and exports stay raw")
        self.sigma_box = QDoubleSpinBox()
        self.sigma_box.setRange(0.3, 5.0)
        self.sigma_box.setSingleStep(0.1)
        self.sigma_box.setValue(1.0)
        self.sigma_box.setPrefix("sigma ")
        self.sigma_box.setSuffix(" steps")
        self.sigma_box.setToolTip("Standard deviation of the Gaussian in grid steps")
        self.denoise_exports_box = QCheckBox("Denoise exports too")
        self.denoise_exports_box.setToolTip("Also blur the exported view PNGs (off: exports hold the raw values)")
        self.levels_label = QLabel()
        self.levels_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        # Two lines always, the second for the negative-values notice: text that comes and goes
        # must not change the dock's height (and with it the window's).
        self.levels_label.setFixedHeight(2 * self.levels_label.fontMetrics().lineSpacing() + 2)

        levels = QHBoxLayout()
        levels.addWidget(self.low_edit)
        levels.addWidget(self.high_edit)
        exposure = QHBoxLayout()
        exposure.addWidget(self.exposure_slider, 1)
        exposure.addWidget(self.exposure_label)
        exposure.addWidget(reset)
        shown = QHBoxLayout()
        shown.addWidget(self.shown_box, 3)
        shown.addWidget(self.map_box, 2)
        denoise = QHBoxLayout()
        denoise.addWidget(self.denoise_box)
        denoise.addWidget(self.sigma_box)
        layout = QFormLayout(self)
        layout.addRow("View", self.view_box)
        layout.addRow("Show", shown)
        layout.addRow("Normalise", self.normalisation_box)
        layout.addRow("Robust max", self.percentile_box)
        layout.addRow("Levels", levels)
        layout.addRow("Log range", self.decades_box)
        layout.addRow("Exposure", exposure)
        layout.addRow(self.levels_label)
        layout.addRow(self.profile_log_box)
        layout.addRow(denoise)
        layout.addRow(self.denoise_exports_box)

        self.set_settings(DisplaySettings())
        self.view_box.currentIndexChanged.connect(self._on_view_edited)
        self.normalisation_box.currentIndexChanged.connect(self._on_edited)
        self.percentile_box.valueChanged.connect(self._on_edited)
        self.low_edit.editingFinished.connect(self._on_edited)
        self.high_edit.editingFinished.connect(self._on_edited)
        self.decades_box.valueChanged.connect(self._on_edited)
        self.exposure_slider.valueChanged.connect(self._on_edited)
        self.shown_box.currentIndexChanged.connect(self._on_edited)
        self.map_box.currentIndexChanged.connect(self._on_map_edited)
        self.profile_log_box.toggled.connect(self.profile_log_changed)
        self.denoise_box.toggled.connect(self._on_denoise_edited)
        self.sigma_box.valueChanged.connect(self._on_denoise_edited)
        self.denoise_exports_box.toggled.connect(self._on_denoise_edited)
        self._on_denoise_edited()

    def view(self) -> str:
        return self.view_box.currentData()

    def map_kind(self) -> str | None:
        """The kind of colour map (:data:`~ringlight.widgets.colormaps.KINDS`) the current view
        uses, or None for a colour view."""
        if self.view() == "snr":
            return "snr"
        if self.view() == "difference":
            return "signed"  # a difference is always shown signed
        shown = self.shown_box.currentData()
        return None if shown == "rgb" else "signed" if shown == "signed" else "channel"

    def colormap_names(self) -> dict[str, str]:
        """The map chosen for each kind (for the settings)."""
        return dict(self._maps)

    def colormap_name(self, kind: str) -> str:
        """The map chosen for ``kind`` (its default until the user picks one)."""
        return self._maps[kind]

    def set_colormap_name(self, kind: str, name: str) -> None:
        """Choose map ``name`` for ``kind`` (shown in the box when that kind is on screen)."""
        if name not in MAPS[kind]:
            raise ValueError(f"{kind} colour map must be one of {MAPS[kind]}, got {name!r}")
        self._maps[kind] = name
        self._update_map_box()
        self._on_edited()

    def set_view(self, key: str) -> None:
        self.view_box.setCurrentIndex(list(VIEWS).index(key))

    def denoise_sigma(self) -> float:
        """Sigma (grid steps) of the display-only Gaussian denoise; 0 when off."""
        return self.sigma_box.value() if self.denoise_box.isChecked() else 0.0

    def denoise_exports(self) -> bool:
        """Whether the user asked for the denoise in exports too."""
        return self.denoise_box.isChecked() and self.denoise_exports_box.isChecked()

    def settings(self) -> DisplaySettings:
        low, high = _number(self.low_edit.text(), 0.0), _number(self.high_edit.text(), 1.0)
        return DisplaySettings(
            normalisation=self.normalisation_box.currentData(),
            percentile=self.percentile_box.value(),
            manual_levels=(low, high),
            exposure_stops=self.exposure_slider.value() / _EXPOSURE_TICKS_PER_STOP,
            diverging=self.shown_box.currentData() == "signed",
            log_decades=self.decades_box.value(),
            channel=self.shown_box.currentData() if self.shown_box.currentData() != "signed" else "rgb",
        )

    def set_settings(self, settings: DisplaySettings) -> None:
        """Show ``settings`` without emitting."""
        widgets = (self.normalisation_box, self.percentile_box, self.decades_box, self.exposure_slider,
                   self.shown_box)
        for widget in widgets:
            widget.blockSignals(True)
        self.normalisation_box.setCurrentIndex(NORMALISATIONS.index(settings.normalisation))
        self.percentile_box.setValue(settings.percentile)
        self.low_edit.setText(f"{settings.manual_levels[0]:.6g}")
        self.high_edit.setText(f"{settings.manual_levels[1]:.6g}")
        self.decades_box.setValue(settings.log_decades)
        self.exposure_slider.setValue(int(round(settings.exposure_stops * _EXPOSURE_TICKS_PER_STOP)))
        self.shown_box.setCurrentIndex(list(SHOWN).index("signed" if settings.diverging else settings.channel))
        for widget in widgets:
            widget.blockSignals(False)
        self._update_enabled(settings)

    def show_levels(self, levels: tuple[float, float], negative_fraction: float) -> None:
        """Report the levels in use and how much of the image is negative and clipped to black
        (the caller passes 0 for a view drawn signed)."""
        text = f"Levels in use: {levels[0]:.4g} .. {levels[1]:.4g}"
        clipped = negative_fraction > 0
        if clipped:
            text += f"<br><b>{negative_fraction:.1%} negative</b>, drawn black (Show: Signed Y)"
        self.levels_label.setText(text)
        self.levels_label.setToolTip("Values below the black level are drawn black; choose Show: Signed Y "
                                     "to see negative transients on a diverging map" if clipped else "")

    def _update_enabled(self, settings: DisplaySettings) -> None:
        manual = settings.normalisation == "manual"
        self.low_edit.setEnabled(manual)
        self.high_edit.setEnabled(manual)
        self.percentile_box.setEnabled(not manual)
        self.decades_box.setEnabled(settings.normalisation == "log")
        self.exposure_label.setText(f"{settings.exposure_stops:+.1f} EV")
        self._update_map_box()

    def _update_map_box(self) -> None:
        """The map box lists the maps of the kind on screen, showing the one chosen for it; the
        Show box is off for the views it does not apply to (SNR and difference maps are scalar)."""
        self.shown_box.setEnabled(self.view() not in ("snr", "difference"))
        kind = self.map_kind()
        self.map_box.blockSignals(True)
        self.map_box.clear()
        if kind is None:
            self.map_box.addItem("no map")
        else:
            self.map_box.addItems(MAPS[kind])
            self.map_box.setCurrentText(self._maps[kind])
        self.map_box.setEnabled(kind is not None)
        self.map_box.blockSignals(False)

    def _on_view_edited(self, _index: int) -> None:
        self._update_map_box()
        self.view_changed.emit(self.view())

    def _on_map_edited(self, _index: int) -> None:
        kind = self.map_kind()
        if kind is not None and self.map_box.currentText() in MAPS[kind]:
            self._maps[kind] = self.map_box.currentText()
            self._on_edited()

    def _on_denoise_edited(self, *_) -> None:
        self.sigma_box.setEnabled(self.denoise_box.isChecked())
        self.denoise_exports_box.setEnabled(self.denoise_box.isChecked())
        self.denoise_changed.emit(self.denoise_sigma(), self.denoise_exports())

    def _on_edited(self, *_):
        try:
            settings = self.settings()
        except ValueError:
            return
        self._update_enabled(settings)
        self.settings_changed.emit(settings)


def _number(text: str, default: float) -> float:
    try:
        value = float(text)
    except ValueError:
        return default
    return value if math.isfinite(value) else default
