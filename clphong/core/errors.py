"""Exceptions raised by clphong.

Every error carries a one-line message that names the file, channel or key at
fault and says what to do about it. The CLI prints ``str(error)`` on one line
of stderr and exits non-zero.
"""


class ClphongError(Exception):
    """Base class of every error clphong raises on bad input or environment."""

    exit_code = 1


class GBufferError(ClphongError):
    """A G-buffer file is unreadable, lacks a channel, or is inconsistent."""


class SceneError(ClphongError):
    """A scene file is invalid: bad TOML, an unknown key, a wrong type or value."""


class DeviceError(ClphongError):
    """No usable OpenCL device, or a kernel failed to build."""


class OutputError(ClphongError):
    """An output file cannot be written."""


class ToneMapError(ClphongError, ValueError):
    """An unknown tone-mapping operator or an invalid operator parameter."""


class ClphongWarning(UserWarning):
    """Input or output that clphong handled by a documented policy (the CLI
    prints each as one line, ``clphong: warning: ...``)."""


class InputWarning(ClphongWarning):
    """Non-finite G-buffer values were handled by the input policy."""


class DeviceWarning(ClphongWarning):
    """A device configuration failed its self-test and a safer one is used instead."""


class OutputWarning(ClphongWarning):
    """Output values were changed to fit the file format (e.g. the half range)."""


#: Longest message line the CLI prints; longer ones are cut, and say so.
MAX_LINE = 2000


def printable(text: str) -> str:
    """``text`` with every control character but the newline escaped as ``\\xNN`` /
    ``\\uNNNN`` (layout kept: spaces and line breaks stay), for multi-line reports
    that show names read from files (a channel named ESC[2K would erase a line)."""
    return "\n".join("".join(ch if ch.isprintable() or ch == " " else
                              (f"\\x{ord(ch):02x}" if ord(ch) < 0x100 else f"\\u{ord(ch):04x}")
                              for ch in line)
                      for line in str(text).split("\n"))


def cut_line(line: str, limit: int = MAX_LINE) -> str:
    """``line`` cut to ``limit`` characters with ``… (N more characters)``, if longer."""
    if len(line) > limit:
        line = f"{line[:limit]}… ({len(line) - limit} more characters)"
    return line


def clean_line(text: str, limit: int = MAX_LINE) -> str:
    """``text`` as one safe line for a terminal: whitespace runs (newlines, tabs)
    become one space, every other control character (C0, DEL, C1: what lets a
    file's channel name or a library's message move the cursor or erase the
    line) is escaped as ``\\xNN`` / ``\\uNNNN``, and a line longer than
    ``limit`` is cut with ``… (N more characters)``."""
    out = []
    for word in str(text).split():
        out.append("".join(ch if ch.isprintable() else
                           (f"\\x{ord(ch):02x}" if ord(ch) < 0x100 else f"\\u{ord(ch):04x}")
                           for ch in word))
    line = cut_line(" ".join(out), limit)
    return line
