"""``glimpse batch``: many scenes (or videos) through the whole pipeline on this machine, a Ray cluster or
Slurm, each retried and resumed from its checkpoints when it fails, and one summary of them all
(docs/batch.md)."""
