"""The ingest: an ordinary video -> a glimpse-scene/1 folder, every person found, tracked and measured
(``glimpse ingest VIDEO SCENE_DIR``; docs/ingest.md). Entry point: :func:`glimpse.ingest.stage.ingest`."""
