"""Numba kernels: every @njit function of facesim lives here (arrays in, arrays out).

All kernels compile with the same :data:`JIT_FLAGS` (PySDM keeps its flags in one place the
same way), so caching and floating-point semantics are changed for every kernel at once.
``fastmath`` stays off: FEM residuals and quality measures must be reproducible and must not
reorder sums that cancel.
"""

JIT_FLAGS = dict(cache=True, nogil=True, fastmath=False)
