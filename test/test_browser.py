"""The headless browser the page tests use: a page served on 127.0.0.1, its script run."""

from __future__ import annotations

import functools
import http.server
import threading
from pathlib import Path

from tools.browser import headless_page


def test_headless_chromium_runs_a_served_page_s_script(tmp_path: Path) -> None:
    (tmp_path / "index.html").write_text(
        "<html><body><p id=x>0</p><script>"
        "setTimeout(() => { document.getElementById('x').textContent = String(6 * 7) }, 50)"
        "</script></body></html>"
    )
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(tmp_path))
    handler.log_message = lambda *a: None  # type: ignore[attr-defined]
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    try:
        with headless_page() as page:
            page.goto(f"http://127.0.0.1:{srv.server_port}/index.html")
            page.wait_for_function("document.getElementById('x').textContent === '42'")
            assert page.text_content("#x") == "42"
            shot = page.screenshot()
            assert shot[:8] == b"\x89PNG\r\n\x1a\n"
    finally:
        srv.shutdown()
        srv.server_close()
