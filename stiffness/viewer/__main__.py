"""``python -m stiffness.viewer --serve HOST PORT PARENT_PID [LOG [LIMITS_JSON]]``:
the live server process.

:class:`stiffness.viewer.server.LiveServer` starts it; see :func:`stiffness.viewer.server.main`.
"""

import sys

from stiffness.viewer.server import main

if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
