"""can-utils' log2asc converts the candump logs slam-sim writes without a complaint.

log2asc exits 0, writes nothing on stderr and one ASC frame line per frame of the log, with the
same ids, lengths and data bytes in the same order, each at its time since the first frame.

    log2asc_log.py LOG2ASC SLAM_SIM WORK_DIR
"""

import os
import re
import subprocess
import sys

import outside_support as support
from outside_support import check

# A log2asc frame line: "   0.1234 1  102             Rx   d 8 20 00 01 00 00 40 2C 01"
ASC_FRAME = re.compile(r"^\s*(\d+\.\d+)\s+(\d+)\s+([0-9A-Fa-f]+)(x?)\s+Rx\s+d\s+(\d)"
                       r"((?:\s+[0-9A-Fa-f]{2})*)\s*$")
CANDUMP_FRAME = re.compile(r"^\((\d+)\.(\d{6})\)\s+(\S+)\s+([0-9A-Fa-f]{3})#((?:[0-9A-Fa-f]{2})*)$")


def main():
    log2asc, slam_sim, work = sys.argv[1:4]
    support.fresh_dir(work)
    experiment = support.make_experiment(slam_sim, os.path.join(work, "exp"), duration_s=20)
    log_path = os.path.join(experiment, "can.log")
    asc_path = os.path.join(work, "can.asc")

    lines = support.candump_frame_lines(log_path)
    frames = []
    for line in lines:
        match = CANDUMP_FRAME.match(line)
        check(match, f"not a standard candump data frame line: {line!r}")
        time_us = int(match.group(1)) * 1_000_000 + int(match.group(2))
        frames.append((time_us, int(match.group(4), 16), bytes.fromhex(match.group(5))))
    first_us = frames[0][0]
    frames = [(t - first_us, can_id, data) for t, can_id, data in frames]

    result = subprocess.run([log2asc, "-I", log_path, "-O", asc_path, "can0"],
                            capture_output=True, text=True, timeout=60)
    check(result.returncode == 0, f"log2asc exited {result.returncode}: {result.stderr.strip()}")
    check(result.stderr == "", f"log2asc wrote on stderr: {result.stderr.strip()[:500]}")

    with open(asc_path, encoding="ascii") as asc:
        asc_lines = asc.read().splitlines()
    converted = []
    for line in asc_lines:
        if " Rx " not in line:
            continue
        match = ASC_FRAME.match(line)
        check(match, f"log2asc wrote a frame line this test cannot read: {line!r}")
        check(match.group(2) == "1" and match.group(4) == "",
              f"not channel 1, standard id: {line!r}")
        data = bytes.fromhex(match.group(6).replace(" ", ""))
        check(int(match.group(5)) == len(data), f"length digit and data disagree: {line!r}")
        seconds, fraction = match.group(1).split(".")
        check(len(fraction) == 6, f"not a microsecond time: {line!r}")
        converted.append((int(seconds) * 1_000_000 + int(fraction), int(match.group(3), 16), data))

    check(len(converted) == len(frames),
          f"log2asc wrote {len(converted)} frames for the log's {len(frames)}")
    for index, (ours, theirs) in enumerate(zip(frames, converted), start=1):
        check(ours == theirs, f"frame {index}: the log has {ours[1]:03X}#{ours[2].hex()} at "
                              f"+{ours[0]} us, log2asc wrote {theirs[1]:03X} {theirs[2].hex()} "
                              f"at +{theirs[0]} us")
    print(f"log2asc converted all {len(frames)} frames of {log_path}, nothing on stderr")


if __name__ == "__main__":
    support.run_test(main)
