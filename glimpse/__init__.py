"""Glimpse: dynamic 3D scenes of people and places from one video, as Gaussians."""

__version__ = "0.1.0"
