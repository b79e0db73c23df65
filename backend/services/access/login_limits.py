"""How often logins may be tried, checked before any password is (scrypt costs 16 MiB and ~50 ms).

Three token buckets: per (username, address), per address whatever the name (a new name per attempt gets
no fresh allowance) and from everyone together; a login must pass all three.
"""

from __future__ import annotations

from backend.core.config import Settings
from backend.core.security import TokenBuckets


class LoginLimits:
    def __init__(self, settings: Settings) -> None:
        self.per_name = TokenBuckets(settings.login_rate_per_s, settings.login_burst)
        self.per_address = TokenBuckets(settings.login_address_rate_per_s, settings.login_address_burst)
        self.total = TokenBuckets(settings.login_total_rate_per_s, settings.login_total_burst)

    def wait(self, username: str, client: str) -> float:
        """Seconds until this login may be tried (0: now)."""
        for buckets, key in (
            (self.per_address, client),
            (self.per_name, (username.lower(), client)),
            (self.total, "*"),
        ):
            wait = buckets.take(key)
            if wait > 0:
                return wait
        return 0.0

    @staticmethod
    def retry_after_header(wait_s: float) -> str:
        return str(max(1, -int(-wait_s // 1)))
