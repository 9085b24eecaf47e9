"""Prometheus' own `promtool check metrics` accepts slamd's /metrics, with no lint problem.

slamd maps the virtual marXbot (sim:box, 8 times real time) so that every family has real
values: scans and their latency histogram, link counters, HTTP requests of several codes and
whole-map exports; the Foxglove server on (its slamd_foxglove_* families). The text is taken twice: at start and after at least 10 scans. promtool must
exit 0 and print nothing; the text must also hold what the test made happen (so an empty or
truncated text cannot pass).

    promtool_metrics.py PROMTOOL SLAMD WORK_DIR
"""

import os
import socket
import subprocess
import sys
import urllib.error

import outside_support as support
from outside_support import check

CONTENT_TYPE = "text/plain; version=0.0.4"


def samples(text):
    """{sample name with labels: value} of a Prometheus text."""
    values = {}
    for line in text.splitlines():
        if line and not line.startswith("#"):
            name, value = line.rsplit(" ", 1)
            values[name] = float(value)
    return values


def promtool_check(promtool, text, where, work):
    path = os.path.join(work, "metrics-" + where.replace(" ", "-") + ".txt")
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)
    with open(path, "rb") as f:
        result = subprocess.run([promtool, "check", "metrics"], stdin=f, capture_output=True,
                                text=True, timeout=60)
    said = (result.stdout + result.stderr).strip()
    check(result.returncode == 0 and said == "",
          f"promtool check metrics on slamd's /metrics {where} (saved in {path}) exited "
          f"{result.returncode}:\n{said}")


def fetch_metrics(slamd):
    status, headers, body = slamd.get("/metrics")
    check(status == 200, f"/metrics answered {status}")
    content_type = headers.get("Content-Type", "")
    check(content_type.startswith(CONTENT_TYPE),
          f"/metrics has Content-Type {content_type!r}, not Prometheus' {CONTENT_TYPE}")
    return body.decode("utf-8")


def main():
    promtool, slamd_bin, work = sys.argv[1:4]
    support.fresh_dir(work)
    # The Foxglove server on a port free now (its port 0 means off), for its metric families.
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        foxglove_port = probe.getsockname()[1]
    args = ["--source", "sim:box", "--speed", "8", "--budget", "8125",
            "--foxglove-port", str(foxglove_port)]
    with support.Slamd(slamd_bin, args, work) as slamd:
        promtool_check(promtool, fetch_metrics(slamd), "at start", work)

        status = slamd.poll_status(lambda s: s["slam"]["scans"] >= 10, 60)
        check(status["slam"]["scans"] >= 10, f"only {status['slam']['scans']} scans in 60 s")
        slamd.get("/api/v1/map.png")  # an export, for slamd_exports_made_total{kind=...}
        try:
            slamd.get("/api/v1/nowhere")
        except urllib.error.HTTPError as error:  # a 404, for another code label
            check(error.code == 404, f"/api/v1/nowhere answered {error.code}")
        text = fetch_metrics(slamd)
        promtool_check(promtool, text, "after scans", work)

    values = samples(text)
    wanted = {
        "slamd_scans_total": lambda v: v >= 10,
        "slamd_scan_latency_seconds_count": lambda v: v >= 10,
        'slamd_scan_latency_seconds_bucket{le="+Inf"}': lambda v: v >= 10,
        "slamd_link_frames_total": lambda v: v > 500,
        "slamd_link_up": lambda v: v == 1,
        "slamd_foxglove_clients": lambda v: v == 0,
        'slamd_http_requests_total{method="GET",code="404"}': lambda v: v >= 1,
    }
    for name, ok in wanted.items():
        check(name in values, f"no sample {name} in /metrics")
        check(ok(values[name]), f"unexpected {name} {values[name]}")
    check(any(name.startswith("slamd_exports_made_total{") for name in values),
          "no slamd_exports_made_total sample after a map.png export")
    # What promtool does not check but Prometheus' histogram_quantile relies on: cumulative
    # buckets, the last (+Inf) equal to the count.
    buckets = [value for name, value in values.items()
               if name.startswith("slamd_scan_latency_seconds_bucket{")]
    check(buckets == sorted(buckets), f"latency buckets not cumulative: {buckets}")
    check(buckets[-1] == values["slamd_scan_latency_seconds_count"],
          "the +Inf latency bucket is not the count")
    print(f"promtool check metrics: no problem in slamd's /metrics ({len(values)} samples, "
          f"{values['slamd_scans_total']:.0f} scans)")


if __name__ == "__main__":
    support.run_test(main)
