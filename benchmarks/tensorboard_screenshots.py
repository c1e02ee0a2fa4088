"""Screenshots of TensorBoard's tabs for one run, as a user opens them: TensorBoard serves the
run, headless Chromium loads each tab and saves it as a PNG.

    python benchmarks/tensorboard_screenshots.py RUN_DIR OUT_DIR [--port 6123] [--wait 20]

RUN_DIR is a stream's run directory (``runs/demo/seed0``, what ``make demo`` writes); OUT_DIR
gets ``scalars.png``, ``custom_scalars.png``, ``images.png``, ``text.png`` and
``hparams.png``. Needs ``chromium`` on the path (Debian: ``apt install chromium``).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

TABS = ("scalars", "custom_scalars", "images", "text", "hparams")


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


def screenshot(url: str, out: Path, wait_s: int, size: str = "1600,1100") -> None:
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
    args = parser.parse_args(argv)
    if not args.run_dir.is_dir():
        raise SystemExit(f"{args.run_dir}: no such run directory")
    args.out_dir.mkdir(parents=True, exist_ok=True)
    proc = serve(args.run_dir, args.port)
    try:
        for tab in TABS:
            out = args.out_dir / f"{tab}.png"
            screenshot(f"http://localhost:{args.port}/#{tab}{args.query}", out, args.wait)
            print(f"wrote {out}")
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    return 0


if __name__ == "__main__":
    sys.exit(main())
