"""funrec view in a real headless Chromium (Debian's chromium and chromium-driver, WebGL in
software): the page shows the highlighted part, and moving the time slider in the browser moves
it. Slow (software WebGL on a shared CPU): run with ``make test-slow``, which installs them."""

from __future__ import annotations

import io
import time
from pathlib import Path

import numpy as np
import pytest

from tests.helpers.view_twin import free_port, write_view_twin

CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
PART_RGB = np.array([255, 140, 0])
"""ViewConfig.part_colour; lit and shaded it stays orange: red high, blue low."""
SETTLE_S, TIMEOUT_S = 3.0, 120.0


def part_pixels(png: bytes) -> np.ndarray:
    """(H, W) bool: pixels of the highlighted parts (orange: red well above blue, green between)."""
    from PIL import Image

    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return (r > 120) & (r - b > 90) & (g > b + 20) & (g < r - 30)


def browser(width: int = 960, height: int = 640):  # noqa: ANN201 - selenium WebDriver
    webdriver = pytest.importorskip("selenium.webdriver")
    if not (Path(CHROMIUM).is_file() and Path(CHROMEDRIVER).is_file()):
        pytest.skip("needs Debian's chromium and chromium-driver (apt-get install -y chromium chromium-driver)")
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", f"--window-size={width},{height}",
                "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"):
        options.add_argument(arg)
    options.binary_location = CHROMIUM
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.set_page_load_timeout(TIMEOUT_S)
    return driver


def settled_screenshot(driver, changed_from: np.ndarray | None = None, timeout_s: float = TIMEOUT_S) -> bytes:  # noqa: ANN001
    """A screenshot once the part pixels stop changing (and, with ``changed_from``, differ from
    it): software WebGL takes seconds per frame here. Empty if the browser never answered."""
    from selenium.common.exceptions import TimeoutException

    deadline = time.monotonic() + timeout_s
    previous, png = None, b""
    while time.monotonic() < deadline:
        time.sleep(SETTLE_S)
        try:
            png = driver.get_screenshot_as_png()
        except TimeoutException:  # the renderer busy drawing a frame in software for over 10 s
            continue
        mask = part_pixels(png)
        stable = previous is not None and np.array_equal(mask, previous) and mask.sum() > 50
        if stable and (changed_from is None or not np.array_equal(mask, changed_from)):
            return png
        previous = mask
    return png


@pytest.fixture()
def twin(tmp_path: Path) -> Path:
    return write_view_twin(tmp_path / "twin")


@pytest.mark.slow
def test_view_in_chromium_shows_the_part_and_the_time_slider_moves_it(twin: Path, tmp_path: Path) -> None:
    viser = pytest.importorskip("viser")
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    from funrec.view import build_twin_view

    port = free_port()
    server = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    driver = browser()
    try:
        view = build_twin_view(server, twin)
        driver.get(f"http://127.0.0.1:{port}/")
        before = settled_screenshot(driver)
        (tmp_path / "before.png").write_bytes(before)
        assert part_pixels(before).sum() > 200, "the highlighted part is not on screen"
        time_slider = driver.find_elements(By.CSS_SELECTOR, "[role=slider]")[0]
        time_slider.click()
        time_slider.send_keys(Keys.END)  # the last frame: the door opened 1.2 rad, the drawer 0.25 m
        deadline = time.monotonic() + 30.0
        while view.time_slider.value != 29 and time.monotonic() < deadline:
            time.sleep(0.2)
        assert view.time_slider.value == 29 and view.sliders["part_0"].value == pytest.approx(1.2)
        after = settled_screenshot(driver, changed_from=part_pixels(before))
        (tmp_path / "after.png").write_bytes(after)
        changed = int((part_pixels(before) ^ part_pixels(after)).sum())
        assert changed > 200, f"only {changed} part pixels changed (screenshots in {tmp_path})"
    finally:
        driver.quit()
        server.stop()
