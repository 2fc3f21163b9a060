"""Take docs/teleop_page.png (and docs/teleop_page_reach.png): the browser seat's page mid-episode, in Chromium.

    python docs/teleop_page_screenshot.py

Serves a session with the scripted suction partner, opens the page at 1280 x 800 in Debian's chromium (driven by
Playwright) and lets the person-like operator (:mod:`dvrl_marl.teleop.person`, which reads only what the page
shows) work the seat: the first picture is taken while it carries a pin (the cue says how far to the hand-off),
the second when a pin is in reach of the open jaw.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from playwright.sync_api import sync_playwright

from dvrl_marl.teleop.person import PersonLikeOperator, drive_page
from dvrl_marl.teleop.session import TeleopSession
from dvrl_marl.teleop.web import TeleopServer

HERE = Path(__file__).parent


def main(out: Path = HERE / "teleop_page.png", reach_out: Path = HERE / "teleop_page_reach.png") -> Path:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    server = TeleopServer(TeleopSession(partner="scripted", seed=0, record=False), port=0).start()
    taken = {}

    def photograph(view, page):
        cues = view["cues"]
        if "reach" not in taken and cues["in_reach"]:
            page.screenshot(path=str(reach_out))
            taken["reach"] = True
        if "carry" not in taken and cues["holding"] and view["debris_delivered"] == 1 and cues["handoff_mm"] < 40:
            page.screenshot(path=str(out))
            taken["carry"] = True

    try:
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.goto(server.url)
            page.wait_for_function("window.dvrl.frames >= 3", timeout=30000)
            drive_page(page, PersonLikeOperator(seed=0), on_view=photograph)
            browser.close()
    finally:
        server.stop()
    print(f"wrote {out} and {reach_out}")
    return out


if __name__ == "__main__":
    main()
