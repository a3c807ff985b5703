"""How fast a replay page (``uvms_env.replay``) opens and plays in headless Chromium.

    python benchmarks/replay_page.py runs/paper/replay.html [--browser PATH] [--repeats 3]

Opens the page from disk in real time (no virtual time budget: the page's own clock is
the wall clock) with WebGL in software (SwiftShader) and reads what the page logs to the
console: the time from navigation start to its first rendered frame, then, with
``#bench``, the frame rate of playing every frame once (one per animation frame) and the
mean time to place the meshes and issue the draw per frame. Prints the medians.
"""

from __future__ import annotations

import re
import shutil
import statistics
import subprocess
from pathlib import Path

from baselines.command_line import positive_int, script_parser

BROWSERS = ("chromium-headless-shell", "chromium", "chromium-browser", "google-chrome")
FLAGS = (
    "--headless",
    "--no-sandbox",  # CI and containers run as root
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--enable-logging=stderr",
    "--v=0",
    "--window-size=1200,800",
    # keeps the browser open after the load (no --dump-dom/--screenshot to end it)
    "--remote-debugging-port=0",
)


def console_line(browser: str, url: str, pattern: str, timeout: float) -> re.Match[str]:
    """Open ``url`` and wait for a console line matching ``pattern``; then close."""
    proc = subprocess.Popen(
        [browser, *FLAGS, url], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True
    )
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            if "CONSOLE" in line and (m := re.search(pattern, line)):
                return m
        raise RuntimeError(f"the browser ended without logging {pattern!r}")
    finally:
        proc.terminate()
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()


def main() -> None:
    ap = script_parser(__file__, __doc__)
    ap.add_argument("page", type=Path)
    ap.add_argument("--browser", default=None)
    ap.add_argument("--repeats", type=positive_int, default=3)
    args = ap.parse_args()
    browser = args.browser or next((p for p in map(shutil.which, BROWSERS) if p), None)
    if browser is None:
        raise SystemExit("no Chromium found: apt-get install chromium-headless-shell")
    url = args.page.resolve().as_uri()
    first, fps, draw = [], [], []
    for _ in range(args.repeats):
        m = console_line(browser, url, r"first frame rendered (\d+) ms", 60)
        first.append(float(m.group(1)))
        m = console_line(browser, url + "#bench", r"= ([\d.]+) fps; place \+ draw ([\d.]+) ms", 600)
        fps.append(float(m.group(1)))
        draw.append(float(m.group(2)))
    size = args.page.stat().st_size / 1e6
    print(f"{args.page} ({size:.2f} MB), {browser}, median of {args.repeats}:")
    print(f"  first frame rendered {statistics.median(first):.0f} ms after navigation start")
    print(f"  playing every frame: {statistics.median(fps):.1f} fps")
    print(f"  place + draw call {statistics.median(draw):.2f} ms per frame")


if __name__ == "__main__":
    main()
