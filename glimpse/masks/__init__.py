"""Stage 03's library: which pixels belong to whom (depth-ordered visible masks), what hides
each person (occluder masks), from the fitted bodies, the frames, or the scene's own masks."""
