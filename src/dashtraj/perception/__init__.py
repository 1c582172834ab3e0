"""Perception (per observer): detection (ONNX run time), tracking, localization."""
