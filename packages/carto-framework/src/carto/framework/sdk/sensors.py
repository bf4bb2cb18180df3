"""For sensor plugins: the sensor type and model bases, the rigorous line scanner and its
parts (camera, line timing, time series), RPC models, reduced sensors, frames and orbits
(see :mod:`carto.framework.sdk`)."""

from carto.framework.geometry import frames, orbit
from carto.framework.geometry.camera import Camera
from carto.framework.geometry.decimated import DecimatedSensor
from carto.framework.geometry.intersection import base_direction
from carto.framework.geometry.linescan.scanner import LineScanner, save_line_scanner
from carto.framework.geometry.linescan.solver import tabulated_lines
from carto.framework.geometry.linescan.timing import LineTiming
from carto.framework.geometry.rpc.readers import read_rpc_txt
from carto.framework.geometry.rpc.sensor import RPCSensor, RPCSensorType, save_corrected_rpc
from carto.framework.geometry.sensor import Parameter, Sensor, SensorType, refuse_options
from carto.framework.geometry.time_series import TimeSeries
from carto.framework.imaging.preparation import ground_sampling_m
from carto.framework.products.ancillary import CameraSpec, read_ancillary

__all__ = [
    "Camera",
    "CameraSpec",
    "DecimatedSensor",
    "LineScanner",
    "LineTiming",
    "Parameter",
    "RPCSensor",
    "RPCSensorType",
    "Sensor",
    "SensorType",
    "TimeSeries",
    "base_direction",
    "frames",
    "ground_sampling_m",
    "orbit",
    "read_ancillary",
    "read_rpc_txt",
    "refuse_options",
    "save_corrected_rpc",
    "save_line_scanner",
    "tabulated_lines",
]
