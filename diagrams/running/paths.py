"""Where runs go: the default run folder of a command."""
import datetime
from pathlib import Path


def default_run_dir(command: str, seed: int) -> Path:
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path("runs") / f"{stamp}-{command}-s{seed}"
