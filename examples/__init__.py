"""Example scripts for the fleet (each tested in tests/examples against simulated robots)."""
