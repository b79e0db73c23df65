"""``fleet-client``: the fleet from a shell script.

    fleet-client [--url URL] [--token TOKEN] robots [--json]
    fleet-client command ROBOT COMMAND [-a speed=0.5 -a duration_s=1] [--wait 5] [--ttl 2]
    fleet-client live [--robot R ...] [--stream S ...] [--count N] [--seconds S]
    fleet-client history ROBOT [--stream position] [--start T] [--end T] [--max-points N] [--fields x,y]
                         [--raw] [--format json|rows|csv|ndjson] [--output FILE]
    fleet-client events [--start T] [--end T] [--kind K] [--robot R]
    fleet-client goto ROBOT X Y [--yaw RAD] [--tolerance 0.05] [--max-speed M/S] [--timeout S] [--no-wait]
    fleet-client path ROBOT X,Y X,Y ... [--loop] [--tolerance 0.05] [--max-speed M/S] [--timeout S] [--no-wait]
    fleet-client drive ROBOT LINEAR [ANGULAR] [--duration 0.5]
    fleet-client cancel ROBOT
    fleet-client run start|stop|list|show|export ...   fleet-client marker TEXT   (fleet_client/cli_runs.py)
    fleet-client mission create|start|pause|resume|abort|list|show|wait|coverage ...  (fleet_client/cli_missions.py)

``--url`` defaults to FLEET_URL (http://127.0.0.1:8000), ``--token`` to FLEET_TOKEN; with a token every
request sends ``Authorization: Bearer <token>``. Times are ISO 8601 or epoch seconds. Exit status: 0 ok,
1 the command was rejected / expired / not acked (a goal: did not end done), 2 usage or server error.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time
from typing import Any

from fleet_client.cli_missions import add_parsers as add_mission_parsers
from fleet_client.cli_missions import mission_command
from fleet_client.cli_runs import add_parsers as add_run_parsers
from fleet_client.cli_runs import marker_command, run_command
from fleet_client.client import FleetClient, FleetError
from fleet_client.errors import CommandFailed


def _arg_value(text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError:
        return text


def _print_json(obj: Any) -> None:
    print(json.dumps(obj, indent=None, separators=(",", ":")))


def _robots(fleet: FleetClient, args: argparse.Namespace) -> int:
    robots = fleet.robots()
    if args.json:
        _print_json(robots)
        return 0
    print(f"{'id':<20} {'online':<7} {'stale':<6} {'x':>8} {'y':>8}  commands")
    for r in robots:
        pos = r.get("position") or {}
        x = f"{pos['x']:.3f}" if pos else "-"
        y = f"{pos['y']:.3f}" if pos else "-"
        cmds = ",".join(r.get("capabilities", {}).get("commands", []))
        print(f"{r['id']:<20} {str(r['online']).lower():<7} {str(r['stale']).lower():<6} {x:>8} {y:>8}  {cmds}")
    return 0


def _command(fleet: FleetClient, args: argparse.Namespace) -> int:
    cmd_args: dict[str, Any] = {}
    for item in args.arg or []:
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"fleet-client command: --arg wants key=value, got {item!r}")
        cmd_args[key] = _arg_value(value)
    cmd = fleet.send_command(
        args.robot, args.command, cmd_args, wait=min(args.wait, 10.0) if args.wait else None, ttl_s=args.ttl
    )
    if args.wait and args.wait > 10 and cmd["status"] not in ("done", "rejected", "expired"):
        cmd = fleet.wait_for_ack(cmd["id"], timeout=args.wait - 10)
    _print_json(cmd)
    return 0 if cmd["status"] in ("done", "accepted", "sent") else 1


def _live(fleet: FleetClient, args: argparse.Namespace) -> int:
    async def run() -> None:
        n = 0
        deadline = time.monotonic() + args.seconds if args.seconds else None
        agen = fleet.live(args.robot or ["*"], args.stream or ["*"])
        try:
            while True:
                timeout = None if deadline is None else max(0.0, deadline - time.monotonic())
                try:
                    msg = await asyncio.wait_for(agen.__anext__(), timeout)
                except (TimeoutError, StopAsyncIteration):
                    return
                if msg.get("type") != "telemetry" and not args.all:
                    continue
                _print_json(msg)
                sys.stdout.flush()
                n += 1
                if args.count and n >= args.count:
                    return
        finally:
            await agen.aclose()

    asyncio.run(run())
    return 0


def _history(fleet: FleetClient, args: argparse.Namespace) -> int:
    fields = args.fields
    if args.format in ("csv", "ndjson"):
        out = open(args.output, "wb") if args.output else sys.stdout.buffer  # noqa: SIM115 - closed below
        try:
            headers = fleet.export(
                out,
                [args.robot],
                [args.stream],
                args.start,
                args.end,
                fmt=args.format,
                raw=args.raw,
                max_points=args.max_points,
                fields=fields,
            )
        finally:
            if args.output:
                out.close()
            else:
                out.flush()
        print(f"method: {headers.get('x-fleet-method', '?')}", file=sys.stderr)
        return 0
    if args.format == "rows":  # one JSON object per stored row (raw) or per point
        rows = (
            fleet.history_rows(args.robot, args.stream, args.start, args.end, fields)
            if args.raw
            else fleet.history(args.robot, args.stream, args.start, args.end, args.max_points, fields)["points"]
        )
        for row in rows:
            _print_json(row)
        return 0
    if args.raw:
        _print_json(
            {
                "robot_id": args.robot,
                "stream": args.stream,
                "method": "none",
                "points": list(fleet.history_rows(args.robot, args.stream, args.start, args.end, fields)),
            }
        )
    else:
        _print_json(fleet.history(args.robot, args.stream, args.start, args.end, args.max_points, fields))
    return 0


def _events(fleet: FleetClient, args: argparse.Namespace) -> int:
    for e in fleet.events(args.start, args.end, args.kind, args.robot, args.limit):
        _print_json(e)
    return 0


def _goal(fleet: FleetClient, args: argparse.Namespace) -> int:
    common = {"tolerance_m": args.tolerance, "max_speed": args.max_speed, "timeout_s": args.timeout}
    try:
        if args.cmd == "goto":
            cmd = fleet.goto(args.robot, args.x, args.y, args.yaw, wait=not args.no_wait, **common)
        else:
            points = []
            for item in args.waypoints:
                x, sep, y = item.partition(",")
                if not sep:
                    raise SystemExit(f"fleet-client path: a waypoint is X,Y, got {item!r}")
                points.append([float(x), float(y)])
            cmd = fleet.follow_path(args.robot, points, loop=args.loop, wait=not args.no_wait, **common)
    except CommandFailed as exc:
        _print_json(exc.command)
        return 1
    _print_json(cmd)
    return 0


def _drive(fleet: FleetClient, args: argparse.Namespace) -> int:
    cmd = fleet.drive(args.robot, args.linear, args.angular, duration_s=args.duration, wait=2.0 + args.duration)
    _print_json(cmd)
    return 0 if cmd["status"] in ("done", "accepted") else 1


def _cancel(fleet: FleetClient, args: argparse.Namespace) -> int:
    cmd = fleet.cancel(args.robot)
    _print_json(cmd)
    return 0 if cmd["status"] == "done" else 1


def _goal_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--tolerance", type=float, default=0.05, help="metres (default 0.05)")
    p.add_argument("--max-speed", type=float, default=None, help="m/s")
    p.add_argument("--timeout", type=float, default=None, help="seconds the robot may take")
    p.add_argument("--no-wait", action="store_true", help="return once sent (default: wait for the final ack)")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="fleet-client", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--url", help="server URL (default FLEET_URL or http://127.0.0.1:8000)")
    p.add_argument("--token", help="API token (default FLEET_TOKEN)")
    p.add_argument("--timeout", type=float, default=30.0, help="HTTP timeout, seconds")
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("robots", help="list robots")
    r.add_argument("--json", action="store_true")
    c = sub.add_parser("command", help="send a command and wait for its ack")
    c.add_argument("robot")
    c.add_argument("command")
    c.add_argument("-a", "--arg", action="append", help="key=value (value parsed as JSON when it is)")
    c.add_argument("--wait", type=float, default=5.0, help="seconds to wait for the final ack (0: don't)")
    c.add_argument("--ttl", type=float, default=None, help="seconds the robot may still start it")
    lv = sub.add_parser("live", help="live telemetry as JSON lines (WebSocket)")
    lv.add_argument("--robot", action="append")
    lv.add_argument("--stream", action="append")
    lv.add_argument("--count", type=int, default=0, help="stop after N messages")
    lv.add_argument("--seconds", type=float, default=0, help="stop after S seconds")
    lv.add_argument("--all", action="store_true", help="also robot/command/estop messages")
    h = sub.add_parser("history", help="stored telemetry: JSON, rows, CSV or NDJSON")
    h.add_argument("robot")
    h.add_argument("--stream", default="position")
    h.add_argument("--start")
    h.add_argument("--end")
    h.add_argument("--max-points", type=int, default=1000)
    h.add_argument("--fields", help="comma-separated data fields, e.g. x,y")
    h.add_argument("--raw", action="store_true", help="every stored row (not downsampled)")
    h.add_argument("--format", choices=["json", "rows", "csv", "ndjson"], default="json")
    h.add_argument("--output", "-o", help="file for csv/ndjson (default stdout)")
    e = sub.add_parser("events", help="events (online/offline, e-stop, rejects), newest first")
    e.add_argument("--start")
    e.add_argument("--end")
    e.add_argument("--kind")
    e.add_argument("--robot")
    e.add_argument("--limit", type=int, default=500)
    g = sub.add_parser("goto", help="drive to X Y with the robot's own controller; waits for the final ack")
    g.add_argument("robot")
    g.add_argument("x", type=float)
    g.add_argument("y", type=float)
    g.add_argument("--yaw", type=float, default=None, help="radians to face at the end")
    _goal_options(g)
    pa = sub.add_parser("path", help="follow waypoints X,Y ...; waits for the final ack")
    pa.add_argument("robot")
    pa.add_argument("waypoints", nargs="+", metavar="X,Y")
    pa.add_argument("--loop", action="store_true", help="forever (use --no-wait or --timeout)")
    _goal_options(pa)
    d = sub.add_parser("drive", help="one velocity command (m/s, rad/s) for --duration seconds")
    d.add_argument("robot")
    d.add_argument("linear", type=float)
    d.add_argument("angular", type=float, nargs="?", default=0.0)
    d.add_argument("--duration", type=float, default=0.5)
    ca = sub.add_parser("cancel", help="stop the robot (ends a goal: aborted)")
    ca.add_argument("robot")
    add_run_parsers(sub)
    add_mission_parsers(sub)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    handlers = {
        "robots": _robots,
        "command": _command,
        "live": _live,
        "history": _history,
        "events": _events,
        "goto": _goal,
        "path": _goal,
        "drive": _drive,
        "cancel": _cancel,
        "run": run_command,
        "marker": marker_command,
        "mission": mission_command,
    }
    try:
        with FleetClient(args.url, args.token, timeout=args.timeout) as fleet:
            return handlers[args.cmd](fleet, args)
    except FleetError as exc:
        print(f"fleet-client: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
