"""Text from files (topics, frame ids, paths, names in headers) made safe to print: control characters escaped.

A topic named "a\\nb" or "\\x1b[31m" must not split a one-line error in two or recolour the user's terminal
(https://owasp.org/www-community/attacks/Log_Injection); printable text, non-ASCII letters included, is kept.
"""

from __future__ import annotations

import logging
import re
from typing import Final

# C0 and C1 controls, DEL, and the Unicode line/paragraph separators and bidi overrides that reorder a line.
_UNSAFE: Final = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029\u202a-\u202e\u2066-\u2069]")


def _escape(match: re.Match[str]) -> str:
    ch = match.group(0)
    named = {"\n": "\\n", "\r": "\\r", "\t": "\\t", "\x1b": "\\x1b"}
    if ch in named:
        return named[ch]
    code = ord(ch)
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}"


def safe(text: object) -> str:
    """`text` as a string with every control character written as an escape (\\n, \\x1b, \\u202e ...)."""
    s = _UNSAFE.sub(_escape, str(text))
    if s.isprintable():
        return s
    # anything else the Unicode database calls unprintable (other format characters, unassigned code points)
    return "".join(c if c.isprintable() or c == " " else _escape_one(c) for c in s)


def _escape_one(ch: str) -> str:
    code = ord(ch)
    return f"\\x{code:02x}" if code < 0x100 else (f"\\u{code:04x}" if code < 0x10000 else f"\\U{code:08x}")


def one_line(text: object) -> str:
    """A message as exactly one safe line (a library's multi-line message keeps its lines, joined by ' | ')."""
    lines = [line.strip() for line in str(text).splitlines() if line.strip()]
    return safe(" | ".join(lines))


class SafeFormatter(logging.Formatter):
    """Log records as one safe line each (a logged path or topic may hold control characters)."""

    def format(self, record: logging.LogRecord) -> str:
        return one_line(super().format(record))
