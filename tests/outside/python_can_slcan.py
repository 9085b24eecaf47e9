"""python-can's slcan bus feeds slamd's slcan source the frames of a slam-sim log.

slamd and python-can each open a serial device by its path, as they would a USB-CAN adapter: two
pseudo-terminals joined like a null-modem cable (what one program writes to its terminal, the
other reads from its own). slamd gets `--source slcan:/dev/pts/A` and sends its open commands
(close, 1 Mbit/s, open: checked); python-can's `interface="slcan"` bus opens /dev/pts/B at 1
Mbit/s (sending its own open commands) and sends every frame of the log, read by python-can's
CanutilsLogReader, at 4 times the log's pace. Then slamd's /api/v1/status must show every frame
read and decoded: its frame counters equal to the frames sent, no frame rejected by reassembly
or decoding, the Aseba messages and robot events the frames hold (reassembled here
independently), no event dropped, scans mapped, and no line of the stream unread but
python-can's own commands.

    python_can_slcan.py SLAMD SLAM_SIM WORK_DIR
"""

import os
import select
import sys
import threading
import time
import tty

import can

import outside_support as support
from outside_support import check

SPEED = 4.0  # times the log's pace


class NullModem:
    """Two pseudo-terminals joined like a null-modem cable. Both terminals start raw (no echo,
    no '\\r' -> '\\n'), and this side keeps each open so neither hangs up while a program
    reopens it. Records the bytes carried from B to A."""

    def __init__(self):
        self.a_master, self.a_slave = os.openpty()
        self.b_master, self.b_slave = os.openpty()
        for fd in (self.a_slave, self.b_slave):
            tty.setraw(fd)
        self.a_path = os.ttyname(self.a_slave)
        self.b_path = os.ttyname(self.b_slave)
        self.b_to_a = bytearray()
        self.a_to_b = bytearray()
        self.lock = threading.Lock()
        self.wake_read, self.wake_write = os.pipe()
        self.thread = threading.Thread(target=self._carry, daemon=True)
        self.thread.start()

    def _carry(self):
        peers = {self.a_master: (self.b_master, self.a_to_b),
                 self.b_master: (self.a_master, self.b_to_a)}
        while True:
            readable, _, _ = select.select([self.a_master, self.b_master, self.wake_read], [], [])
            if self.wake_read in readable:
                return
            for fd in readable:
                data = os.read(fd, 4096)
                peer, record = peers[fd]
                with self.lock:
                    record.extend(data)
                view = memoryview(data)
                while view:
                    view = view[os.write(peer, view):]

    def carried_to_a(self):
        with self.lock:
            return bytes(self.b_to_a)

    def carried_to_b(self):
        with self.lock:
            return bytes(self.a_to_b)

    def close(self):
        os.write(self.wake_write, b"x")
        self.thread.join(timeout=5)
        for fd in (self.a_master, self.a_slave, self.b_master, self.b_slave, self.wake_read,
                   self.wake_write):
            os.close(fd)


def send_paced(bus, messages, speed):
    """Sends the messages at `speed` times the pace of their time stamps."""
    start = time.monotonic()
    first = messages[0].timestamp
    for message in messages:
        delay = start + (message.timestamp - first) / speed - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        bus.send(message)


def main():
    slamd_bin, slam_sim, work = sys.argv[1:4]
    support.fresh_dir(work)
    experiment = support.make_experiment(slam_sim, os.path.join(work, "exp"), duration_s=20)
    log_path = os.path.join(experiment, "can.log")
    with can.CanutilsLogReader(log_path) as reader:
        messages = list(reader)
    lines = support.candump_frame_lines(log_path)
    check(len(messages) == len(lines) > 1000,
          f"python-can read {len(messages)} frames of the log's {len(lines)}")

    aseba = support.AsebaReassembler()
    for m in messages:
        aseba.add(m.timestamp, m.arbitration_id, m.data, "log frame")
    check(not aseba.anomalies, f"the log itself has framing anomalies: {aseba.anomalies[:3]}")
    events, others = support.decode_events(
        aseba.messages, support.robot_nodes(os.path.join(experiment, "robot.json")))
    odometry = sum(1 for _, text in events if text.startswith("odometry"))
    scanner = len(events) - odometry

    modem = NullModem()
    try:
        args = ["--source", f"slcan:{modem.a_path}", "--robot",
                os.path.join(experiment, "robot.json"), "--budget", "8125"]
        with support.Slamd(slamd_bin, args, work) as slamd:
            bus = can.Bus(interface="slcan", channel=modem.b_path, bitrate=1000000,
                          sleep_after_open=0)
            try:
                send_paced(bus, messages, SPEED)
                status = slamd.poll_status(
                    lambda s: s["link"]["frames"] >= len(messages)
                    and s["link"]["events_queued"] >= len(events), 10)
                # What python-can wrote that is not a frame: its open commands.
                sent_lines = modem.carried_to_a().split(b"\r")
                commands = [line for line in sent_lines[:-1] if not line.startswith(b"t")]
                frame_lines = len(sent_lines) - 1 - len(commands)
                slamd_sent = modem.carried_to_b()
            finally:
                bus.shutdown()
    finally:
        modem.close()

    check(frame_lines == len(messages),
          f"python-can wrote {frame_lines} frame lines for {len(messages)} frames")
    # slamd only opens the adapter at 1 Mbit/s (close, bit rate, open) and never sends a frame.
    check(slamd_sent == b"C\rS8\rO\r", f"slamd sent {slamd_sent!r} to the adapter")
    link = status["link"]
    source = link["source_counters"]
    expected = {
        "link.state": "running",
        "link.source_errors": 0,
        "link.frames": len(messages),
        "link.source_counters.frames": len(messages),
        "link.source_counters.nacks": 0,
        "link.source_counters.bad_lines": len(commands),
        "link.frames_rejected": 0,
        "link.reassembly.frames": len(messages),
        "link.reassembly.messages": len(aseba.messages),
        "link.decoder.messages": len(aseba.messages),
        "link.decoder.odometry": odometry,
        "link.decoder.scanner": scanner,
        "link.decoder.raw_out_of_range": 0,
        "link.events_queued": len(events),
        "link.queue_drops": 0,
    }
    for name in ("extended", "remote", "fd", "foreign", "bad_length", "middle_without_start",
                 "stop_without_start", "oversize", "abandoned"):
        expected[f"link.reassembly.{name}"] = 0
    for key, value in expected.items():
        node = status
        for part in key.split("."):
            node = node[part]
        check(node == value, f"/api/v1/status {key} is {node!r}, expected {value!r} "
                             f"(python-can sent {len(messages)} frames; commands {commands})\n"
                             f"link: {link}")
    check(status["slam"]["scans"] >= 10,
          f"only {status['slam']['scans']} scans mapped from a 20 s log: {status['slam']}")
    print(f"python-can sent {len(messages)} frames over slcan ({len(commands)} commands: "
          f"{b' '.join(commands).decode()}); slamd read {source['frames']}, decoded "
          f"{link['decoder']['odometry']} odometry and {link['decoder']['scanner']} scanner "
          f"events, rejected none, mapped {status['slam']['scans']} scans")


if __name__ == "__main__":
    support.run_test(main)
