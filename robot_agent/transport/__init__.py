"""Network transport of the agent (MQTT via paho, in :mod:`robot_agent.transport.mqtt` only)."""
