"""The browser seat on localhost: key press to the first frame that shows the move, and frames per second served.

Starts ``dvrl-marl teleop``'s server in this process (scripted partner, recording off), opens the page in headless
Chromium (Debian's ``chromium`` driven by Playwright), starts the episode and presses movement keys; the page
times each press to the first drawn frame whose status says a step has used it (``window.dvrl.latencies``).

    python benchmarks/teleop_latency.py [--presses 60] [--out benchmarks/teleop_latency.txt]

Targets: median <= 60 ms (issue 38, with the depth views and cues on the page; issue 14 asked <= 100 ms), >= 20
frames/s at 640x480 while the env runs at 50 Hz.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import time
from pathlib import Path

import numpy as np

CHROMIUM_ARGS = ["--no-sandbox", "--disable-dev-shm-usage", "--disable-background-networking",
                 "--disable-component-update", "--no-first-run"]
KEYS = ("KeyD", "KeyA", "KeyW", "KeyS")


def measure(presses: int, hold_s: float, gap_s: float) -> dict:
    from playwright.sync_api import sync_playwright

    from dvrl_marl.teleop.session import TeleopSession, unpack_frame
    from dvrl_marl.teleop.web import TeleopServer

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        raise SystemExit("needs Debian's chromium: apt-get install chromium")
    server = TeleopServer(TeleopSession(partner="scripted", seed=0, record=False), port=0).start()
    try:
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1100, "height": 640})
            page.goto(server.url)
            page.wait_for_function("window.dvrl.frames >= 3", timeout=30000)
            page.keyboard.press("Enter")
            page.wait_for_function("window.dvrl.status && window.dvrl.status.state === 'running'")
            frames0, began = page.evaluate("window.dvrl.frames"), time.monotonic()
            step0 = page.evaluate("window.dvrl.status.step")
            for index in range(presses):
                key = KEYS[index % len(KEYS)]
                page.keyboard.down(key)
                time.sleep(hold_s)
                page.keyboard.up(key)
                time.sleep(gap_s)
            elapsed = time.monotonic() - began
            frames = page.evaluate("window.dvrl.frames") - frames0
            latencies = np.array(page.evaluate("window.dvrl.latencies"))
            final = page.evaluate("window.dvrl.status")
            browser.close()
        server_status = unpack_frame(server.session.latest()[1])[0]
    finally:
        server.stop()
    return {"presses": presses, "timed": len(latencies), "median_ms": float(np.median(latencies)),
            "p90_ms": float(np.percentile(latencies, 90)), "max_ms": float(latencies.max()),
            "frames_per_s_drawn": frames / elapsed, "steps_per_s": (final["step"] - step0) / elapsed,
            "steps_late": server_status["steps_late"], "server_fps": server_status["fps"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presses", type=int, default=60)
    parser.add_argument("--hold", type=float, default=0.12, help="seconds each key is held")
    parser.add_argument("--gap", type=float, default=0.25, help="seconds between presses")
    parser.add_argument("--out", help="also write the figures to this text file")
    args = parser.parse_args()
    result = measure(args.presses, args.hold, args.gap)
    lines = [
        f"browser seat on localhost ({os.cpu_count()} CPU cores, {platform.machine()}, headless Chromium, "
        "640x480 JPEG, "
        "scripted partner, 50 Hz control)",
        f"key press -> first frame showing the move: median {result['median_ms']:.0f} ms, p90 {result['p90_ms']:.0f} "
        f"ms, max {result['max_ms']:.0f} ms over {result['timed']} of {result['presses']} presses (target: median "
        "<= 60 ms)",
        f"frames drawn by the page: {result['frames_per_s_drawn']:.1f}/s (server: {result['server_fps']}/s; target "
        ">= 20)",
        f"env steps: {result['steps_per_s']:.1f}/s (50 = real time), {result['steps_late']} steps late",
    ]
    print("\n".join(lines))
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
