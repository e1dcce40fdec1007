"""Open a report in headless Chromium (Debian's /usr/bin/chromium through playwright): console errors, failed
requests, each image's natural width; optionally a screenshot and a PDF through Chromium's print."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

CHROMIUM: Final = Path("/usr/bin/chromium")
ARGS: Final = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


@dataclass
class Rendered:
    console_errors: list[str] = field(default_factory=list)
    requests: list[str] = field(default_factory=list)  # every URL the page asked for
    image_widths: list[int] = field(default_factory=list)
    text: str = ""


def render(html: Path, screenshot: Path | None = None, pdf: Path | None = None, full_page: bool = False) -> Rendered:
    from playwright.sync_api import sync_playwright

    out = Rendered()
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 1400})
            page.on("console", lambda m: out.console_errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: out.console_errors.append(str(e)))
            page.on("request", lambda r: out.requests.append(r.url))
            page.goto(html.resolve().as_uri(), wait_until="load")
            out.image_widths = page.eval_on_selector_all("img", "els => els.map(e => e.complete ? e.naturalWidth : 0)")
            out.text = page.inner_text("body")
            if screenshot is not None:
                page.screenshot(path=str(screenshot), full_page=full_page)
            if pdf is not None:
                page.pdf(path=str(pdf), format="A4", print_background=True)
        finally:
            browser.close()
    return out
