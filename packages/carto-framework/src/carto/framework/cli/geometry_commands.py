"""``carto project`` and ``carto locate``: ground <-> image through any sensor."""

from __future__ import annotations

import argparse

from carto.framework.cli.common import examples, formatter


# --------------------------------------------------------------------------- project / locate
def _transform_points(
    args: argparse.Namespace, inputs: tuple[str, str, str], outputs: tuple[str, str], forward: bool
) -> int:
    """Read a point table, project or locate it with the model, write it with new columns."""
    from carto.framework.files.point_table import read_point_table, write_point_table
    from carto.framework.files.staging import check_output_file
    from carto.framework.workflows.opening import open_sensor

    source = args.ground if forward else args.image
    check_output_file(args.out, "--out", [args.model, source])
    sensor = open_sensor(args.model, args.sensor)
    table = read_point_table(source, numeric=inputs)
    method = sensor.ground_to_image if forward else sensor.image_to_ground
    first, second = method(*(table[c] for c in inputs))
    out = {k: v for k, v in table.items() if k not in outputs}
    out[outputs[0]], out[outputs[1]] = first, second
    write_point_table(args.out, out, precision=17)
    import numpy as np

    failed = int(np.count_nonzero(~np.isfinite(first)))
    verb, note = (
        ("projected", "outside the image or not converged")
        if forward
        else ("located", "not located")
    )
    print(
        f"{verb} {first.size} point(s) with {args.model} -> {args.out}"
        + (f" ({failed} {note}: nan)" if failed else "")
    )
    return 0


def cmd_project(args: argparse.Namespace) -> int:
    return _transform_points(args, ("lon_deg", "lat_deg", "h_m"), ("line", "sample"), True)


def cmd_locate(args: argparse.Namespace) -> int:
    return _transform_points(args, ("line", "sample", "h_m"), ("lon_deg", "lat_deg"), False)


_PIXELS = (
    "image coordinates: continuous (line, sample) in pixels, centre of the first pixel at "
    "(0.5, 0.5)\n(GDAL's convention); heights: metres above the WGS84 ellipsoid."
)


def _add_model_and_points(p: argparse.ArgumentParser, points: str, columns: str) -> None:
    """The arguments ``project`` and ``locate`` share: the model, the input point table (the
    option ``points`` with the ``columns`` it holds), the output table and the sensor type."""
    p.add_argument(
        "model",
        metavar="MODEL",
        help="model file or product any sensor plugin opens (RPC GeoTIFF, _RPC.TXT ...)",
    )
    p.add_argument(points, required=True, metavar="IN.csv", help=columns)
    p.add_argument("--out", required=True, metavar="OUT.csv", help="output CSV")
    p.add_argument(
        "--sensor", metavar="TYPE", help="sensor type (see `carto plugins --kind sensor`)"
    )


def add_project_locate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "project",
        help="ground -> image: project lon/lat/height points into an image",
        description="Project ground points (CSV columns lon_deg,lat_deg,h_m) into the image of "
        "MODEL;\nwrites the input columns plus line,sample (nan outside the image).\n\n" + _PIXELS,
        epilog=examples(
            "carto project fore.model.json --ground points.csv --out pixels.csv",
            "carto project IMG_01.tif --ground points.csv --out pixels.csv --sensor rpc",
        ),
        formatter_class=formatter,
    )
    _add_model_and_points(p, "--ground", "lon_deg,lat_deg,h_m")
    p.set_defaults(handler=cmd_project)

    p = sub.add_parser(
        "locate",
        help="image -> ground: locate image points at given heights",
        description="Locate image points (CSV columns line,sample,h_m) of MODEL on the surface at "
        "the given\nellipsoidal heights; writes the input columns plus lon_deg,lat_deg.\n\n"
        + _PIXELS,
        epilog=examples(
            "carto locate fore.model.json --image pixels.csv --out ground.csv",
            "carto locate scene_RPC.TXT --image pixels.csv --out ground.csv",
        ),
        formatter_class=formatter,
    )
    _add_model_and_points(p, "--image", "line,sample,h_m")
    p.set_defaults(handler=cmd_locate)
