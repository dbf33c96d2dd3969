"""Less for the main command to compile on an empty cache (issue 31, item 5: the first result soon after install).

Two cuts, each checked on what numba compiled in a fresh process with an empty cache:

* the EWMA recursion compiles for one signature: the population (the tuning's strided
  ``out[:, p, :]``) and the deployed chart (contiguous arrays) used to compile it twice;
* the kernels compile with :data:`mosd.kernels.LLVM_OPTIONS`: a lane loop has one vector body and a
  scalar remainder, not also an epilogue vector loop, and the loop around it is not unrolled into
  further copies of all that (code LLVM optimised and generated for little).
"""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

_PROBE = """
import json
import re
import numpy as np
from mosd.detectors.statistics import ewma_continue, ewma_time_major
from mosd.kernels import cubature, ewma

x = np.random.default_rng(0).normal(size=(30, 4))
ewma_time_major(x, np.array([0.2, 0.5]), 2)  # the population: ewma_population
ewma_continue(x, 0.3, 2, np.zeros((2, 4)))  # the deployed chart: ewma_recursion directly
cubature.warm_up()
fill_rows = cubature._fill_rows.inspect_llvm(cubature._fill_rows.signatures[0])
print(json.dumps({"ewma_recursion": [str(s) for s in ewma.ewma_recursion.signatures],
                  "epilogue_loops": len(re.findall(r"^vec\\.epilog\\.vector\\.body[\\w.]*:", fill_rows, re.M)),
                  "vector_loops": len(re.findall(r"^vector\\.body[\\w.]*:", fill_rows, re.M))}))
"""


@pytest.fixture(scope="module")
def compiled(tmp_path_factory):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path_factory.mktemp("numba_cache")), MOSD_KERNEL_THREADS="1")
    env.pop("MOSD_KERNELS", None)
    run = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_ewma_recursion_compiles_once_for_the_population_and_the_deployed_chart(compiled):
    assert len(compiled["ewma_recursion"]) == 1, compiled["ewma_recursion"]


@pytest.mark.slow
def test_lane_loops_compile_without_epilogue_loops_or_runtime_unrolling(compiled):
    # _fill_rows is one lane loop inside two loops: with LLVM's defaults it held 3 vector bodies and 3
    # epilogue vector loops (the middle loop unrolled twice, plus its remainder); now one vector body
    assert compiled["epilogue_loops"] == 0
    assert compiled["vector_loops"] == 1, compiled["vector_loops"]


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
