"""Opening products as sensors through the registry of sensor types.

:func:`open_sensor` and :func:`open_sensors` ask every registered sensor type whether it
recognises a file (``identify``); the one with the highest priority opens it.
"""

from __future__ import annotations

from pathlib import Path

from carto.framework.errors import InputError
from carto.framework.geometry.sensor import Sensor, SensorType


def _sensor_type_for(path: Path, sensor_type: str | None, what: str) -> SensorType:
    """The named sensor type, or the one that identifies ``path`` (highest priority)."""
    from carto.framework.plugins.registry import get_registry

    if not path.exists():
        raise InputError(f"{path}: no such file or directory")
    registry = get_registry()
    if sensor_type is not None:
        return registry.get("sensor", sensor_type)
    types = [info.component for info in registry.components("sensor")]
    candidates = [t for t in types if _safe_identify(t, path)]
    if not candidates:
        names = ", ".join(t.name for t in types) or "none"
        raise InputError(
            f"{path}: no sensor type recognises this {what} (known: {names}); "
            "name one with --sensor TYPE"
        )
    best = max(t.priority for t in candidates)
    top = [t for t in candidates if t.priority == best]
    if len(top) > 1:
        raise InputError(
            f"{path}: several sensor types recognise this {what} "
            f"({', '.join(t.name for t in top)}); choose one with --sensor"
        )
    return top[0]


def open_sensor(path: str | Path, sensor_type: str | None = None) -> Sensor:
    """Open ``path`` with the named sensor type, or with the one that identifies it.

    Raises:
        InputError: the file does not exist, no registered type recognises it, or several do
            with the same priority.
        UnknownComponentError: ``sensor_type`` is not registered.
    """
    path = Path(path)
    return _sensor_type_for(path, sensor_type, "file").open(path)


def open_sensors(path: str | Path, sensor_type: str | None = None) -> dict[str, Sensor]:
    """Open every image of a product (scene folder, stereo product, single image) by name.

    Like :func:`open_sensor`, but through the sensor type's ``open_all``.
    """
    path = Path(path)
    return _sensor_type_for(path, sensor_type, "product").open_all(path)


def _safe_identify(sensor_type: SensorType, path: Path) -> bool:
    try:
        return bool(sensor_type.identify(path))
    except Exception:  # noqa: BLE001 - a faulty identify must not hide the other types
        return False
