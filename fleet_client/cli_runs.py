"""``fleet-client run start|stop|list|show|export`` and ``fleet-client marker``: experiment runs from a shell.

fleet-client run start NAME [--robot R ...] [--tag T ...] [--notes TEXT] [--frame-rate 5]
fleet-client run stop [RUN_ID]          (no id: the one run recording)
fleet-client run list [--name N] [--tag T] [--robot R] [--running]
fleet-client run show RUN_ID            (markers and summary)
fleet-client run export RUN_ID [--format mcap|parquet|zip] -o FILE
fleet-client marker TEXT [--run RUN_ID] [--robot R] [--ts T]   (no run: the one recording)
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from fleet_client.client import FleetClient, FleetError


def _print_json(obj: Any) -> None:
    print(json.dumps(obj, indent=None, separators=(",", ":")))


def add_parsers(sub: Any) -> None:
    run = sub.add_parser("run", help="experiment runs: start, stop, list, show, export")
    rs = run.add_subparsers(dest="run_cmd", required=True)
    start = rs.add_parser("start", help="start recording a run (prints it as JSON)")
    start.add_argument("name")
    start.add_argument("--robot", action="append", help="a robot to record (default: every robot online)")
    start.add_argument("--tag", action="append", default=[])
    start.add_argument("--notes", default="")
    start.add_argument("--frame-rate", type=float, default=5.0, help="camera frames kept per second (0: none)")
    stop = rs.add_parser("stop", help="end a run")
    stop.add_argument("run_id", nargs="?", type=int, help="default: the one run recording")
    ls = rs.add_parser("list", help="runs, newest first, one JSON line each")
    ls.add_argument("--name")
    ls.add_argument("--tag")
    ls.add_argument("--robot")
    ls.add_argument("--running", action="store_true")
    show = rs.add_parser("show", help="a run with its markers and summary")
    show.add_argument("run_id", type=int)
    export = rs.add_parser("export", help="download a run (streamed)")
    export.add_argument("run_id", type=int)
    export.add_argument("--format", choices=["mcap", "parquet", "zip"], default="mcap")
    export.add_argument("--output", "-o", required=True, help="file to write")
    marker = sub.add_parser("marker", help="mark a moment of a run")
    marker.add_argument("text")
    marker.add_argument("--run", type=int, help="default: the one run recording")
    marker.add_argument("--robot")
    marker.add_argument("--ts", type=float, help="epoch seconds (default: now)")


def run_command(fleet: FleetClient, args: argparse.Namespace) -> int:
    if args.run_cmd == "start":
        _print_json(fleet.run_start(args.name, args.robot, args.tag, args.notes, args.frame_rate))
    elif args.run_cmd == "stop":
        _print_json(fleet.run_stop(args.run_id))
    elif args.run_cmd == "list":
        for r in fleet.runs(args.name, args.tag, args.robot, True if args.running else None):
            _print_json(r)
    elif args.run_cmd == "show":
        _print_json(fleet.run(args.run_id))
    else:
        headers = fleet.download_run(args.run_id, args.output, args.format)
        if headers.get("x-fleet-run-running") == "true":
            print("note: the run is still recording; the export holds it up to now", file=sys.stderr)
    return 0


def marker_command(fleet: FleetClient, args: argparse.Namespace) -> int:
    run_id = args.run
    if run_id is None:
        running = fleet.runs(running=True)
        if len(running) != 1:
            names = ", ".join(f"{r['id']} ({r['name']})" for r in running) or "none"
            raise FleetError(409, f"name the run with --run: runs recording: {names}")
        run_id = running[0]["id"]
    _print_json(fleet.marker(run_id, args.text, args.robot, args.ts))
    return 0
