"""dashtraj: reconstruct the routes vehicles drove from what many moving dashcams saw."""

__version__ = "0.1.0"
