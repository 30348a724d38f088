"""Offline simulator: the map-management core driven by covisibility data and a channel model."""
