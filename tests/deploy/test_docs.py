"""The infrastructure docs stay true: their links resolve, and docs/protocol.md states the numbers and topic
names fleet_protocol actually uses (the module's docstring asks for the two to be kept in step)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import fleet_protocol as fp

ROOT = Path(__file__).resolve().parents[2]
DOCS = sorted(["README.md", "deploy/README.md", *(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))])
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _anchors(md: Path) -> set[str]:
    """GitHub-style heading anchors of a Markdown file."""
    out = set()
    for line in md.read_text().splitlines():
        if line.startswith("#"):
            title = line.lstrip("#").strip().lower()
            out.add(re.sub(r"\s", "-", re.sub(r"[^\w\s-]", "", title)))
    return out


@pytest.mark.parametrize("doc", DOCS)
def test_links_resolve(doc: str) -> None:
    path = ROOT / doc
    broken = []
    for target in LINK.findall(path.read_text()):
        if target.startswith(("http://", "https://", "mailto:")):
            continue
        file_part, _, anchor = target.partition("#")
        dest = (path.parent / file_part).resolve() if file_part else path
        missing_anchor = bool(anchor) and dest.suffix == ".md" and dest.exists() and anchor not in _anchors(dest)
        if not dest.exists() or missing_anchor:
            broken.append(target)
    assert broken == [], f"{doc}: broken links {broken}"


def test_protocol_doc_matches_the_protocol_module() -> None:
    text = (ROOT / "docs" / "protocol.md").read_text()
    t = fp.Topics()
    for name in ("status", "cmd", "ack", "camera", "ping"):
        assert getattr(t, name)("r1") == f"fleet/r1/{name}"
        assert f"`fleet/{{id}}/{name}`" in text, name
    assert t.telemetry("r1", "imu") == "fleet/r1/telemetry/imu" and "`fleet/{id}/telemetry/{stream}`" in text
    assert f"`{t.estop()}`" in text
    assert f"`{fp.ROBOT_ID_PATTERN}`" in text
    assert f"{fp.MAX_JSON_PAYLOAD_BYTES // 1024} KiB" in text
    assert f"{fp.MAX_CAMERA_PAYLOAD_BYTES // (1024 * 1024)} MiB" in text
    assert f'"{fp.CAMERA_MAGIC.decode()}"' in text
    assert f"every {fp.LINK_PING_PERIOD_S} s" in text and f"for {fp.LINK_SILENCE_S} s" in text
    assert f"≤ {fp.MAX_COMMAND_TTL_S:g}, default {fp.DEFAULT_COMMAND_TTL_S:g}" in text
    assert f"≤ {fp.MAX_DRIVE_DURATION_S:g} (default {fp.DEFAULT_DRIVE_DURATION_S:g})" in text
    assert f"`PROTOCOL_VERSION = {fp.PROTOCOL_VERSION}`" in text
    assert f"`{fp.COMMAND_NAME_PATTERN}`" in text
    for cmd in fp.SEED_COMMANDS:
        assert f"`{cmd}`" in text
    for status in fp.AckStatus:
        assert f"| `{status.value}` |" in text
    for stream in fp.STREAM_SCHEMAS:
        assert f"| `{stream}` |" in text
    for topic in (fp.LEGACY_POSITION_TOPIC, fp.LEGACY_IMU_TOPIC, fp.LEGACY_APRILTAG_TOPIC, fp.LEGACY_COMMAND_TOPIC):
        assert f"`{topic}`" in text
    qos = {
        "status": fp.QOS_STATUS,
        "cmd": fp.QOS_COMMAND,
        "ack": fp.QOS_ACK,
        "camera": fp.QOS_CAMERA,
        "ping": fp.QOS_PING,
    }
    for name, level in qos.items():
        row = next(ln for ln in text.splitlines() if ln.startswith(f"| `fleet/{{id}}/{name}` |"))
        assert f"| {level} |" in row, row
    row = next(ln for ln in text.splitlines() if ln.startswith("| `fleet/estop` |"))
    assert f"| {fp.QOS_ESTOP} | yes |" in row
    # gap repair
    from fleet_protocol import repair

    for name in ("request", "reply"):
        assert getattr(t, f"repair_{name}")("r1") == f"fleet/r1/repair/{name}"
        row = next(ln for ln in text.splitlines() if ln.startswith(f"| `fleet/{{id}}/repair/{name}` |"))
        assert f"| {fp.QOS_REPAIR} | no |" in row, row
    assert f"`{fp.BOOT_ID_PATTERN}`" in text
    assert f"at most {repair.MAX_REPAIR_RANGES} ranges and {repair.MAX_REPAIR_SEQS:,} seq numbers" in text
    assert f"about\n{repair.REPLY_TARGET_BYTES // 1024} KiB" in text


def test_server_md_lists_every_setting() -> None:
    from backend.core.config import Settings

    text = (ROOT / "docs" / "server.md").read_text()
    missing = [f"FLEET_{name.upper()}" for name in Settings.model_fields if f"`FLEET_{name.upper()}`" not in text]
    assert missing == [], f"docs/server.md does not explain {missing}"
