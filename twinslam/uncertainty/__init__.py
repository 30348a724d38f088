"""Covisibility math: the map graph's uncertainty u(G), the next slot's υ and their kernels."""
