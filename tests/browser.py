"""The headless browser of the page-rendering tests (issue 40, item 5).

:func:`chromium` returns Debian's ``chromium`` (or ``chromium-browser``). Where none is found the
test skips, unless ``STIFFNESS_REQUIRE_BROWSER=1`` (set by ``.ci/run``, which installs the
browser and stops when it cannot): then it fails, so CI never passes with its browser tests
silently skipped.
"""

from __future__ import annotations

import os
import shutil

import pytest

#: The environment variable that makes a missing browser a failure.
REQUIRE = "STIFFNESS_REQUIRE_BROWSER"


def chromium() -> str:
    """Path of the headless browser; skip (or fail under ``STIFFNESS_REQUIRE_BROWSER=1``)
    when there is none."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        message = "no chromium on this machine (.ci/run installs Debian's chromium)"
        if os.environ.get(REQUIRE) == "1":
            pytest.fail(f"{message}, and {REQUIRE}=1 requires it")
        pytest.skip(message)
    return browser
