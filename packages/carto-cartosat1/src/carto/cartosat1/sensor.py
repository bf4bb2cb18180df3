"""Sensor type ``cartosat1``: Cartosat-1 products as Carto sensors.

Two kinds of product open:

* **Scenes** with ancillary data (the simulator's products, ``docs/formats.md``): the Fore and
  Aft images become rigorous line scanners on **one** body trajectory (both cameras sit on one
  rigid platform, so they share its attitude and its corrections). Open the scene folder (all
  images, :meth:`Cartosat1SensorType.open_all`) or one image raster of it.
* **Orthokit products**: band GeoTIFFs ``*_A`` / ``*_F`` (or ``BANDA`` / ``BANDF``) with RPC
  sidecars ``<band>_RPC_ORG.TXT`` and/or ``<band>_RPC.TXT`` (``KEY: value``). When both exist the
  original ``_RPC_ORG.TXT`` is used (``_RPC.TXT`` may already carry a vendor refinement) and the
  sensor's ``source`` says which file it is. ``*_MET.TXT`` (``key=value``) metadata is read into
  ``sensor.metadata``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from carto.framework.sdk.common import InputError
from carto.framework.sdk.presets import Scene, find_scene_manifest
from carto.framework.sdk.sensors import (
    RPCSensor,
    Sensor,
    SensorType,
    read_rpc_txt,
    refuse_options,
    save_corrected_rpc,
    save_line_scanner,
)

_BAND = re.compile(r"(^band[af]|[_-][af])$", re.IGNORECASE)
PLATFORM_PREFIX = "Cartosat-1"


def _scene_manifest(path: Path) -> Path | None:
    """The scene.json of a Cartosat-1 scene that ``path`` is, or is an image of."""
    return find_scene_manifest(path, PLATFORM_PREFIX)


def rpc_sidecar(band: Path) -> tuple[Path, Path | None]:
    """The RPC file to use for an orthokit band and the one passed over, if any.

    Raises:
        InputError: the band has no ``_RPC_ORG.TXT`` nor ``_RPC.TXT``.
    """
    by_name = {p.name.lower(): p for p in band.parent.iterdir()} if band.parent.is_dir() else {}
    org = by_name.get(f"{band.stem.lower()}_rpc_org.txt")
    plain = by_name.get(f"{band.stem.lower()}_rpc.txt")
    if org is not None:
        return org, plain
    if plain is not None:
        return plain, None
    raise InputError(
        f"{band}: no RPC file beside it ({band.stem}_RPC_ORG.TXT or {band.stem}_RPC.TXT)"
    )


def read_met(path: Path) -> dict[str, str]:
    """``key=value`` lines of an orthokit ``*_MET.TXT`` (comments and blank lines skipped)."""
    out: dict[str, str] = {}
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise InputError(f"{path}: cannot read metadata: {exc.strerror}") from None
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        key, sep, value = line.partition("=")
        if not sep:
            raise InputError(f"{path}: line {number} is not key=value: {line[:60]!r}")
        out[key.strip()] = value.strip()
    return out


def _met_file(band: Path) -> Path | None:
    for cand in sorted(band.parent.glob("*")):
        if cand.name.lower() == f"{band.stem.lower()}_met.txt":
            return cand
    mets = sorted(p for p in band.parent.glob("*") if p.name.lower().endswith("_met.txt"))
    return mets[0] if len(mets) == 1 else None


def _is_orthokit_band(path: Path) -> bool:
    if path.suffix.lower() not in (".tif", ".tiff") or not _BAND.search(path.stem):
        return False
    try:
        rpc_sidecar(path)
    except (InputError, OSError):
        return False
    return True


def open_orthokit_band(band: Path) -> RPCSensor:
    """An orthokit band GeoTIFF as an RPC sensor (``source`` names the RPC file used)."""
    import warnings

    import rasterio

    chosen, passed_over = rpc_sidecar(band)
    rpc = read_rpc_txt(chosen)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with rasterio.open(band) as ds:
                shape = (ds.height, ds.width)
    except rasterio.errors.RasterioError as exc:
        raise InputError(f"{band}: not a readable GeoTIFF: {exc}") from None
    note = f" (preferred over {passed_over.name})" if passed_over is not None else ""
    met = _met_file(band)
    return RPCSensor(
        rpc,
        shape,
        source=f"{chosen}{note}",
        prefix=f"{band.stem}.",
        metadata=read_met(met) if met is not None else {},
    )


class Cartosat1SensorType(SensorType):
    """Cartosat-1 Fore/Aft: scenes with ancillary data and orthokit RPC products."""

    name = "cartosat1"
    description = "Cartosat-1 Fore/Aft: tied rigorous model from ancillary data, or orthokit RPCs"
    priority = 10  # more specific than the generic rpc and linescan types
    default_adjuster = "cartosat1-combined"
    default_dem_generator = "ior"

    def identify(self, path: Path) -> bool:
        path = Path(path)
        try:
            return _scene_manifest(path) is not None or _is_orthokit_band(path)
        except OSError:
            return False

    def open_all(self, path: Path, **options: Any) -> dict[str, Sensor]:
        """Fore and Aft of a scene (``options``: ``trajectory_model``, ``components`` and
        the fit options of :meth:`carto.framework.products.ancillary.Ancillary.trajectory`),
        or the bands of an orthokit product (RPCs: no options but ``components``)."""
        path = Path(path)
        manifest = _scene_manifest(path)
        if manifest is not None:
            return dict(Scene.open(manifest).sensors(**options))
        if path.is_dir():
            bands = sorted(p for p in path.iterdir() if _is_orthokit_band(p))
        else:
            bands = sorted(p for p in path.parent.iterdir() if _is_orthokit_band(p))
        if not bands:
            raise InputError(f"{path}: not a Cartosat-1 scene or orthokit product")
        refuse_options(f"{path} (an orthokit RPC product has no trajectory)", options)
        return {b.stem: open_orthokit_band(b) for b in bands}

    def save(
        self, sensor: Sensor, out_dir: Path, name: str, *, h_range_m: tuple[float, float]
    ) -> dict[str, Any]:
        """A scene image's line scanner as a model file and a fitted RPC; an orthokit band's
        RPC with its correction baked in."""
        if isinstance(sensor, RPCSensor):
            return save_corrected_rpc(sensor, Path(out_dir), name)
        return save_line_scanner(sensor, Path(out_dir), name, h_range_m)

    def open(self, path: Path, **options: Any) -> Sensor:
        path = Path(path)
        manifest = _scene_manifest(path)
        if manifest is not None:
            sensors = Scene.open(manifest).sensors(**options)
            if path.is_dir() or path.name == "scene.json":
                raise InputError(
                    f"{path}: a scene holds several images "
                    f"({', '.join(sensors)}); open one of its rasters"
                )
            for name, image in json.loads(manifest.read_text())["images"].items():
                if image["raster"] == path.name:
                    return sensors[name]
        if _is_orthokit_band(path):
            refuse_options(f"{path} (an orthokit RPC product has no trajectory)", options)
            return open_orthokit_band(path)
        raise InputError(f"{path}: not a Cartosat-1 scene image or orthokit band")
