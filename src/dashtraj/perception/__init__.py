"""perception: detect (ONNX run time), track, localize and map-match what each observer's dashcam
sees."""
