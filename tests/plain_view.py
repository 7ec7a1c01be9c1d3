"""Settings for windows whose tests describe a dataset opened at radius 0 and the grid's centre:
View > Open datasets at their structure (:mod:`ringlight.core.colour.first_view`) off."""


def plain_settings(path):
    """A QSettings in the INI file ``path`` with the structure view off."""
    from PySide6.QtCore import QSettings

    settings = QSettings(str(path), QSettings.Format.IniFormat)
    settings.setValue("structure_view", "false")
    return settings
