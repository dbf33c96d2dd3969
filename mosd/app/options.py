"""``mosd options [GROUP ...]``: every option of every config group, derived from the YAMLs and the classes.

The listing is not kept anywhere by hand (issue 28, "found, not registered"):
the options are the files in ``conf/<group>/``, the class is each YAML's
``_target_``, the one-line description is the YAML's leading comment, and each
key shows its default (the YAML's value), the YAML's comment on it and the
allowed values the class declares (:class:`mosd.validation.Param`). A new
component (one module and one YAML) is listed without touching any other file;
the README's option tables are a selection that ``tests/test_configs.py``
checks against :func:`listing`.
"""
from __future__ import annotations

import argparse
import importlib
import re
import sys
from dataclasses import dataclass, field
from typing import Sequence

from .config import CONFIG_DIR, groups, options

#: a top-level key of a YAML and its trailing comment
_KEY = re.compile(r"^(?P<key>[A-Za-z_]\w*):(?P<value>[^#]*)(#\s?(?P<comment>.*))?$")


@dataclass
class Key:
    """One top-level key of an option: its default, the YAML's comment, the class's declaration."""

    name: str
    default: str
    comment: str = ""
    declared: str = ""


@dataclass
class Option:
    """One option of a config group (one YAML file)."""

    group: str
    name: str
    target: str | None
    description: str
    keys: list[Key] = field(default_factory=list)
    note: str = ""


def _leading_comment(lines: list[str]) -> str:
    text = []
    for line in lines:
        if line.startswith("# @package"):
            continue
        if not line.startswith("#"):
            break
        text.append(line.lstrip("#").strip())
    return " ".join(text)


def _declaration(target: str | None) -> tuple[dict, str]:
    """The class's declared parameters (name -> Param), or {} and why not."""
    if not target or not target.startswith("mosd."):
        return {}, ""
    module, _, name = target.rpartition(".")
    try:
        cls = getattr(importlib.import_module(module), name)
    except ImportError as exc:  # an optional dependency (PyTorch, pandas) that is not installed
        return {}, f"keys' allowed values need {exc.name or 'an optional dependency'} installed"
    return dict(getattr(cls, "params", {}) or {}), ""


def option(group: str, name: str) -> Option:
    """The derived description of ``conf/<group>/<name>.yaml``."""
    from omegaconf import OmegaConf

    path = CONFIG_DIR / group / f"{name}.yaml"
    lines = path.read_text(encoding="utf-8").splitlines()
    config = OmegaConf.load(path)
    target = config.get("_target_") if group != "experiment" else None
    declared, note = _declaration(target)
    comments = {}
    for line in lines:
        match = _KEY.match(line)
        if match:
            comments[match["key"]] = (match["comment"] or "").strip()
    keys = []
    if group != "experiment":
        for key in config:
            if str(key).startswith("_"):
                continue
            value = OmegaConf.to_container(config, resolve=False)[key]
            param = declared.get(key)
            allowed = param._domain_text() if param is not None else ""
            if param is not None and param.optional:
                allowed += " or null"
            keys.append(Key(str(key), _short(value), comments.get(str(key), ""), allowed))
    return Option(group, name, target, _leading_comment(lines), keys, note)


def _short(value) -> str:
    text = str(value).replace("'", "")
    return text if len(text) <= 60 else text[:57] + "..."


def listing(selected: Sequence[str] = ()) -> dict[str, list[Option]]:
    """group -> its options (every group when ``selected`` is empty)."""
    known = groups()
    return {group: [option(group, name) for name in options(group)] for group in (selected or known)}


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def markdown(found: dict[str, list[Option]]) -> str:
    out = []
    for group, opts in found.items():
        out += [f"### `{group}`", "", "| option | class | description | keys |", "|---|---|---|---|"]
        for opt in opts:
            keys = "; ".join(f"`{k.name}` = `{_cell(k.default)}`" + (f" ({_cell(k.declared)})" if k.declared else "")
                             + (f": {_cell(k.comment)}" if k.comment else "") for k in opt.keys)
            note = f" ({opt.note})" if opt.note else ""
            out.append(f"| `{opt.name}` | {f'`{opt.target}`' if opt.target else '—'} | {_cell(opt.description)} | "
                       f"{keys or '—'}{note} |")
        out.append("")
    return "\n".join(out)


class _Parser(argparse.ArgumentParser):
    """Argument errors are one line and exit 2, as everywhere in the app."""

    def error(self, message: str):
        self.exit(2, f"mosd: error: options: {message}\n")


def main(argv: Sequence[str]) -> int:
    parser = _Parser(
        prog="mosd options", description="Every option of the config groups: class, description, keys with their "
        "defaults and allowed values (derived from conf/ and the classes' declarations).")
    parser.add_argument("groups", nargs="*", metavar="GROUP", help="config groups to list (default: all)")
    try:
        args = parser.parse_args(list(argv))
    except SystemExit as exc:
        return int(exc.code or 0)
    unknown = [g for g in args.groups if g not in groups()]
    if unknown:
        print(f"mosd: error: options group {unknown[0]!r} is unknown; allowed: {', '.join(groups())}", file=sys.stderr)
        return 2
    sys.stdout.write(markdown(listing(args.groups)))
    return 0
