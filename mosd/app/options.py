"""``mosd options [GROUP ...]``: every option of every config group, derived from the YAMLs and the classes.

The listing is not kept anywhere by hand (issue 28, "found, not registered"):
the options are the files in ``conf/<group>/``, the class is each YAML's
``_target_``, the one-line description is the YAML's leading comment, and each
key shows its default (the YAML's value), the YAML's comment on it and the
allowed values the class declares (:class:`mosd.validation.Param`). A new
component (one module and one YAML) is listed without touching any other file:
the documentation site's configuration pages are generated from :func:`listing` and
:func:`option_index` when the site is built (``docs/gen_reference.py``), nothing of them is
committed. The configuration reference page's curated option tables (``docs/reference/options.md``)
are a selection that ``tests/test_configs.py`` checks against the components.
"""
from __future__ import annotations

import argparse
import importlib
import re
import sys
from dataclasses import dataclass, field
from typing import Sequence

from .config import CONFIG_DIR, CONFIG_NAME, groups, options

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
    #: a fault: where it acts (mosd.faults.base.ACTS_ON; a fault set's members'); a plant: where it takes faults
    acts_on: str = ""


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


def _class(target: str | None):
    """The class a ``_target_`` names, or None (not mosd's, or an optional dependency missing)."""
    if not target or not target.startswith("mosd."):
        return None
    module, _, name = target.rpartition(".")
    try:
        return getattr(importlib.import_module(module), name, None)
    except ImportError:
        return None


def fault_acts_on(spec) -> str:
    """Where the fault of a YAML acts: its class's ``acts_on``, or its members' (a fault set), comma-separated."""
    declared = getattr(_class(spec.get("_target_")), "acts_on", "")
    if isinstance(declared, str) and declared:
        return declared
    members = [fault_acts_on(member) for member in spec.get("faults") or () if hasattr(member, "get")]
    return ", ".join(dict.fromkeys(m for m in members if m))


def plant_fault_targets(spec) -> str:
    """Where the plant of a YAML takes faults (its class's ``fault_targets``), comma-separated."""
    return ", ".join(getattr(_class(spec.get("_target_")), "fault_targets", ()))


def faults_for(plant: str) -> list[str]:
    """The fault options (``conf/fault``) that can act on the plant option ``plant``: every member's
    ``acts_on`` among the plant's ``fault_targets`` (what :meth:`mosd.plants.base.Plant.check_fault` checks)."""
    takes = set(option("plant", plant).acts_on.split(", "))
    return [o.name for o in listing(["fault"])["fault"] if o.acts_on and set(o.acts_on.split(", ")) <= takes]


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
    where = {"fault": fault_acts_on, "plant": plant_fault_targets}.get(group)
    acts_on = where(OmegaConf.to_container(config, resolve=False)) if where else ""
    return Option(group, name, target, _leading_comment(lines), keys, note, acts_on)


def _short(value) -> str:
    text = str(value).replace("'", "")
    return text if len(text) <= 60 else text[:57] + "..."


def listing(selected: Sequence[str] = ()) -> dict[str, list[Option]]:
    """group -> its options (every group when ``selected`` is empty)."""
    known = groups()
    return {group: [option(group, name) for name in options(group)] for group in (selected or known)}


def defaults_choices(path) -> dict[str, str]:
    """{group: option} of a YAML's defaults list (``/fault: offset``, ``override /plant: two_tank``)."""
    from omegaconf import OmegaConf

    choices = {}
    for entry in OmegaConf.to_container(OmegaConf.load(path)).get("defaults") or ():
        if isinstance(entry, dict):
            for key, value in entry.items():
                choices[key.replace("override ", "").strip("/ ")] = None if value is None else str(value)
    return choices


def presets() -> dict[str, dict[str, str]]:
    """{preset: {group: option}}: each ``conf/experiment`` preset's choices over ``conf/config.yaml``'s defaults."""
    base = defaults_choices(CONFIG_DIR / f"{CONFIG_NAME}.yaml")
    return {name: {**base, **defaults_choices(CONFIG_DIR / "experiment" / f"{name}.yaml")}
            for name in options("experiment")}


def option_index(group_pages: bool = False) -> str:
    """The index of every preset and every option, derived from conf/ and the classes.

    Two markdown tables: each preset's choice of plant (or recorded data), fault, estimator, monitor and
    detector, and each config group's options, with where each fault acts and where each plant takes
    faults. The site's configuration page shows it (``docs/gen_reference.py``, at every build).

    Parameters
    ----------
    group_pages : bool
        Link each group's name to ``<group>.md``, its page next to the index on the site.
    """
    columns = ("plant", "fault", "estimator", "monitor", "detector")
    out = ["| preset | " + " | ".join(columns) + " |", "|---" * (len(columns) + 1) + "|"]
    for name, choices in presets().items():
        cells = [f"`{choices[c]}`" if choices.get(c) else "—" for c in columns]
        if choices.get("data"):  # recorded data replace plant, noise and fault
            cells[0] = f"data `{choices['data']}`"
        out.append(f"| `{name}` | " + " | ".join(cells) + " |")
    out += ["", "| group | options |", "|---|---|"]
    for group, opts in listing([g for g in groups() if g != "experiment"]).items():
        names = ", ".join(f"`{o.name}`" + (f" ({_INDEX_WHERE[group].format(o.acts_on)})" if o.acts_on else "")
                          for o in opts)
        name = f"[`{group}`]({group}.md)" if group_pages else f"`{group}`"
        out.append(f"| {name} | {names} |")
    return "\n".join(out)


#: how the listing words Option.acts_on for each group that has it
_WHERE = {"fault": "Acts on", "plant": "Takes faults acting on"}
_INDEX_WHERE = {"fault": "on {}", "plant": "takes faults on {}"}


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
            acts = f" {_WHERE[group]}: {opt.acts_on}." if opt.acts_on else ""
            out.append(f"| `{opt.name}` | {f'`{opt.target}`' if opt.target else '—'} | {_cell(opt.description)}{acts} | "
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

