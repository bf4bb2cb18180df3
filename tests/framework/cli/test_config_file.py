"""``--config FILE`` and ``used_config.json`` (issue 34 item 1): a command's settings from a
JSON or YAML file, parsed as the command line is, the command line winning."""

from __future__ import annotations

import json

import pytest

from carto.framework.cli import build_parser
from carto.framework.cli.config_file import parse_with_config, used_config
from carto.framework.errors import UsageError


def _parse(argv):
    return parse_with_config(build_parser(), argv)


def test_a_yaml_file_sets_options_and_the_command_line_wins(tmp_path):
    config = tmp_path / "dem.yaml"
    config.write_text("scene: s1\nposting: 5\ninit_height: 300\nmatcher: ncc\nallow-poor: true\n")
    args = _parse(["dem", "--config", str(config), "--out", "o", "--posting", "20"])
    assert args.scene == "s1"
    assert args.posting == 20.0  # the command line's
    assert args.init_height == 300.0
    assert args.matcher == "ncc"
    assert args.allow_poor is True
    # a positional argument on the command line wins over the file's
    assert _parse(["dem", "s2", "--config", str(config), "--out", "o"]).scene == "s2"


def test_a_json_file_for_simulate_with_lists_and_pairs(tmp_path):
    config = tmp_path / "sim.json"
    config.write_text(
        json.dumps(
            {"preset": "cartosat1-pair", "size": [300, 400], "error-size": [["jitter_deg", 0]]}
        )
    )
    args = _parse(["simulate", "--config", str(config), "--out", "o"])
    assert args.preset == "cartosat1-pair"
    assert args.size == [300, 400]
    assert args.error_size == [("jitter_deg", 0.0)]
    document = used_config(args)
    assert document["command"] == "simulate"
    assert document["settings"]["size"] == [300, 400]
    assert document["settings"]["seed"] == 0  # defaults included
    assert "out" not in document["settings"]
    again = tmp_path / "used.json"
    again.write_text(json.dumps(document))
    replayed = _parse(["simulate", "--config", str(again), "--out", "o"])
    assert used_config(replayed) == document


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('{"postng": 5}', "carto dem has no setting 'postng' (did you mean 'posting'?)"),
        ("[1, 2]", "expected a mapping of option names to values"),
        ('{"allow-poor": "yes"}', "allow-poor is a flag: true or false"),
        ("{not json", "not valid JSON or YAML"),
        (
            '{"format": "carto-used-config", "command": "adjust", "settings": {}}',
            "the settings of carto adjust, not of carto dem",
        ),
    ],
)
def test_bad_configurations_are_usage_errors_naming_the_file(tmp_path, text, message):
    config = tmp_path / "bad.json"
    config.write_text(text)
    with pytest.raises(UsageError, match=r"--config .*bad\.json") as caught:
        _parse(["dem", "scene", "--config", str(config), "--out", "o"])
    assert message in str(caught.value)


def test_a_value_the_option_refuses_gets_the_command_line_message(tmp_path, capsys):
    config = tmp_path / "c.json"
    config.write_text('{"max-iterations": 0}')
    with pytest.raises(SystemExit) as stop:
        _parse(["dem", "scene", "--config", str(config), "--out", "o"])
    assert stop.value.code == 2
    assert "--max-iterations: must be >= 1, got 0" in capsys.readouterr().err


def test_the_cli_exits_2_on_a_bad_configuration(run_carto, tmp_path):
    config = tmp_path / "c.json"
    config.write_text('{"postng": 5}')
    proc = run_carto(["dem", "scene", "--config", str(config), "--out", str(tmp_path / "o")])
    assert proc.returncode == 2
    assert "has no setting 'postng'" in proc.stderr
    assert "Traceback" not in proc.stderr
