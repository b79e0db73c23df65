"""CPU seconds spent by a test process and everything it started: the figure that says which tests load the
machine (a test's wall time does not: most of it is robots moving in real time, at a few per cent of a core).

A process that exits and is reaped by its parent moves its time into the parent's ``children_*`` times, so
the sum over the live tree (self and children times of each) only grows, and a difference between two reads
is the CPU the tree used in between: the brokers, servers, agents and browsers a test started and stopped.
"""

from __future__ import annotations

import psutil


def tree_cpu_seconds() -> float:
    """User plus system CPU of this process and its live descendants, each with its reaped children."""
    me = psutil.Process()
    total = 0.0
    for proc in [me, *me.children(recursive=True)]:
        try:
            t = proc.cpu_times()
        except psutil.Error:  # it exited between the listing and the read: its parent counts it from now on
            continue
        total += t.user + t.system + t.children_user + t.children_system
    return total
