"""``FleetClient``: the REST API and the live WebSocket from a script."""

from __future__ import annotations

import email.utils
import json
import os
import time
from collections.abc import AsyncGenerator, Iterator, Sequence
from pathlib import Path
from typing import IO, Any

import httpx

from fleet_client.control import DEFAULT_DEADMAN_S, DEFAULT_MAX_RATE_HZ, DEFAULT_RATE_HZ, RobotControl, control_url
from fleet_client.errors import FleetError
from fleet_client.missions import MissionsMixin
from fleet_client.motion import MotionMixin
from fleet_client.runs import RunsMixin

DEFAULT_URL = "http://127.0.0.1:8000"
#: command statuses after which nothing changes any more
FINAL_STATUSES = frozenset({"done", "rejected", "expired", "failed", "aborted"})
TimeArg = str | float | int | None
#: a GET or a download refused with 429/503 and Retry-After is asked again after that wait, this many times
DEFAULT_RETRIES = 3
#: the longest wait between two tries, whatever Retry-After says
MAX_RETRY_WAIT_S = 60.0


def _time(value: TimeArg) -> str | None:
    return None if value is None else str(value)


def _csv(values: str | Sequence[str] | None) -> str | None:
    if values is None:
        return None
    return values if isinstance(values, str) else ",".join(values)


def _params(**kw: Any) -> dict[str, Any]:
    return {k: v for k, v in kw.items() if v is not None}


def retry_after(r: httpx.Response) -> float | None:
    """The seconds a 429 or 503 asks the client to wait (Retry-After: seconds or an HTTP date), or None."""
    value = r.headers.get("retry-after") if r.status_code in (429, 503) else None
    if value is None:
        return None
    try:
        return max(0.0, float(value))
    except ValueError:
        pass
    try:
        when = email.utils.parsedate_to_datetime(value)
    except (TypeError, ValueError):
        return None
    return max(0.0, when.timestamp() - time.time())


class FleetClient(MotionMixin, RunsMixin, MissionsMixin):
    """Synchronous REST client; :meth:`live` is the asynchronous WebSocket stream, :meth:`control` an
    off-board controller's socket. The motion methods (goto, follow_path, drive, cancel, site) come from
    :class:`~fleet_client.motion.MotionMixin`, the runs (start, stop, markers, export) from
    :class:`~fleet_client.runs.RunsMixin`, the missions (create, start ... wait_mission, coverage) from
    :class:`~fleet_client.missions.MissionsMixin`."""

    def __init__(
        self,
        url: str | None = None,
        token: str | None = None,
        timeout: float = 30.0,
        transport: httpx.BaseTransport | None = None,
        retries: int = DEFAULT_RETRIES,
        max_retry_wait_s: float = MAX_RETRY_WAIT_S,
    ) -> None:
        """``retries``: how many times a GET or a download the server refused for now (429/503 with
        Retry-After: too many exports at once) is sent again, each after the wait the server asks (at most
        ``max_retry_wait_s``); 0: never."""
        self.url = (url or os.environ.get("FLEET_URL") or DEFAULT_URL).rstrip("/")
        self.token = token if token is not None else (os.environ.get("FLEET_TOKEN") or None)
        self.timeout = timeout
        self.retries = retries
        self.max_retry_wait_s = max_retry_wait_s
        headers = {"User-Agent": "fleet-client"}
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        self._http = httpx.Client(base_url=self.url, headers=headers, timeout=timeout, transport=transport)

    # -- plumbing -------------------------------------------------------------------------------------
    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> FleetClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _wait_to_retry(self, r: httpx.Response, tries: int) -> bool:
        """After a refusal: wait as the server asks and say to try again, while tries are left."""
        wait = retry_after(r)
        if wait is None or tries >= self.retries:
            return False
        time.sleep(min(wait, self.max_retry_wait_s))
        return True

    def _download(self, path: str, params: dict[str, Any], out: str | Path | IO[bytes]) -> dict[str, str]:
        """Stream a GET's body into ``out`` (a binary file or a path, closed here if opened here); returns the
        X-Fleet-* response headers. A refusal for now (429/503 with Retry-After) is retried after the wait;
        any other refusal raises FleetError with the server's detail."""
        close = False
        if isinstance(out, str | Path):
            out, close = open(out, "wb"), True  # noqa: SIM115 - closed below
        try:
            tries = 0
            while True:
                with self._http.stream("GET", path, params=params) as r:
                    if r.status_code != 200:
                        r.read()
                        if self._wait_to_retry(r, tries):
                            tries += 1
                            continue
                        try:
                            detail = r.json().get("detail", r.text)
                        except ValueError:
                            detail = r.text
                        raise FleetError(r.status_code, str(detail)[:500])
                    for chunk in r.iter_bytes():
                        out.write(chunk)
                    return {k.lower(): v for k, v in r.headers.items() if k.lower().startswith("x-fleet-")}
        except httpx.HTTPError as exc:
            raise FleetError(0, f"cannot reach {self.url}: {exc}") from exc
        finally:
            if close:
                out.close()

    def _request(self, method: str, path: str, ok: tuple[int, ...] = (200,), **kw: Any) -> httpx.Response:
        """One request; a GET refused for now (429/503 with Retry-After) is sent again after the wait (other
        methods never are: a command sent late is not the command that was meant)."""
        tries = 0
        while True:
            try:
                r = self._http.request(method, path, **kw)
            except httpx.HTTPError as exc:
                raise FleetError(0, f"cannot reach {self.url}: {exc}") from exc
            if r.status_code in ok or method != "GET" or not self._wait_to_retry(r, tries):
                break
            tries += 1
        if r.status_code not in ok:
            try:
                body = r.json()
                detail = body.get("detail", r.text) if isinstance(body, dict) else r.text
            except ValueError:
                body, detail = None, r.text
            raise FleetError(r.status_code, str(detail)[:500], body)
        return r

    def _get(self, path: str, **params: Any) -> Any:
        return self._request("GET", path, params=_params(**params)).json()

    # -- robots and commands ----------------------------------------------------------------------------
    def health(self) -> dict[str, Any]:
        return self._get("/api/health")

    def robots(self) -> list[dict[str, Any]]:
        return self._get("/api/robots")

    def robot(self, robot_id: str) -> dict[str, Any]:
        return self._get(f"/api/robots/{robot_id}")

    def streams(self, robot_id: str) -> list[dict[str, Any]]:
        return self._get(f"/api/robots/{robot_id}/streams")

    def send_command(
        self,
        robot_id: str,
        command: str,
        args: dict[str, Any] | None = None,
        *,
        wait: float | None = 5.0,
        ttl_s: float | None = None,
        source: str = "fleet-client",
    ) -> dict[str, Any]:
        """Send a command. With ``wait`` (seconds, max 10) the server answers once the robot's final ack came
        (or with the latest status / ``timeout`` when none came in time); ``wait=None`` returns at once
        (status ``sent``) - then :meth:`wait_for_ack`."""
        body: dict[str, Any] = {"command": command, "args": args or {}, "source": source}
        if ttl_s is not None:
            body["ttl_s"] = ttl_s
        params = {"wait": wait} if wait is not None else {}
        r = self._request("POST", f"/api/robots/{robot_id}/commands", ok=(200, 202, 504), json=body, params=params)
        return r.json()

    def command(self, command_id: str) -> dict[str, Any]:
        return self._get(f"/api/commands/{command_id}")

    def commands(
        self, robot_id: str, start: TimeArg = None, end: TimeArg = None, limit: int = 100
    ) -> list[dict[str, Any]]:
        """Newest first."""
        return self._get(f"/api/robots/{robot_id}/commands", start=_time(start), end=_time(end), limit=limit)

    def wait_for_ack(self, command_id: str, timeout: float = 10.0, interval: float = 0.1) -> dict[str, Any]:
        """Poll until the command has a final status (done/failed/aborted/rejected/expired) or ``timeout``."""
        deadline = time.monotonic() + timeout
        while True:
            cmd = self.command(command_id)
            if cmd["status"] in FINAL_STATUSES or time.monotonic() >= deadline:
                return cmd
            time.sleep(interval)

    def estop(self, reason: str = "", source: str = "fleet-client") -> dict[str, Any]:
        r = self._request("POST", "/api/estop", ok=(200, 202), json={"reason": reason, "source": source})
        return r.json()

    def release_estop(self) -> dict[str, Any]:
        return self._request("POST", "/api/estop/release", ok=(200, 202)).json()

    def hold(self, robot_id: str, reason: str = "") -> dict[str, Any]:
        """Hold one robot: it is stopped and its drives are refused (409 ``robot_held``) until released."""
        return self._request("PUT", f"/api/robots/{robot_id}/hold", json={"reason": reason}).json()

    def release_hold(self, robot_id: str) -> dict[str, Any]:
        return self._request("DELETE", f"/api/robots/{robot_id}/hold").json()

    def events(
        self,
        start: TimeArg = None,
        end: TimeArg = None,
        kind: str | None = None,
        robot_id: str | None = None,
        limit: int = 500,
    ) -> list[dict[str, Any]]:
        """Newest first."""
        return self._get("/api/events", start=_time(start), end=_time(end), kind=kind, robot_id=robot_id, limit=limit)

    # -- history ----------------------------------------------------------------------------------------
    def history(
        self,
        robot_id: str,
        stream: str = "position",
        start: TimeArg = None,
        end: TimeArg = None,
        max_points: int = 1000,
        fields: str | Sequence[str] | None = None,
    ) -> dict[str, Any]:
        """At most ``max_points`` points; ``method`` says whether/how they were downsampled."""
        return self._get(
            f"/api/robots/{robot_id}/telemetry",
            stream=stream,
            start=_time(start),
            end=_time(end),
            max_points=max_points,
            fields=_csv(fields),
        )

    def history_many(
        self,
        robots: str | Sequence[str] | None = None,
        streams: str | Sequence[str] = "position",
        start: TimeArg = None,
        end: TimeArg = None,
        max_points: int = 1000,
        fields: str | Sequence[str] | None = None,
    ) -> dict[str, Any]:
        return self._get(
            "/api/telemetry",
            robots=_csv(robots),
            streams=_csv(streams),
            start=_time(start),
            end=_time(end),
            max_points=max_points,
            fields=_csv(fields),
        )

    def history_rows(
        self,
        robot_id: str,
        stream: str = "position",
        start: TimeArg = None,
        end: TimeArg = None,
        fields: str | Sequence[str] | None = None,
        page_size: int = 5000,
    ) -> Iterator[dict[str, Any]]:
        """Every stored row in the range ({ts, seq, data}), page by page (cursor), in time order."""
        cursor: str | None = None
        while True:
            page = self._get(
                f"/api/robots/{robot_id}/telemetry",
                stream=stream,
                start=_time(start),
                end=_time(end),
                fields=_csv(fields),
                raw="true",
                limit=page_size,
                cursor=cursor,
            )
            yield from page["points"]
            cursor = page.get("next_cursor")
            if not cursor:
                return

    def export(
        self,
        out: IO[bytes] | str | Path,
        robots: str | Sequence[str],
        streams: str | Sequence[str] = "position",
        start: TimeArg = None,
        end: TimeArg = None,
        fmt: str = "csv",
        raw: bool = True,
        max_points: int = 1000,
        fields: str | Sequence[str] | None = None,
    ) -> dict[str, str]:
        """Stream a CSV/NDJSON export into ``out`` (a binary file or a path). ``raw=False``: the downsampled
        series instead of every stored row. Returns the X-Fleet-* response headers (method, sources)."""
        params = _params(
            robots=_csv(robots),
            streams=_csv(streams),
            start=_time(start),
            end=_time(end),
            format=fmt,
            raw="true" if raw else None,
            max_points=None if raw else max_points,
            fields=_csv(fields),
        )
        return self._download("/api/telemetry", params, out)

    # -- live -------------------------------------------------------------------------------------------
    def ws_url(self) -> str:
        scheme = "wss" if self.url.startswith("https") else "ws"
        return f"{scheme}://{self.url.split('://', 1)[1]}/ws"

    async def live(
        self, robots: Sequence[str] = ("*",), streams: Sequence[str] = ("*",)
    ) -> AsyncGenerator[dict[str, Any], None]:
        """Every live message (snapshot, robot, telemetry, command, estop) as it arrives. Needs ``websockets``."""
        try:
            import websockets
        except ImportError as exc:  # pragma: no cover - depends on the installation
            raise FleetError(0, "live streaming needs the websockets package (pip install websockets)") from exc
        headers = {"Authorization": f"Bearer {self.token}"} if self.token else {}
        async with websockets.connect(self.ws_url(), additional_headers=headers, max_size=None) as ws:
            await ws.send(json.dumps({"type": "subscribe", "robots": list(robots), "streams": list(streams)}))
            async for frame in ws:
                for msg in json.loads(frame):
                    yield msg

    def control(
        self,
        robot_id: str,
        *,
        watch: Sequence[str] = (),
        streams: Sequence[str] = ("position",),
        duration_s: float = DEFAULT_DEADMAN_S,
        rate_hz: float = DEFAULT_RATE_HZ,
        max_rate_hz: float = DEFAULT_MAX_RATE_HZ,
        client_id: str = "",
    ) -> RobotControl:
        """``async with fleet.control("r1") as ctl:`` live poses of ``robot_id`` (and of the robots in
        ``watch``) and velocity set-points (``await ctl.drive(linear, angular)``), kept alive at ``rate_hz``
        with the deadman ``duration_s``; the robot is stopped when the block ends. See fleet_client.control."""
        headers = {"Authorization": f"Bearer {self.token}"} if self.token else {}
        url = control_url(self.url, robot_id, watch, streams, client_id)
        return RobotControl(url, headers, robot_id, rate_hz=rate_hz, duration_s=duration_s, max_rate_hz=max_rate_hz)
