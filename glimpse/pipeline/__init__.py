"""The pipeline frame: stage registry, parameter files, artifacts and stage runs."""
