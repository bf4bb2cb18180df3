"""``carto plugins``: what is installed, for people and machines."""

from __future__ import annotations

import argparse
import inspect
import json
import textwrap

import attrs

from carto.framework import __version__
from carto.framework.cli.common import examples, formatter, table
from carto.framework.errors import PluginError
from carto.framework.plugins.registry import KINDS, ComponentInfo, get_registry


# --------------------------------------------------------------------------- carto plugins
def _component_details(info: ComponentInfo) -> dict[str, str]:
    obj = info.component
    doc = inspect.getdoc(type(obj)) or ""
    return {
        **info.as_dict(),
        "class": f"{type(obj).__module__}.{type(obj).__qualname__}",
        "documentation": doc,
    }


def cmd_plugins(args: argparse.Namespace) -> int:
    registry = get_registry()
    kinds = [args.kind] if args.kind else list(KINDS)
    if args.name:
        details = [_component_details(c) for c in registry.find(args.name, args.kind)]
        if args.json:
            print(json.dumps(details, indent=2))
        else:
            for d in details:
                for key in ("kind", "name", "distribution", "version", "plugin", "class"):
                    print(f"{key + ':':14}{d[key]}")
                print(f"{'description:':14}{d['description']}")
                if d["documentation"]:
                    print()
                    print(textwrap.indent(d["documentation"], "  "))
                print()
        return 0
    components = [c for k in kinds for c in registry.components(k)]
    if args.json:
        document = {
            "carto_framework_version": __version__,
            "components": [c.as_dict() for c in components],
            "plugins": [attrs.asdict(p) for p in registry.plugins],
            "broken": [attrs.asdict(b) for b in registry.broken],
        }
        print(json.dumps(document, indent=2))
    else:
        rows = [(c.kind, c.name, c.distribution, c.version, c.description) for c in components]
        if rows:
            print(table(rows, ("KIND", "NAME", "DISTRIBUTION", "VERSION", "DESCRIPTION")))
        else:
            print("no components registered" + (f" of kind {args.kind}" if args.kind else ""))
        print()
        loaded = ", ".join(f"{p.name} ({p.distribution} {p.version})" for p in registry.plugins)
        print("plugins loaded: " + (loaded or "none"))
        if registry.broken:
            print()
            print("broken plugins (skipped):")
            for b in registry.broken:
                print(f"  {b.one_line()}")
    if registry.broken:
        names = ", ".join(sorted({b.name for b in registry.broken}))
        raise PluginError(f"{len(registry.broken)} plugin problem(s): {names}")
    return 0


def add_plugins(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "plugins",
        help="list installed plugins and the components they register",
        description=(
            "List every registered component (sensor types, trajectory models, adjusters,\n"
            "matchers, DEM generators, scene presets) with the distribution that provides it,\n"
            "then the plugins that failed to load and why. Exits 1 when any plugin is broken."
        ),
        epilog=examples(
            "carto plugins",
            "carto plugins --kind matcher",
            "carto plugins --json | python -m json.tool",
            "carto plugins example-shift          # details of one component",
        ),
        formatter_class=formatter,
    )
    p.add_argument("name", nargs="?", help="show the details of the component of this name")
    p.add_argument("--kind", choices=list(KINDS), help="list only this kind of component")
    p.add_argument("--json", action="store_true", help="print JSON for machines")
    p.set_defaults(handler=cmd_plugins, needs_registry=False)
