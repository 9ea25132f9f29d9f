"""Progress of a long tool run (a conversion, a re-simulation, a repair) on stderr.

On a terminal the bar redraws in place ('\\r', at most every `interval` seconds) and ends
with a newline; anywhere else (a pipe, a log file, CI) nothing is drawn while working and
one final line is printed, so logs stay short. Whether it is a terminal is asked of the
stream actually written to, stderr, not of stdout.
"""
import sys
import time


class Progress:
    """Counts work done out of a total and draws it (see the module docstring).

    unit names what is counted ('steps', 'bytes'); label starts the line (the tool's name).
    """

    def __init__(self, total, unit, label, stream=None, width=30, interval=0.1):
        self.total = max(int(total), 0)
        self.unit = unit
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        self.width = width
        self.interval = interval
        self.done = 0
        isatty = getattr(self.stream, 'isatty', None)
        self.tty = bool(isatty and isatty())
        self._drawn_at = None
        self._started = time.monotonic()
        self._finished = False

    def advance(self, amount=1):
        self.done += amount
        if self.tty:
            now = time.monotonic()
            if self._drawn_at is None or now - self._drawn_at >= self.interval:
                self._drawn_at = now
                self._write('\r' + self.line())

    def line(self):
        """The bar as one line of text (no newline)."""
        count = f'{self.done:,}/{self.total:,} {self.unit}' if self.total else \
            f'{self.done:,} {self.unit}'
        if not self.total:
            return f'{self.label}: {count}'
        fraction = min(self.done / self.total, 1.0)
        filled = round(fraction * self.width)
        bar = '#' * filled + '.' * (self.width - filled)
        return f'{self.label}: [{bar}] {fraction:4.0%} {count}'

    def finish(self):
        """Draw the final state and end the line (once; later calls do nothing)."""
        if self._finished:
            return
        self._finished = True
        seconds = time.monotonic() - self._started
        self._write(('\r' if self.tty else '') + f'{self.line()} in {seconds:.1f} s\n')

    def abandon(self):
        """End a bar drawn in place, so an error message starts on a line of its own."""
        if self.tty and self._drawn_at is not None and not self._finished:
            self._finished = True
            self._write('\n')

    def _write(self, text):
        self.stream.write(text)
        self.stream.flush()


class StepProgress(Progress):
    """A Progress that is also a Sink: feed_sinks() advances it one step per record."""

    def __init__(self, total, label, stream=None):
        super().__init__(total, 'steps', label, stream)

    def start_segment(self, world, info):
        """Segments do not change the count."""

    def write_step(self, record):
        self.advance()

    def flush(self):
        """Nothing is buffered."""

    def close(self):
        self.finish()
