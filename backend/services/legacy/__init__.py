"""Robots on the old framework: their sensor topics bridged in, and drives relayed to their seed command topics."""
