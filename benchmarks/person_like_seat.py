"""A person-like operator in the grasper seat: does the page tell enough to finish the task, at a person's pace?

The operator (:mod:`dvrl_marl.teleop.person`) reads only what the page shows (its status: tips, visible pins, the
cues, the top and side views' outline), 200 ms late, decides every 0.25 s or slower once its last move has ended,
holds the page's keys for a time with 10 % motor noise and pauses now and then. Beside the scripted suction on
``dvrl_marl/SurgeonSeat-v8`` (a 120 s horizon, the browser seat's):

    python benchmarks/person_like_seat.py [--episodes 50] [--browser 3] [--out benchmarks/person_like_seat.txt]

``--episodes``: seeds run in simulated time through the browser device (the page's messages); ``--browser``: seeds
run in real time in the real page (headless Chromium driven by Playwright). Target (issue 38): 3 of 3 pins in
<= 90 s on most seeds.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import numpy as np

from dvrl_marl.teleop.person import PersonLikeOperator, drive_page, run_episode

SEED_BASE = 1000  # seeds 1000.. (the tests use 11-13 and 4)


def simulated(episodes: int) -> list[dict]:
    return [run_episode(SEED_BASE + k) for k in range(episodes)]


def in_browser(episodes: int) -> list[dict]:
    from playwright.sync_api import sync_playwright

    from dvrl_marl.teleop.session import TeleopSession
    from dvrl_marl.teleop.web import TeleopServer

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    results = []
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
        for k in range(episodes):
            seed = SEED_BASE + k
            server = TeleopServer(TeleopSession(partner="scripted", seed=seed, record=False), port=0).start()
            try:
                page = browser.new_page(viewport={"width": 1280, "height": 800})
                page.goto(server.url)
                page.wait_for_function("window.dvrl.frames >= 1", timeout=30000)
                final = drive_page(page, PersonLikeOperator(seed), time_limit_s=90.0)
                if final["state"] == "over":
                    final = page.evaluate("window.dvrl.status")
                results.append({"seed": seed, "success": bool(final["success"]),
                                "delivered": final["debris_delivered"],
                                "seconds": final["time_s"] if final["success"] else None})
                page.close()
            finally:
                server.stop()
        browser.close()
    return results


def summary(name: str, results: list[dict]) -> str:
    seconds = np.array([r["seconds"] for r in results if r["success"]], dtype=float)
    within = sum(r["success"] and r["delivered"] == 3 and r["seconds"] <= 90.0 for r in results)
    line = f"{name}: {within} of {len(results)} episodes delivered 3/3 pins within 90 s"
    if len(seconds):
        line += (f"; time to success median {np.median(seconds):.1f} s, p90 {np.percentile(seconds, 90):.1f} s, "
                 f"max {seconds.max():.1f} s")
    return line


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=50, help="seeds in simulated time (default 50)")
    parser.add_argument("--browser", type=int, default=0, help="seeds in real time in Chromium (default 0)")
    parser.add_argument("--out", type=Path, help="also write the figures to this file")
    args = parser.parse_args()
    lines = ["person-like operator, grasper seat of dvrl_marl/SurgeonSeat-v8 beside the scripted suction "
             "(200 ms reaction, >= 0.25 s decisions, 10 % motor noise)"]
    if args.episodes > 0:
        lines.append(summary("simulated time, the page's messages", simulated(args.episodes)))
    if args.browser > 0:
        lines.append(summary("real time, the page in Chromium", in_browser(args.browser)))
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
