"""``fleet-client mission ...``: missions from a shell (docs/missions.md).

fleet-client mission create --robot R [--robot R ...] [--area='X,Y;X,Y;X,Y...'] [--width 0.2] [--overlap 0]
                            [--speed M/S] [--name NAME]          (coverage; default area: the whole site)
fleet-client mission create --robot R --path='R:X,Y;X,Y;...' ...   (waypoints: one --path per robot)
fleet-client mission start|pause|resume|abort ID [--reason TEXT] [--rejoin R ...]
fleet-client mission list                    (one JSON line per mission, newest first)
fleet-client mission show ID                 (state, progress, transitions, events)
fleet-client mission wait ID [--timeout S] [--until completed,paused]
fleet-client mission coverage ID [--format geojson|png] [-o FILE] [--px-per-m 100]
fleet-client mission rehearse ID [--seeds N] [--seed S] [--again] [--tracks FILE]
                             (the prediction of a run in the simulated twin, as JSON; the tracks to a file)

(Write ``--area=...`` with the ``=``: a first corner like -0.5,0 would otherwise read as an option.)
Exit status: 0 ok, 1 ``wait`` saw the mission end otherwise (aborted, failed) or time out, 2 refused by the
server (the detail names the bad field) or a usage error.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from fleet_client.client import FleetClient
from fleet_client.errors import MissionFailed


def _print_json(obj: Any) -> None:
    print(json.dumps(obj, indent=None, separators=(",", ":")))


def _point(text: str) -> list[float]:
    x, sep, y = text.partition(",")
    if not sep:
        raise SystemExit(f"fleet-client mission: a point is X,Y, got {text!r}")
    return [float(x), float(y)]


def add_parsers(sub: Any) -> None:
    mission = sub.add_parser("mission", help="missions: create, start, pause, resume, abort, list, show, wait")
    ms = mission.add_subparsers(dest="mission_cmd", required=True)
    create = ms.add_parser("create", help="a draft mission with its plan (printed as JSON)")
    create.add_argument("--robot", action="append", required=True, help="a robot of the mission (repeat)")
    create.add_argument("--name", default="")
    create.add_argument(
        "--area", metavar="'X,Y;X,Y;...'", help="the area's corners, --area=... (default: the whole site)"
    )
    create.add_argument("--width", type=float, default=None, help="sweep width, metres (server default 0.2)")
    create.add_argument("--overlap", type=float, default=None, help="share of the width lanes share")
    create.add_argument("--speed", type=float, default=None, help="m/s")
    create.add_argument("--path", action="append", metavar="R:X,Y;X,Y", help="a waypoints mission: R's path")
    for action in ("start", "pause", "resume", "abort"):
        a = ms.add_parser(action, help=f"{action} a mission")
        a.add_argument("mission_id")
        if action in ("pause", "abort"):
            a.add_argument("--reason", default="")
        if action == "resume":
            a.add_argument("--rejoin", action="append", default=[], help="a dropped robot to take back")
    ms.add_parser("list", help="missions, newest first, one JSON line each")
    show = ms.add_parser("show", help="a mission with its progress, transitions and events")
    show.add_argument("mission_id")
    wait = ms.add_parser("wait", help="wait until the mission completes (exit 1 if it ends otherwise)")
    wait.add_argument("mission_id")
    wait.add_argument("--timeout", type=float, default=3600.0, help="seconds (default 3600)")
    wait.add_argument("--until", default="completed", help="states to stop at, comma-separated")
    rehearse = ms.add_parser("rehearse", help="run a draft or paused mission in the simulated twin first")
    rehearse.add_argument("mission_id")
    rehearse.add_argument("--seeds", type=int, default=1, help="runs with consecutive seeds, 1-5: a spread")
    rehearse.add_argument("--seed", type=int, default=None, help="the first seed (default: a random one)")
    rehearse.add_argument("--again", action="store_true", help="from where the latest rehearsal started")
    rehearse.add_argument("--tracks", metavar="FILE", help="write the predicted tracks (GeoJSON) here")
    cov = ms.add_parser("coverage", help="the swept area: GeoJSON (stdout) or PNG (-o)")
    cov.add_argument("mission_id")
    cov.add_argument("--format", choices=["geojson", "png"], default="geojson")
    cov.add_argument("--output", "-o", help="file to write (needed for png)")
    cov.add_argument("--px-per-m", type=float, default=100.0)


def _create(fleet: FleetClient, args: argparse.Namespace) -> dict[str, Any]:
    if args.path:
        paths: dict[str, list[list[float]]] = {}
        for item in args.path:
            rid, sep, pts = item.partition(":")
            if not sep:
                raise SystemExit(f"fleet-client mission create: --path wants R:X,Y;X,Y, got {item!r}")
            paths[rid] = [_point(p) for p in pts.split(";") if p]
        return fleet.create_mission(args.robot, type="waypoints", name=args.name, speed=args.speed, paths=paths)
    area = [_point(p) for p in args.area.split(";") if p.strip()] if args.area else None
    return fleet.create_mission(
        args.robot, name=args.name, area=area, sweep_width_m=args.width, overlap=args.overlap, speed=args.speed
    )


def _rehearse(fleet: FleetClient, args: argparse.Namespace) -> dict[str, Any]:
    """The prediction, its tracks written to ``--tracks`` (else left out: a long line of coordinates)."""
    result = fleet.rehearse_mission(args.mission_id, seeds=args.seeds, seed=args.seed, again=args.again)
    tracks = result["predicted"].pop("tracks", None)
    if args.tracks:
        with open(args.tracks, "w") as f:
            json.dump(tracks, f)
    return result


def mission_command(fleet: FleetClient, args: argparse.Namespace) -> int:
    cmd = args.mission_cmd
    if cmd == "create":
        _print_json(_create(fleet, args))
    elif cmd == "start":
        _print_json(fleet.start_mission(args.mission_id))
    elif cmd == "pause":
        _print_json(fleet.pause_mission(args.mission_id, args.reason))
    elif cmd == "resume":
        _print_json(fleet.resume_mission(args.mission_id, args.rejoin))
    elif cmd == "abort":
        _print_json(fleet.abort_mission(args.mission_id, args.reason))
    elif cmd == "list":
        for m in fleet.missions():
            _print_json(m)
    elif cmd == "show":
        _print_json(fleet.mission(args.mission_id))
    elif cmd == "wait":
        until = [s.strip() for s in args.until.split(",") if s.strip()]
        try:
            _print_json(fleet.wait_mission(args.mission_id, args.timeout, until=until))
        except MissionFailed as exc:
            _print_json(exc.mission)
            print(f"fleet-client: {exc}", file=sys.stderr)
            return 1
    elif cmd == "rehearse":
        _print_json(_rehearse(fleet, args))
    elif args.format == "png":
        if not args.output:
            raise SystemExit("fleet-client mission coverage --format png: give the file with -o")
        headers = fleet.mission_coverage_png(args.mission_id, args.output, args.px_per_m)
        _print_json(headers)
    else:
        geometry = fleet.mission_coverage(args.mission_id)
        if args.output:
            with open(args.output, "w") as f:
                json.dump(geometry, f)
        else:
            _print_json(geometry)
    return 0
