"""Where the configuration lives and which keys it has (shared by preflight, build and run)."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

from ..validation import ConfigError  # noqa: F401  (re-exported for the app's modules)


def _find_config_dir() -> Path:
    """``conf/`` shipped inside the package (wheel) or beside it (checkout, editable install).

    Chosen at import time because a path relative to this file
    (``config_path="../conf"``) does not exist after a wheel install.
    """
    package = Path(__file__).resolve().parent.parent  # mosd/
    for candidate in (package / "conf", package.parent / "conf"):
        if (candidate / "config.yaml").is_file():
            return candidate
    return package.parent / "conf"


CONFIG_DIR = _find_config_dir()
CONFIG_NAME = "config"

#: Sections built with ``hydra.utils.instantiate`` (config group → constructor).
COMPONENTS = ("plant", "noise", "fault", "estimator", "monitor", "denoise", "detector", "optimizer", "study", "data")
#: Keys of a component section that configure the run, not the constructor.
RUN_KEYS = {"detector": ("bounds",), "optimizer": ("n_gen", "n_jobs", "objectives", "backend", "dask_address")}
#: Plain sections and their keys.
SECTIONS = {
    "budget": ("n_calibration", "n_train", "n_test", "n_estimator"),
    "selection": ("rule", "alpha"),
    "scenario": ("duration",),
    "tracking": ("enabled", "uri", "artifact_root", "experiment"),
}
SCALARS = ("seed", "progress", "outputs_root")
TOP_LEVEL_KEYS = tuple(sorted((*COMPONENTS, *SECTIONS, *SCALARS)))



class UsageError(Exception):
    """A command-line or configuration mistake: reported as one line, exit code 2."""


def options(group: str) -> list[str]:
    """The options of a config group (the YAML files in ``conf/<group>/``)."""
    return sorted(p.stem for p in (CONFIG_DIR / group).glob("*.yaml"))


def with_debug_last(overrides: Sequence[str]) -> list[str]:
    """The overrides with ``debug=NAME`` composed last, after a preset, and the preset's own part of it.

    ``debug=tiny`` (conf/debug/tiny.yaml) must override a preset's budgets, but
    Hydra merges a ``+experiment=NAME`` after every entry of the defaults list; so
    ``debug=NAME`` (with or without ``+``, anywhere on the line) becomes
    ``+debug=NAME`` at the end, followed by ``+debug/NAME=PRESET`` when
    ``conf/debug/NAME/PRESET.yaml`` exists (the preset's own study and training
    sizes: keys only that preset's components have). A sweep over ``debug`` is
    left as written.
    """
    debug = [o for o in overrides if o.split("=", 1)[0].lstrip("+") == "debug" and "," not in o]
    if not debug:
        return list(overrides)
    rest = [o for o in overrides if o not in debug]
    name = debug[-1].split("=", 1)[1]
    presets = [o.split("=", 1)[1] for o in rest if o.split("=", 1)[0].lstrip("+") == "experiment"]
    out = [*rest, f"+debug={name}"]
    if presets and (CONFIG_DIR / "debug" / name / f"{presets[-1]}.yaml").is_file():
        out.append(f"+debug/{name}={presets[-1]}")
    return out


def groups() -> list[str]:
    return sorted(p.name for p in CONFIG_DIR.iterdir() if p.is_dir())


def default_groups() -> set[str]:
    """Groups that have an entry in the defaults list of ``config.yaml``."""
    from omegaconf import OmegaConf

    defaults = OmegaConf.load(CONFIG_DIR / f"{CONFIG_NAME}.yaml").get("defaults", [])
    return {key for entry in defaults if not isinstance(entry, str) for key in entry}


def one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())


def no_fault_message() -> str:
    names = options("fault")
    return (f"no fault chosen: add +fault=NAME with NAME one of {', '.join(names)} "
            f"(e.g. python -m mosd +fault={'offset_var' if 'offset_var' in names else names[0]}), "
            f"or a preset +experiment=NAME with NAME one of {', '.join(options('experiment'))}")


def described(exc: BaseException) -> str:
    """``Type: message`` on one line (for errors whose type says what failed: sqlite's, MLflow's)."""
    text = one_line(exc)
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
