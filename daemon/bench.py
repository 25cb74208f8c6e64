"""``python -m scotti.daemon.bench``: the name the docs and issues have used for the bench.

The bench lives with the other tools in daemon/tools/bench.py; this module only
keeps the short command working.
"""

from scotti.daemon.tools.bench import main

if __name__ == "__main__":
    raise SystemExit(main())
