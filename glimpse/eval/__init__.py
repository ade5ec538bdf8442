"""Stage 07's library: the views it scores, the scores and their tables (score), the never-seen
pixels and the flat-body baseline (never_seen), holes in canonical people (coverage), the standard
videos (renders) and the render speed (speed)."""
