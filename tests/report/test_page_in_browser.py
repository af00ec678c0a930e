"""The report page in a real browser (headless Chromium): it draws something, every image loads, nothing errs."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from browser import Browser, file_url, find_chromium  # noqa: E402

from bop_cender.report.run_report import write_report  # noqa: E402

CHROMIUM = find_chromium()
pytestmark = pytest.mark.skipif(
    CHROMIUM is None, reason="no Chromium on PATH (Debian: apt-get install chromium; .ci/run installs it)"
)

#: Per image: [src, loaded]; loaded is what a browser shows as a picture (not a broken-image icon).
IMAGES_LOADED = "Array.from(document.images).map(i => [i.getAttribute('src'), i.complete && i.naturalWidth > 0])"


def png_pixels(data: bytes) -> np.ndarray:
    import cv2

    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    assert image is not None, "the screenshot is not a PNG"
    return image


@pytest.mark.timeout(120)
def test_the_page_renders_with_every_image_and_no_error(report_run, tmp_path):
    written = write_report(report_run, tmp_path / "page")
    with Browser(CHROMIUM, timeout=60) as browser:
        visit = browser.visit(file_url(written.index), IMAGES_LOADED)
    assert visit.errors == []
    assert len(visit.value) == 4  # two plots, two scene figures
    assert all(loaded for _, loaded in visit.value), visit.value
    pixels = png_pixels(visit.screenshot)
    assert pixels.shape[0] > 500 and pixels.std() > 20  # not a blank page


@pytest.mark.timeout(120)
def test_the_check_sees_a_missing_image_and_a_script_error(report_run, tmp_path):
    """The checks above can fail: a page with a broken image and a throwing script is caught by each of them."""
    page = tmp_path / "broken.html"
    page.write_text('<html><body><img src="missing.png"><script>console.error("bad"); undefined_call();</script>'
                    "</body></html>")  # fmt: skip
    with Browser(CHROMIUM, timeout=60) as browser:
        visit = browser.visit(file_url(page), IMAGES_LOADED)
    assert visit.value == [["missing.png", False]]
    joined = "\n".join(visit.errors)
    assert "console: bad" in joined and "exception:" in joined and "missing.png" in joined
    assert png_pixels(visit.screenshot).std() < 5  # a white page: the blank check would refuse it
