"""Write the site's Reference section: one page per config group and one API page per package.

Run by the ``gen-files`` plugin of ``mkdocs.yml`` at every build (nothing it writes is in the repository):

* ``reference/config/index.md``: every preset's choices and every group's options, with where each fault
  acts and where each plant takes faults (:func:`mosd.app.options.option_index`);
* ``reference/config/<group>.md``: every option of ``conf/<group>/`` with its class, description and keys
  (default, the class's declared domain, the YAML's comment), from :func:`mosd.app.options.listing`, what
  ``python -m mosd options GROUP`` prints;
* ``reference/api/<package>.md``: the docstrings of the package's modules (mkdocstrings);
* ``reference/SUMMARY.md``: the section's navigation (literate-nav), which also lists ``reference/options.md``,
  the one page of the section kept in the repository (the curated option tables with the papers' context).

A new config group, option or module appears without editing this file, ``mkdocs.yml`` or any page: the
index is generated here, never committed (issue 50 item 3: a new system touches no other file). Imported
under the name ``gen_reference`` (``tests/test_readme_tables.py``, ``tests/test_add_a_system.py``) it only
defines the page functions; run by mkdocs-gen-files it writes the pages.
"""
from __future__ import annotations

import pkgutil
from pathlib import Path

import mosd
from mosd.app.config import groups
from mosd.app.options import listing, option_index

#: the packages whose modules get an API page, in the navigation's order, with a line on each
PACKAGES = {
    "mosd": "the experiment, scenario, types, parameter declarations and the streaming contract",
    "mosd.plants": "plants (simulated systems)",
    "mosd.noise": "noise models",
    "mosd.faults": "faults",
    "mosd.data": "recorded data sources (Tennessee Eastman, SKAB, any table)",
    "mosd.estimators": "residual generators",
    "mosd.monitors": "monitors (standardisation, subgroups, selected outputs)",
    "mosd.detectors": "detectors (control charts, latent-variable monitors, decision rules)",
    "mosd.denoisers": "denoisers",
    "mosd.metrics": "metrics (FAR, MDR, delays, the run's summary)",
    "mosd.optim": "optimisers (MO-PSO and the pymoo/jMetal adapters)",
    "mosd.kernels": "compiled numerical kernels (numba)",
    "mosd.systems": "the systems' studies and report commands",
    "mosd.live": "live monitoring (OPC UA)",
    "mosd.app": "the application: Hydra, MLflow, preflight, serving",
}

#: modules left out of the API pages: command-line entry points whose import runs a command
SKIP = {"mosd.__main__", "mosd.kernels.__main__"}


def modules(package: str) -> list[str]:
    """The modules of ``package``: its own top-level modules for ``mosd``, else the package and its modules."""
    if package == "mosd":
        found = [f"mosd.{m.name}" for m in pkgutil.iter_modules(mosd.__path__) if not m.ispkg]
        return sorted(m for m in found if m not in SKIP)
    path = Path(mosd.__path__[0]) / package.split(".", 1)[1]
    found = [f"{package}.{m.name}" for m in pkgutil.iter_modules([str(path)]) if not m.ispkg]
    return [package] + sorted(m for m in found if m not in SKIP)


def config_pages() -> dict[str, str]:
    """{path under reference/: markdown} of the configuration reference."""
    pages = {"config/index.md": (
        "# Configuration\n\n"
        "Every run composes one option per config group (`group=option` on the command line, `+group=option` "
        "for a group without a default such as `fault`) and any key of it (`group.key=value`). A preset "
        "(`+experiment=NAME`) chooses one option per group; the presets' choices over `conf/config.yaml`'s "
        "defaults, then every option of every group. A fault acts on a sensor, an actuator or the state, and "
        "a plant takes the faults that act where it injects them (`+fault=NAME` of another kind is one line, "
        "exit 2). This page is generated from `conf/` and the classes when the site is built; the "
        "[configuration reference](../options.md) adds the papers' context.\n\n"
        + option_index(group_pages=True) + "\n\n"
        "One page per group lists each option's class, its description and its keys: the default (the YAML's "
        "value), the domain the class declares (what preflight checks) and the YAML's comment. "
        "`python -m mosd options [GROUP ...]` prints the same tables.\n")}
    found = listing([g for g in groups() if g != "experiment"]) | listing(["experiment"])
    for group, opts in found.items():
        pages[f"config/{group}.md"] = (
            f"# `{group}`\n\n{len(opts)} options: " + ", ".join(f"[`{o.name}`](#{o.name})" for o in opts)
            + f". Choose one with `{group}=NAME`, set a key with `{group}.KEY=VALUE`; "
            f"`python -m mosd options {group}` prints the same.\n\n" + "\n".join(_option(o) for o in opts))
    return pages


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _option(opt) -> str:
    """One option: its heading, class, description, where it acts, and a table of its keys."""
    out = [f"## `{opt.name}` {{#{opt.name}}}", ""]
    if opt.target:
        out += [f"Class: `{opt.target}`", ""]
    if opt.description:
        out += [opt.description, ""]
    if opt.acts_on:
        out += [f"{'Acts on' if opt.group == 'fault' else 'Takes faults acting on'}: {opt.acts_on}.", ""]
    if opt.note:
        out += [f"*{opt.note}*", ""]
    if opt.keys:
        out += ["| key | default | allowed | meaning |", "|---|---|---|---|"]
        out += [f"| `{k.name}` | `{_cell(k.default)}` | {_cell(k.declared) or '—'} | {_cell(k.comment)} |"
                for k in opt.keys]
        out.append("")
    return "\n".join(out)


def api_pages() -> dict[str, str]:
    pages = {}
    for package, what in PACKAGES.items():
        blocks = [f"# `{package}`\n\nThe {what}.\n"]
        for module in modules(package):
            blocks.append(f"## `{module}`\n\n::: {module}\n    options:\n      show_root_heading: false\n"
                          f"      heading_level: 3\n")
        pages[f"api/{package}.md"] = "\n".join(blocks)
    return pages


def summary() -> str:
    # options.md is a page of the repository (the curated tables with the papers' context), not one this
    # script writes
    lines = ["* [Configuration reference](options.md)", "* [Configuration](config/index.md)"]
    lines += [f"    * [{g}](config/{g}.md)" for g in groups()]
    lines += ["* API", *[f"    * [{p}](api/{p}.md)" for p in PACKAGES]]
    return "\n".join(lines) + "\n"


def write() -> None:
    """Write every page into the build's virtual files (mkdocs-gen-files; the ``docs`` extra)."""
    import mkdocs_gen_files  # here, not at the top: the tests import the page functions without the extra

    for path, text in {**config_pages(), **api_pages(), "SUMMARY.md": summary()}.items():
        with mkdocs_gen_files.open(f"reference/{path}", "w") as out:
            out.write(text)


# mkdocs-gen-files runs this file (runpy, "<run_path>"); the tests import it as ``gen_reference`` for the pages
if __name__ != "gen_reference":
    write()
