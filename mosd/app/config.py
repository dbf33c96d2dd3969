"""Where the configuration lives and which keys it has (shared by preflight, build and run)."""
from __future__ import annotations

from pathlib import Path

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
