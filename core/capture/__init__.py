"""Capture at a rig: the hardware plugin API, built-in devices, Gray code, HDR, probe and scan.

The top layer of ``ringlight.core``: may use every other subpackage (the simulated rig uses the
simulator).
"""
