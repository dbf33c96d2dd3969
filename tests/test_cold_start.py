"""A run on an empty kernel cache compiles its kernels ahead, on two cores (issue 31: the first result soon after
install).

Preflight names the kernel modules the run's components call (:func:`mosd.app.compile_ahead.kernel_modules`)
and :func:`mosd.kernels.compile_ahead` shares the missing ones between this process and a second one. The
end-to-end check (the main command on an empty cache: the filter compiled by the second process and loaded
by the run, every kernel compiled once) is ``tests/test_first_hour.py``'s slow test.
"""
from __future__ import annotations

import pytest
from hydra import compose, initialize_config_dir

from mosd import kernels
from mosd.app.build import build
from mosd.app.compile_ahead import kernel_modules
from mosd.app.config import CONFIG_DIR


@pytest.fixture(scope="module")
def experiment():
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3", job_name="test"):
        yield lambda *overrides: build(compose("config", overrides=list(overrides))).experiment


def test_the_main_command_names_the_four_modules_it_compiles(experiment):
    # the set tests/test_first_hour.py finds in the cache after the main command on an empty one
    main = experiment("+fault=offset_var", "optimizer=mopso")
    assert set(kernel_modules(main)) == {"plants", "cubature", "ewma", "chart"}
    # a wavelet-denoised chart: the wavelet's kernels, not the plain chart's
    denoised = experiment("+fault=offset_var", "denoise=wavelet")
    assert set(kernel_modules(denoised)) == {"plants", "cubature", "ewma", "wavelet"}
    # kernels off (MOSD_KERNELS=numpy): nothing to compile
    with kernels.disabled():
        assert kernel_modules(main) == ()


def test_a_recorded_table_compiles_no_plant_kernel(experiment, tmp_path):
    from test_first_hour import write_table

    write_table(tmp_path / "plant.csv", 4)
    table = experiment("+experiment=table", f"data.path={tmp_path / 'plant.csv'}", "data.label_column=fault")
    assert not {"plants", "cubature"} & set(kernel_modules(table))


def test_the_largest_module_goes_to_the_second_process():
    here, there = kernels.share(("ewma", "plants", "cubature:filter", "cubature:output", "chart"))
    assert there == ["cubature:filter"]  # 12 s of compile against 11.5 s for the rest together
    assert sorted(here) == ["chart", "cubature:output", "ewma", "plants"]
    # one CPU, or one module: all in this process, no second one started
    assert kernels.share(("ewma", "chart"), workers=1) == (["chart", "ewma"], [])
    assert kernels.share(("ewma",)) == (["ewma"], [])
    # the parts a module is shared out in are warm-ups of that module
    import importlib

    for module, parts in kernels.PARTS.items():
        for part in parts:
            name, _, suffix = part.partition(":")
            assert name == module and callable(getattr(importlib.import_module(f"mosd.kernels.{name}"),
                                                       f"warm_up_{suffix}"))
            assert part in kernels.COMPILE_SECONDS


def test_a_warm_cache_starts_no_second_process(monkeypatch):
    started = []
    monkeypatch.setattr(kernels, "cached", lambda name: True)
    monkeypatch.setattr("subprocess.Popen", lambda *a, **k: started.append(a))
    assert kernels.compile_ahead(("plants", "cubature", "ewma", "chart")) == ([], [])
    assert not started


def test_a_failed_compile_ahead_leaves_the_run_to_compile_where_it_calls(monkeypatch, caplog):
    from mosd.app import compile_ahead

    def broken(modules):
        raise RuntimeError("no space left on device")

    monkeypatch.setattr(kernels, "compile_ahead", broken)
    monkeypatch.setattr(compile_ahead, "kernel_modules", lambda experiment: ("chart",))
    with caplog.at_level("WARNING"):
        compile_ahead.compile_for(object())  # no exception: the dry run goes on
    assert "kernels not compiled ahead: RuntimeError: no space left on device" in caplog.text
