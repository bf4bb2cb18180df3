"""Where the bundle's points start: against the known ground points the image measurements
were projected from (the sensors' own ground -> image, independent of the code under test)."""

from __future__ import annotations

import numpy as np

from carto.framework.adjustment.observations import Observations
from carto.framework.adjustment.starting_points import place_points


def _measured(sensor, lon, lat, h):
    line, sample = sensor.ground_to_image(lon, lat, h)
    assert np.isfinite(line).all()
    assert np.isfinite(sample).all()
    return line, sample


def test_points_start_where_they_are_seen(cartosat1_pair):
    """Stereo points are intersected; points seen once, or by two images with the same
    line of sight (a strip's consecutive scenes where they overlap), start on their one ray
    at their constrained height; points seen once without a height are dropped."""
    fore, aft = cartosat1_pair["fore"], cartosat1_pair["aft"]
    sensors = {"fore": fore, "aft": aft, "fore_again": fore}
    rng = np.random.default_rng(7)
    # ground points both images see (the fixture's Fore sees Aft's last lines and columns)
    line, sample = rng.uniform(200.0, 6000.0, 400), rng.uniform(100.0, 2000.0, 400)
    h = rng.uniform(0.0, 1500.0, 400)
    lon, lat = fore.image_to_ground(line, sample, h)
    both = aft.project(lon, lat, h)[2]
    lon, lat, h = lon[both][:30], lat[both][:30], h[both][:30]
    assert lon.size == 30
    groups = {
        "stereo": (["fore", "aft"], range(0, 10)),
        "once": (["aft"], range(10, 20)),
        "same_ray": (["fore", "fore_again"], range(20, 27)),
        "unplaced": (["fore"], range(27, 30)),
    }
    table = {"id": [], "image": [], "line": [], "sample": []}
    for kind, (images, points) in groups.items():
        for image in images:
            idx = np.array(points)
            line, sample = _measured(sensors[image], lon[idx], lat[idx], h[idx])
            table["id"] += [f"{kind}{i:02d}" for i in idx]
            table["image"] += [image] * idx.size
            table["line"] += line.tolist()
            table["sample"] += sample.tolist()
    ties = {
        k: np.array(v, dtype=object if k in ("id", "image") else float) for k, v in table.items()
    }
    held = [f"{kind}{i:02d}" for kind in ("once", "same_ray") for i in groups[kind][1]]
    held_h = np.concatenate([h[10:20], h[20:27]])
    obs = Observations.from_tables(None, ties).with_heights(held, held_h, 30.0)

    kept, point_ids, (p_lon, p_lat, p_h) = place_points(sensors, obs, None)

    expected = [
        f"{kind}{i:02d}" for kind in ("once", "same_ray", "stereo") for i in groups[kind][1]
    ]
    assert point_ids == sorted(expected)
    assert not any(p.startswith("unplaced") for p in kept.point_id)
    truth = {f"{kind}{i:02d}": i for kind, (_, points) in groups.items() for i in points}
    k = np.array([truth[p] for p in point_ids])
    # 1e-9 deg ~ 0.1 mm: the sensors' own inversions agree to well below that
    np.testing.assert_allclose(p_lon, lon[k], rtol=0, atol=1e-8)
    np.testing.assert_allclose(p_lat, lat[k], rtol=0, atol=1e-8)
    np.testing.assert_allclose(p_h, h[k], rtol=0, atol=1e-3)
