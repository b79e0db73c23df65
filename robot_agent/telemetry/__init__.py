"""The agent's telemetry: the publisher that stamps each message, its replay ring, and gap repair answers."""
