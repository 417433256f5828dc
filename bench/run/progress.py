"""Progress of long work: a bar on a terminal (tqdm), a line every PERIOD_S seconds elsewhere.

A run, a sweep or a scene build shows how far it is and how long is left, without costing the
work it reports on: update() reads a clock and returns unless PERIOD_S (a log) or REFRESH_S (a
bar) has passed, and a run calls it between timed steps, never inside one.
"""
import sys
import time

PERIOD_S = 10.0   # seconds between progress lines when not on a terminal
REFRESH_S = 0.25  # seconds between redraws of a terminal bar


def on_terminal(stream=None):
    stream = stream or sys.stderr
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


def format_seconds(s):
    """'42 s', '3 min 05 s', '1 h 02 min'."""
    s = max(0.0, float(s))
    if s < 60:
        return f"{s:.0f} s"
    if s < 3600:
        return f"{int(s // 60)} min {int(s % 60):02d} s"
    return f"{int(s // 3600)} h {int(s % 3600 // 60):02d} min"


class Progress:
    """Progress over `total` units of work named `unit`, with a label. enabled=False makes every
    call free of output (a quiet run, a rank other than 0). `line(done, now)` gives the text of a
    log line; the bar is tqdm's, on stderr."""

    def __init__(self, total, label, unit="step", enabled=True, terminal=None, stream=None, clock=time.monotonic):
        self.total = int(total)
        self.label = label
        self.unit = unit
        self.enabled = bool(enabled) and self.total > 0
        self.clock = clock
        self.stream = stream or sys.stdout
        self.start = clock()
        self.last = self.start
        self.done = 0
        self.bar = None
        terminal = on_terminal() if terminal is None else terminal
        if self.enabled and terminal:
            from tqdm import tqdm
            self.bar = tqdm(total=self.total, desc=label, unit=unit, leave=False, dynamic_ncols=True,
                            mininterval=REFRESH_S, file=sys.stderr)

    def line(self, done, now):
        """'LABEL: 1200/2000 steps (60 %), 35 s elapsed, about 23 s left'."""
        el = now - self.start
        text = f"{self.label}: {done}/{self.total} {self.unit}s ({100.0 * done / self.total:.0f} %), " \
               f"{format_seconds(el)} elapsed"
        if done > 0:
            text += f", about {format_seconds(el / done * (self.total - done))} left"
        return text

    def update(self, done):
        """Record that `done` units are finished (absolute, not an increment)."""
        if not self.enabled:
            return
        now = self.clock()
        if self.bar is not None:
            if now - self.last >= REFRESH_S or done >= self.total:
                self.bar.update(done - self.bar.n)
                self.last = now
        elif now - self.last >= PERIOD_S:
            print(self.line(done, now), file=self.stream, flush=True)
            self.last = now
        self.done = done

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def build_log(terminal=None, stream=None, clock=time.monotonic, period=PERIOD_S):
    """A scene build's log function: every message on a terminal (stderr), else at most one every
    `period` seconds on stdout (a log file or a pipe)."""
    terminal = on_terminal() if terminal is None else terminal
    if terminal:
        return lambda msg: print(msg, file=stream or sys.stderr, flush=True)
    last = [clock()]

    def log(msg):
        now = clock()
        if now - last[0] >= period:
            print(msg, file=stream or sys.stdout, flush=True)
            last[0] = now
    return log
