"""Render report pages to PNG in headless Chromium, to look at them as a browser shows them.

Usage: ``python scripts/render_reports.py chaintwin-demo/reports/*.html --out shots/``

Needs Debian's ``chromium`` (``apt-get install chromium``); not part of the
tests. Each page is rendered full height (``--height``) at 1300 px width with
the flags that keep Chromium off the network (the pages need none).
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
)


def main() -> int:
    """Render each page; print where the PNGs are."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pages", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, default=Path("shots"))
    ap.add_argument("--height", type=int, default=6000, help="window height, px")
    args = ap.parse_args()
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        print("render_reports: chromium not found (apt-get install chromium)", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    for page in args.pages:
        target = args.out / (page.stem + ".png")
        with tempfile.TemporaryDirectory() as profile:
            subprocess.run(
                [
                    browser,
                    *FLAGS,
                    f"--user-data-dir={profile}",
                    f"--window-size=1300,{args.height}",
                    f"--screenshot={target.resolve()}",
                    page.resolve().as_uri(),
                ],
                check=True,
                capture_output=True,
                timeout=120,
            )
        print(target)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
