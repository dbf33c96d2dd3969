"""The experiment presets (``conf/experiment/NAME.yaml``) as built components, for the report commands.

The report commands (``python -m mosd.systems.paperNNN``, ``python -m mosd.paper``) run a
system's study without the optimiser; their experiment is the preset's own, composed here
with Hydra's compose API and built by :func:`mosd.app.build.build` exactly as
``python -m mosd +experiment=NAME`` builds it, so that each preset has one source of truth.
The systems import this module lazily (:func:`mosd.systems.cli.preset`): importing
``mosd.systems`` never loads Hydra.
"""
from __future__ import annotations

from typing import Sequence

from ..validation import ConfigError, check_choice
from .config import CONFIG_DIR, CONFIG_NAME, one_line, options, with_debug_last


def compose_preset(name: str, overrides: Sequence[str] = ()):
    """The composed config of ``+experiment=NAME`` with ``overrides`` (Hydra override syntax), no tracking.

    Raises
    ------
    ConfigError
        One line naming the preset or the override Hydra could not apply.
    """
    from hydra import compose, initialize_config_dir
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    check_choice("experiment", name, options("experiment"))
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3", job_name="mosd"):
        try:
            return compose(CONFIG_NAME, overrides=with_debug_last([f"+experiment={name}", "tracking=none", *overrides]))
        except (HydraException, OmegaConfBaseException) as exc:
            raise ConfigError(f"+experiment={name} {' '.join(overrides)}: {one_line(exc)}") from None


def preset_setup(name: str, overrides: Sequence[str] = ()):
    """The :class:`~mosd.app.build.Setup` of ``+experiment=NAME`` (components validated and built), its
    component count's range bounded by the data as a run's is (:func:`mosd.app.preflight.fit_to_data`)."""
    from .build import build
    from .preflight import fit_to_data

    setup = build(compose_preset(name, overrides))
    fit_to_data(setup)
    return setup


def component(group: str, option: str, overrides: Sequence[str] = ()):
    """A fresh component of ``conf/GROUP/OPTION.yaml`` with ``overrides`` (e.g. ``pop_size=40``).

    Run keys of the group (``optimizer.n_gen``, ``detector.bounds``, ...) are dropped: the
    object is what the YAML's ``_target_`` builds.
    """
    from hydra import compose, initialize_config_dir
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    from .build import instantiate_section
    from .config import RUN_KEYS, groups

    check_choice("group", group, groups())
    check_choice(group, option, options(group))
    with initialize_config_dir(config_dir=str(CONFIG_DIR / group), version_base="1.3", job_name="mosd"):
        try:
            cfg = compose(option, overrides=list(overrides))
        except (HydraException, OmegaConfBaseException) as exc:
            raise ConfigError(f"{group}={option} {' '.join(overrides)}: {one_line(exc)}") from None
    return instantiate_section(group, cfg, exclude=RUN_KEYS.get(group, ()))
