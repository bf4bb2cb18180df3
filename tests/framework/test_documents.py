"""Versioned JSON documents: format and version checks, one-line errors naming the file."""

from __future__ import annotations

import pytest

from carto.framework.documents import read_json_document, write_json_atomic
from carto.framework.errors import InputError


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
