"""``python -m stiffness``: the ``stiffness`` command (:func:`stiffness.cli.main.main`), for
an environment whose scripts folder is not on the PATH."""

import sys

from stiffness.cli.main import main

if __name__ == "__main__":
    sys.exit(main())
