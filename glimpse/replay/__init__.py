"""Rendering a finished run from any camera at any time, with people removed (docs/renders.md)."""
