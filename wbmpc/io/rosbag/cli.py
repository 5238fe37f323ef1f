"""Command line: ``python -m wbmpc.io.rosbag export LOG.npz BAG | import BAG LOG.npz | topic-map [PATH]``."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from wbmpc.io.logs import load_log, save_log
from wbmpc.io.rosbag.reader import read_bag
from wbmpc.io.rosbag.topic_map import TopicMap
from wbmpc.io.rosbag.writer import write_bag


# ---------------------------------------------------------------------------------------------------- CLI
def main(argv: Sequence[str] | None = None) -> int:
    """Command line: ``export LOG.npz BAG_DIR``, ``import BAG_DIR LOG.npz``, ``topic-map [PATH]``."""
    parser = argparse.ArgumentParser(prog="python -m wbmpc.io.rosbag", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    export = sub.add_parser("export", help="write a run log (.npz) as a ROS 2 bag")
    export.add_argument("log", type=Path)
    export.add_argument("bag", type=Path)
    export.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3")
    export.add_argument("--topic-map", type=Path, help="TopicMap JSON file")
    export.add_argument("--robot", help="robot name of wbmpc.model.robot.ROBOTS giving the joint names")
    imp = sub.add_parser("import", help="read a ROS 2 bag into a run log (.npz)")
    imp.add_argument("bag", type=Path)
    imp.add_argument("log", type=Path)
    imp.add_argument("--topic-map", type=Path, help="TopicMap JSON file")
    imp.add_argument("--robot", help="robot name of wbmpc.model.robot.ROBOTS giving the joint order")
    tmap = sub.add_parser("topic-map", help="write (or print) the default topic map as JSON")
    tmap.add_argument("path", type=Path, nargs="?")
    args = parser.parse_args(argv)

    robot = None
    if getattr(args, "robot", None):
        from wbmpc.model.robot import load

        robot = load(args.robot)
    topic_map = TopicMap.from_json(args.topic_map) if getattr(args, "topic_map", None) else None
    try:
        if args.command == "export":
            out = write_bag(
                load_log(args.log), args.bag, robot=robot, storage=args.storage, topic_map=topic_map
            )
            print(f"wrote {out}")
        elif args.command == "import":
            out = save_log(read_bag(args.bag, topic_map=topic_map, robot=robot), args.log)
            print(f"wrote {out}")
        else:
            text = TopicMap().to_json(args.path)
            print(f"wrote {args.path}" if args.path else text, end="\n" if args.path else "")
    except (ValueError, FileNotFoundError, FileExistsError, ImportError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0
