"""Exceptions raised by clphong.

Every error carries a one-line message that names the file, channel or key at
fault and says what to do about it. The CLI prints ``str(error)`` on one line
of stderr and exits non-zero.
"""


import re

#: The most characters of one name or value a message quotes (issue 26): a longer run of
#: non-space characters is abbreviated around an ellipsis, with its length.
QUOTE_MAX = 200
_LONG_WORD = re.compile(r"\S{%d,}" % (QUOTE_MAX + 1))


def abbreviate(text: str, limit: int = QUOTE_MAX) -> str:
    """``text`` with every run of non-space characters longer than ``limit`` (a name or
    value a user supplied: a 100,000-character TOML key) cut to its first and last
    characters around an ellipsis, and its length: ``'kkk…kkk' (100,002 characters)``."""
    if len(text) <= limit:
        return text
    head, tail = limit * 3 // 4, limit // 8

    def short(m):
        w = m.group(0)
        return f"{w[:head]}…{w[-tail:]} ({len(w):,} characters)"

    pattern = _LONG_WORD if limit == QUOTE_MAX else re.compile(r"\S{%d,}" % (limit + 1))
    return pattern.sub(short, text)


class ClphongError(Exception):
    """Base class of every error clphong raises on bad input or environment. Its message
    quotes at most QUOTE_MAX characters of any one word (:func:`abbreviate`), in the CLI
    and from the API alike."""

    exit_code = 1

    def __init__(self, *args):
        if args and isinstance(args[0], str):
            args = (abbreviate(args[0]),) + args[1:]
        super().__init__(*args)


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
    line = cut_line(abbreviate(" ".join(out)), limit)
    return line
