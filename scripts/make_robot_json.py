#!/usr/bin/env python3
"""Writes config/marxbot.robot.json: the marXbot description of docs/design.md section 5.

The calibration tables come from the Sharp response curves of docs/design.md appendix B (single-beam
parts of the same ranges), read by a 3.3 V 10-bit ADC: raw = round(V / 3.3 * 1023).

    short GP2Y3A001K0F  d_cm = 2.076 / (V/5 - 0.011)    table 4 cm .. 35 cm, 0.5 cm steps
    long  GP2Y3A002K0F  d_cm = 9.462 / (V/5 - 0.01692)  table 20 cm .. 150 cm, 2 then 5 cm steps

Points whose rounded raw value repeats the previous one are dropped, so raw strictly decreases.
Usage: scripts/make_robot_json.py [--out PATH] [--check]
"""

import argparse
import json
import math
import pathlib
import sys

ADC_VREF = 3.3
ADC_MAX = 1023

REPO = pathlib.Path(__file__).resolve().parent.parent
DEFAULT_OUT = REPO / "config" / "marxbot.robot.json"


def raw_of_volts(volts):
    """10-bit ADC value of a voltage, rounded half up (Python's round() rounds half to even)."""
    return min(ADC_MAX, max(0, math.floor(volts / ADC_VREF * ADC_MAX + 0.5)))


def short_volts(d_cm):
    return 5.0 * (2.076 / d_cm + 0.011)


def long_volts(d_cm):
    return 5.0 * (9.462 / d_cm + 0.01692)


def table(volts_of_cm, distances_mm):
    """[[raw, distance_m], ...] with raw strictly decreasing."""
    points = []
    for mm in distances_mm:
        raw = raw_of_volts(volts_of_cm(mm / 10.0))
        if points and raw >= points[-1][0]:
            continue
        points.append([raw, mm / 1000.0])
    return points


def robot():
    short_mm = range(40, 351, 5)  # 4 cm .. 35 cm every 0.5 cm
    long_mm = list(range(200, 600, 20)) + list(range(600, 1501, 50))  # 20..58 by 2, 60..150 by 5
    return {
        "name": "marxbot",
        "base": {"node": 1, "event": 16, "track_width_m": 0.15, "ticks_per_m": 11375,
                 "gyro_unit_dps": 0.01},
        "scanner": {
            "node": 2, "event": 32, "sample_rate_hz": 60, "mount_radius_m": 0.05,
            "sensors": [
                {"type": "short", "angle_deg": 0},
                {"type": "long", "angle_deg": 90},
                {"type": "short", "angle_deg": 180},
                {"type": "long", "angle_deg": 270},
            ],
        },
        "sensor_types": {
            "short": {
                "model": "GP2Y3A001K0F",
                "range_m": [0.04, 0.30],
                "use_m": [0.0, 0.35],
                "calibration": table(short_volts, short_mm),
                "sigma_m": [0.003, 0.0, 0.02],
            },
            "long": {
                "model": "GP2Y3A002K0F",
                "range_m": [0.20, 1.50],
                "use_m": [0.35, 1.0],
                "calibration": table(long_volts, long_mm),
                "sigma_m": [0.005, 0.0, 0.02],
            },
        },
    }


def dumps(value, indent=0):
    """Pretty JSON; arrays of scalars and small objects of scalars stay on one line."""
    pad = "  " * indent
    inner = "  " * (indent + 1)
    if isinstance(value, dict):
        if not value:
            return "{}"
        if len(value) <= 2 and all(not isinstance(v, (dict, list)) for v in value.values()):
            members = (f"{json.dumps(k)}: {json.dumps(v)}" for k, v in value.items())
            return "{" + ", ".join(members) + "}"
        items = [f"{inner}{json.dumps(k)}: {dumps(v, indent + 1)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    if isinstance(value, list):
        if all(not isinstance(v, (dict, list)) for v in value):
            return "[" + ", ".join(json.dumps(v) for v in value) + "]"
        items = [f"{inner}{dumps(v, indent + 1)}" for v in value]
        return "[\n" + ",\n".join(items) + "\n" + pad + "]"
    return json.dumps(value)


def check(description):
    """The spot values docs/design.md section 5 quotes, and the table invariants."""
    types = description["sensor_types"]
    assert types["short"]["calibration"][0] == [822, 0.04], types["short"]["calibration"][0]
    assert types["long"]["calibration"][0] == [760, 0.2], types["long"]["calibration"][0]
    for name, sensor in types.items():
        cal = sensor["calibration"]
        for (raw0, d0), (raw1, d1) in zip(cal, cal[1:]):
            assert 0 <= raw1 < raw0 <= ADC_MAX and 0 < d0 < d1, (name, raw0, d0, raw1, d1)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=pathlib.Path, default=DEFAULT_OUT)
    parser.add_argument("--check", action="store_true",
                        help="exit 1 if --out differs from what would be written")
    args = parser.parse_args()

    description = robot()
    check(description)
    text = dumps(description) + "\n"
    if args.check:
        current = args.out.read_text() if args.out.exists() else ""
        if current != text:
            print(f"{args.out} is out of date; run {sys.argv[0]}", file=sys.stderr)
            return 1
        return 0
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_name(args.out.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
