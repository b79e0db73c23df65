"""The robots as the server knows them: registry, readiness, clock sync, heartbeat, forgetting one."""
