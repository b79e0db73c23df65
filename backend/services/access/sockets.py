"""Open WebSockets and who holds them: a socket is authorised by its principal's state now, not only at its
handshake.

Each socket route holds its socket here (:meth:`SocketHolders.hold`) with the role it needs. The access
routes tell this registry at once when they revoke a token, end a session, or disable, demote or delete a
user (:meth:`SocketHolders.deny`), before they answer; every held socket of that principal is then denied:
its next message is refused (:attr:`HeldSocket.denied`) and its route closes it with 1008 and the reason.
Another replica, or the CLI, changes only the database: once a second the registry re-reads the state of
every token and session it holds sockets for, in one query (none while it holds none), so a change made
elsewhere closes the sockets here within about a second. An expired token or session ends the same way.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable, Iterator

from sqlalchemy import Engine

from backend.core.security import AUTH_OFF_PRINCIPAL, Principal, Role
from backend.models import ApiToken
from backend.services.access.tokens import owner_allows, with_owner

log = logging.getLogger("backend.auth")

#: how often the principals of open sockets are re-read from the database (one query each time)
RECHECK_INTERVAL_S = 1.0
#: ids per query (bounded parameters; a server holds far fewer sockets than this)
IDS_PER_QUERY = 500


class HeldSocket:
    """One open socket of ``principal`` that needs ``needs``; ``denied`` is why it may no longer be used."""

    def __init__(self, principal: Principal, needs: Role) -> None:
        self.principal = principal
        self.needs = needs
        self.denied: str | None = None
        self._ended = asyncio.Event()

    def deny(self, reason: str) -> None:
        if self.denied is None:
            self.denied = reason[:120]
            self._ended.set()

    async def wait_denied(self) -> None:
        await self._ended.wait()


#: a held socket -> why it goes (None: it stays)
Verdict = Callable[[HeldSocket], str | None]


class SocketHolders:
    """The open sockets of this server, by principal; ``engine``: where tokens and sessions are read."""

    def __init__(self, *, engine: Engine, interval_s: float = RECHECK_INTERVAL_S) -> None:
        self._engine = engine
        self._interval_s = interval_s
        self._held: set[HeldSocket] = set()
        self._task: asyncio.Task[None] | None = None
        self.rechecks = 0

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self._recheck_forever(), name="socket-principals")

    async def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task

    @contextlib.contextmanager
    def hold(self, principal: Principal, needs: Role) -> Iterator[HeldSocket]:
        """``with holders.hold(principal, Role.OPERATOR) as held:`` for as long as the socket is open."""
        held = HeldSocket(principal, needs)
        self._held.add(held)
        try:
            yield held
        finally:
            self._held.discard(held)

    def __len__(self) -> int:
        return len(self._held)

    # -- notices from the access routes (event loop) -------------------------------------------------------
    def deny(self, verdict: Verdict) -> int:
        """Deny every held socket ``verdict`` gives a reason for; -> how many."""
        reasons = []
        for held in list(self._held):
            reason = verdict(held) if held.denied is None else None
            if reason is not None:
                held.deny(reason)
                reasons.append(reason)
        if reasons:
            log.info("%d WebSocket(s) closed: %s", len(reasons), ", ".join(sorted(set(reasons))))
        return len(reasons)

    def token_revoked(self, token_id: str) -> int:
        return self.deny(lambda h: "token revoked" if _is_token(h.principal, "token", token_id) else None)

    def session_ended(self, session_id: str, reason: str = "logged out") -> int:
        return self.deny(lambda h: reason if _is_token(h.principal, "session", session_id) else None)

    def user_changed(
        self, username: str, *, role: Role | None = None, gone: str | None = None, tokens_too: bool = False
    ) -> int:
        """``gone``: why all the user's sessions end (disabled, deleted, new password), and with ``tokens_too``
        (disabled, deleted) the tokens that answer to them as well; ``role``: their new role, which closes the
        sockets that need more (a demoted operator keeps /ws, loses /ws/control) and those of their tokens
        above it (such a token no longer works at all)."""

        def verdict(held: HeldSocket) -> str | None:
            principal = held.principal
            if principal.owner != username or principal.kind not in ("session", "token"):
                return None
            if principal.kind == "token":
                if gone is not None and tokens_too:
                    return f"{gone} (the token's user)"
                if role is not None and role < principal.role:
                    return f"its user's role changed to {role.label}"
                return None
            if gone is not None:
                return gone
            return f"role changed to {role.label}" if role is not None and role < held.needs else None

        return self.deny(verdict)

    # -- changes made elsewhere (another replica, the CLI, an expiry) ----------------------------------------
    async def _recheck_forever(self) -> None:
        while True:
            await asyncio.sleep(self._interval_s)
            try:
                await self.recheck()
            except Exception as exc:  # the database away: try again next time; the handshake still checks
                log.warning("could not re-check the principals of open WebSockets: %r", exc)

    async def recheck(self) -> None:
        ids = sorted({h.principal.token_id for h in self._held if h.principal.token_id and _recheckable(h.principal)})
        if not ids:
            return
        roles = await asyncio.to_thread(self._current_roles, ids)
        self.rechecks += 1
        for held in list(self._held):
            if held.denied is not None or not _recheckable(held.principal):
                continue
            role = roles.get(held.principal.token_id or "")
            if role is None:
                held.deny("credentials revoked or expired")
            elif role < held.needs:
                held.deny(f"{held.needs.label} role required")

    def _current_roles(self, ids: list[str]) -> dict[str, Role]:
        """{token or session id: its role now}, for those still valid (not revoked, expired or disabled, nor a
        token whose user is gone, disabled or demoted below it)."""
        now = time.time()
        out: dict[str, Role] = {}
        with self._engine.connect() as conn:
            for start in range(0, len(ids), IDS_PER_QUERY):
                rows = conn.execute(with_owner().where(ApiToken.id.in_(ids[start : start + IDS_PER_QUERY])))
                for row in rows:
                    if row.revoked_at is not None or (row.expires_at is not None and row.expires_at <= now):
                        continue
                    name = row.role if row.kind == "api" else (None if row.disabled else row.user_role)
                    with contextlib.suppress(ValueError, TypeError):
                        role = Role.parse(name or "")
                        if row.kind != "api" or owner_allows(
                            row.user_id, row.username, row.user_role, row.disabled, role
                        ):
                            out[row.id] = role
        return out


def _recheckable(principal: Principal) -> bool:
    """Tokens and sessions live in the database; FLEET_ADMIN_TOKEN and auth off do not (nothing revokes them)."""
    return principal is not AUTH_OFF_PRINCIPAL and principal.token_id is not None


def _is_token(principal: Principal, kind: str, token_id: str) -> bool:
    return principal.kind == kind and principal.token_id == token_id
