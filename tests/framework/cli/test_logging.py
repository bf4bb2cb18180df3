"""How much a command says (issue 34 item 5): -q, -v, -vv and --log-file through the standard
logging module, GDAL's messages (rasterio's loggers) included."""

from __future__ import annotations

import logging

import pytest

ARGS = ["simulate", "cartosat1-pair", "--size", "150", "150", "--terrain", "plains"]


def test_quiet_with_a_log_file_keeps_everything_in_the_file(run_carto, tmp_path):
    log = tmp_path / "run.log"
    proc = run_carto([*ARGS, "--out", str(tmp_path / "s"), "-q", "--log-file", str(log)])
    assert proc.returncode == 0, proc.stderr
    assert "carto simulate:" not in proc.stderr  # quiet on the terminal
    text = log.read_text()
    assert " INFO carto.simulate: " in text  # the progress lines, time-stamped
    assert " DEBUG rasterio" in text  # GDAL through rasterio's loggers
    assert " DEBUG carto.simulate: " in text  # carto's details


def test_v_shows_carto_details_and_vv_the_libraries(run_carto, tmp_path):
    one = run_carto([*ARGS, "--out", str(tmp_path / "a"), "-v"])
    assert one.returncode == 0, one.stderr
    assert "carto: DEBUG carto.simulate: " in one.stderr
    assert "DEBUG rasterio" not in one.stderr
    assert one.stderr.count("carto simulate: ") >= 3  # progress lines once, not twice
    assert "INFO carto.simulate" not in one.stderr
    two = run_carto([*ARGS, "--out", str(tmp_path / "b"), "-vv"])
    assert two.returncode == 0, two.stderr
    assert "DEBUG rasterio" in two.stderr


def test_an_unwritable_log_file_is_a_usage_error(run_carto, tmp_path):
    proc = run_carto(
        [*ARGS, "--out", str(tmp_path / "s"), "--log-file", str(tmp_path / "no" / "x.log")]
    )
    assert proc.returncode == 2
    assert "--log-file" in proc.stderr
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("flags", [["-v", "--log-file", "{tmp}/l.log"], ["-q"]])
def test_logging_is_put_back_after_an_in_process_run(tmp_path, flags):
    import rasterio  # noqa: F401 (its import adds a NullHandler to its logger)

    from carto.framework.cli import main

    before = [(n, logging.getLogger(n).level, list(logging.getLogger(n).handlers))
              for n in ("carto", "rasterio")]  # fmt: skip
    flags = [f.format(tmp=tmp_path) for f in flags]
    assert main([*ARGS, "--out", str(tmp_path / "s"), *flags]) == 0
    after = [(n, logging.getLogger(n).level, list(logging.getLogger(n).handlers))
             for n in ("carto", "rasterio")]  # fmt: skip
    assert after == before


@pytest.mark.parametrize("to_file", [True, False])
def test_a_local_cluster_does_not_silence_carto(tmp_path, to_file, capsys):
    """dask's LocalCluster sets the stream handlers of the ``distributed`` logger to WARNING;
    the handler carto shares with it must keep carto's details (``carto demo --log-file``
    stopped writing them at its first local cluster)."""
    import argparse

    from distributed import LocalCluster

    from carto.framework.cli.logging_setup import command_logging

    # --log-file FILE, or -vv (the terminal's handler is then the libraries' too)
    log_file = tmp_path / "l.log" if to_file else None
    args = argparse.Namespace(verbose=0 if to_file else 2, log_file=log_file)
    log = logging.getLogger("carto.test")
    with command_logging(args):
        with LocalCluster(n_workers=1, processes=False, dashboard_address=None):
            log.debug("inside the cluster")
        log.debug("after the cluster")
    text = log_file.read_text() if log_file else capsys.readouterr().err
    assert "inside the cluster" in text
    assert "after the cluster" in text
