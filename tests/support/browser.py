"""Headless Chromium for the tests that check what a person sees (the run report, the viewer), driven by
Playwright with Debian's ``chromium`` package (no browser download). Where no Chromium is installed the tests
skip, unless $GLIMPSE_REQUIRE_BROWSER is set (CI sets it), which makes a missing browser a failure."""

from __future__ import annotations

import os
import shutil
import socket

import pytest

CANDIDATES = ("chromium", "chromium-browser", "google-chrome")


def chromium_path() -> str:
    """The Chromium executable: $GLIMPSE_CHROMIUM, else the first of CANDIDATES on PATH; skips (or fails under
    $GLIMPSE_REQUIRE_BROWSER) when there is none or Playwright is not installed."""
    found = os.environ.get("GLIMPSE_CHROMIUM") or next(filter(None, map(shutil.which, CANDIDATES)), None)
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        found = None
    if found is None:
        message = "no headless Chromium with Playwright here (apt-get install chromium; the test extra)"
        if os.environ.get("GLIMPSE_REQUIRE_BROWSER"):
            pytest.fail(message + ", and GLIMPSE_REQUIRE_BROWSER is set")
        pytest.skip(message)
    return found


def launch(playwright, webgl: bool = False):
    """A headless Chromium browser (the caller closes it); ``webgl``: with WebGL in software (SwiftShader), for
    pages that draw with three.js such as the viewer's."""
    flags = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"] if webgl else ["--disable-gpu"]
    return playwright.chromium.launch(executable_path=chromium_path(), headless=True, args=["--no-sandbox", *flags])


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]
