"""The socketcand protocol's text elements as the hub reads and writes them (socketcand
``doc/protocol.md``): ``< send ID LEN B0 … >`` parsed, the ``SEC.USEC`` time stamp of ``< frame … >``."""
from __future__ import annotations

import re

#: What :func:`parse_send` returns for a remote request (LEN > 0 without data: python-can's client sends
#: an RTR frame so).
REMOTE = "remote"
HEX = re.compile(r"[0-9A-Fa-f]{1,8}")
#: ``< send ID LEN B0 … >`` with a standard (≤ 3 digit) ID and up to 8 data bytes: the hub's hot path.
FAST_SEND = re.compile(rb"\s*<\s*send\s+([0-9A-Fa-f]{1,3})\s+([0-8])((?:\s+[0-9A-Fa-f]{1,2}){0,8})\s*>")


def stamp(now: float) -> str:
    """SEC.USEC of a Unix time (socketcand's frame time stamp)."""
    sec = int(now)
    return f"{sec}.{int((now - sec) * 1e6):06d}"


def parse_send(args: list[str]) -> tuple[int, bool, bytes] | str:
    """``ID LEN B0 ...`` → (id, extended, data), :data:`REMOTE`, or an error text. IDs are unsigned
    hexadecimal: up to 3 digits an 11-bit identifier (≤ 0x7FF), more a 29-bit one (≤ 0x1FFFFFFF)."""
    if len(args) < 2:
        return "usage: send ID LEN DATA"
    if not all(HEX.fullmatch(a) for a in args) or any(len(b) > 2 for b in args[2:]) or len(args[1]) > 1:
        return "send: ID, LEN and data must be unsigned hexadecimal (data bytes of two digits)"
    can_id, length = int(args[0], 16), int(args[1], 16)
    data = bytes(int(b, 16) for b in args[2:])
    extended = len(args[0]) > 3
    if can_id > (0x1FFFFFFF if extended else 0x7FF):
        return "send: ID out of range"
    if 0 < length <= 8 and not data:
        return REMOTE
    if not 0 <= length <= 8 or len(data) != length:
        return "send: LEN must be 0..8 and equal the number of data bytes"
    return can_id, extended, data
