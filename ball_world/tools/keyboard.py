"""The terminal as a keyboard and a small screen, for ball_world_teleop.

Single key presses without echo (Ctrl-C arrives as a key), the escape sequences of arrow keys
decoded, a few lines redrawn in place under a fixed help text, and the terminal put back
exactly as it was on every way out: q, Ctrl-C, SIGTERM, SIGHUP or an exception.
"""
import os
import select
import signal
import termios

#: Final bytes of the escape sequences a terminal sends for these keys (CSI or SS3 form).
_ESCAPE_KEYS = {'A': 'up', 'B': 'down', 'C': 'right', 'D': 'left', 'Z': 'backtab'}


class Quit(Exception):
    """Raised by the signal handlers, so that every way out restores the terminal."""


class KeyDecoder:
    """Bytes read from a terminal in non-canonical mode -> key names.

    Arrow keys arrive as ESC [ A..D (ESC O A..D in application cursor mode), Shift-Tab as
    ESC [ Z. A read may hold several keys or half a sequence, and keys this tool does not
    use (Ctrl-arrows, F-keys) send longer sequences whose bytes must not be taken for
    digits: a CSI sequence runs to its final byte (0x40-0x7E) and only unmodified ones count.
    """

    def __init__(self):
        self._pending = b''

    def feed(self, data):
        data = self._pending + data
        keys = []
        i = 0
        while i < len(data):
            if data[i] != 0x1B:
                keys.append(chr(data[i]))
                i += 1
                continue
            if i + 1 == len(data):
                break  # the rest of the sequence is still on its way
            kind = data[i + 1]
            if kind == ord('O'):
                if i + 2 == len(data):
                    break
                keys.append(_ESCAPE_KEYS.get(chr(data[i + 2])))
                i += 3
            elif kind == ord('['):
                end = i + 2
                while end < len(data) and not 0x40 <= data[end] <= 0x7E:
                    end += 1
                if end == len(data):
                    break
                plain = end == i + 2
                keys.append(_ESCAPE_KEYS.get(chr(data[end])) if plain else None)
                i = end + 1
            else:
                i += 1  # a lone Esc
        self._pending = data[i:]
        return [key for key in keys if key is not None]


class Screen:
    """The help text, then lines redrawn in place; never wider than the terminal.

    Output processing stays on (RawKeys changes input only), so '\\n' starts a new line.
    """

    def __init__(self, fd, header):
        self.fd = fd
        self.header = header.splitlines()
        self.shown = []

    def _write(self, text):
        os.write(self.fd, text.encode())

    def start(self):
        width = self._width()
        self._write('\x1b[?25l\x1b[2J\x1b[H'  # hide the cursor, clear, home
                    + ''.join(line[:width] + '\n' for line in self.header))

    def _width(self):
        try:
            return max(20, os.get_terminal_size(self.fd).columns - 1)
        except OSError:
            return 79

    def draw(self, lines):
        if lines == self.shown:
            return
        width = self._width()
        first = len(self.header) + 2  # a blank line after the help text
        out = [f'\x1b[{first + row};1H{line[:width]}\x1b[K' for row, line in enumerate(lines)]
        self._write(''.join(out))
        self.shown = lines

    def finish(self):
        row = len(self.header) + 2 + len(self.shown)
        try:
            self._write(f'\x1b[{row};1H\x1b[?25h\n')  # below the lines, cursor shown
        except OSError:
            pass  # the terminal is gone (hung up): nothing left to show


class RawKeys:
    """The terminal in single-key mode (no line buffering, no echo, Ctrl-C as a key).

    Signals that end the program (SIGINT, SIGTERM, SIGHUP) raise Quit in the one thread, and
    are blocked while the saved settings go back, so nothing can interrupt the restore:

        with RawKeys(fd) as keys:
            try:
                keys.let_signals_in()
                ...
            except Quit:
                ...
    """

    QUIT_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

    def __init__(self, fd):
        self.fd = fd
        self.saved = None

    def __enter__(self):
        self.saved = termios.tcgetattr(self.fd)
        mode = termios.tcgetattr(self.fd)
        mode[0] &= ~termios.IXON  # Ctrl-S would freeze the screen
        mode[3] &= ~(termios.ICANON | termios.ECHO | termios.ISIG | termios.IEXTEN)
        mode[6][termios.VMIN], mode[6][termios.VTIME] = 1, 0
        # Signals wait until the caller is inside its try block (see let_signals_in), so
        # none can land between this change and the code that undoes it.
        self.hold_signals()
        termios.tcsetattr(self.fd, termios.TCSADRAIN, mode)
        for signum in self.QUIT_SIGNALS:
            signal.signal(signum, self._on_signal)
        return self

    def let_signals_in(self):
        """From here on SIGINT, SIGTERM and SIGHUP raise Quit (one waiting is raised now)."""
        signal.pthread_sigmask(signal.SIG_UNBLOCK, self.QUIT_SIGNALS)

    @staticmethod
    def _on_signal(signum, frame):
        raise Quit(signal.Signals(signum).name)

    def read(self, timeout):
        """Bytes typed so far (b'' if none within timeout); Quit when the terminal is gone."""
        ready, _, _ = select.select([self.fd], [], [], timeout)
        if not ready:
            return b''
        data = os.read(self.fd, 1024)
        if not data:
            raise Quit('end of input')
        return data

    def hold_signals(self):
        """From here on a signal waits: the clean-up runs to its end."""
        signal.pthread_sigmask(signal.SIG_BLOCK, self.QUIT_SIGNALS)

    def __exit__(self, *exc):
        self.hold_signals()
        try:
            termios.tcsetattr(self.fd, termios.TCSADRAIN, self.saved)
        except termios.error:
            pass  # the terminal is gone (hung up): nothing left to restore
        return False
