"""Make the user guide's pictures of ``hd view``'s detection page and of ``hd eval``'s landing figure,
from scratch, with the ``hd`` command as a user runs it.

``guide_detect_page.png``: ``hd view`` of an ``hd detect`` output (a procedural Mars terrain the run
never saw, ``--nav-sigma 1 --site-margin 1``), screenshot by headless Chromium at 1400 x 1000 CSS
pixels; ``guide_landing.png``: the ``landing.png`` of ``hd eval --nav-sigma 0 --nav-sigma 1``.
The chain: ``hd make-dtm`` (400 m, seed 7) -> ``hd build-dataset`` (120 scans at 1.67 cm) ->
``hd label`` -> ``hd train --profile cpu --epochs 20`` -> ``hd detect`` of a second terrain (300 m,
seed 8) -> ``hd view`` -> Chromium, and ``hd eval`` of the run on the dataset's test split. Every
step is seeded; 1 min 42 s on 2 shared cores. Chromium must be on the PATH (``chromium``).
Run: ``.venv/bin/python docs/figures/guide_images.py [--work DIR]``; it prints the detection's and the
evaluation's summaries, whose numbers the captions in docs/user-guide.md quote.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from PIL import Image

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
WINDOW = (1400, 1000)  # CSS pixels, the window of issue 48's screenshots
MAX_BYTES = 300_000  # the largest PNG committed to the docs
TRAIN_TERRAIN = ("--seed", "7", "--size", "400")  # metres; the dataset's terrain
DETECT_TERRAIN = ("--seed", "8", "--size", "300")  # metres; a terrain the run never saw
SCANS = 120  # 96 train / 12 validation / 12 test scans (the default 80/10/10 split)
SIGMA_M = "0.0167"  # the sensor's range noise, metres (the paper's 1.67 cm)
EPOCHS = 20  # of the cpu profile: enough to leave the coin's loss behind on this dataset


def hd(work: Path, *args: str) -> str:
    """Run ``python -m hdcli ARGS`` in ``work`` with this checkout first on the path; its output."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # twice as fast on shared cores (docs/benchmarks.md)
    print("$ hd", " ".join(args), flush=True)  # the command, as a user would type it
    done = subprocess.run(
        [sys.executable, "-m", "hdcli", "--no-progress", *args], cwd=work, env=env, capture_output=True, text=True
    )
    if done.returncode != 0:
        raise SystemExit(f"hd {args[0]} failed ({done.returncode}): {done.stderr.strip() or done.stdout.strip()}")
    if done.stderr.strip():
        print(done.stderr.strip(), flush=True)  # hd's warnings (e.g. the held-out scans' overlap)
    return done.stdout


def screenshot(page: Path, png: Path) -> None:
    """A headless Chromium screenshot of ``page`` at ``WINDOW`` CSS pixels, written to ``png``."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        raise SystemExit("chromium is not on the PATH (Debian: apt-get install chromium).")
    command = [
        browser,
        "--headless",
        "--no-sandbox",
        "--hide-scrollbars",
        "--disable-gpu",
        f"--screenshot={png}",
        f"--window-size={WINDOW[0]},{WINDOW[1]}",
        page.resolve().as_uri(),
    ]
    subprocess.run(command, check=True, capture_output=True, timeout=120)
    if not png.is_file():
        raise SystemExit(f"chromium wrote no screenshot of {page}.")


def save_small(source: Path, target: Path) -> None:
    """Copy the PNG ``source`` to ``target``, quantised to 256 colours when it is over ``MAX_BYTES``;
    written beside it and renamed, so that a failure leaves the committed image as it was."""
    with Image.open(source) as image:
        rgb = image.convert("RGB")
    partial = target.with_name(target.name + ".partial")
    rgb.save(partial, format="PNG", optimize=True)
    if partial.stat().st_size > MAX_BYTES:
        rgb.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(partial, format="PNG", optimize=True)
    partial.replace(target)
    print(f"wrote {target.relative_to(ROOT)}: {rgb.width} x {rgb.height} px, {target.stat().st_size / 1e3:.0f} kB")


def make_run(work: Path) -> None:
    """Step 1: the terrain, the dataset, its labels and a short cpu-profile run, all in ``work``."""
    hd(work, "make-dtm", "train.tif", *TRAIN_TERRAIN)
    hd(work, "build-dataset", "--dtm", "train.tif", "--scans", str(SCANS), "--sigma", SIGMA_M, "--out", "data")
    hd(work, "label", "data")
    hd(work, "train", "data", "--out", "run", "--profile", "cpu", "--epochs", str(EPOCHS))


def make_images(work: Path) -> None:
    """Step 2: the detection and its page, the evaluation, and the two PNGs of docs/figures."""
    hd(work, "make-dtm", "site.tif", *DETECT_TERRAIN)
    print(
        hd(work, "detect", "run", "--dtm", "site.tif", "--out", "site-detect", "--nav-sigma", "1", "--site-margin", "1")
    )
    hd(work, "view", "site-detect")
    screenshot(work / "site-detect-view.html", work / "page.png")
    save_small(work / "page.png", HERE / "guide_detect_page.png")
    print(hd(work, "eval", "run", "--data", "data", "--out", "report", "--nav-sigma", "0", "--nav-sigma", "1"))
    save_small(work / "report" / "landing.png", HERE / "guide_landing.png")


def main() -> None:
    """Make both images in ``--work`` (default: a temporary directory, removed afterwards)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, help="directory to make the outputs in and keep (must not exist)")
    args = parser.parse_args()
    if args.work is not None:
        args.work.mkdir(parents=True)
        make_run(args.work)
        make_images(args.work)
        return
    with tempfile.TemporaryDirectory(prefix="hd-guide-") as tmp:
        make_run(Path(tmp))
        make_images(Path(tmp))


if __name__ == "__main__":
    main()
