"""What the browser client's end-to-end tests share: `resecta serve --demo` with its session
ready, a server with no session, and Debian's Chromium (software WebGL through SwiftShader)
driven by Playwright."""
import shutil

import pytest
import requests

from server_harness import Server, wait_for

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
        "--disable-background-networking", "--disable-component-update", "--no-first-run"]


@pytest.fixture(scope="module")
def demo():
    """A demo server and the id of its session, once its models are built."""
    server = Server("--demo")

    def ready():
        sessions = requests.get(f"{server.http_url}/v1/sessions", timeout=30).json()
        s = sessions.get("sessions", [])
        return s and s[0].get("state") == "SESSION_STATE_READY" and s[0]["id"]

    sid = wait_for(ready, timeout=180)
    yield server, sid
    server.stop()


@pytest.fixture(scope="module")
def empty():
    """A server holding no session (in memory, no demo)."""
    server = Server()
    yield server
    server.stop()


@pytest.fixture(scope="module")
def browser():
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


def open_page(browser, server):
    """A page on the server's browser client, once it shows a resection; and the list its
    uncaught errors are collected into."""
    page = browser.new_page(viewport={"width": 1024, "height": 700})
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server.bound["page"])
    page.wait_for_function(
        "() => { const s = window.resecta && window.resecta.state();"
        " return s && s.sessionId && Object.keys(s.resections).length > 0; }", timeout=60_000)
    return page, errors
