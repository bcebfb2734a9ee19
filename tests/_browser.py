"""Open a static report in a real headless Chromium (Debian's ``chromium``, driven by Playwright).

No browser is downloaded: Playwright launches the system binary
(``executable_path``), with a new empty profile and no network-facing
features. :func:`require_browser` skips a test, saying why, only when the
binary or the ``playwright`` package is missing (``.ci/run`` installs both).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import pytest

#: The flags of every launch: headless, no sandbox (containers), nothing that phones home.
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
#: Where the screenshots of the docs live (written only with OSCAR_UPDATE_SCREENSHOTS=1; a person looks first).
DOCS_IMAGES = Path(__file__).resolve().parents[1] / "docs" / "images"


def chromium_path() -> str | None:
    for name in (os.environ.get("OSCAR_CHROMIUM"), "chromium", "chromium-browser"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def require_browser() -> str:
    """The chromium binary, or skip the test with the reason."""
    path = chromium_path()
    if path is None:
        pytest.skip("no chromium on PATH (CI installs Debian's: apt-get install chromium)")
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        pytest.skip('the playwright package is missing (pip install "oscar-wm[dev]")')
    return path


# every <video>: scrolled to, played; the result of each (error code, readyState, time advanced)
_PLAY_ALL = """async () => {
  const out = [];
  for (const v of Array.from(document.querySelectorAll('video'))) {
    v.scrollIntoView();
    // let the page's IntersectionObserver see the scroll first (it plays what is on screen, pauses the rest)
    await new Promise(ok => requestAnimationFrame(() => requestAnimationFrame(() => setTimeout(ok, 100))));
    const r = {src: v.getAttribute('src'), played: false, error: null};
    try {
      await Promise.race([v.play(), new Promise((_, no) => setTimeout(() => no(new Error('play() timed out')), 8000))]);
      // frames presented while playing (currentTime alone can wrap round a short looping clip)
      const f0 = v.getVideoPlaybackQuality().totalVideoFrames, t0 = v.currentTime;
      await new Promise(ok => setTimeout(ok, 400));
      r.frames = v.getVideoPlaybackQuality().totalVideoFrames - f0;
      r.played = !v.paused && (r.frames > 0 || v.currentTime !== t0);
      r.readyState = v.readyState; r.width = v.videoWidth; r.height = v.videoHeight;
      const box = v.getBoundingClientRect();
      r.shown_width = box.width; r.shown_height = box.height; r.controls = v.controls;
    } catch (e) { r.error = String(e); }
    if (v.error) r.error = 'MediaError ' + v.error.code + ' ' + (v.error.message || '');
    v.pause();
    out.push(r);
  }
  return out;
}"""


# every <img>: scrolled to (they may be loading="lazy"), then whether it decoded
_IMAGES = """async () => {
  const out = [];
  for (const img of Array.from(document.querySelectorAll('img'))) {
    img.scrollIntoView();
    try { await img.decode(); } catch (e) {}
    out.push({src: img.getAttribute('src'), ok: img.complete && img.naturalWidth > 0, width: img.naturalWidth});
  }
  return out;
}"""


@dataclass
class PageCheck:
    """What a page did in the browser."""

    videos: list = field(default_factory=list)  # per <video>: src, played, error, readyState, width, height,
    # shown_width, shown_height (CSS px on the page), controls (the player's controls shown)
    images: list = field(default_factory=list)  # one dict per <img>: src, ok, width
    problems: list = field(default_factory=list)  # console errors, page errors, failed requests, bad videos
    texts: dict = field(default_factory=dict)  # selector → list of text contents (see :func:`open_page`)
    screenshot: Path | None = None


def open_page(
    html: Path, screenshot: Path, *, select: dict[str, str] | None = None, screenshot_at: str | None = None
) -> PageCheck:
    """Load ``html`` from disk, play every video, collect problems and texts, save a screenshot.

    select: ``{name: css selector}``; ``texts[name]`` is the list of
    ``[attributes..., textContent]`` of the matches as dicts
    (``{"text": ..., "data": {dataset}}``). screenshot_at: a css selector
    scrolled to the top of the window for the screenshot (default: the page's top).
    """
    from playwright.sync_api import sync_playwright

    exe = require_browser()
    check = PageCheck()
    with tempfile.TemporaryDirectory(prefix="oscar-chromium-") as profile, sync_playwright() as p:
        ctx = p.chromium.launch_persistent_context(
            profile, executable_path=exe, headless=True, args=FLAGS, viewport={"width": 1280, "height": 900}
        )
        try:
            page = ctx.new_page()
            page.on("console", lambda m: m.type == "error" and check.problems.append(f"console: {m.text}"))
            page.on("pageerror", lambda e: check.problems.append(f"page error: {e}"))
            page.on("requestfailed", lambda r: check.problems.append(f"request failed: {r.url} {r.failure}"))
            page.goto(Path(html).resolve().as_uri(), wait_until="load")
            check.videos = page.evaluate(_PLAY_ALL)
            for v in check.videos:
                if v["error"] or not v["played"]:
                    check.problems.append(f"video {v['src']}: {v['error'] or 'did not play'}")
            check.images = page.evaluate(_IMAGES)
            check.problems += [f"image {i['src']}: not loaded" for i in check.images if not i["ok"]]
            for name, css in (select or {}).items():
                check.texts[name] = page.eval_on_selector_all(
                    css, "els => els.map(e => ({text: e.textContent.trim(), data: Object.assign({}, e.dataset)}))"
                )
            if screenshot_at:
                page.eval_on_selector(screenshot_at, "e => e.scrollIntoView({block: 'start'})")
            else:
                page.evaluate("window.scrollTo(0, 0)")
            page.wait_for_timeout(300)
            page.screenshot(path=str(screenshot), full_page=False)
            check.screenshot = Path(screenshot)
        finally:
            ctx.close()
    return check


def keep_screenshot(check: PageCheck, name: str) -> None:
    """Copy the screenshot to ``docs/images/<name>`` when OSCAR_UPDATE_SCREENSHOTS=1 (halved, PNG)."""
    if os.environ.get("OSCAR_UPDATE_SCREENSHOTS") != "1":
        return
    import cv2
    from PIL import Image

    img = cv2.imread(str(check.screenshot))
    img = cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2), interpolation=cv2.INTER_AREA)
    DOCS_IMAGES.mkdir(parents=True, exist_ok=True)
    # a 64-colour palette keeps the docs' pictures small (tens of kB)
    Image.fromarray(img[..., ::-1]).quantize(colors=64).save(DOCS_IMAGES / name, optimize=True)


def report_json(folder: Path) -> dict:
    return json.loads((Path(folder) / "report.json").read_text())
