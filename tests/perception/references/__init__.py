"""Plain versions of the perception core's compiled kernels: the specification they meet.

One module per step, beside that step's tests (``tests/perception/test_<step>.py``):
plain NumPy / OpenCV code, most of it the code the numba kernels replaced (issue 4),
written for clarity, not speed. The kernels must give identical arrays and identical
chains (same joints, same order); the end fits and the gap curves to 1e-9 px.
"""
