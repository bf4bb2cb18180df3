"""``--config FILE``: a command's settings from a JSON or YAML file, and ``used_config.json``,
the settings a run used (issue 34 item 1).

A configuration maps the long option names of the command (``posting``, ``init-dem`` or
``init_dem``) and its positional arguments (``scene``, ``source``, ``preset``) to values:
numbers, strings, true/false for flags, lists for options that take several values. Its
settings come first and the command line after them, so an option given on the command line
wins. They go through the same parsing as the command line: the same checks, the same
messages. ``used_config.json`` holds every setting of a run, defaults included, as such a
configuration (input paths absolute); ``carto dem --config OUT/used_config.json --out OTHER``
runs the same DEM again. Left out of it: where the output goes and how the work is run
(``--out``, ``--resume``, ``--workers``, ``--scheduler``, ``--quiet``, ``--verbose``,
``--log-file``), which do not change the results.
"""

from __future__ import annotations

import argparse
import difflib
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from carto.framework.errors import UsageError

__all__ = ["FORMAT", "add_config_option", "parse_with_config", "used_config"]

FORMAT = "carto-used-config"
"""The ``format`` field of ``used_config.json``."""

NOT_RECORDED = frozenset(
    {
        "config", "out", "resume", "workers", "scheduler", "quiet", "verbose", "log_file",
        "help", "debug",
    }
)  # fmt: skip
"""Options that say where the output goes or how the work runs, not what it is."""


def add_config_option(p: argparse.ArgumentParser, command: str) -> None:
    """``--config FILE`` on the parser of ``command``."""
    p.add_argument(
        "--config",
        metavar="FILE",
        help="settings from a JSON or YAML file (long option names as keys, e.g. "
        '{"posting": 5, "init-dem": "srtm.hgt"}; a run\'s used_config.json); options on the '
        "command line win",
    )
    p.set_defaults(config_parser=p, config_command=command)


def parse_with_config(parser: argparse.ArgumentParser, argv: Sequence[str]) -> argparse.Namespace:
    """Parse ``argv``; with ``--config``, with the file's settings before the command line's
    options (see the module docstring)."""
    argv = list(argv)
    at, command, sub = _command(parser, argv)
    path = _config_path(argv[at + 1 :]) if sub is not None else None
    if path is None or command is None or sub is None:
        return parser.parse_args(argv)
    tokens = _tokens(sub, read_config(Path(path), command), path, command)
    return parser.parse_args([*argv[: at + 1], *tokens, *argv[at + 1 :]])


def _command(
    parser: argparse.ArgumentParser, argv: list[str]
) -> tuple[int, str | None, argparse.ArgumentParser | None]:
    """Where the sub-command is in ``argv`` (the first word that is not an option: the
    global options take no value), its name and its parser when it takes ``--config``."""
    for at, word in enumerate(argv):
        if word.startswith("-"):
            continue
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction) and word in action.choices:
                sub = action.choices[word]
                takes = any("--config" in a.option_strings for a in sub._actions)
                return at, word, sub if takes else None
        return at, None, None
    return 0, None, None


def _config_path(words: list[str]) -> str | None:
    """The value of the last ``--config`` in ``words`` (None: none, or no value: the parser
    says so)."""
    path = None
    for k, word in enumerate(words):
        if word == "--config" and k + 1 < len(words):
            path = words[k + 1]
        elif word.startswith("--config="):
            path = word.split("=", 1)[1]
    return path


def read_config(path: Path, command: str) -> dict[str, Any]:
    """The settings of a configuration file (JSON, or YAML for ``.yaml``/``.yml``); a
    ``used_config.json`` of another command is refused."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"--config {path}: cannot be read ({exc})") from exc
    try:
        if path.suffix.lower() in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(text)
        else:
            data = json.loads(text)
    except Exception as exc:
        cause = " ".join(str(exc).split())
        raise UsageError(f"--config {path}: not valid JSON or YAML ({cause})") from exc
    if isinstance(data, Mapping) and data.get("format") == FORMAT:
        if data.get("command") != command:
            raise UsageError(
                f"--config {path}: the settings of carto {data.get('command')}, not of carto "
                f"{command}"
            )
        data = data.get("settings")
    if not isinstance(data, Mapping):
        raise UsageError(f"--config {path}: expected a mapping of option names to values")
    return dict(data)


def _actions(sub: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    """The command's arguments by setting name: long option names without dashes, and the
    positional arguments' names."""
    out: dict[str, argparse.Action] = {}
    for action in sub._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        if not action.option_strings:
            out[action.dest] = action
            continue
        for option in action.option_strings:
            if option.startswith("--"):
                out.setdefault(option[2:], action)
    return out


def _tokens(
    sub: argparse.ArgumentParser, settings: Mapping[str, Any], path: str, command: str
) -> list[str]:
    """Command-line tokens of ``settings``: options first, then positional arguments (set
    as the parser's defaults, so that the command line's own win)."""
    actions = _actions(sub)
    tokens: list[str] = []
    for key, value in settings.items():
        name = str(key).replace("_", "-")
        action = actions.get(name) or actions.get(str(key))
        if action is None or action.dest in ("config", "help"):
            close = difflib.get_close_matches(name, list(actions), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise UsageError(f"--config {path}: carto {command} has no setting {key!r}{hint}")
        if value is None:
            continue
        if not action.option_strings:
            action.default = str(value)
            if action.nargs is None:
                action.nargs = "?"
            continue
        tokens += _option_tokens(action, name, value, path)
    return tokens


def _option_tokens(action: argparse.Action, name: str, value: Any, path: str) -> list[str]:
    option = f"--{name}"
    if isinstance(action, argparse._CountAction):  # -v -v
        return [option] * int(value)
    if action.nargs == 0:  # a flag
        if not isinstance(value, bool):
            raise UsageError(f"--config {path}: {name} is a flag: true or false, got {value!r}")
        flag_on = isinstance(action, argparse._StoreTrueAction)
        return [option] if value == flag_on else []
    values = value if isinstance(value, list | tuple) else [value]
    if isinstance(action, argparse._AppendAction):
        return [t for v in values for t in (option, _text(v))]
    return [option, *(_text(v) for v in values)]


def _text(value: Any) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, list | tuple) and len(value) == 2:  # NAME=VALUE pairs
        return f"{value[0]}={value[1]}"
    return str(value)


def used_config(args: argparse.Namespace) -> dict[str, Any] | None:
    """The ``used_config.json`` document of a parsed command (None for a command without
    ``--config``): every setting, defaults included, input paths made absolute."""
    sub = getattr(args, "config_parser", None)
    if sub is None:
        return None
    settings: dict[str, Any] = {}
    for name, action in _actions(sub).items():
        if action.dest in NOT_RECORDED or name != _primary(action):
            continue
        value = getattr(args, action.dest, None)
        if value is None:
            continue
        settings[name] = _json_value(value)
    return {"format": FORMAT, "version": 1, "command": args.config_command, "settings": settings}


def _primary(action: argparse.Action) -> str:
    longs = [o[2:] for o in action.option_strings if o.startswith("--")]
    return longs[0] if longs else action.dest


def _json_value(value: Any) -> Any:
    if isinstance(value, list | tuple):
        return [_json_value(v) for v in value]
    if isinstance(value, str) and value and os.path.exists(value):
        return str(Path(value).resolve())
    if isinstance(value, bool | int | float | str):
        return value
    return str(value)
