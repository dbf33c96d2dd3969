"""What the plants' and the filter's kernels compile on an empty cache (issue 31: the first result soon after install).

Numba compiles a function once per type signature it is called with; a literal argument (a bare ``0``
or ``1``) is first typed as its own literal type, so a helper called with one compiles twice. Every
kernel of mosd.kernels.plants and mosd.kernels.cubature must compile exactly once for a filter run
with missing channels and a closed-loop simulation, and the helpers (called only from compiled code)
must have no CPython entry point to build.
"""
import json
import os
import subprocess
import sys

import pytest

_PROBE = """
import json
import numpy as np
from numba.core.registry import CPUDispatcher
from mosd.estimators import CESCKF
from mosd.kernels import cubature, plants
from mosd.noise import GaussianNoise
from mosd.plants import MouldOscillator
from mosd.scenario import Scenario

plant, noise = MouldOscillator(), GaussianNoise()
trace = Scenario(plant, noise, None, duration=0.05).simulate(0, 3, stream="calibration")  # the compiled simulation
y = trace.y.copy()
y[0, 3, 1] = np.nan  # one lane with a missing channel: the update again on the present channels
y[1, 4, :] = np.nan  # nothing measured
CESCKF().filter(plant.model(noise), y, trace.u)
out = {}
for module in (plants, cubature):
    for name, obj in vars(module).items():
        if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == module.__name__:
            out[module.__name__ + "." + name] = {
                "signatures": [str(s) for s in obj.signatures],
                "wrapper": not obj.targetoptions.get("no_cpython_wrapper", False),
            }
# issue 31's compile cuts, on the same empty cache (after the signatures above are taken): the EWMA
# recursion compiles once for the population and the deployed chart; a lane loop holds one vector body
import re
from mosd.detectors.statistics import ewma_continue, ewma_time_major
from mosd.kernels import ewma

x = np.random.default_rng(0).normal(size=(30, 4))
ewma_time_major(x, np.array([0.2, 0.5]), 2)  # the population: ewma_population
ewma_continue(x, 0.3, 2, np.zeros((2, 4)))  # the deployed chart: ewma_recursion directly
if not cubature._fill_rows.signatures:
    cubature.warm_up()
fill_rows = cubature._fill_rows.inspect_llvm(cubature._fill_rows.signatures[0])
# the filter's two big helpers are called by address, not linked into (and compiled again inside) their callers
defined = lambda f: re.findall(r"^define [^@]*@\\W?(?:cfunc\\.)?_ZN\\w*?(_tria_lanes|_update_lanes)", f, re.M)
out["_linked_in"] = {name: defined(getattr(cubature, name).inspect_llvm(getattr(cubature, name).signatures[0]))
                     for name in ("cesckf", "_update_lanes")}
out["_compile_cuts"] = {
    "ewma_recursion": [str(s) for s in ewma.ewma_recursion.signatures],
    "epilogue_loops": len(re.findall(r"^vec\\.epilog\\.vector\\.body[\\w.]*:", fill_rows, re.M)),
    "vector_loops": len(re.findall(r"^vector\\.body[\\w.]*:", fill_rows, re.M))}
print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def probe(tmp_path_factory):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path_factory.mktemp("numba_cache")), MOSD_KERNEL_THREADS="1")
    env.pop("MOSD_KERNELS", None)
    run = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    return out.pop("_compile_cuts"), out, out.pop("_linked_in")


@pytest.fixture(scope="module")
def compiled(probe):
    return probe[1]


@pytest.fixture(scope="module")
def compile_cuts(probe):
    return probe[0]


@pytest.fixture(scope="module")
def linked_in(probe):
    return probe[2]


@pytest.mark.slow
def test_every_kernel_compiles_once_from_an_empty_cache(compiled):
    twice = {name: info["signatures"] for name, info in compiled.items() if len(info["signatures"]) > 1}
    assert not twice, f"compiled for several signatures: {twice}"
    for name in ("mosd.kernels.cubature.cesckf", "mosd.kernels.cubature._update_lanes",
                 "mosd.kernels.cubature._tria_lanes", "mosd.kernels.plants.simulate_mould_oscillator",
                 "mosd.kernels.plants.transition_lanes"):
        assert len(compiled[name]["signatures"]) == 1, name


@pytest.mark.slow
def test_helpers_have_no_python_entry_point(compiled):
    entry = {"mosd.kernels.cubature.cesckf", "mosd.kernels.cubature._output_prediction",
             "mosd.kernels.plants.simulate_mould_oscillator", "mosd.kernels.plants.simulate_flapping_wing",
             "mosd.kernels.plants.transition_points"}
    for name, info in compiled.items():
        assert info["wrapper"] == (name in entry), name


@pytest.mark.slow
def test_ewma_recursion_compiles_once_for_the_population_and_the_deployed_chart(compile_cuts):
    assert len(compile_cuts["ewma_recursion"]) == 1, compile_cuts["ewma_recursion"]


@pytest.mark.slow
def test_lane_loops_compile_without_epilogue_loops_or_runtime_unrolling(compile_cuts):
    # _fill_rows is one lane loop inside two loops: with LLVM's defaults (before mosd.kernels.LLVM_OPTIONS) it
    # held 3 vector bodies and 3 epilogue vector loops (the middle loop unrolled twice, plus its remainder)
    assert compile_cuts["epilogue_loops"] == 0
    assert compile_cuts["vector_loops"] == 1, compile_cuts["vector_loops"]


@pytest.mark.slow
def test_the_filters_big_helpers_are_called_not_compiled_again_inside_their_callers(linked_in):
    # before: numba linked _update_lanes and _tria_lanes into cesckf's module and _tria_lanes into
    # _update_lanes', where LLVM optimised and generated them again (3 compiles of _tria_lanes, 2 of _update_lanes)
    assert linked_in["cesckf"] == [], linked_in
    assert linked_in["_update_lanes"] == ["_update_lanes"], linked_in
