"""Less for the main command to compile on an empty cache (issue 31, item 5: the first result soon after install).

Two cuts, each checked on what numba compiled in a fresh process with an empty cache (in
``tests/test_kernel_compile.py``, whose probe compiles the filter anyway):

* the EWMA recursion compiles for one signature: the population (the tuning's strided
  ``out[:, p, :]``) and the deployed chart (contiguous arrays) used to compile it twice;
* the kernels compile with :data:`mosd.kernels.LLVM_OPTIONS`: a lane loop has one vector body and a
  scalar remainder, not also an epilogue vector loop, and the loop around it is not unrolled into
  further copies of all that (code LLVM optimised and generated for little).
"""
import numpy as np


def test_ewma_population_unchanged_by_the_contiguous_scratch():
    """The population, now through a contiguous scratch, gives the NumPy reference's bits."""
    from mosd import kernels
    from mosd.detectors.statistics import ewma_time_major

    x = np.random.default_rng(3).normal(size=(40, 5))
    lams = np.array([0.1, 0.45, 0.9])
    for order in (1, 2, 3):
        compiled = ewma_time_major(x, lams, order)
        with kernels.disabled():
            reference = ewma_time_major(x, lams, order)
        np.testing.assert_array_equal(compiled, reference)
