"""The corpus of issue #15 (items 2-5 and the DIMAP ``LAST_COL`` variant) through the ``carto``
command: every bad input ends with exit 1 (bad data) or 2 (usage) and a single
``carto: error:`` line naming the file and the field or value, never a traceback, an internal
error or a silent exit 0, and ``--out`` is not created; the inputs that are merely unusual
(a GCP table with a UTF-8 BOM, undeclared voids in a DEM, a DIMAP retina one column wider than
the image) work. No library chatter (RuntimeWarnings, GDAL lines) reaches stderr.

The cases not repeated here are in ``test_bad_input.py`` (``--workers 0``,
``--init-height 1e7``, swapped lat/lon, a GCP outside its image or given twice, configuration
image entries). Cases are built from one simulated Cartosat-1 scene (``cartosat1_scene``: a
variant links every file of it but the edited ones) and from ``../shared/data``; the commands
run in this process (``carto.framework.cli.main``) with the file descriptors captured, so
that GDAL's C-level messages would be seen too.
"""

from __future__ import annotations

import csv
import json
import re
import shutil
import subprocess
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from .test_bad_input import one_line_error

REUNION = "pleiades-reunion-pair"
IKONOS = "rpc-files/rpc_IKONOS.txt"
DIMAP = "pleiades-dimap-algeria/PHRDIMAP_P1BP--2018122638935449CP.XML"
GEOID = "geoid/egm96_15.gtx"
Run = Callable[[list[str]], subprocess.CompletedProcess[str]]


# --------------------------------------------------------------------------- helpers
@pytest.fixture
def carto(capfd: pytest.CaptureFixture[str]) -> Run:
    """``carto ARGS`` in this process; stdout/stderr captured at the file descriptors."""
    from carto.framework.cli import main

    def run(args: list[str]) -> subprocess.CompletedProcess[str]:
        capfd.readouterr()
        try:
            code = main([str(a) for a in args])
        except SystemExit as exc:  # argparse
            code = int(exc.code or 0)
        out, err = capfd.readouterr()
        return subprocess.CompletedProcess(args, code, out, err)

    return run


def no_leaks(res: subprocess.CompletedProcess[str]) -> None:
    """stderr holds Carto's own lines only: no traceback, no internal error, no warning of a
    library (``/path/x.py:12: RuntimeWarning: ...``), no GDAL line."""
    assert "internal error" not in res.stderr, res.stderr
    assert "Traceback" not in res.stderr, res.stderr
    for line in res.stderr.splitlines():
        if not line.strip():
            continue
        assert line.startswith("carto"), ("not a carto line", line, res.stderr)
        assert "Warning:" not in line or line.startswith("carto: warning:"), line


def refused(res: subprocess.CompletedProcess[str], code: int, out: Path, *words: str) -> str:
    """Exit ``code``, one ``carto: error:`` line holding ``words``, no leak, ``out`` absent."""
    line = one_line_error(res, code, *words)
    no_leaks(res)
    assert not out.exists(), f"{out} was created"
    return line


def ok(res: subprocess.CompletedProcess[str]) -> None:
    assert res.returncode == 0, res.stderr
    no_leaks(res)
    assert "carto: error" not in res.stderr, res.stderr


@pytest.fixture
def variant(tmp_path: Path, cartosat1_scene: Path) -> Callable[..., Path]:
    """``variant("gcps.csv", ...)``: a scene folder linking every entry of the scene but the
    named files, which are copied (to be edited)."""

    def make(*edited: str) -> Path:
        folder = tmp_path / "scene"
        folder.mkdir()
        for entry in cartosat1_scene.iterdir():
            if entry.name in edited:
                shutil.copy2(entry, folder / entry.name)
            else:
                (folder / entry.name).symlink_to(entry)
        return folder

    return make


def edit_json(path: Path, edit: Callable[[dict[str, Any]], None]) -> None:
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))


def edit_gcps(path: Path, edit: Callable[[list[list[str]]], None]) -> None:
    rows = list(csv.reader(path.open(newline="")))
    edit(rows)
    with path.open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)


def set_cell(column: str, value: str, row: int = 1) -> Callable[[list[list[str]]], None]:
    def edit(rows: list[list[str]]) -> None:
        rows[row][rows[0].index(column)] = value

    return edit


def write_tif(path: Path, data: np.ndarray, **profile: Any) -> Path:
    import rasterio

    rpc_tags = profile.pop("rpc_tags", None)
    tags = profile.pop("tags", None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(
            path,
            "w",
            driver="GTiff",
            width=data.shape[1],
            height=data.shape[0],
            count=1,
            dtype=data.dtype,
            **profile,
        ) as dst:
            dst.write(data[None])
            if rpc_tags:
                dst.update_tags(ns="RPC", **rpc_tags)
            if tags:
                dst.update_tags(**tags)
    return path


def ground_csv(path: Path, points: list[tuple[float, float, float]]) -> Path:
    path.write_text(
        "lon_deg,lat_deg,h_m\n" + "".join(f"{lo!r},{la!r},{h!r}\n" for lo, la, h in points)
    )
    return path


# --------------------------------------------------------------------------- RPC models
def _ikonos_layout(rpc: Any) -> str:
    """``rpc`` as an ``_RPC.TXT`` in the IKONOS / Cartosat orthokit layout (every coefficient
    ``+d.dddddddddddddddE+dd``)."""
    units = {"LINE": "pixels", "SAMP": "pixels", "LAT": "degrees", "LONG": "degrees"}
    lines = []
    for key, value in rpc.as_dict().items():
        if isinstance(value, list):
            lines += [f"{key}_{i}: {v:+.15E}" for i, v in enumerate(value, 1)]
        else:
            lines.append(f"{key}: {value:+.8f} {units.get(key.split('_')[0], 'meters')}")
    return "\n".join(lines) + "\n"


def _set(key: str, value: str) -> Callable[[str], str]:
    def edit(text: str) -> str:
        out, n = re.subn(rf"^{key}: [^\n]*$", f"{key}: {value}", text, flags=re.M)
        assert n == 1, key
        return out

    return edit


def _cut_last(text: str) -> str:
    """Cut inside the value of the last coefficient, then a line break (an editor's save)."""
    at = text.index("SAMP_DEN_COEFF_20") + len("SAMP_DEN_COEFF_20: +1.9296")
    return text[:at] + "\r\n"


def _exponent(text: str) -> str:
    """LINE_NUM_COEFF_2 (the dominant term) with its exponent raised by 3."""
    line = re.search(r"^LINE_NUM_COEFF_2: [^\n]*$", text, flags=re.M)
    assert line is not None
    value = float(line.group(0).split(":")[1])
    return _set("LINE_NUM_COEFF_2", f"{value * 1e3:+.15E}")(text)


RPC_TEXT_CASES = {
    "cut-in-last-coefficient": (_cut_last, ("SAMP_DEN_COEFF_20", "truncated")),
    "second-LINE_OFF": (
        lambda t: t + "LINE_OFF: +000100.00 pixels\n",
        ("duplicate key LINE_OFF",),
    ),
    "LAT_OFF-500": (_set("LAT_OFF", "+500.00000000 degrees"), ("LAT_OFF", "500")),
    "LINE_SCALE-1e308": (_set("LINE_SCALE", "1e308 pixels"), ("LINE_SCALE", "1e+308")),
    "changed-exponent": (_exponent, ("LINE_NUM_COEFF", "longer than wide")),
}


@pytest.fixture(scope="module")
def reunion_rpc_text(shared_data: Path) -> str:
    from carto.framework.geometry.rpc.readers import read_rpc

    return _ikonos_layout(read_rpc(shared_data / REUNION / "img_01.tif"))


@pytest.mark.realdata
@pytest.mark.parametrize("case", sorted(RPC_TEXT_CASES))
def test_corrupt_rpc_text_project(carto: Run, tmp_path: Path, shared_data: Path, case: str) -> None:
    """``carto project`` of a damaged Cartosat-style (IKONOS layout) ``_RPC.TXT``."""
    edit, words = RPC_TEXT_CASES[case]
    bad = tmp_path / "scene_RPC.TXT"
    bad.write_bytes(edit((shared_data / IKONOS).read_bytes().decode("latin-1")).encode("latin-1"))
    ground = ground_csv(tmp_path / "g.csv", [(-56.1722, -34.903, 28.0)])
    res = carto(["project", bad, "--ground", ground, "--out", tmp_path / "o.csv"])
    refused(res, 1, tmp_path / "o.csv", str(bad), *words)


@pytest.mark.realdata
@pytest.mark.parametrize("case", sorted(RPC_TEXT_CASES))
def test_corrupt_rpc_text_dem(
    carto: Run, tmp_path: Path, shared_data: Path, reunion_rpc_text: str, case: str
) -> None:
    """``carto dem --left/--right`` with a damaged ``_RPC.TXT`` of the left image."""
    edit, words = RPC_TEXT_CASES[case]
    bad = tmp_path / "img_01_RPC.TXT"
    bad.write_text(edit(reunion_rpc_text))
    res = carto(
        [
            "dem",
            "--left",
            shared_data / REUNION / "img_01.tif",
            "--left-model",
            bad,
            "--right",
            shared_data / REUNION / "img_02.tif",
            "--init-height",
            "2320",
            "--out",
            tmp_path / "o",
            "--quiet",
        ]
    )
    refused(res, 1, tmp_path / "o", str(bad), *words)


@pytest.fixture(scope="module")
def reunion_crop(shared_data: Path) -> tuple[np.ndarray, dict[str, str]]:
    """A 200 x 200 px crop of img_01 (pixels, RPC tags of the crop)."""
    import rasterio
    from rasterio.windows import Window

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with rasterio.open(shared_data / REUNION / "img_01.tif") as ds:
            data = ds.read(1, window=Window(400, 400, 200, 200))
            tags = ds.tags(ns="RPC")
    tags["LINE_OFF"] = repr(float(tags["LINE_OFF"]) - 400)
    tags["SAMP_OFF"] = repr(float(tags["SAMP_OFF"]) - 400)
    return data, tags


GARBAGE_TAGS = {
    "LINE_NUM_COEFF--4e233": (
        {"LINE_NUM_COEFF": "-4e233 " + "0 " * 19},
        ("LINE_NUM_COEFF_1", "-4e+233"),
    ),
    "HEIGHT_SCALE-text": ({"HEIGHT_SCALE": "garbage"}, ("HEIGHT_SCALE",)),
    "LAT_OFF-123": ({"LAT_OFF": "123"}, ("LAT_OFF", "123")),
}


@pytest.mark.realdata
@pytest.mark.parametrize("case", sorted(GARBAGE_TAGS))
@pytest.mark.parametrize("command", ["dem", "project"])
def test_garbage_rpc_tag_in_a_geotiff(
    carto: Run, tmp_path: Path, shared_data: Path, reunion_crop: Any, case: str, command: str
) -> None:
    data, tags = reunion_crop
    changes, words = GARBAGE_TAGS[case]
    bad = write_tif(tmp_path / "crop.tif", data, rpc_tags={**tags, **changes})
    if command == "dem":
        args = ["dem", "--left", bad, "--right", shared_data / REUNION / "img_02.tif"]
        args += ["--init-height", "2320", "--quiet"]
        out = tmp_path / "o"
    else:
        args = ["project", bad, "--ground", ground_csv(tmp_path / "g.csv", [(55.7, -21.2, 2300.0)])]
        out = tmp_path / "o.csv"
    refused(carto([*args, "--out", out]), 1, out, str(bad), *words)


@pytest.mark.realdata
def test_rpc_projection_far_outside_the_image_is_nan(
    carto: Run, tmp_path: Path, shared_data: Path
) -> None:
    """10 E 10 N on the 1024 x 1024 Reunion product: nan, counted; the inside point is not."""
    from carto.framework.geometry.rpc.readers import read_rpc

    image = shared_data / REUNION / "img_01.tif"
    rpc = read_rpc(image)
    lon, lat = (float(v) for v in rpc.locate(512.0, 512.0, rpc.height_off))
    ground = ground_csv(tmp_path / "g.csv", [(lon, lat, rpc.height_off), (10.0, 10.0, 0.0)])
    res = carto(["project", image, "--ground", ground, "--out", tmp_path / "o.csv"])
    ok(res)
    assert "(1 outside the image or not converged: nan)" in res.stdout, res.stdout
    rows = list(csv.DictReader((tmp_path / "o.csv").open()))
    assert abs(float(rows[0]["line"]) - 512.0) < 1e-3
    assert np.isnan(float(rows[1]["line"]))
    assert np.isnan(float(rows[1]["sample"]))


# --------------------------------------------------------------------------- item 5: opening
@pytest.mark.realdata
def test_project_says_why_a_file_is_not_a_model(
    carto: Run, tmp_path: Path, shared_data: Path
) -> None:
    ground = ground_csv(tmp_path / "g.csv", [(55.7, -21.2, 2300.0)])
    out = tmp_path / "o.csv"
    folder = tmp_path / "folder"
    folder.mkdir()
    cut = tmp_path / "cut.tif"
    cut.write_bytes((shared_data / REUNION / "img_01.tif").read_bytes()[:300])
    plain = write_tif(tmp_path / "plain.tif", np.zeros((8, 8), np.uint8))
    cases = [
        (folder, ("is a folder",)),
        (cut, ("GDAL cannot open it",)),
        (plain, ("has no RPC metadata",)),
    ]
    for model, words in cases:
        res = carto(["project", model, "--ground", ground, "--out", out])
        line = refused(res, 1, out, str(model), *words)
        assert "no sensor type recognises this file (known" not in line, line


@pytest.mark.realdata
def test_dem_on_a_tiff_truncated_inside_its_pixels(
    carto: Run, tmp_path: Path, shared_data: Path
) -> None:
    """The header and the RPC tag survive, the pixels do not: the raster is named."""
    src = shared_data / REUNION / "img_01.tif"
    cut = tmp_path / "img_01.tif"
    cut.write_bytes(src.read_bytes()[: src.stat().st_size // 2])
    res = carto(
        [
            "dem",
            "--left",
            cut,
            "--right",
            shared_data / REUNION / "img_02.tif",
            "--init-height",
            "2320",
            "--out",
            tmp_path / "o",
            "--quiet",
        ]
    )
    refused(res, 1, tmp_path / "o", str(cut))


@pytest.mark.realdata
def test_geom_with_negative_number_lines(carto: Run, tmp_path: Path, shared_data: Path) -> None:
    src = shared_data / "pleiades-ventoux-pair" / "left_image.geom"
    bad = tmp_path / "left_image.geom"
    bad.write_text(re.sub(r"number_lines:\s+\d+", "number_lines:  -5", src.read_text()))
    ground = ground_csv(tmp_path / "g.csv", [(5.19, 44.21, 500.0)])
    res = carto(["project", bad, "--ground", ground, "--out", tmp_path / "o.csv"])
    refused(res, 1, tmp_path / "o.csv", str(bad), "number_lines", "-5")


@pytest.mark.realdata
@pytest.mark.parametrize("name", ["rpc-files/rpc_WV2.xml", "rpc-files/rpc_PLEIADES.xml", DIMAP])
def test_xml_model_with_an_unknown_encoding(
    carto: Run, tmp_path: Path, shared_data: Path, name: str
) -> None:
    src = shared_data / name
    bad = tmp_path / src.name
    text = src.read_text(encoding="utf-8")
    bad.write_text(text.replace('encoding="UTF-8"', 'encoding="klingon"', 1), encoding="utf-8")
    ground = ground_csv(tmp_path / "g.csv", [(2.23, 30.5, 300.0)])
    res = carto(["project", bad, "--ground", ground, "--out", tmp_path / "o.csv"])
    refused(res, 1, tmp_path / "o.csv", str(bad), "klingon")


@pytest.mark.realdata
def test_dimap_retina_one_column_wider_is_read(
    carto: Run, tmp_path: Path, shared_data: Path
) -> None:
    """``LAST_COL`` = ``NCOLS`` + 1: read (a warning at most), projects as the original."""
    src = shared_data / DIMAP
    wider = tmp_path / src.name
    wider.write_text(
        src.read_text(encoding="utf-8").replace(
            "<LAST_COL>40000</LAST_COL>", "<LAST_COL>40001</LAST_COL>"
        ),
        encoding="utf-8",
    )
    ground = ground_csv(tmp_path / "g.csv", [(2.23, 30.5, 300.0)])
    res = carto(["project", src, "--ground", ground, "--out", tmp_path / "a.csv"])
    ok(res)
    res = carto(["project", wider, "--ground", ground, "--out", tmp_path / "b.csv"])
    ok(res)
    for line in res.stderr.splitlines():
        assert "plugin skipped" in line or "LAST_COL" in line, line
    assert (tmp_path / "a.csv").read_text() == (tmp_path / "b.csv").read_text()


# --------------------------------------------------------------------------- ancillary data
def _bad_quaternion(doc: dict[str, Any]) -> None:
    doc["attitude"]["quaternion_wxyz"][300] = [0.9, 0.3, 0.2, 0.1]  # |q| = 0.99


def _zero_quaternion(doc: dict[str, Any]) -> None:
    doc["attitude"]["quaternion_wxyz"][1] = [0.0, 0.0, 0.0, 0.0]


def _kilometres(doc: dict[str, Any]) -> None:
    eph = doc["ephemeris"]
    eph["position_m"] = [[v / 1000.0 for v in p] for p in eph["position_m"]]
    eph["velocity_m_s"] = [[v / 1000.0 for v in p] for p in eph["velocity_m_s"]]


def _late_image(doc: dict[str, Any]) -> None:
    timing = doc["images"]["fore"]["timing"]
    timing["dt_nodes_s"] = [t + 1e4 for t in timing["dt_nodes_s"]]


def _negative_lines(doc: dict[str, Any]) -> None:
    doc["images"]["fore"]["n_lines"] = -5


ANCILLARY_CASES = {
    "bad-quaternion": (_bad_quaternion, ("attitude.quaternion_wxyz", "sample 300")),
    "zero-quaternion": (_zero_quaternion, ("attitude.quaternion_wxyz", "sample 1")),
    "positions-in-km": (_kilometres, ("ephemeris.position_m",)),
    "image-times-outside-the-ephemeris": (_late_image, ("fore", "ephemeris")),
    "n_lines--5": (_negative_lines, ("n_lines", "-5")),
}


@pytest.mark.parametrize("case", sorted(ANCILLARY_CASES))
def test_bad_ancillary_data(carto: Run, tmp_path: Path, variant: Any, case: str) -> None:
    edit, words = ANCILLARY_CASES[case]
    scene = variant("body.ancillary.json")
    edit_json(scene / "body.ancillary.json", edit)
    res = carto(["adjust", scene, "--gcps", "1", "--out", tmp_path / "o", "--quiet"])
    line = refused(res, 1, tmp_path / "o", "body.ancillary.json", *words)
    for misleading in ("do not overlap", "resolution nan", "ortho grid"):
        assert misleading not in line, line


# --------------------------------------------------------------------------- control
def test_gcp_naming_an_unknown_image(carto: Run, tmp_path: Path, variant: Any) -> None:
    scene = variant("gcps.csv")
    edit_gcps(scene / "gcps.csv", set_cell("image", "nadir"))
    res = carto(["adjust", scene, "--out", tmp_path / "o", "--quiet"])
    refused(res, 1, tmp_path / "o", "gcps.csv", "nadir")


def test_gcp_with_negative_sigma_px(carto: Run, tmp_path: Path, variant: Any) -> None:
    scene = variant("gcps.csv")
    edit_gcps(scene / "gcps.csv", set_cell("sigma_px", "-1"))
    res = carto(["adjust", scene, "--out", tmp_path / "o", "--quiet"])
    refused(res, 1, tmp_path / "o", "gcps.csv", "sigma_px", "-1")


def test_scene_whose_image_entry_is_a_number(carto: Run, tmp_path: Path, variant: Any) -> None:
    scene = variant("scene.json")
    edit_json(scene / "scene.json", lambda doc: doc["images"].__setitem__("fore", 5))
    res = carto(["adjust", scene, "--out", tmp_path / "o", "--quiet"])
    refused(res, 1, tmp_path / "o", "scene.json", "images.fore")


def test_gcp_table_with_a_bom_works(
    carto: Run, tmp_path: Path, variant: Any, cartosat1_adjusted: Path
) -> None:
    """A UTF-8 BOM (Excel's "CSV UTF-8") is read: the same adjustment as without it."""
    scene = variant("gcps.csv")
    path = scene / "gcps.csv"
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    res = carto(["adjust", scene, "--gcps", "1", "--out", tmp_path / "o", "--quiet"])
    ok(res)
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    normal = json.loads((cartosat1_adjusted / "report.json").read_text())
    assert report["outliers"] == normal["outliers"]  # the same adjustment
    assert not [o for o in report["outliers"] if not o.startswith("A")]  # no GCP rejected
    assert report["checkpoints"] == pytest.approx(normal["checkpoints"], rel=1e-6)


# --------------------------------------------------------------------------- images
def _image_cases(shape: tuple[int, int]) -> dict[str, tuple[np.ndarray, tuple[str, ...]]]:
    return {
        "all-nan": (np.full(shape, np.nan, np.float32), ("no valid pixels",)),
        "textureless": (np.full(shape, 512, np.uint16), ("no texture", "512")),
        "1x1": (np.full((1, 1), 512, np.uint16), ("1 x 1 pixels",)),
    }


@pytest.mark.parametrize("case", ["all-nan", "textureless", "1x1"])
def test_unusable_left_image(
    carto: Run, tmp_path: Path, variant: Any, cartosat1_adjusted: Path, case: str
) -> None:
    """The left image of the pair (aft, closer to nadir) replaced."""
    import rasterio

    scene = variant("aft.tif")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a raw image: not georeferenced
        with rasterio.open(scene / "aft.tif") as ds:
            shape, tags = ds.shape, ds.tags()
    data, words = _image_cases(shape)[case]
    (scene / "aft.tif").unlink()
    write_tif(scene / "aft.tif", data, tags=tags)
    res = carto(["dem", scene, "--models", cartosat1_adjusted, "--out", tmp_path / "o", "--quiet"])
    line = refused(res, 1, tmp_path / "o", "aft.tif", *words)
    assert "matched" not in line, line


# --------------------------------------------------------------------------- DEMs, geoid
SCENE_TILE = "N30E077.hgt"  # the scene is at 77.95 E, 30.3 N
HGT_SIZE = 1201


def write_hgt(path: Path, heights: np.ndarray) -> Path:
    path.write_bytes(np.asarray(heights).astype(">i2").tobytes())
    return path


def srtm_heights(shared_data: Path) -> np.ndarray:
    """An SRTM3 tile of the scene's area: EGM96 heights of a level plain at the scene's
    ellipsoidal height (about 260 m)."""
    from carto.framework.raster.dem import Geoid

    n = float(Geoid.open(shared_data / GEOID).undulation(77.95, 30.3))
    return np.full((HGT_SIZE, HGT_SIZE), round(260.0 - n), np.int16)


def geotiff_dem(path: Path, heights: np.ndarray, like: Path, **profile: Any) -> Path:
    import rasterio

    with rasterio.open(like) as ds:
        crs, transform, tags = ds.crs, ds.transform, ds.tags()
    return write_tif(path, heights, crs=crs, transform=transform, tags=tags, **profile)


def dem_run(scene: Path, cartosat1_adjusted: Path, out: Path, *extra: Any) -> list[Any]:
    return ["dem", scene, "--models", cartosat1_adjusted, "--out", out, "--quiet", *extra]


@pytest.mark.realdata
@pytest.mark.parametrize(
    "case", ["1x1", "1e30", "all-void-hgt", "misnamed-hgt", "hgt-without-geoid", "zero-geoid"]
)
def test_bad_initial_dem_or_geoid(
    carto: Run,
    tmp_path: Path,
    cartosat1_scene: Path,
    cartosat1_adjusted: Path,
    shared_data: Path,
    case: str,
) -> None:
    like = cartosat1_scene / "init_dem.tif"
    geoid = shared_data / GEOID
    if case == "1x1":
        dem = geotiff_dem(tmp_path / "one.tif", np.full((1, 1), 260.0, np.float32), like)
        extra, words = ["--init-dem", dem], (str(dem), "1 x 1")
    elif case == "1e30":
        dem = geotiff_dem(tmp_path / "huge.tif", np.full((18, 20), 1e30, np.float32), like)
        extra, words = ["--init-dem", dem], (str(dem), "no valid height")
    elif case == "all-void-hgt":
        dem = write_hgt(tmp_path / SCENE_TILE, np.full((HGT_SIZE, HGT_SIZE), -32768))
        extra, words = ["--init-dem", dem, "--geoid", geoid], (str(dem), "no valid height")
    elif case == "misnamed-hgt":
        dem = write_hgt(tmp_path / "N31E077.hgt", srtm_heights(shared_data))
        extra, words = ["--init-dem", dem, "--geoid", geoid], (str(dem), "cover")
    elif case == "hgt-without-geoid":
        dem = write_hgt(tmp_path / SCENE_TILE, srtm_heights(shared_data))
        extra, words = ["--init-dem", dem], (str(dem), "--geoid")
    else:  # a geoid grid (GTX) with zero latitude spacing
        dem = write_hgt(tmp_path / SCENE_TILE, srtm_heights(shared_data))
        bad = tmp_path / "zero.gtx"
        header = np.array([29.0, 76.0, 0.0, 0.25], ">f8").tobytes()
        header += np.array([9, 9], ">i4").tobytes()
        bad.write_bytes(header + np.full(81, -30.0, ">f4").tobytes())
        extra, words = ["--init-dem", dem, "--geoid", bad], (str(bad),)
    out = tmp_path / "o"
    line = refused(carto(dem_run(cartosat1_scene, cartosat1_adjusted, out, *extra)), 1, out, *words)
    assert "do not overlap" not in line, line
    if case == "hgt-without-geoid":
        assert "--geoid GTX" in line, line


def _accuracy(out: Path) -> dict[str, float]:
    return json.loads((out / "report.json").read_text())["accuracy"]


@pytest.fixture(scope="module")
def normal_accuracy(
    tmp_path_factory: pytest.TempPathFactory, cartosat1_scene: Path, cartosat1_adjusted: Path
) -> dict[str, float]:
    """The accuracy of the DEM run of the corpus with the scene's own initial DEM."""
    from carto.framework.cli import main

    out = tmp_path_factory.mktemp("corpus-dem") / "dem"
    args = dem_run(
        cartosat1_scene,
        cartosat1_adjusted,
        out,
        *DEM_RUN,
        "--reference",
        cartosat1_scene / TRUTH_DEM,
    )
    assert main([str(a) for a in args]) == 0
    return _accuracy(out)


DEM_RUN = ["--posting", "20", "--max-iterations", "1"]
TRUTH_DEM = "truth/dem.tif"


def _partly_nan(heights: np.ndarray) -> np.ndarray:
    out = heights.copy()
    out[:6, :6] = np.nan  # a corner, 10 % of the posts
    return out


def test_mostly_void_initial_dem_is_refused(
    carto: Run, tmp_path: Path, cartosat1_scene: Path, cartosat1_adjusted: Path
) -> None:
    """Two thirds void over the images: less than 75 % of their footprint covered, refused
    naming the DEM (the voids are not filled over that much)."""
    import rasterio

    like = cartosat1_scene / "init_dem.tif"
    with rasterio.open(like) as ds:
        heights = ds.read(1)
    heights[:, : 2 * heights.shape[1] // 3] = np.nan
    dem = geotiff_dem(tmp_path / "init.tif", heights, like)
    out = tmp_path / "o"
    res = carto(dem_run(cartosat1_scene, cartosat1_adjusted, out, "--init-dem", dem, *DEM_RUN))
    line = refused(res, 1, out, str(dem), "covers", "footprint")
    assert "do not overlap" not in line, line


def _undeclared_voids(heights: np.ndarray) -> np.ndarray:
    out = heights.copy()
    out[::3, ::2] = -9999.0
    return out


@pytest.mark.parametrize("case", ["partly-nan", "undeclared-9999"])
def test_initial_dem_with_voids_is_measured(
    carto: Run,
    tmp_path: Path,
    cartosat1_scene: Path,
    cartosat1_adjusted: Path,
    normal_accuracy: dict[str, float],
    case: str,
) -> None:
    """Voids (NaN, -9999 without a nodata declaration) are nodata, filled: the DEM is as
    good as with the complete initial DEM (not a "converged" DEM with 60 m RMSE)."""
    import rasterio

    like = cartosat1_scene / "init_dem.tif"
    with rasterio.open(like) as ds:
        heights = ds.read(1)
    edit = _partly_nan if case == "partly-nan" else _undeclared_voids
    dem = geotiff_dem(tmp_path / "init.tif", edit(heights), like)
    out = tmp_path / "o"
    res = carto(
        dem_run(
            cartosat1_scene,
            cartosat1_adjusted,
            out,
            "--init-dem",
            dem,
            *DEM_RUN,
            "--reference",
            cartosat1_scene / TRUTH_DEM,
        )
    )
    ok(res)
    acc = _accuracy(out)
    assert acc["rmse_m"] < max(2.0, 2 * normal_accuracy["rmse_m"]), (acc, normal_accuracy)
    assert abs(acc["median_m"]) < 1.0, acc
    assert acc["completeness"] > 0.8 * normal_accuracy["completeness"], (acc, normal_accuracy)


@pytest.mark.realdata
def test_half_void_hgt(
    carto: Run, tmp_path: Path, cartosat1_scene: Path, cartosat1_adjusted: Path, shared_data: Path
) -> None:
    """An SRTM tile void east of 77.95 E (the scene's centre): refused naming the tile and how
    much of the footprint it covers, not "the images do not overlap"."""
    heights = srtm_heights(shared_data)
    heights[:, int((77.95 - 77.0) * (HGT_SIZE - 1)) :] = -32768
    dem = write_hgt(tmp_path / SCENE_TILE, heights)
    out = tmp_path / "o"
    res = carto(
        dem_run(
            cartosat1_scene,
            cartosat1_adjusted,
            out,
            "--init-dem",
            dem,
            "--geoid",
            shared_data / GEOID,
        )
        + DEM_RUN
    )
    line = refused(res, 1, out, str(dem), "covers 46 %", "footprint")
    assert "do not overlap" not in line, line


# --------------------------------------------------------------------------- dem options
@pytest.mark.parametrize(
    ("option", "value", "code", "words"),
    [
        ("--posting", "0.001", 1, ("--posting", "0.001", "cells", "at least")),
        ("--posting", "1e9", 1, ("--posting", "1e+09", "footprint", "2 x 2 nodes")),
        # a CRS IOR cannot use whatever the scene: a usage error (a geographic one is warped
        # to, issue 34; feet are not metres)
        ("--crs", "EPSG:2263", 2, ("--crs", "EPSG:2263", "projected CRS in metres")),
    ],
)
def test_dem_option_values_absurd_for_the_scene(
    carto: Run,
    tmp_path: Path,
    cartosat1_scene: Path,
    cartosat1_adjusted: Path,
    option: str,
    value: str,
    code: int,
    words: tuple[str, ...],
) -> None:
    out = tmp_path / "o"
    res = carto(dem_run(cartosat1_scene, cartosat1_adjusted, out, option, value))
    line = refused(res, code, out, *words)
    assert "does not cover" not in line, line
