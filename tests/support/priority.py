"""Browsers run below the robots: a test's browser is niced so that the simulated robots, the broker and
the server it watches keep the CPU they need on a loaded two-core machine.

On the 2-core CI machine the browser lane's Chromium processes held the load average at 7-13, and a
simulated robot whose agent waited that long for a core went silent on its link (the agent stops its
motors after 0.35 s without an echo): its mission failed (``link_lost``) under a test that only meant to
watch it. At a base station the robots are Pis of their own and the browser is on a laptop; here they share
two cores, so the browser, which only has to render in time for Playwright's waits, yields first.

As root, Chromium raises its browser and GPU processes to nice -8 (CAP_SYS_NICE): a browser is therefore
started without that capability (``setpriv``), so that it keeps the niceness it was given.
"""

from __future__ import annotations

import os
import shutil

import psutil

#: the niceness of browsers and their drivers (a CFS weight about a tenth of a robot's)
BROWSER_NICE = 10


def below_the_robots(cmd: list[str]) -> list[str]:
    """``cmd`` (a browser, or the bridge that starts one) at BROWSER_NICE, without CAP_SYS_NICE as root."""
    up = max(0, BROWSER_NICE - os.nice(0))
    niced = ["nice", "-n", str(up), *cmd]
    setpriv = shutil.which("setpriv")
    if os.geteuid() == 0 and setpriv:
        return [setpriv, "--bounding-set", "-sys_nice", "--inh-caps", "-sys_nice", *niced]
    return niced


def nice_playwright_driver() -> None:
    """Nice the Playwright driver this process started (it relays every call to the browser); the browser
    itself is launched through tests/frontend/chromium-niced."""
    for child in psutil.Process().children(recursive=True):
        try:
            if "run-driver" in " ".join(child.cmdline()) and child.nice() < BROWSER_NICE:
                child.nice(BROWSER_NICE)
        except psutil.Error:
            continue
