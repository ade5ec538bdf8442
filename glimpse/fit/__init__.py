"""Stage 02's library: body parameters for each person, from the scene's own parameters or
fitted to its keypoints, and how well they agree with the keypoints."""
