"""Stage 05: per-person crops for the identity prior: the square box and soft mask (box) and the
stage's loop (stage); the OpenPose-18 skeleton and view words come from glimpse.prior."""
