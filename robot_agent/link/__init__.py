"""The agent's link: MQTT and the one-shot publish (the only paho users), clock sync, watchdog, discovery."""

# Nothing is re-exported: importing the package (for the clock sync, say) must not import paho.
