"""python-can's CanutilsLogReader reads the candump logs slam-sim writes.

Every frame line is read (as many messages as the log has lines starting with '('), each a
classic standard data frame on can0 in time order; the frames reassemble into Aseba messages
without a single anomaly; and the robot events in them, field by field and in order, are the
events the project's own reader decodes from the log (`slam-link --source candump:LOG
--as-fast --events`), whose counters agree too.

    python_can_log.py SLAM_SIM SLAM_LINK WORK_DIR
"""

import json
import os
import subprocess
import sys

import can

import outside_support as support
from outside_support import check


def read_with_python_can(log_path):
    with can.CanutilsLogReader(log_path) as reader:
        return list(reader)


def check_frames(messages, lines):
    check(len(messages) == len(lines),
          f"python-can read {len(messages)} frames, the log holds {len(lines)} frame lines")
    previous = None
    for index, (message, line) in enumerate(zip(messages, lines), start=1):
        what = f"frame {index} ({line!r})"
        check(message.channel == "can0", f"{what}: channel {message.channel!r}")
        check(not (message.is_extended_id or message.is_remote_frame or message.is_error_frame
                   or message.is_fd), f"{what}: not a classic standard data frame: {message}")
        check(message.dlc == len(message.data) and 1 <= message.dlc <= 8,
              f"{what}: dlc {message.dlc}, {len(message.data)} data bytes")
        check(previous is None or message.timestamp >= previous,
              f"{what}: time goes back ({previous} -> {message.timestamp})")
        previous = message.timestamp


def project_events(slam_link, log_path, robot_path):
    """slam-link's decoded events as (time, text) and its counters JSON."""
    result = subprocess.run(
        [slam_link, "--source", f"candump:{log_path}", "--robot", robot_path, "--as-fast",
         "--events"], capture_output=True, text=True, timeout=120)
    check(result.returncode == 0,
          f"slam-link exited {result.returncode}: {result.stderr.strip()}")
    out = result.stdout
    json_start = out.find("\n{")
    check(json_start >= 0, "slam-link printed no counters JSON")
    events = []
    for line in out[:json_start + 1].splitlines():
        t, text = line.split(" ", 1)
        events.append((float(t), text))
    return events, json.loads(out[json_start + 1:])


def main():
    slam_sim, slam_link, work = sys.argv[1:4]
    support.fresh_dir(work)
    experiment = support.make_experiment(slam_sim, os.path.join(work, "exp"), duration_s=20)
    log_path = os.path.join(experiment, "can.log")
    robot_path = os.path.join(experiment, "robot.json")

    lines = support.candump_frame_lines(log_path)
    check(len(lines) > 1000, f"only {len(lines)} frame lines in a 20 s log")
    messages = read_with_python_can(log_path)
    check_frames(messages, lines)

    aseba = support.AsebaReassembler()
    for index, m in enumerate(messages, start=1):
        aseba.add(m.timestamp, m.arbitration_id, m.data, f"frame {index} ({lines[index - 1]!r})")
    check(not aseba.anomalies,
          f"{len(aseba.anomalies)} Aseba framing anomalies, first: {aseba.anomalies[:3]}")
    check(not aseba.pending, f"messages left unfinished at the end: {sorted(aseba.pending)}")
    events, others = support.decode_events(aseba.messages, support.robot_nodes(robot_path))
    check(not others, f"{len(others)} messages are not robot events, first: {others[:3]}")

    theirs, counters = project_events(slam_link, log_path, robot_path)
    check(len(events) == len(theirs),
          f"python-can's frames make {len(events)} events, slam-link decodes {len(theirs)}")
    for index, ((t, text), (their_t, their_text)) in enumerate(zip(events, theirs), start=1):
        check(text == their_text and abs(t - their_t) < 2e-6,
              f"event {index}: from python-can's frames {t:.6f} {text}, "
              f"slam-link {their_t:.6f} {their_text}")

    odometry = sum(1 for _, text in events if text.startswith("odometry"))
    expected = {
        "frames": len(messages),
        "frames_rejected": 0,
        "reassembly.frames": len(messages),
        "reassembly.messages": len(aseba.messages),
        "decoder.odometry": odometry,
        "decoder.scanner": len(events) - odometry,
    }
    for key, value in expected.items():
        node = counters
        for part in key.split("."):
            node = node[part]
        check(node == value, f"slam-link's {key} is {node}, python-can's reading gives {value}")

    print(f"python-can read all {len(messages)} frames of {log_path}: {len(aseba.messages)} "
          f"Aseba messages, {odometry} odometry and {len(events) - odometry} scanner events, "
          "the same as slam-link decodes")


if __name__ == "__main__":
    support.run_test(main)
