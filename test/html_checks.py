"""Reading a report's HTML page back: its tags, its embedded images, its value cells.

Reference for the values: the JSON document the page claims to show. Each value cell carries
``data-path`` (a JSON list of keys); its text is read back as a number, ``yes``/``no``, ``—``
(null) or text and compared with the JSON's value there, independently of the page's own
formatting code.
"""

from __future__ import annotations

import base64
import json
import math
import re
from html.parser import HTMLParser
from typing import Any


class Page(HTMLParser):
    """Every start tag with its attributes, the value cells and the text of a page."""

    def __init__(self, text: str) -> None:
        super().__init__(convert_charrefs=True)
        self.tags: list[tuple[str, dict[str, str | None]]] = []
        self.cells: list[tuple[list[Any], str]] = []
        self.text: list[str] = []
        self._open: list[tuple[list[Any], list[str]]] = []
        self.open_tags: list[str] = []
        self.feed(text)
        self.close()

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        self.tags.append((tag, a))
        if a.get("data-path") is not None:
            self._open.append((json.loads(a["data-path"] or "null"), []))

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th") and self._open:
            path, parts = self._open.pop()
            self.cells.append((path, "".join(parts).strip()))

    def handle_data(self, data: str) -> None:
        self.text.append(data)
        if self._open:
            self._open[-1][1].append(data)

    def images(self) -> list[bytes]:
        """The bytes of every ``<img>`` (each must be a base64 PNG ``data:`` URI)."""
        out = []
        for tag, a in self.tags:
            if tag == "img":
                src = a.get("src") or ""
                head = "data:image/png;base64,"
                assert src.startswith(head), src[:60]
                out.append(base64.b64decode(src[len(head) :], validate=True))
        return out


def assert_self_contained(text: str, page: Page) -> None:
    """No script, no stylesheet link, no external reference, no ``@import``."""
    assert not re.search(r"@import", text)
    for tag, a in page.tags:
        assert tag not in ("script", "link", "iframe", "object", "embed"), tag
        for name in ("src", "href", "action", "srcset"):
            value = (a.get(name) or "").strip().lower()
            assert not value.startswith(("http:", "https:", "//", "ftp:", "file:")), (tag, a)
    assert not re.search(r"url\(\s*['\"]?(https?:|//)", text)


def value_at(doc: Any, path: list[Any]) -> Any:
    for key in path:
        doc = doc[key]
    return doc


def assert_cells_equal(page: Page, doc: Any, rel: float = 5e-4) -> int:
    """Every value cell shows the JSON's value at its path; returns how many cells."""
    assert page.cells, "no value cell"
    for path, text in page.cells:
        want = value_at(doc, path)
        where = f"{path}: {text!r} vs {want!r}"
        if want is None:
            assert text == "—", where
        elif isinstance(want, bool) and path[-1] == "invalidated":  # a window's verdict
            judged = value_at(doc, [*path[:-1], "beta"]) is not None
            expect = ("INVALIDATED" if want else "valid") if judged else "not judged"
            assert text == expect, where
        elif isinstance(want, bool):
            assert text == ("yes" if want else "no"), where
        elif isinstance(want, int | float):
            got = float(text)
            assert math.isclose(got, float(want), rel_tol=rel, abs_tol=1e-300), where
            if isinstance(want, int):
                assert got == want, where
        else:
            assert text == str(want), where
    return len(page.cells)
