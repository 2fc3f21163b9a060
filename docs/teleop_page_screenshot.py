"""Take docs/teleop_page.png: the browser seat's page (``dvrl-marl teleop``) mid-episode, in headless Chromium.

    python docs/teleop_page_screenshot.py

Serves a session with the scripted suction partner, opens the page in Debian's chromium (driven by Playwright),
starts the episode, holds S then F for a moment (the LND goes back, then down) and photographs the page.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

from playwright.sync_api import sync_playwright

from dvrl_marl.teleop.session import TeleopSession
from dvrl_marl.teleop.web import TeleopServer


def main(out: Path = Path(__file__).with_name("teleop_page.png")) -> Path:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    server = TeleopServer(TeleopSession(partner="scripted", seed=0, record=False), port=0).start()
    try:
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": 1060, "height": 760})
            page.goto(server.url)
            page.wait_for_function("window.dvrl.frames >= 3", timeout=30000)
            page.keyboard.press("Enter")
            for key, seconds in (("KeyS", 0.6), ("KeyF", 0.5)):
                page.keyboard.down(key)
                time.sleep(seconds)
                page.keyboard.up(key)
            time.sleep(2.5)  # the scripted suction clears the first cavity
            page.screenshot(path=str(out))
            browser.close()
    finally:
        server.stop()
    print(f"wrote {out}")
    return out


if __name__ == "__main__":
    main()
