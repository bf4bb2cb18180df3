"""Versioned JSON documents: format and version checks, one-line errors naming the file."""

from __future__ import annotations

import pytest

from carto.framework.errors import InputError
from carto.framework.files.documents import read_json_document, write_json_atomic


def test_versioned_documents_are_checked(tmp_path):
    path = write_json_atomic(tmp_path / "d.json", {"format": "x", "version": 2, "a": 1})
    assert read_json_document(path, "x", 2, "thing")["a"] == 1
    with pytest.raises(InputError, match=r"d\.json: not a Carto thing: field 'format' is 'x'"):
        read_json_document(path, "y", 2, "thing")
    with pytest.raises(InputError, match="thing version 2 is not supported"):
        read_json_document(path, "x", 3, "thing")
    (tmp_path / "l.json").write_text("[1]")
    with pytest.raises(InputError, match=r"l\.json: not a Carto thing: a JSON object expected"):
        read_json_document(tmp_path / "l.json", "x", 2, "thing")
    (tmp_path / "e.json").write_text("[1")
    with pytest.raises(InputError, match=r"e\.json: not a JSON thing"):
        read_json_document(tmp_path / "e.json", "x", 2, "thing")
    with pytest.raises(InputError, match="cannot read thing"):
        read_json_document(tmp_path / "missing.json", "x", 2, "thing")


def test_a_configuration_that_is_not_an_object_is_a_one_line_error(run_carto, tmp_path):
    config = tmp_path / "pair.json"
    config.write_text("[1, 2]")
    res = run_carto(["adjust", str(config), "--out", str(tmp_path / "o"), "--quiet"])
    assert res.returncode == 1
    assert "a configuration is a JSON object, got list" in res.stderr
    assert "Traceback" not in res.stderr
    (tmp_path / "bad.json").write_text("{")
    res = run_carto(["adjust", str(tmp_path / "bad.json"), "--out", str(tmp_path / "o")])
    assert "not a JSON configuration" in res.stderr
