"""What stops robots: the fleet e-stop, per-robot holds, and the alarms that block driving."""
