"""Less for the main command to compile on an empty cache (issue 31, item 5: the first result soon after install).

Two cuts, each checked on what numba compiled in a fresh process with an empty cache (in
``tests/test_kernel_compile.py``, whose probe compiles the filter anyway):

* the EWMA recursion compiles for one signature: the population (the tuning's strided
  ``out[:, p, :]``) and the deployed chart (contiguous arrays) used to compile it twice;
* the kernels compile with :data:`mosd.kernels.LLVM_OPTIONS`: a lane loop has one vector body and a
  scalar remainder, not also an epilogue vector loop, and the loop around it is not unrolled into
  further copies of all that (code LLVM optimised and generated for little);
* the filter's ``_tria_lanes`` and ``_update_lanes`` are compiled once each and called by address,
  not linked into their callers' modules and compiled again there;
* the chart's helpers build no CPython or C entry point (numba builds both for every function it
  compiles unless told not to, called from Python or not); ``mean_std`` and ``ewma_recursion`` keep
  theirs, as the main command calls them from Python too (one compile serves both).
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
        # two code paths (numba's loop, NumPy's): 40 steps of a multiply-add recursion, 1e-13 relative on any CPU
        # (issue 50: no comparison bit for bit across implementations)
        np.testing.assert_allclose(compiled, reference, rtol=1e-13, atol=0)


def test_the_charts_helpers_build_no_python_entry_point():
    """On the tuning's path only the kernels Python calls have a CPython wrapper; ``pairwise_sum`` (the
    tests' entry point) calls the helper and agrees with NumPy."""
    from mosd.kernels import chart, ewma

    helpers = (chart._pairwise_sum, chart._statistics, chart._count, chart._buffers)
    for helper in helpers:
        assert helper.targetoptions.get("no_cpython_wrapper") and helper.targetoptions.get("no_cfunc_wrapper"), \
            helper.py_func.__name__
    for entry in (chart.alarm_counts, chart.alarm_counts_denoised, chart.pairwise_sum, chart.mean_std,
                  ewma.ewma_recursion, ewma.ewma_population):
        assert not entry.targetoptions.get("no_cpython_wrapper"), entry.py_func.__name__
    x = np.random.default_rng(5).normal(size=1000)
    assert chart.pairwise_sum(x, 0, 1000) == np.sum(x)
    assert chart.mean_std(x) == (np.mean(x), np.std(x, ddof=1))


def test_a_call_by_address_checks_the_argument_types():
    """The filter's call by address refuses arguments of other types than the helper was compiled for
    (a wrong type would call the code with a mismatched layout)."""
    import pytest
    from numba import njit
    from numba.core.errors import TypingError

    from mosd.kernels import cubature

    @njit
    def wrong(address, a):
        cubature._call_tria(address, (a, 1, 1, a, 1))

    with pytest.raises(TypingError, match="call by address"):
        wrong(0, np.zeros((2, 2, 2)))
