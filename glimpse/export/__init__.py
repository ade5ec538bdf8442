"""Exports for users' tools: standard 3DGS PLYs of posed people and whole frames (docs/exports.md)."""
