"""A mission's set-up (issue 18): CPU time of loading the field scenario and building its landing
diagram with a context, `--missions` times in one process with seeds 0, 1, ..., as a campaign
worker or a test session does. The first includes what a process reads once (shipped model
files, the VIO camera's landmark map). Prints the figures; asserts nothing.

    python bench/setup_cost.py [--missions 4]
"""
import argparse
import time

from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.running.runner import build
from alight.diagrams.scenario import load_scenario


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--missions", type=int, default=4)
    args = parser.parse_args()
    seconds = []
    for seed in range(args.missions):
        start = time.process_time()
        scenario = load_scenario("field", overrides=[f"random_seed: {seed}"])
        builder = DiagramBuilder()
        build(builder, scenario)
        builder.Build().CreateDefaultContext()
        seconds.append(time.process_time() - start)
    print("load + build CPU s per mission: " + ", ".join(f"{s:.2f}" for s in seconds))


if __name__ == "__main__":
    main()
