"""The documentation's screenshots of reports, made again from runs: ``make docs-figures``, or
``python -m runners.docs_figures [--out DIR] [NAME ...]``.

Each figure is a run of the command line into ``DIR/<name>`` (``runs/docs`` by default; replaced
when it is not a finished run of the same configuration), and its ``report.html`` as headless
Chromium renders it, :data:`WIDTH_PX` wide, cut below the end of the page. Needs Chromium (or
Google Chrome) on ``PATH``.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
WIDTH_PX = 1150  # the page's width in the screenshots [px]
MAX_HEIGHT_PX = 16000  # the window the page is drawn in; the screenshot is cut below the page's end [px]

# name -> (the png in the repository, the command line's arguments)
FIGURES = {
    "report_cross4_counts": ("docs/report_cross4_counts.png",
                             ["run", "sumo_scenarios/cross4/counts.toml", "--duration", "900"]),
}

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")


def browser() -> str:
    for name in BROWSERS:
        found = shutil.which(name)
        if found:
            return found
    raise SystemExit(f"docs_figures: no Chromium on PATH (looked for {', '.join(BROWSERS)}): install chromium "
                     "(e.g. apt-get install chromium)")


def screenshot(html: Path, png: Path, width: int = WIDTH_PX) -> Path:
    """``html`` as headless Chromium draws it in a window ``width`` px wide, saved as ``png`` (256
    colours) and cut 24 px below the last row that is not the page's background."""
    import numpy as np
    from PIL import Image

    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "page.png"
        cmd = [browser(), "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
               f"--user-data-dir={tmp}/profile", f"--window-size={width},{MAX_HEIGHT_PX}",
               f"--screenshot={raw}", Path(html).resolve().as_uri()]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
        if proc.returncode != 0 or not raw.is_file():
            raise SystemExit(f"docs_figures: Chromium failed on {html}: {proc.stderr.strip()[-1000:]}")
        img = Image.open(raw).convert("RGB")
        a = np.asarray(img)
        background = a[-1, -1]
        rows = np.nonzero((a != background).any(axis=(1, 2)))[0]
        bottom = min(a.shape[0], int(rows[-1]) + 1 + 24) if len(rows) else a.shape[0]
        png.parent.mkdir(parents=True, exist_ok=True)
        page = img.crop((0, 0, a.shape[1], bottom))  # (256 colours: half the bytes, the same to the eye)
        page.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE).save(png, optimize=True)
    return png


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m runners.docs_figures", description=__doc__.split("\n\n")[0])
    p.add_argument("names", nargs="*", choices=[[], *FIGURES], metavar="NAME",
                   help=f"figures to make (default all: {', '.join(FIGURES)})")
    p.add_argument("--out", type=Path, default=Path("runs") / "docs", metavar="DIR",
                   help="where the runs are written, relative to the repository (default runs/docs; the report "
                        "names it)")
    args = p.parse_args(argv)
    for name in args.names or FIGURES:
        png, cli = FIGURES[name]
        run_dir = args.out / name
        cmd = [sys.executable, "-m", "runners.cli", *cli, "--out", str(run_dir), "--force", "--no-progress"]
        print(f"docs_figures: {' '.join(['nrtraffic', *cli])} -> {run_dir}", file=sys.stderr, flush=True)
        proc = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.DEVNULL)
        if proc.returncode != 0:
            print(f"docs_figures: the run for {png} failed (exit {proc.returncode})", file=sys.stderr)
            return proc.returncode
        screenshot(ROOT / run_dir / "report.html", ROOT / png)
        print(f"docs_figures: wrote {png}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
