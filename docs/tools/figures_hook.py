"""MkDocs hook: every picture on a page opens full size.

A page's figures are shown at the text's width, where the four panels of a learning-curve plot are too small to
read. Each `<img>` that is not already inside a link becomes a link to its own file, so a click opens it at its
own resolution (the browser's zoom then works on it). No lightbox script: it would be one more dependency of the
docs extra for what a link does.
"""

from __future__ import annotations

import re
from typing import Any

# A whole link (left as it is: its picture already leads somewhere) or a picture outside any link (links do not nest).
LINK_OR_IMAGE = re.compile(r"<a\b[^>]*>.*?</a>|<img\b[^>]*?\bsrc=\"(?P<src>[^\"]+)\"[^>]*>", re.DOTALL)


def on_page_content(html: str, page: Any, config: Any, files: Any) -> str:
    return full_size_links(html)


def full_size_links(html: str) -> str:
    """`html` with each picture that is not inside a link wrapped in a link to its own source."""

    def wrap(match: re.Match) -> str:
        if match["src"] is None:
            return match[0]
        return f'<a class="full-size" href="{match["src"]}" title="Open full size">{match[0]}</a>'

    return LINK_OR_IMAGE.sub(wrap, html)
