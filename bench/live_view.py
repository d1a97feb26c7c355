"""The live web view as a user sees it: headless Chromium on ``heightpipe run --rerun web``.

Starts ``heightpipe run SOURCE --rerun web`` (free ports on 127.0.0.1), opens the address it
prints in headless Chromium (software WebGL: SwiftShader through ANGLE), and takes screenshots
until the frame panel shows track boxes, judged by pixels: enough pixels of the box colours
(``stages.sink_common.QUALITY_RGB``) inside the frame panel. Then it stops the run with Ctrl-C
(SIGINT) and saves the screenshot. Prints how long the view took to appear.

    python -m bench.live_view [SOURCE] [--out docs/live_view.png] [--timeout 600]

Needs Debian's ``chromium`` and ``chromium-driver`` and the ``selenium`` package (test extra).
rerun's viewer tries to reach its servers for examples and telemetry; offline, those requests
fail harmlessly.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parent.parent
TRAFFIC = REPO_ROOT.parent / "shared" / "real" / "traffic_bridge" / "car_traffic_small.mp4"
CHROMIUM_FLAGS = ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--use-angle=swiftshader",
                  "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", "--window-size=1400,900")
FRAME_PANEL = (0.0, 0.05, 0.6, 0.6)
"""The frame view's part of the window (left, top, right, bottom as shares) in the blueprint."""
MIN_BOX_PIXELS = 150
"""Pixels of box colours in the frame panel that count as 'boxes drawn'."""
COLOR_TOLERANCE = 40


def browser_available() -> str | None:
    """Why the browser check cannot run here (None: it can)."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install '.[test]')"
    for name in ("chromium", "chromedriver"):
        if _find(name) is None:
            return f"{name} not found (Debian packages chromium, chromium-driver)"
    return None


def _find(name: str) -> str | None:
    return shutil.which(name) or next((p for p in (f"/usr/bin/{name}", f"/usr/lib/chromium/{name}")
                                       if os.path.exists(p)), None)


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def box_pixels(screenshot: np.ndarray) -> int:
    """Pixels of the box colours (settled / settling) inside the frame panel of an RGB screenshot."""
    from stages.sink_common import QUALITY_RGB

    rows, cols = screenshot.shape[:2]
    left, top, right, bottom = FRAME_PANEL
    panel = screenshot[int(top * rows):int(bottom * rows), int(left * cols):int(right * cols)].astype(int)
    hits = np.zeros(panel.shape[:2], bool)
    for name in ("settled", "settling"):
        hits |= np.abs(panel - np.array(QUALITY_RGB[name])).max(axis=2) <= COLOR_TOLERANCE
    return int(hits.sum())


@dataclass
class LiveViewResult:
    screenshot: np.ndarray | None
    """RGB, the first one with boxes in the frame panel (else the last one taken)."""
    box_pixels: int
    seconds_to_view: float | None
    """From opening the page to the first screenshot with boxes (None: never)."""
    run_output: str
    run_exit: int | None
    url: str
    run_alive: bool = False
    """The run was still processing frames when the screenshot with boxes was taken."""


def watch_live_run(source: Path, out_prefix: Path, extra_args: list[str] = (), timeout_s: float = 600.0,
                   every_s: float = 5.0, reload_s: float = 240.0) -> LiveViewResult:
    """Runs ``heightpipe run SOURCE --rerun web``, watches it in headless Chromium, stops the run.

    The page is opened once the run has written its first tracks, and reloaded when it shows no
    boxes for ``reload_s`` (on a loaded machine the viewer was seen stuck on its welcome page).
    """
    import cv2
    from selenium import webdriver
    from selenium.common.exceptions import WebDriverException
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    web_port, grpc_port = free_port(), free_port()
    command = [sys.executable, "-m", "pipeline.cli", "run", str(source), "--out", str(out_prefix),
               "--rerun", "web", "--no-progress", "--set", "web.keep_serving=false",
               "--set", f"web.web_port={web_port}",
               "--set", f"web.grpc_port={grpc_port}", *extra_args]
    run = subprocess.Popen(command, cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    output: list[str] = []
    result = LiveViewResult(None, 0, None, "", None, "")
    driver = None
    try:
        for line in run.stdout:  # the address comes first, before the first frame
            output.append(line)
            if "watch the run at " in line:
                result.url = line.split("watch the run at ", 1)[1].strip()
                break
        if not result.url:
            return result
        options = Options()
        options.binary_location = _find("chromium")
        for flag in CHROMIUM_FLAGS:
            options.add_argument(flag)
        tracks_csv = Path(f"{out_prefix}.tracks.csv")
        started = time.monotonic()
        while run.poll() is None and time.monotonic() - started < timeout_s:
            if tracks_csv.is_file() and tracks_csv.read_text().count("\n") > 1:
                break
            time.sleep(1.0)
        driver = webdriver.Chrome(service=Service(_find("chromedriver")), options=options)
        driver.set_page_load_timeout(timeout_s)
        opened = loaded = time.monotonic()
        driver.get(result.url)
        best_pixels = -1
        while time.monotonic() - opened < timeout_s and run.poll() is None:
            time.sleep(every_s)
            if time.monotonic() - loaded > reload_s:
                try:
                    driver.refresh()
                except WebDriverException:
                    pass
                loaded = time.monotonic()
                continue
            try:
                png = driver.get_screenshot_as_png()
            except WebDriverException:  # the page is busy (compiling the viewer, first render)
                continue
            shot = cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
            pixels = box_pixels(shot)
            if pixels > best_pixels:
                result.screenshot, result.box_pixels, best_pixels = shot, pixels, pixels
            if pixels >= MIN_BOX_PIXELS:  # rerun's welcome page and an empty view have none
                result.screenshot, result.box_pixels = shot, pixels
                result.seconds_to_view = time.monotonic() - opened
                result.run_alive = run.poll() is None  # keep_serving is off: alive = still processing
                break
        return result
    finally:
        if driver is not None:
            driver.quit()
        if run.poll() is None:
            run.send_signal(signal.SIGINT)  # exit 130: it was stopped mid-run; 0: it had finished
        try:
            rest, _ = run.communicate(timeout=300)  # it flushes the viewer's backlog first
        except subprocess.TimeoutExpired:
            run.kill()
            rest, _ = run.communicate()
        output.append(rest or "")
        result.run_output, result.run_exit = "".join(output), run.returncode


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("source", nargs="?", type=Path, default=TRAFFIC)
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "docs" / "live_view.png")
    parser.add_argument("--prefix", type=Path, default=Path("runs/live_view/run"),
                        help="the run's output prefix")
    parser.add_argument("--timeout", type=float, default=600.0)
    args = parser.parse_args(argv)
    why_not = browser_available()
    if why_not:
        print(f"live_view: {why_not}", file=sys.stderr)
        return 2
    import cv2

    result = watch_live_run(args.source, args.prefix, timeout_s=args.timeout)
    if result.screenshot is None:
        print(f"live_view: no screenshot (run exit {result.run_exit}):\n{result.run_output}", file=sys.stderr)
        return 1
    cv2.imwrite(str(args.out), cv2.cvtColor(result.screenshot, cv2.COLOR_RGB2BGR))
    seconds = "never" if result.seconds_to_view is None else f"{result.seconds_to_view:.0f} s"
    live = "yes" if result.run_alive else "no"
    print(f"| source | boxes in the frame panel | page open to boxes | run still processing |\n"
          f"|---|---|---|---|\n| {args.source.name} | {result.box_pixels} px of box colours "
          f"(>= {MIN_BOX_PIXELS} needed) | {seconds} | {live} |")
    print(f"wrote {args.out}")
    return 0 if result.seconds_to_view is not None else 1


if __name__ == "__main__":
    sys.exit(main())
