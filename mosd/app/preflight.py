"""Preflight: everything that can be wrong on the command line, checked before Hydra runs.

:func:`preflight` parses the command line, composes the configuration of every
job with Hydra's compose API and builds every component, so that a missing
fault, a typo, an unknown option or an out-of-range value ends with one line on
stderr and exit code 2 — no run directory, no MLflow run.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Sequence

from .build import build
from .config import CONFIG_DIR, CONFIG_NAME, UsageError, default_groups, groups, one_line, options


def _args_parser():
    from hydra._internal.utils import get_args_parser

    parser = get_args_parser()

    def error(message: str):  # argparse would print usage on several lines and exit 2
        raise UsageError(message)

    parser.error = error
    return parser


def check_group_overrides(parsed) -> None:
    """Unknown options (``optimizer=foo``) and the ``+`` rules of Hydra, as one-line errors."""
    known = set(groups())
    in_defaults = default_groups()
    # an experiment preset adds the fault group itself: then fault=NAME replaces the preset's choice
    if any(o.key_or_group == "experiment" for o in parsed):
        in_defaults = in_defaults | {"fault"}
    for override in parsed:
        group = override.key_or_group
        if group not in known or override.package or override.is_delete():
            continue
        values = (list(override.sweep_string_iterator()) if override.is_sweep_override()
                  else [override.get_value_element_as_str()])
        allowed = options(group)
        for value in values:
            if value not in allowed:
                raise UsageError(f"{group}={value} is not an option; allowed: {', '.join(allowed)}")
        adds = override.is_add() or override.is_force_add()
        if group not in in_defaults and not adds:
            raise UsageError(f"{group} is chosen with a plus sign: +{group}={values[0]} "
                             f"(allowed: {', '.join(allowed)})")
        if group in in_defaults and override.is_add():
            raise UsageError(f"{group} already has a default: write {group}={values[0]} without the + "
                             f"(allowed: {', '.join(allowed)})")


def _jobs(parsed, multirun: bool) -> list[list[str]]:
    """Override lists of the jobs a command will run (the basic sweeper's expansion)."""
    if not multirun:
        return [[o.input_line for o in parsed]]
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper

    if any(o.key_or_group == "hydra/sweeper" for o in parsed):
        # another sweeper chooses its own points: check the fixed part only
        return [[o.input_line for o in parsed if not o.is_sweep_override()]]
    try:
        return BasicSweeper.split_arguments(parsed, None)[0]
    except Exception as exc:
        raise UsageError(one_line(exc)) from None


def _composition_message(exc: BaseException, compose_group_only: Callable[[], Any]) -> str:
    """One line for a Hydra composition error; names the allowed keys or options."""
    import re

    from omegaconf import OmegaConf

    text = str(exc)
    missing = re.search(r"Could not find '([^']+)/([^'/]+)'", text)
    listed = re.search(r"Available options in '[^']+':\s*\n((?:\t.*\n?)+)", text)
    if missing and listed:
        allowed = ", ".join(line.strip() for line in listed.group(1).splitlines() if line.strip())
        return f"{missing.group(1)}={missing.group(2)} is not an option; allowed: {allowed}"
    bad_key = re.search(r"Could not override '([^']+)'", text)
    if bad_key:
        key = bad_key.group(1)
        parent = key.rpartition(".")[0]
        try:
            node = compose_group_only()
            node = OmegaConf.select(node, parent) if parent else node
            allowed = ", ".join(str(k) for k in node.keys() if k != "hydra")
            where = f"of {parent}" if parent else "at the top level"
            return f"{key} is not a config key {where}; allowed: {allowed}"
        except Exception:
            pass
    return one_line(exc)


def preflight(argv: Sequence[str]) -> None:
    """Compose and build every job of a command line; raise UsageError/ConfigError on a mistake."""
    args = _args_parser().parse_args(list(argv))
    if args.help or args.hydra_help or args.cfg or args.info or args.shell_completion or args.experimental_rerun:
        return  # Hydra's own informational modes
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    try:
        parsed = OverridesParser.create().parse_overrides(list(args.overrides))
    except HydraException as exc:
        raise UsageError(one_line(exc)) from None
    check_group_overrides(parsed)
    config_dir = Path(args.config_path).resolve() if args.config_path else CONFIG_DIR
    extra = [f"hydra.searchpath=[file://{Path(args.config_dir).resolve()}]"] if args.config_dir else []
    config_name = args.config_name or CONFIG_NAME
    group_only = [o.input_line for o in parsed if o.key_or_group in set(groups()) and not o.is_sweep_override()]
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(config_dir), version_base="1.3", job_name="mosd"):
        for job in _jobs(parsed, args.multirun):
            try:
                cfg = compose(config_name, overrides=[*extra, *job], return_hydra_config=True)
            except (HydraException, OmegaConfBaseException) as exc:
                raise UsageError(_composition_message(
                    exc, lambda: compose(config_name, overrides=[*extra, *group_only]))) from None
            try:
                build(cfg)
            except OmegaConfBaseException as exc:
                raise UsageError(one_line(exc)) from None


