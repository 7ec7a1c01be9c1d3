"""The window's device setting: Settings > Device, where the stacks, the layer fits and the optics tables run.

A mixin of :class:`ringlight.app.window.MainWindow`, stored in its QSettings under ``device``.
The choice is ``--device``'s (:data:`ringlight.core.device.CHOICES`); the window's workers pass
the device it names to the core calls that take ``device=``. Without a usable NVIDIA GPU the
menu offers the CPU only, and says why.
"""

from __future__ import annotations

from PySide6.QtGui import QAction, QActionGroup
from ringlight.core.device import CHOICES, Device, DeviceError, choose_device, cpu_device, cuda_device

LABELS = {"auto": "&Automatic (a GPU when usable)", "cpu": "&CPU", "cuda": "CUDA &GPU"}
NO_GPU = "No usable NVIDIA GPU: install ringlight[cuda] and check the driver with nvidia-smi"


class WindowDevice:
    """The device setting (mixed into MainWindow)."""

    def _build_device_menu(self, menu) -> None:
        """Settings > Device: one checkable action per choice; CUDA disabled without a GPU."""
        usable = cuda_device()
        device_menu = menu.addMenu("&Device")
        group = QActionGroup(self)
        self.device_actions: dict[str, QAction] = {}
        for choice in CHOICES:
            action = QAction(LABELS[choice], self)
            action.setCheckable(True)
            action.setData(choice)
            action.triggered.connect(lambda _=False, choice=choice: self.set_device_choice(choice))
            group.addAction(action)
            device_menu.addAction(action)
            self.device_actions[choice] = action
        if usable is None:
            self.device_actions["cuda"].setEnabled(False)
            self.device_actions["cuda"].setStatusTip(NO_GPU)
            self.device_actions["auto"].setText("&Automatic: the CPU (no usable GPU)")
            reason = device_menu.addAction(NO_GPU)
            reason.setEnabled(False)
        else:
            self.device_actions["cuda"].setText(f"CUDA &GPU: {usable.name}")
        self.device_actions["auto"].setChecked(True)

    def device_choice(self) -> str:
        """The checked choice: ``auto``, ``cpu`` or ``cuda``."""
        return next(choice for choice, action in self.device_actions.items() if action.isChecked())

    def set_device_choice(self, choice: str) -> None:
        """Check ``choice``; one this machine cannot run (``cuda`` without a GPU, or a value no
        version offered) falls back to ``auto``, which runs on the CPU here."""
        action = self.device_actions.get(choice)
        if action is None or not action.isEnabled():
            action = self.device_actions["auto"]
        action.setChecked(True)
        self.layer_tab.device = self.compute_device().kind
        self.statusBar().showMessage(f"Stacks, layer fits and optics tables run on {self.compute_device().name}",
                                     5000)

    def compute_device(self) -> Device:
        """The device the checked choice runs on now (the CPU when its GPU has gone)."""
        try:
            return choose_device(self.device_choice())
        except DeviceError:
            return cpu_device()

    def _restore_device(self) -> None:
        self.set_device_choice(str(self.settings.value("device", "auto")))

    def _save_device(self) -> None:
        self.settings.setValue("device", self.device_choice())
