"""Screenshots of TensorBoard's tabs for one run, as a user opens them: TensorBoard serves the
run, headless Chromium loads each tab and saves it as a PNG.

    python benchmarks/tensorboard_screenshots.py RUN_DIR OUT_DIR [--port 6123] [--wait 20]

RUN_DIR is a stream's run directory (``runs/demo/seed0``, what ``make demo`` writes); OUT_DIR
gets one PNG per view of :data:`VIEWS`: each tab as it opens (TensorBoard's default smoothing
and outlier scaling, nothing clicked), and the Time Series tab filtered to the stream-level
tags a user looks for first. Needs ``chromium`` on the path (Debian: ``apt install chromium``).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
import urllib.request
from pathlib import Path
from urllib.parse import quote

# (file name, the address after the server's root): the tabs as they open, then the Time
# Series tab filtered (its ``tagFilter`` query) to the forgetting curves, anchor counts and
# the pruning rule, whose cards would otherwise sit below the fold under the training curves.
# The Time Series tab draws its lines with WebGL, which a headless Chromium without a GPU
# leaves blank (axes, no line): ``forceSVG`` has the same charts, scaled and smoothed the same
# way, drawn as SVG.
SVG = "forceSVG=true"
VIEWS = (
    ("timeseries", f"?{SVG}#timeseries"),
    (
        "timeseries_stream",
        f"?{SVG}&tagFilter="
        + quote("^(stream/success|anchors|pruning)|1_plus|_over_")
        + "#timeseries",
    ),
    ("scalars", "#scalars"),
    ("custom_scalars", "#custom_scalars"),
    ("images", "#images"),
    ("text", "#text"),
    ("hparams", "#hparams"),
)


def serve(run_dir: Path, port: int) -> subprocess.Popen:
    """TensorBoard on ``run_dir``, once it answers (it loads the event files first)."""
    tensorboard = Path(sys.executable).with_name("tensorboard")
    proc = subprocess.Popen(
        [str(tensorboard), "--logdir", str(run_dir), "--port", str(port), "--bind_all"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    for _ in range(120):
        try:
            urllib.request.urlopen(f"http://localhost:{port}/", timeout=1)
            return proc
        except OSError:
            time.sleep(0.5)
    proc.terminate()
    raise SystemExit(f"TensorBoard did not answer on port {port} within a minute")


def screenshot(url: str, out: Path, wait_s: int, size: str) -> None:
    """``url`` as headless Chromium renders it after ``wait_s`` seconds of page time."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        raise SystemExit("chromium is not on the path (Debian: apt install chromium)")
    subprocess.run(
        [
            chromium,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            f"--window-size={size}",
            f"--virtual-time-budget={wait_s * 1000}",
            f"--screenshot={out}",
            url,
        ],
        check=True,
        capture_output=True,
        timeout=wait_s + 120,
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("out_dir", type=Path)
    parser.add_argument("--port", type=int, default=6123)
    parser.add_argument("--wait", type=int, default=20, help="seconds each page may load")
    parser.add_argument(
        "--query",
        default="",
        help="appended to each tab's URL, e.g. &_smoothingWeight=0 (the default: what a user sees)",
    )
    parser.add_argument("--size", default="1600,1400", help="the window, width,height in pixels")
    args = parser.parse_args(argv)
    if not args.run_dir.is_dir():
        raise SystemExit(f"{args.run_dir}: no such run directory")
    args.out_dir.mkdir(parents=True, exist_ok=True)
    proc = serve(args.run_dir, args.port)
    try:
        for name, address in VIEWS:
            out = args.out_dir / f"{name}.png"
            url = f"http://localhost:{args.port}/{address}{args.query}"
            screenshot(url, out, args.wait, args.size)
            print(f"wrote {out}")
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    return 0


if __name__ == "__main__":
    sys.exit(main())
