"""Numba kernels: every @njit function of facesim lives here (arrays in, arrays out)."""
