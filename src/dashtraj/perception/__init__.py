"""perception: detect, track, localize and map-match what each observer's dashcam sees."""
