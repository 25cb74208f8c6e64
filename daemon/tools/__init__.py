"""What stands around the service: fault and soak drivers, the fuzzer.

Each tool is a command, ``python -m scotti.daemon.tools.<name>``; none is
imported by the daemon itself.
"""

import re

_LITERAL = re.compile(r"``(.+?)``", re.S)


def plain_help(text: str | None) -> str:
    """A docstring as a --help text: its reST literals (``x``) as a terminal shows 'x'."""
    return _LITERAL.sub(r"'\1'", text or "")
