"""Stage 01's library: frames, camera motion, structure from motion (pycolmap), the stage's logic."""
