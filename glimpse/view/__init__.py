"""``glimpse view RUN``: a finished run in the browser (viser): orbit the scene, scrub or play time, show or
hide each person and the background, drive a person with a new motion, save a screenshot (docs/viewer.md)."""
