"""Every config group option composes and builds; defaults match the paper; errors are one line.

Uses Hydra's compose API in-process (no run directory, no MLflow).
"""
from __future__ import annotations

import atexit
import functools
import io
import re
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from mosd.app import build as _build_module, config as _config_module, options as _options_module
from mosd.app import preflight as _preflight_module
from mosd.detectors import EWMA, SSDEWMA
from mosd.denoisers import NoDenoiser, WaveletDenoiser
from mosd.estimators import CESCKF, DedicatedObserverResidual, InnovationResidual
from mosd.faults import FAULT_KINDS, SensorFault
from mosd.monitors import SubgroupMonitor as Monitor
from mosd.noise import GaussianNoise
from mosd.optim.mopso import MOPSO
from mosd.plants import MouldOscillator
from mosd.app.progress import Progress, hypervolume_2d
from mosd.app.mlflow_client import flatten
from mosd.app.settings import TrackingSettings, default_tracking_uri
from mosd.validation import ConfigError

CONF = _config_module.CONFIG_DIR
#: the fault options as a one-line error lists them: read from conf/fault/, never spelled out here (issue 50:
#: adding a fault is one module and one YAML, no test to edit)
FAULTS = ", ".join(sorted(path.stem for path in (CONF / "fault").glob("*.yaml")))
GROUPS = sorted(p.name for p in CONF.iterdir() if p.is_dir())
OPTIONS = [(g, o) for g in GROUPS for o in _config_module.options(g)]
README = Path(__file__).resolve().parents[1] / "README.md"
#: the configuration reference (the README's, moved to the site by issue 51)
OPTIONS_PAGE = README.parent / "docs" / "reference" / "options.md"


@pytest.fixture(scope="module")
def composer():
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3", job_name="test"):
        yield lambda *overrides: compose("config", overrides=list(overrides))


def _preset_choices() -> dict[str, dict[str, str]]:
    """{preset: {group: option}} from the defaults lists of conf/experiment/*.yaml (the preset's own choices)."""
    return {name: _options_module.defaults_choices(CONF / "experiment" / f"{name}.yaml")
            for name in _config_module.options("experiment")}


PRESETS = _preset_choices()
#: plant option -> the fault options that act where it takes faults (found from the declarations)
FAULTS_FOR = {plant: _options_module.faults_for(plant) for plant in _config_module.options("plant")}
DEFAULT_PLANT = _options_module.defaults_choices(CONF / "config.yaml")["plant"]


@functools.lru_cache(maxsize=1)
def _skab_folder() -> Path:
    """A small folder of SKAB's layout (seeded numbers, not SKAB's), written once, removed at exit."""
    from mosd.data.skab import write_example

    folder = Path(tempfile.mkdtemp(prefix="mosd-skab-"))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return write_example(folder / "data", np.random.default_rng(0))


def _fault_override(group, option):
    """The context an option is composed in: the paper-000 default, or the preset that uses the option."""
    if option == "skab" and group in ("data", "experiment"):  # SKAB reads a folder of its layout
        return [*(["+experiment=skab"] if group == "data" else []), f"data.root={_skab_folder()}"]
    if group == "data":  # recorded data replace plant/noise/fault: the TE preset; a table needs a file
        from mosd.data.tep import bibmon_directory

        table = bibmon_directory().parent / "real_process_data" / "real_process_data.csv"
        return ["+experiment=tep", *([f"data.path={table}"] if option == "table" else [])]
    if group == "experiment" and option == "table":  # the table preset needs its file
        return _fault_override("data", "table")[1:]
    if group in ("experiment", "denoise", "optimizer", "tracking"):
        return [] if group == "experiment" else ["+fault=offset_var"]
    for preset, choices in PRESETS.items():
        if preset not in ("paper000", "table", "skab") and choices.get(group) == option:  # no data file needed
            return [f"+experiment={preset}"]
    if group == "fault":  # on the default plant if it takes the fault, else on a preset's plant that does
        return [] if option in FAULTS_FOR[DEFAULT_PLANT] else _preset_taking(option)
    return ["+fault=offset_var"]


def _preset_taking(fault):
    """``+experiment=P`` for the first simulated preset whose plant takes ``fault`` (where it acts)."""
    for preset, choices in PRESETS.items():
        if choices.get("plant") and not choices.get("data") and fault in FAULTS_FOR.get(choices["plant"], ()):
            return [f"+experiment={preset}"]
    raise AssertionError(f"no plant of conf/plant takes fault={fault}: its acts_on matches no plant's fault_targets")


def test_groups_are_the_documented_ones():
    assert set(GROUPS) >= {"plant", "noise", "fault", "estimator", "detector", "denoise", "optimizer", "tracking"}
    assert set(_config_module.options("fault")) >= set(FAULT_KINDS)
    assert set(_config_module.options("optimizer")) >= {"mopso", "nsga2"}


@pytest.mark.parametrize("group,option", OPTIONS, ids=[f"{g}={o}" for g, o in OPTIONS])
def test_every_option_composes_and_builds(composer, group, option):
    context = _fault_override(group, option)
    plus = group in ("experiment", "debug") or (group == "fault" and not context)
    choice = f"+{group}={option}" if plus else f"{group}={option}"
    cfg = composer(*context, choice)
    setup = _build_module.build(cfg)
    exp = setup.experiment
    built = {"plant": exp.plant, "noise": exp.noise, "fault": exp.fault, "estimator": exp.estimator,
             "monitor": exp.monitor, "detector": exp.detector, "denoise": getattr(exp.detector, "denoiser", None),
             "optimizer": setup.algorithm}
    if group in built:
        node = OmegaConf.to_container(cfg[group], resolve=True)
        obj = built[group]
        assert f"{type(obj).__module__}.{type(obj).__name__}" == node["_target_"]
        # scalar YAML values land on the object unchanged; nested components have their type
        for key, value in node.items():
            if isinstance(value, dict) and "_target_" in value:
                inner = getattr(obj, key)
                assert f"{type(inner).__module__}.{type(inner).__name__}" == value["_target_"]
                continue
            if key in _config_module.RUN_KEYS.get(group, ()) or key.startswith("_") or isinstance(value, (dict, list)):
                continue
            if hasattr(obj, key) and value is not None:
                actual = getattr(obj, key)
                if isinstance(actual, np.ndarray) and actual.ndim > 0 and isinstance(value, (int, float)):
                    continue  # a scalar shorthand expanded to a matrix (covariance, transition): derived

                expected = pytest.approx(value) if isinstance(value, float) else value
                assert actual == expected, f"{group}.{key}"
    if group == "tracking":
        settings = TrackingSettings.from_config(dict(cfg.tracking), "outputs")
        assert (settings is None) == (option == "none")


def test_default_options_mirror_the_class_defaults(composer):
    """The default option of a group is the component as its class builds it by default."""
    import inspect

    from hydra.utils import get_object

    cfg = composer("+fault=offset_var")
    for group in ("plant", "noise", "estimator", "monitor", "detector", "denoise", "optimizer"):
        node = OmegaConf.to_container(cfg[group], resolve=True)
        signature = inspect.signature(get_object(node["_target_"]))
        for key, value in node.items():
            parameter = signature.parameters.get(key)
            if parameter is None or parameter.default is inspect.Parameter.empty or isinstance(value, dict):
                continue
            default = parameter.default
            if isinstance(default, tuple):
                default = list(default)
            if isinstance(value, list) and isinstance(default, float):
                # a covariance given as its diagonal vs. a scalar times the identity
                assert np.allclose(value, default), f"{group}.{key}: config {value!r}, class default {default!r}"
            else:
                assert value == default, f"{group}.{key}: config {value!r}, class default {default!r}"


def test_fault_is_not_in_defaults_and_null_in_body(composer):
    raw = OmegaConf.load(CONF / "config.yaml")
    groups_in_defaults = {k for entry in raw.defaults if not isinstance(entry, str) for k in entry}
    assert "fault" not in groups_in_defaults and "optimizer" in groups_in_defaults
    assert raw.fault is None
    assert composer().fault is None
    with pytest.raises(_config_module.UsageError, match=r"\+fault=NAME .*" + re.escape(FAULTS)):
        _build_module.build(composer())


#: the issue's sizes of the sensor-fault options (paper 000): pinned values, not a list of the options
ISSUE_SIZES = {"offset": (2.0, 1.0), "variance": (None, 2.0), "offset_var": (2.0, 2.0), "drift": (2.0, 1.0)}


@pytest.mark.parametrize("kind", sorted(ISSUE_SIZES))
def test_fault_options_match_the_issue(composer, kind):
    a, b = ISSUE_SIZES[kind]
    fault = _build_module.build(composer(f"+fault={kind}")).experiment.fault
    assert isinstance(fault, SensorFault)
    assert (fault.kind, fault.channel, fault.onset, fault.b) == (kind, 0, 2.7, b)
    if a is not None:
        assert fault.a == a


def test_every_fault_option_acts_somewhere_a_plant_takes_faults():
    """Each fault option declares where it acts and some plant option takes it (conf/ and classes, no list)."""
    from mosd.faults.base import ACTS_ON

    for name in _config_module.options("fault"):
        acts_on = _options_module.option("fault", name).acts_on
        assert acts_on and set(acts_on.split(", ")) <= set(ACTS_ON), (name, acts_on)
        assert any(name in faults for faults in FAULTS_FOR.values()), f"fault={name}: no plant takes it"
    assert set(ISSUE_SIZES) <= set(FAULTS_FOR[DEFAULT_PLANT])


def test_defaults_are_paper_scale(composer):
    cfg = composer("+fault=offset_var")
    setup = _build_module.build(cfg)
    assert isinstance(setup.algorithm, MOPSO) and setup.algorithm.pop_size == 100 and setup.n_gen == 100
    budget = setup.experiment.budget
    assert (budget.n_calibration, budget.n_train, budget.n_test) == (10, 10, 100)
    assert setup.bounds == {"K": (0.0, 10.0)}  # Fig. 1's range (lam: its allowed range); paper000 keeps 5
    exp = setup.experiment
    assert isinstance(exp.plant, MouldOscillator) and isinstance(exp.noise, GaussianNoise)
    assert isinstance(exp.estimator, DedicatedObserverResidual) and isinstance(exp.estimator.filter, CESCKF)
    assert exp.estimator.monitored == (0,)
    assert isinstance(exp.monitor, Monitor) and (exp.monitor.subgroup, exp.monitor.n, exp.monitor.channels,
                                                  exp.monitor.burn_in) == ("window", 5, (0,), 200)
    assert isinstance(exp.detector, SSDEWMA) and exp.detector.limit == "phase1"
    # the default is causal (no whole-series denoising); paper 000's wavelet is one option away
    assert not isinstance(exp.detector.denoiser, WaveletDenoiser) and exp.detector.is_causal
    paper = _build_module.build(composer("+fault=offset_var", "denoise=wavelet")).experiment.detector.denoiser
    assert isinstance(paper, WaveletDenoiser) and (paper.wavelet, paper.level) == ("db3", 3)
    assert exp.duration == 5.2 and exp.seed == 0
    assert exp.noise.process_cov.shape == (3, 3)  # n_x, n_y filled in from the plant
    # run directories named down to the microsecond, under the outputs root
    hydra = OmegaConf.to_container(OmegaConf.load(CONF / "config.yaml").hydra, resolve=False)
    for where in (hydra["run"]["dir"], hydra["sweep"]["dir"]):
        assert where.startswith("${outputs_root}/") and where.endswith("%H-%M-%S-%f}")


def test_chart_and_denoise_alternatives(composer):
    setup = _build_module.build(composer("+fault=offset", "detector=ewma", "denoise=none", "estimator=innovation"))
    assert isinstance(setup.experiment.detector, EWMA) and isinstance(setup.experiment.detector.denoiser, NoDenoiser)
    assert isinstance(setup.experiment.estimator, InnovationResidual)
    assert set(setup.bounds) == {"L"}  # lam: searched over its allowed range


def test_choose_uses_the_selection_section(composer):
    setup = _build_module.build(composer("+fault=offset", "selection.rule=min_mdr_far_le", "selection.alpha=0.01"))
    F = np.array([[0.0, 0.5], [0.005, 0.2], [0.05, 0.0]])
    assert setup.choose(np.zeros((3, 2)), F) == 1  # lowest MDR among FAR <= 0.01
    setup = _build_module.build(composer("+fault=offset"))
    assert setup.choose(np.zeros((3, 2)), F) == 2  # max accuracy


def _message(exc_info) -> str:
    text = str(exc_info.value)
    assert "\n" not in text
    return text


@pytest.mark.parametrize("overrides,pattern", [
    (["+faults=offset_var"], r"'faults'.*did you mean \+fault=NAME.*offset_var"),
    (["+fault=offset_var", "detector.lam=1.5"], r"detector\.lam=1\.5 is out of range; allowed: \(0, 1\)"),
    (["+fault=offset_var", "optimizer.pop_size=0"], r"optimizer\.pop_size=0 .*allowed: integers in \[1"),
    (["+fault=offset_var", "optimizer.n_gen=-2"], r"optimizer\.n_gen=-2 .*allowed"),
    (["+fault=offset_var", "optimizer.velocity=fast"], r"optimizer\.velocity='fast'.*constriction, inertia"),
    (["+fault=offset_var", "budget.n_test=0"], r"budget\.n_test=0"),
    (["+fault=offset_var", "detector.bounds.K=[0,20]"], r"detector\.bounds\.K=.*allowed: low <= high within \[0, 10\]"),
    (["+fault=offset_var", "+detector.foo=1"], r"detector\.foo is not a parameter of SSDEWMA; allowed: lam, K, limit"),
    (["+fault=offset_var", "selection.rule=best"], r"selection\.rule='best'.*max_accuracy"),
    (["+fault=offset_var", "tracking.uri=ftp://x"], r"tracking\.uri='ftp://x'.*sqlite"),
    (["+fault=offset_var", "progress=maybe"], r"progress='maybe'.*true, false"),
    (["+fault=offset_var", "monitor.channels=[5]"], r"monitor\.channels=\[5\] is out of range; allowed: channels 0\.\.2"),
])
def test_build_errors_are_one_line_naming_key_and_allowed(composer, overrides, pattern):
    with pytest.raises((_config_module.UsageError, ConfigError)) as info:
        _build_module.build(composer(*overrides))
    assert re.search(pattern, _message(info)), _message(info)


@pytest.mark.parametrize("argv,pattern", [
    ([], r"no fault chosen.*" + re.escape(FAULTS)),
    (["+fault=offset_var", "optimizer=foo"], r"optimizer=foo is not an option; allowed: mopso, (.*, )?nsga2"),
    (["+fault=nope"], r"fault=nope is not an option; allowed: " + re.escape(FAULTS)),
    (["fault=offset"], r"\+fault=offset"),
    (["+fault=offset", "+optimizer=nsga2"], r"optimizer=nsga2 without the \+"),
    (["+fault=offset", "detector.lamm=0.3"], r"detector\.lamm is not a config key of detector; allowed: .*lam"),
    (["+fault=offset", "optimizer=mopso,nsga2"], r"multirun"),
    (["-m", "+fault=offset,variance", "detector.lam=0.5,1.5"], r"detector\.lam=1\.5 is out of range"),
    (["--multirn"], r"unrecognized arguments: --multirn"),
])
def test_preflight_errors(argv, pattern):
    with pytest.raises((_config_module.UsageError, ConfigError)) as info:
        _preflight_module.preflight(argv)
    assert re.search(pattern, _message(info)), _message(info)


def test_preflight_accepts_the_main_command_and_a_sweep():
    _preflight_module.preflight(["+fault=offset_var", "optimizer=mopso"])
    _preflight_module.preflight(["-m", "+fault=offset,variance", "optimizer=mopso,nsga2", "hydra/launcher=joblib"])


def test_the_packages_are_found_and_conf_ships_inside_the_package():
    """setup.py finds every package and config group: a new one needs no edit (issue 28 item 3)."""
    import importlib.util

    import tomllib
    from setuptools import find_packages

    setuptools = tomllib.loads((README.parent / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert "packages" not in setuptools and "package-dir" not in setuptools  # no hand-kept list left
    spec = importlib.util.spec_from_file_location("mosd_setup", README.parent / "setup.py")
    setup_module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(setup_module)  # defines packages(); setup() runs only as __main__
    nested = sorted(".".join(p.relative_to(CONF).parts) for p in CONF.rglob("*") if p.is_dir())
    assert "debug.tiny" in nested
    assert set(setup_module.packages()) == {*find_packages(str(README.parent), include=["mosd", "mosd.*"]),
                                            "mosd.conf", *(f"mosd.conf.{g}" for g in nested)}


def test_the_options_listing_derives_every_option_and_key():
    """``mosd options``: every YAML of every group, its class and every key with the class's allowed values."""
    from mosd.app.options import listing, markdown

    found = listing()
    assert set(found) == set(GROUPS)
    for group, opts in found.items():
        assert [o.name for o in opts] == _config_module.options(group)
        for opt in opts:
            node = OmegaConf.load(CONF / group / f"{opt.name}.yaml")
            assert opt.target == (node.get("_target_") if group != "experiment" else None)
            if group != "experiment":
                assert [k.name for k in opt.keys] == [k for k in node if not k.startswith("_")]
    ewma = {k.name: k for k in next(o for o in found["detector"] if o.name == "ewma").keys}
    assert ewma["lam"].declared == "float in (0, 1]" and ewma["lam"].default == "0.2"
    assert ewma["lam"].comment == "smoothing lambda"
    text = markdown(found)
    assert "| `cusum` | `mosd.detectors.cusum.Cusum` |" in text and "### `debug`" in text


def test_the_options_command_lists_a_group_and_refuses_an_unknown_one(capsys):
    import mosd.app

    assert mosd.app.main(["options", "detector"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("### `detector`") and "`ss_dewma`" in out and "### `plant`" not in out
    assert mosd.app.main(["options", "detectors"]) == 2
    assert capsys.readouterr().err.strip().startswith("mosd: error: options group 'detectors' is unknown; allowed: ")
    assert mosd.app.main(["options", "--no-such-flag"]) == 2
    assert capsys.readouterr().err.strip() == "mosd: error: options: unrecognized arguments: --no-such-flag"


def _readme_option_rows() -> list[tuple[str, str, str]]:
    """(group, option, class cell) of every row of the configuration reference's option tables (``| option | ...``
    headers): ``docs/reference/options.md``, where the README's configuration reference moved (issue 51)."""
    rows, group, in_table = [], None, False
    for line in OPTIONS_PAGE.read_text().splitlines():
        heading = re.match(r"^### `(\w+)`", line)
        if heading:
            group, in_table = heading.group(1), False
        elif line.startswith("| option |"):
            in_table = True
        elif not line.startswith("|"):
            in_table = False
        elif in_table and group and not line.startswith("|---"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            rows.append((group, re.match(r"`([\w.]+)`", cells[0]).group(1), cells[1]))
    return rows


def test_the_readme_option_tables_agree_with_the_configs():
    """The reference page's tables are a selection, never a registry: each row names an existing option and its class.

    The complete list is derived (``python -m mosd options``): a new component is one module and one YAML.
    """
    rows = _readme_option_rows()
    assert len(rows) >= 30 and {g for g, _, _ in rows} >= {"plant", "estimator", "detector", "optimizer"}
    for group, option, cell in rows:
        assert option in _config_module.options(group), (f"{OPTIONS_PAGE.name} lists {group}={option}, "
                                                         "which conf/ lacks")
        target = OmegaConf.load(CONF / group / f"{option}.yaml").get("_target_")
        named = re.search(r"`([A-Za-z_]\w*(?:\.\w+){2,})`", cell)
        if target and named:
            assert named.group(1) == target, (f"{OPTIONS_PAGE.name}: {group}={option} is {named.group(1)}, "
                                              f"conf/ says {target}")
    assert "python -m mosd options" in OPTIONS_PAGE.read_text()
    assert "python -m mosd options" in README.read_text()  # the README points at the complete list too


def test_the_reference_documents_the_top_level_keys():
    text = OPTIONS_PAGE.read_text()
    for key in ("seed", "scenario.duration", "budget.n_train", "budget.n_test", "budget.n_calibration",
                "selection.rule", "selection.alpha", "progress", "outputs_root"):
        assert f"`{key}`" in text, f"{OPTIONS_PAGE.name} misses key {key}"


# -- progress and tracking helpers -----------------------------------------------------
def test_hypervolume_matches_pymoo():
    from pymoo.indicators.hv import HV

    rng = np.random.default_rng(3)
    for _ in range(5):
        F = rng.random((rng.integers(1, 30), 2))
        assert hypervolume_2d(F) == pytest.approx(HV(ref_point=np.array([1.1, 1.1]))(F), rel=1e-12)
    assert hypervolume_2d(np.array([[1.2, 0.0]])) == 0.0
    assert hypervolume_2d(np.array([[0.0, 0.0]])) == pytest.approx(1.21)


class _FakeAlgorithm:
    def __init__(self, gen, F):
        from pymoo.core.population import Population

        self.n_gen = gen
        self.opt = Population.new("F", np.asarray(F, float))
        self.evaluator = type("E", (), {"n_eval": 10 * gen})()


class _Terminal(io.StringIO):
    def isatty(self):
        return True


@pytest.mark.parametrize("enabled", [True, False])
def test_progress_records_and_flag(enabled):
    stream = _Terminal()
    progress = Progress(n_gen=3, enabled=enabled, stream=stream, min_interval=0.0)
    fronts = [[[0.5, 0.5]], [[0.2, 0.6], [0.6, 0.1]], [[0.1, 0.1]]]
    for gen, F in enumerate(fronts, start=1):
        progress(_FakeAlgorithm(gen, F))
    assert [r["generation"] for r in progress.records] == [1, 2, 3]
    assert [r["archive_size"] for r in progress.records] == [1, 2, 1]
    assert progress.records[2]["best_accuracy"] == pytest.approx(0.8)
    assert progress.records[1]["hypervolume"] == pytest.approx(hypervolume_2d(np.array(fronts[1])))
    assert progress.records[2]["n_eval"] == 30
    out = stream.getvalue()
    if enabled:
        assert out.endswith("\n") and "\r" in out and "gen 3/3" in out and "best acc 0.8000" in out
    else:
        assert out == ""


def test_progress_is_quiet_when_not_a_terminal():
    # a log file or a pipe must not collect carriage-return updates
    stream = io.StringIO()
    progress = Progress(n_gen=2, enabled=True, stream=stream, min_interval=0.0)
    for gen in (1, 2):
        progress(_FakeAlgorithm(gen, [[0.1, 0.2]]))
    assert stream.getvalue() == "" and len(progress.records) == 2


def test_progress_bars_of_concurrent_jobs_take_their_own_line():
    streams = [_Terminal(), _Terminal()]
    bars = [Progress(n_gen=2, stream=s, min_interval=0.0, position=i, description=f"job {i}")
            for i, s in enumerate(streams)]
    for gen in (1, 2):
        for bar in bars:
            bar(_FakeAlgorithm(gen, [[0.1, 0.2]]))
    assert "job 0 gen 2/2" in streams[0].getvalue() and "job 1 gen 2/2" in streams[1].getvalue()
    # tqdm moves the cursor down to line `position` before drawing the second job's bar
    assert "\n" in streams[1].getvalue().split("job 1")[0]


def test_flatten_and_tracking_settings(tmp_path):
    assert flatten({"a": {"b": 1, "c": {"d": None}}, "e": [1, 2]}) == {"a.b": "1", "a.c.d": "None", "e": "[1, 2]"}
    s = TrackingSettings.from_config({"enabled": True, "uri": None, "artifact_root": None, "experiment": "x"},
                                     str(tmp_path / "out"))
    assert s.uri == f"sqlite:///{tmp_path / 'out' / 'mlflow.db'}" and s.uri.startswith("sqlite:////")
    assert s.artifact_root == (tmp_path / "out" / "mlartifacts").as_uri()
    assert default_tracking_uri(tmp_path) == f"sqlite:///{tmp_path / 'mlflow.db'}"
    with pytest.raises(ConfigError, match="tracking.bogus"):
        TrackingSettings.from_config({"enabled": True, "bogus": 1}, "out")
