"""Stage 05: per-person crops for the identity prior: the square box and soft mask (box), the
OpenPose-18 skeleton (skeleton), view words and prompts (view), and the stage's loop (stage)."""
