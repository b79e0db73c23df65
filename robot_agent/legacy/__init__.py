"""Inputs from today's Mollusca sensor modules (the seed's UDP ports), fed unchanged into the agent."""
