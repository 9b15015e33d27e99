"""A review page served in a background thread and a headless Chromium to drive it: what the browser
tests and the review benchmark share. Chromium runs offline: no first-run, sync, component updates,
background networking or QUIC, and a fresh profile each time.
"""

from __future__ import annotations

import os
import shutil
import socket
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

INSTALL = ("apt-get install chromium chromium-driver (Debian) and pip install selenium "
           "(make install has it)")
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--window-size=1400,1000")


def missing() -> str | None:
    """Why a browser cannot be driven here (with the install line), or None when it can."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        return f"selenium is not installed: {INSTALL}"
    if not chromium_binary() or not shutil.which("chromedriver"):
        return f"chromium or chromedriver is not on PATH: {INSTALL}"
    return None


def chromium_binary() -> str | None:
    """The Chromium executable on PATH, if any."""
    return shutil.which("chromium") or shutil.which("chromium-browser")


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def served(app, timeout: float = 30.0) -> Iterator[str]:
    """``app`` served by uvicorn on 127.0.0.1 in a daemon thread; yields its URL, stops it on exit."""
    import uvicorn

    port = free_port()
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + timeout
    while not server.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            raise RuntimeError(f"the review server did not start on port {port}")
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}/"
    finally:
        server.should_exit = True
        thread.join(timeout)


@contextmanager
def chromium() -> Iterator:
    """A headless Chromium driven by selenium (chromedriver from PATH, never downloaded)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    os.environ.setdefault("SE_OFFLINE", "true")  # selenium's manager must not look for drivers online
    with tempfile.TemporaryDirectory(prefix="rdd-chromium-") as profile:
        options = webdriver.ChromeOptions()
        options.binary_location = chromium_binary() or ""
        for flag in (*CHROMIUM_FLAGS, f"--user-data-dir={profile}"):
            options.add_argument(flag)
        driver = webdriver.Chrome(options=options, service=Service(executable_path=shutil.which("chromedriver")))
        try:
            yield driver
        finally:
            driver.quit()
