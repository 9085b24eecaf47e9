"""What the outside-client tests share: slam-sim logs, a slamd child process, HTTP, Aseba.

The Aseba reassembly and event decoding here are written from the framing facts (notes on CAN
and Aseba, docs/design.md section 5), not from the project's C++: they are a second reading of
the same bytes, to hold the project's own reader against.
"""

import json
import os
import re
import signal
import subprocess
import sys
import time
import urllib.request


class TestFailure(Exception):
    """A check that failed: the runner prints it and exits 1."""


def check(condition, message):
    if not condition:
        raise TestFailure(message)


def run_test(main):
    """Runs main(); exit 0 on success, 1 (with the reason on stderr) on a failed check."""
    try:
        main()
    except TestFailure as failure:
        print(f"FAIL: {failure}", file=sys.stderr)
        sys.exit(1)


def fresh_dir(path):
    """An empty directory at `path` (whatever was there is removed)."""
    if os.path.isdir(path):
        subprocess.run(["rm", "-rf", path], check=True)
    os.makedirs(path)
    return path


def make_experiment(slam_sim, out, world="box", duration_s=20, seed=5):
    """Writes a recorded experiment with slam-sim; its directory (can.log, robot.json, ...)."""
    result = subprocess.run(
        [slam_sim, "--world", world, "--duration", str(duration_s), "--seed", str(seed),
         "--out", out], capture_output=True, text=True, timeout=120)
    check(result.returncode == 0,
          f"slam-sim exited {result.returncode}: {result.stderr.strip()}")
    check(os.path.isfile(os.path.join(out, "can.log")), f"slam-sim wrote no {out}/can.log")
    return out


def candump_frame_lines(path):
    """The frame lines of a candump log by canplayer's rule: lines starting with '('."""
    with open(path, encoding="ascii") as log:
        return [line.rstrip("\n") for line in log if line.lstrip().startswith("(")]


def robot_nodes(robot_json_path):
    """(base node, base event, scanner node, scanner event) from a robot.json."""
    with open(robot_json_path, encoding="utf-8") as f:
        robot = json.load(f)
    return (robot["base"]["node"], robot["base"]["event"], robot["scanner"]["node"],
            robot["scanner"]["event"])


# --- Aseba over CAN ----------------------------------------------------------------------------

SMALL, START, MIDDLE, STOP = 3, 1, 0, 2  # fragment type: CAN id bits 9..8


class AsebaReassembler:
    """Per-source reassembly of Aseba messages from CAN frames, strict: on a clean log every
    frame must fit, so any anomaly is recorded (the tests expect none)."""

    def __init__(self):
        self.pending = {}  # source -> (bytes so far)
        self.messages = []  # (time, source, type, payload bytes)
        self.anomalies = []

    def add(self, t, can_id, data, what):
        if can_id > 0x3FF:
            self.anomalies.append(f"{what}: id {can_id:#x} is not an Aseba id")
            return
        kind, source = can_id >> 8, can_id & 0xFF
        if kind == SMALL:
            if not 2 <= len(data) <= 8:
                self.anomalies.append(f"{what}: single frame of {len(data)} bytes")
            if source in self.pending:
                self.anomalies.append(f"{what}: single frame abandons a message of {source}")
                del self.pending[source]
            self._emit(t, source, bytes(data))
        elif kind == START:
            if len(data) != 8:
                self.anomalies.append(f"{what}: start frame of {len(data)} bytes")
            if source in self.pending:
                self.anomalies.append(f"{what}: start frame abandons a message of {source}")
            self.pending[source] = bytes(data)
        elif kind == MIDDLE:
            if source not in self.pending:
                self.anomalies.append(f"{what}: middle frame without a start")
            elif len(data) != 8:
                self.anomalies.append(f"{what}: middle frame of {len(data)} bytes")
            else:
                self.pending[source] += bytes(data)
        else:  # STOP
            if source not in self.pending:
                self.anomalies.append(f"{what}: stop frame without a start")
            elif not 1 <= len(data) <= 8:
                self.anomalies.append(f"{what}: stop frame of {len(data)} bytes")
            else:
                self._emit(t, source, self.pending.pop(source) + bytes(data))

    def _emit(self, t, source, message):
        if len(message) > 518:
            self.anomalies.append(f"message of {len(message)} bytes from {source}")
        self.messages.append((t, source, message[0] | message[1] << 8, message[2:]))


def words(payload):
    """16-bit little-endian words."""
    return [payload[i] | payload[i + 1] << 8 for i in range(0, len(payload) - 1, 2)]


def signed(value, bits):
    return value - (1 << bits) if value >= 1 << (bits - 1) else value


def decode_events(messages, nodes):
    """The robot events of Aseba messages, as (time, text) with the text in slam-link's
    `--events` layout; messages that are not robot events go into the second list."""
    base_node, base_event, scanner_node, scanner_event = nodes
    events, others = [], []
    for t, source, kind, payload in messages:
        w = words(payload)
        if source == base_node and kind == base_event and len(payload) == 12:
            left = signed(w[1] | w[2] << 16, 32)
            right = signed(w[3] | w[4] << 16, 32)
            events.append((t, f"odometry seq={w[0]} left={left} right={right} "
                              f"gyro={signed(w[5], 16)}"))
        elif source == scanner_node and kind == scanner_event and len(payload) == 14:
            events.append((t, f"scanner seq={w[0]} angle={w[1]} "
                              f"raw={w[2]},{w[3]},{w[4]},{w[5]} rectifier_mv={w[6]}"))
        else:
            others.append((t, source, kind, len(payload)))
    return events, others


# --- slamd ---------------------------------------------------------------------------------------

class Slamd:
    """A slamd child process on a free port: started, waited for, always stopped."""

    SERVING = re.compile(r"^slamd: serving (http://[^ ]+)")

    def __init__(self, binary, args, work_dir):
        self.binary = binary
        # The Foxglove server's default port is fixed (8765): off unless a test gives a port.
        foxglove = [] if "--foxglove-port" in args else ["--foxglove-port", "0"]
        self.args = ["--port", "0", "--quiet"] + foxglove + list(args)
        self.stdout_path = os.path.join(work_dir, "slamd.stdout")
        self.stderr_path = os.path.join(work_dir, "slamd.stderr")
        self.process = None
        self.url = None

    def __enter__(self):
        with open(self.stdout_path, "wb") as out, open(self.stderr_path, "wb") as err:
            self.process = subprocess.Popen([self.binary] + self.args, stdout=out, stderr=err)
        try:
            return self._wait_ready()
        except BaseException:
            self.__exit__()  # a with block whose __enter__ fails never calls __exit__
            raise

    def _wait_ready(self):
        deadline = time.monotonic() + 20
        while self.url is None:
            with open(self.stdout_path, encoding="utf-8", errors="replace") as out:
                for line in out:
                    match = self.SERVING.match(line)
                    if match:
                        self.url = match.group(1).rstrip("/")
            if self.url is None:
                self._check_alive("before serving")
                check(time.monotonic() < deadline,
                      "slamd printed no 'slamd: serving' line within 20 s" + self.stderr_tail())
                time.sleep(0.1)
        deadline = time.monotonic() + 10
        while True:
            try:
                if self.get_json("/api/v1/health").get("status") == "ok":
                    return self
            except OSError:
                pass
            self._check_alive("before it was healthy")
            check(time.monotonic() < deadline, "slamd was not healthy within 10 s")
            time.sleep(0.1)

    def __exit__(self, *exc):
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        return False

    def _check_alive(self, when):
        code = self.process.poll()
        check(code is None, f"slamd exited ({code}) {when}" + self.stderr_tail())

    def stderr_tail(self):
        try:
            with open(self.stderr_path, encoding="utf-8", errors="replace") as err:
                lines = err.read().splitlines()[-20:]
        except OSError:
            return ""
        return "\n--- slamd stderr (last lines) ---\n" + "\n".join(lines) if lines else ""

    def get(self, path):
        """(status, headers, body bytes) of GET path."""
        with urllib.request.urlopen(self.url + path, timeout=5) as response:
            return response.status, response.headers, response.read()

    def get_json(self, path):
        return json.loads(self.get(path)[2])

    def poll_status(self, done, timeout_s):
        """Polls /api/v1/status until done(status) or the timeout; the last status."""
        deadline = time.monotonic() + timeout_s
        while True:
            status = self.get_json("/api/v1/status")
            if done(status) or time.monotonic() >= deadline:
                return status
            self._check_alive("while the test waited")
            time.sleep(0.1)
