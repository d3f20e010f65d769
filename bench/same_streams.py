"""Do two versions of the code fly the same missions? Records every run-folder stream of a few
seeded missions to a file, then compares two such files stream by stream (`DataFrame.equals`;
the `timing` stream, wall-clock compute times, aside). The check behind every speed change that
claims "the same streams": record with the old code (a `git archive` of it on PYTHONPATH, which
wins over the editable install), record with the new, compare.

    mkdir -p /tmp/old/alight && git archive REV | tar -x -C /tmp/old/alight
    PYTHONPATH=/tmp/old python bench/same_streams.py record /tmp/before.pkl
    python bench/same_streams.py record /tmp/after.pkl
    python bench/same_streams.py compare /tmp/before.pkl /tmp/after.pkl   # exit 1 if any differ

The missions (`--missions` picks some): the direct stack on mocap at 2 m/s; the direct stack on
the VIO at 5 m/s in 15 km/h wind with 0.8 m/s gusts; the managed stack (control manager, MPC
tracker, MPC force controller) at 2 m/s. About 3 CPU minutes on the 2-core machine.
"""
import argparse
import pickle
import sys
import tempfile

import numpy as np

MISSIONS = {
    "mocap": ["target_motion.speed: 2", "random_seed: 0", "onboard.estimator: mocap"],
    "vio_gusts": ["target_motion.speed: 5", "random_seed: 3", "vehicle.wind.mean_speed: 4.1667",
                  "vehicle.wind.gust_std: 0.8"],
    "managed": ["target_motion.speed: 2", "random_seed: 1", "onboard.stack: landing_managed"],
}


def record(path: str, missions: list[str]) -> None:
    """Flies the field scenario with each mission's overrides; pickles {mission: {stream: frame}}."""
    from alight.diagrams.running.run_log import RunLog
    from alight.diagrams.running.runner import run
    from alight.diagrams.scenario import load_scenario
    streams = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in missions:
            flown = run(load_scenario("field", overrides=MISSIONS[name]),
                        run_dir=f"{tmp}/{name}", command="land")
            log = RunLog(flown.path)
            streams[name] = {stream: log[stream] for stream in log.streams if stream != "timing"}
            print(f"{name}: {len(streams[name])} streams, {flown.metadata['duration']:.2f} s")
    with open(path, "wb") as f:
        pickle.dump(streams, f)


def differences(before: dict, after: dict) -> list[str]:
    """One line per stream that is missing or differs (where it first differs)."""
    lines = []
    for mission, frames in before.items():
        if mission not in after:
            lines.append(f"{mission}: not recorded in the second file")
            continue
        for stream, frame in frames.items():
            other = after[mission].get(stream)
            if other is None:
                lines.append(f"{mission}/{stream}: missing")
            elif not frame.equals(other):
                lines.append(f"{mission}/{stream}: {_first_difference(frame, other)}")
    return lines


def _first_difference(a, b) -> str:
    if a.shape != b.shape or list(a.columns) != list(b.columns):
        return f"shape {a.shape} vs {b.shape}"
    differ = ~((a == b) | (a.isna() & b.isna()))
    rows = np.flatnonzero(differ.any(axis=1).to_numpy())
    columns = list(a.columns[differ.any(axis=0).to_numpy()])
    return (f"{len(rows)} rows differ, from t = {a['time'].iloc[rows[0]]:.3f} s, in "
            f"{', '.join(columns[:5])}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    rec = commands.add_parser("record", help="fly the missions, write their streams")
    rec.add_argument("out")
    rec.add_argument("--missions", default=",".join(MISSIONS),
                     help=f"comma-separated, of {', '.join(MISSIONS)}")
    cmp = commands.add_parser("compare", help="compare two recordings")
    cmp.add_argument("before")
    cmp.add_argument("after")
    args = parser.parse_args()
    if args.command == "record":
        missions = args.missions.split(",")
        unknown = [m for m in missions if m not in MISSIONS]
        if unknown:
            parser.error(f"unknown mission(s) {unknown}: expected some of {list(MISSIONS)}")
        record(args.out, missions)
        return 0
    with open(args.before, "rb") as a, open(args.after, "rb") as b:
        before, after = pickle.load(a), pickle.load(b)
    lines = differences(before, after)
    compared = sum(len(frames) for frames in before.values())
    print("\n".join(lines) if lines else f"all {compared} streams equal")
    return 1 if lines else 0


if __name__ == "__main__":
    sys.exit(main())
