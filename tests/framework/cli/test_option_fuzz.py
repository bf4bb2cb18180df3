"""Fuzzing the command line's option values (issue 31, family 4): any text given to any
option of any command either parses or is a usage error (``SystemExit(2)`` with a message
naming the option), never a traceback; numbers that parse are finite."""

from __future__ import annotations

import argparse
import contextlib
import io
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carto.framework.cli import build_parser


def _options() -> list[tuple[str, str, argparse.Action]]:
    """Every ``(command, option, action)`` of the parser that takes a value."""
    found = []
    parser = build_parser()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for command, sub in action.choices.items():
                for option in sub._actions:
                    if option.option_strings and option.nargs != 0:
                        found.append((command, option.option_strings[-1], option))
    return found


OPTIONS = _options()
VALUES = st.text(max_size=12) | st.sampled_from(
    ["-1", "0", "nan", "inf", "-inf", "1e308", "1e-320", "--", "1,2", " 3", "0x10", "٣"]
)


def test_every_command_has_options_to_fuzz() -> None:
    commands = {c for c, _o, _a in OPTIONS}
    assert {"dem", "adjust", "simulate", "evaluate"} <= commands
    assert len(OPTIONS) > 40


@settings(max_examples=300, deadline=None)
@given(case=st.sampled_from(OPTIONS), value=VALUES)
def test_any_option_value_parses_or_is_a_usage_error(case, value) -> None:
    command, option, action = case
    n = action.nargs if isinstance(action.nargs, int) else 1
    argv = [command, f"{option}={value}"] if n == 1 else [command, option, *[value] * n]
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            parsed = build_parser().parse_known_args(argv)[0]
    except SystemExit as exc:
        code = exc.code
    else:
        code = 0
    if code:
        assert code == 2
        assert "Traceback" not in err.getvalue()
        assert option in err.getvalue() or command in err.getvalue()
        return
    got = getattr(parsed, action.dest)
    for item in got if isinstance(got, list | tuple) else [got]:
        if isinstance(item, float) and action.type is not None and value.strip() != "":
            assert math.isfinite(item), (option, value, item)


@pytest.mark.parametrize("value", ["-1", "0", "nan", "1e999"])
def test_workers_must_be_a_positive_whole_number(value, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(["dem", "scene", "--workers", value, "--out", "x"])
    assert exc.value.code == 2
    assert "--workers" in capsys.readouterr().err
