"""Screenshots of a Meshcat replay in a headless browser: what a person sees when opening
`alight land --record FILE.html` (the flight view: framed on the vehicle and the car, their
paths, the mission's mode). Needs Chromium's headless shell (Debian: `apt-get install
chromium-headless-shell`); WebGL runs on SwiftShader, on the CPU.

    python bench/replay_screenshot.py REPLAY.html OUT_FOLDER [--at 3 12 21] [--size 1280,800]

The replay plays from its start when the page opens; each screenshot lets the page run `--at`
seconds of the browser's virtual time (the page's set-up included, so about that far into the
flight) and prints the PNG file it wrote.
"""
import argparse
import shutil
import subprocess
from pathlib import Path

BROWSERS = ("chromium-headless-shell", "chromium", "chromium-browser", "google-chrome")


def browser() -> str:
    for name in BROWSERS:
        if shutil.which(name):
            return shutil.which(name)
    raise SystemExit(f"no headless browser found (tried {', '.join(BROWSERS)})")


def screenshot(replay: Path, png: Path, at: float, size: str) -> Path:
    subprocess.run([browser(), "--headless", "--no-sandbox", "--disable-gpu",
                    "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
                    f"--window-size={size}", f"--virtual-time-budget={int(at * 1000)}",
                    f"--screenshot={png}", replay.resolve().as_uri()],
                   check=True, capture_output=True, timeout=600)
    return png


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("replay", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--at", type=float, nargs="+", default=[3.0, 12.0, 21.0])
    parser.add_argument("--size", default="1280,800")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for at in args.at:
        print(screenshot(args.replay, args.out / f"{args.replay.stem}_{at:05.1f}s.png", at,
                         args.size))


if __name__ == "__main__":
    main()
