"""Experiment runs from Python: start, stop, mark, find, download, and open a stream as a DataFrame."""

from __future__ import annotations

import io
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import httpx

from fleet_client.errors import FleetError

if TYPE_CHECKING:
    import pandas


class RunsMixin:
    """Methods of :class:`fleet_client.FleetClient` for runs (docs/runs.md)."""

    url: str
    _http: httpx.Client

    if TYPE_CHECKING:

        def _request(self, method: str, path: str, ok: tuple[int, ...] = (200,), **kw: Any) -> httpx.Response: ...

        def _download(self, path: str, params: dict[str, Any], out: str | Path | IO[bytes]) -> dict[str, str]: ...

    def run_start(
        self,
        name: str,
        robots: Sequence[str] | None = None,
        tags: Sequence[str] = (),
        notes: str = "",
        frame_rate: float = 5.0,
    ) -> dict[str, Any]:
        """Start recording a run; ``robots`` None: every robot online now."""
        body: dict[str, Any] = {"name": name, "tags": list(tags), "notes": notes, "frame_rate": frame_rate}
        if robots is not None:
            body["robots"] = list(robots)
        return self._request("POST", "/api/runs", ok=(201,), json=body).json()

    def run_stop(self, run_id: int | None = None) -> dict[str, Any]:
        """End a run; without an id, the one run that is recording (an error if none or several are)."""
        if run_id is None:
            running = self.runs(running=True)
            if len(running) != 1:
                names = ", ".join(f"{r['id']} ({r['name']})" for r in running) or "none"
                raise FleetError(409, f"name the run to stop: runs recording: {names}")
            run_id = running[0]["id"]
        return self._request("POST", f"/api/runs/{run_id}/stop").json()

    def marker(self, run_id: int, text: str, robot_id: str | None = None, ts: float | None = None) -> dict[str, Any]:
        """Mark a moment of a run (default: now)."""
        body: dict[str, Any] = {"text": text}
        if robot_id is not None:
            body["robot_id"] = robot_id
        if ts is not None:
            body["ts"] = ts
        return self._request("POST", f"/api/runs/{run_id}/markers", ok=(201,), json=body).json()

    def runs(
        self, name: str | None = None, tag: str | None = None, robot: str | None = None, running: bool | None = None
    ) -> list[dict[str, Any]]:
        params: dict[str, Any] = {"name": name, "tag": tag, "robot": robot}
        if running is not None:
            params["running"] = "true" if running else "false"
        params = {k: v for k, v in params.items() if v is not None}
        return self._request("GET", "/api/runs", params=params).json()

    def run(self, run_id: int) -> dict[str, Any]:
        """A run with its markers and summary."""
        return self._request("GET", f"/api/runs/{run_id}").json()

    def download_run(self, run_id: int, path: str | Path | IO[bytes], fmt: str = "zip") -> dict[str, str]:
        """Stream a run's export (mcap, parquet or zip) into a file; returns the X-Fleet-* headers."""
        return self._download(f"/api/runs/{run_id}/export", {"format": fmt}, path)

    def run_frame(self, run_id: int, stream: str = "position") -> pandas.DataFrame:
        """One stream of a run as a pandas DataFrame (``robot_id``, ``ts``, ``seq``, one column per field),
        read from the run's Parquet export. Needs the ``analysis`` extra (pandas, pyarrow)."""
        import pyarrow.parquet as pq

        buf = io.BytesIO()
        self.download_run(run_id, buf, fmt="parquet")
        with zipfile.ZipFile(buf) as zf:
            name = f"{stream}.parquet"
            if name not in zf.namelist():
                have = ", ".join(n.removesuffix(".parquet") for n in zf.namelist()) or "none"
                raise FleetError(404, f"run {run_id} has no {stream!r} stream (it has: {have})")
            return pq.read_table(io.BytesIO(zf.read(name))).to_pandas()
