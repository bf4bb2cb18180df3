"""The record of a run in report.json (issue 34 item 1): inputs hashed with SHA-256 (checked
against hashlib), large ones by size and time, folders file by file, nothing walked that is
not an input (a calibration given as one path was taken letter by letter and '/' walked)."""

from __future__ import annotations

import hashlib

from carto.framework.workflows import run_record
from carto.framework.workflows.run_record import input_files, input_record


def test_inputs_are_listed_once_and_hashed(tmp_path, monkeypatch) -> None:
    folder = tmp_path / "scene"
    folder.mkdir()
    (folder / "b.txt").write_text("bbb")
    (folder / "a.txt").write_text("aa")
    single = tmp_path / "one.csv"
    single.write_text("x,y\n")
    files = input_files([folder, None, single, folder / "a.txt", tmp_path / "missing"])
    assert [f.name for f in files] == ["a.txt", "b.txt", "one.csv"]
    entry = input_record(single)
    assert entry["sha256"] == hashlib.sha256(b"x,y\n").hexdigest()
    assert entry["size_bytes"] == 4
    monkeypatch.setattr(run_record, "HASH_LIMIT_BYTES", 3)
    large = input_record(single)
    assert "sha256" not in large
    assert large["mtime_utc"].endswith("+00:00")


def test_a_folder_of_thousands_of_files_is_not_walked_file_by_file(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(run_record, "MAX_FOLDER_FILES", 3)
    for k in range(5):
        (tmp_path / f"{k}.txt").write_text(str(k))
    assert input_files([tmp_path]) == []
