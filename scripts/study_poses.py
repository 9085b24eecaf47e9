"""Trajectories as the study scripts read them (scripts/kidnap-study, scripts/localize-study):
TUM files, poses (x, y, theta), the ground truth at a time, and rigid fits."""
import bisect
import math


def read_tum(path):
    rows = []
    with open(path) as f:
        for line in f:
            v = line.split()
            if len(v) != 8 or line.startswith("#"):
                continue
            t, x, y = float(v[0]), float(v[1]), float(v[2])
            qz, qw = float(v[6]), float(v[7])
            rows.append((t, x, y, 2.0 * math.atan2(qz, qw)))
    return rows


def relative(a, b):
    """a^-1 * b for poses (x, y, theta)."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    c, s = math.cos(a[2]), math.sin(a[2])
    return (c * dx + s * dy, -s * dx + c * dy, wrap(b[2] - a[2]))


def wrap(a):
    return math.atan2(math.sin(a), math.cos(a))


def truth_at(truth, t):
    # The first ground-truth row at or after t (the simulator writes it at 30 Hz), the last
    # one past the end.
    i = bisect.bisect_left(truth, t, key=lambda row: row[0])
    return truth[min(i, len(truth) - 1)]


def fit_rigid(pairs):
    """The rigid motion (x, y, theta) that best carries the first points of `pairs` onto the
    second ones (least squares)."""
    n = len(pairs)
    ax = sum(a[0] for a, _ in pairs) / n
    ay = sum(a[1] for a, _ in pairs) / n
    bx = sum(b[0] for _, b in pairs) / n
    by = sum(b[1] for _, b in pairs) / n
    sxx = sum((a[0] - ax) * (b[0] - bx) + (a[1] - ay) * (b[1] - by) for a, b in pairs)
    sxy = sum((a[0] - ax) * (b[1] - by) - (a[1] - ay) * (b[0] - bx) for a, b in pairs)
    th = math.atan2(sxy, sxx)
    c, s = math.cos(th), math.sin(th)
    return (bx - (c * ax - s * ay), by - (s * ax + c * ay), th)


def apply(T, p):
    c, s = math.cos(T[2]), math.sin(T[2])
    return (T[0] + c * p[0] - s * p[1], T[1] + s * p[0] + c * p[1], wrap(p[2] + T[2]))
