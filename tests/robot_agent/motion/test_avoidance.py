"""The barrier filter on its own (robot_agent/motion/avoidance.py): two and more unicycles driven at each other
keep their look-ahead points the safety distance apart, a zero command stays zero, a command that leads away
is not changed, and a neighbour that does not cooperate gets the whole of the avoidance.

Integrated with simple unicycle kinematics at the agent's control rate (20 Hz); the robots in the simulator,
with its disturbances, are measured where the filter is wired into the agent."""

from __future__ import annotations

import itertools
import math
import random

import pytest

from robot_agent.motion.avoidance import BarrierFilter, Neighbour, solve_qp

DT = 0.05
SAFETY_M = 0.3
SPEED = 0.2


def _step(pose: list[float], v: float, w: float) -> None:
    pose[0] += v * math.cos(pose[2]) * DT
    pose[1] += v * math.sin(pose[2]) * DT
    pose[2] += w * DT


def _run(poses: list[list[float]], goals: list[tuple[float, float]], steps: int, cooperative: list[bool]) -> float:
    """Each robot steers to its goal (a proportional heading law) through the filter when it cooperates, and
    straight at it when it does not; returns the closest any two look-ahead points came."""
    f = BarrierFilter(safety_m=SAFETY_M)
    closest = math.inf
    last = [(0.0, 0.0)] * len(poses)  # each look-ahead point's velocity at the step before, as measured
    for _ in range(steps):
        points = [f.lookahead_point(*p) for p in poses]
        vels = []
        for i, (p, goal) in enumerate(zip(poses, goals, strict=True)):
            heading = math.atan2(goal[1] - p[1], goal[0] - p[0])
            err = math.atan2(math.sin(heading - p[2]), math.cos(heading - p[2]))
            v = SPEED if math.hypot(goal[0] - p[0], goal[1] - p[1]) > 0.05 else 0.0
            w = max(-1.5, min(1.5, 3.0 * err))
            if cooperative[i]:
                others = [
                    Neighbour(str(j), *points[j], *last[j], cooperative=cooperative[j])
                    for j in range(len(poses))
                    if j != i
                ]
                out = f.filter(p[0], p[1], p[2], v, w, others)
                v, w = out.linear, out.angular
            vels.append((v, w))
        before = [f.lookahead_point(*p) for p in poses]
        for p, (v, w) in zip(poses, vels, strict=True):
            _step(p, v, w)
        points = [f.lookahead_point(*p) for p in poses]
        last = [((a[0] - b[0]) / DT, (a[1] - b[1]) / DT) for a, b in zip(points, before, strict=True)]
        for a, b in itertools.combinations(points, 2):
            closest = min(closest, math.dist(a, b))
    return closest


def test_two_robots_driven_head_on_keep_the_safety_distance() -> None:
    poses = [[-1.0, 0.0, 0.0], [1.0, 0.01, math.pi]]
    unfiltered = _run([p[:] for p in poses], [(1.0, 0.0), (-1.0, 0.0)], 200, [False, False])
    assert unfiltered < 0.05  # without the filter they meet: the check below could fail
    assert _run(poses, [(1.0, 0.0), (-1.0, 0.0)], 200, [True, True]) >= SAFETY_M - 1e-3


def test_six_robots_crossing_keep_the_safety_distance() -> None:
    rng = random.Random(3)
    for _ in range(5):
        angles = [k * math.pi / 3 + rng.uniform(-0.1, 0.1) for k in range(6)]
        poses = [[1.2 * math.cos(a), 1.2 * math.sin(a), a + math.pi] for a in angles]
        goals = [(-1.2 * math.cos(a), -1.2 * math.sin(a)) for a in angles]
        assert _run([p[:] for p in poses], goals, 300, [False] * 6) < SAFETY_M  # they would come close
        assert _run(poses, goals, 300, [True] * 6) >= SAFETY_M - 1e-3


def test_a_robot_that_does_not_cooperate_gets_the_whole_avoidance() -> None:
    # their paths cross where both arrive at once; robot 1 ignores robot 0, which alone keeps them apart
    poses = [[0.0, -1.0, math.pi / 2], [1.0, 0.0, math.pi]]
    goals = [(0.0, 1.0), (-1.0, 0.0)]
    assert _run([p[:] for p in poses], goals, 200, [False, False]) < 0.1
    assert _run(poses, goals, 200, [True, False]) >= SAFETY_M - 0.02


def test_a_zero_command_stays_zero_and_a_command_away_is_not_changed() -> None:
    f = BarrierFilter(safety_m=SAFETY_M)
    near = [Neighbour("n", 0.4, 0.0)]
    still = f.filter(0.0, 0.0, 0.0, 0.0, 0.0, near)
    assert (still.linear, still.angular, still.changed) == (0.0, 0.0, False)
    away = f.filter(0.0, 0.0, 0.0, -0.2, 0.0, near)  # backing away from the neighbour ahead
    assert (away.linear, away.angular, away.changed) == (-0.2, 0.0, False)
    towards = f.filter(0.0, 0.0, 0.0, 0.2, 0.0, near)  # straight at it, close: slowed
    assert towards.changed and towards.linear < 0.2
    assert towards.nearest_id == "n" and towards.nearest_m == pytest.approx(0.4 - f.lookahead_m)


def _operators_head_on(dy: float, yaw_err: float, drift: tuple[float, float], seconds: float) -> tuple[bool, float]:
    """Two operators hold full forward (no turn) 1.2 m apart, head-on; the filter of each robot (the agent's
    limits and passing turn) is all that steers. Returns whether they passed each other, and their closest
    approach (centres)."""
    # as the agent's guard: the distance is kept between centres (the look-ahead added as far as a robot faces
    # away from the other)
    f = BarrierFilter(
        safety_m=0.36, lookahead_m=0.04, pass_right_rad=0.6, limits=(0.2, 1.5, 0.3, 0.2), centre_safety=True
    )
    poses = [[-0.6, 0.0, yaw_err], [0.6, dy, math.pi - yaw_err]]
    last = [(0.0, 0.0), (0.0, 0.0)]
    closest = math.inf
    for _ in range(int(seconds / DT)):
        commands = []
        for i, p in enumerate(poses):
            q, (vx, vy) = poses[1 - i], last[1 - i]
            dist = math.dist(p[:2], q[:2])
            ex, ey = (q[0] - p[0]) / dist, (q[1] - p[1]) / dist
            away = max(0.0, vx * ex + vy * ey)  # of a filtering neighbour only its moving away counts
            out = f.filter(p[0], p[1], p[2], SPEED, 0.0, [Neighbour("o", q[0], q[1], away * ex, away * ey)], drift)
            commands.append((out.linear, out.angular))
        before = [(p[0], p[1]) for p in poses]
        for p, (v, w) in zip(poses, commands, strict=True):
            p[0] += (v * math.cos(p[2]) + drift[0]) * DT
            p[1] += (v * math.sin(p[2]) + drift[1]) * DT
            p[2] += w * DT
        last = [((p[0] - b[0]) / DT, (p[1] - b[1]) / DT) for p, b in zip(poses, before, strict=True)]
        closest = min(closest, math.dist(poses[0][:2], poses[1][:2]))
    return poses[0][0] > poses[1][0], closest


def test_two_operators_holding_forward_head_on_pass_each_other_from_any_start() -> None:
    """No deadlock: lateral offsets, heading errors and a current of 2 cm/s either way, the passing turn alone
    (no give-way). A second certificate on the centres, tried on 2026-11-29, stopped a robot whose look-ahead
    point would have slid past: 28 of 84 such starts then stood face to face for good."""
    stuck = []
    for dy in (-0.05, 0.0, 0.02, 0.1):
        for yaw_err in (0.0, 0.05, -0.05, 0.15):
            for drift in ((0.0, 0.0), (0.02, 0.0), (0.0, 0.02)):
                passed, closest = _operators_head_on(dy, yaw_err, drift, 10.0)
                assert closest >= 0.36, (dy, yaw_err, drift, closest)
                if not passed:
                    stuck.append((dy, yaw_err, drift))
    assert stuck == []


def test_the_quadratic_programme_is_exact() -> None:
    rng = random.Random(7)
    for _ in range(40):
        rows = [(rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-0.5, 1)) for _ in range(rng.randint(1, 6))]
        ux, uy = rng.uniform(-2, 2), rng.uniform(-2, 2)
        got = solve_qp(ux, uy, rows)
        # brute force on a fine grid around the target: nothing feasible is nearer than the answer
        grid = [(ux + i * 0.03, uy + j * 0.03) for i in range(-100, 101) for j in range(-100, 101)]
        feasible = [(x, y) for x, y in grid if all(a * x + b * y <= c for a, b, c in rows)]
        if got is None:
            assert not feasible
            continue
        assert all(a * got[0] + b * got[1] <= c + 1e-6 for a, b, c in rows)
        best = min(((x - ux) ** 2 + (y - uy) ** 2 for x, y in feasible), default=math.inf)
        assert (got[0] - ux) ** 2 + (got[1] - uy) ** 2 <= best + 1e-9


def _enumerated_qp(ux: float, uy: float, rows: list[tuple[float, float, float]]) -> tuple[float, float] | None:
    """The same optimum by exhaustion: u itself, every projection and every corner, the cheapest feasible."""
    candidates = [(ux, uy)]
    for ax, ay, b in rows:
        k = (ax * ux + ay * uy - b) / (ax * ax + ay * ay)
        candidates.append((ux - k * ax, uy - k * ay))
    for (a1, b1, c1), (a2, b2, c2) in itertools.combinations(rows, 2):
        det = a1 * b2 - a2 * b1
        if abs(det) > 1e-12:
            candidates.append(((c1 * b2 - c2 * b1) / det, (a1 * c2 - a2 * c1) / det))
    feasible = [p for p in candidates if all(a * p[0] + b * p[1] <= c + 1e-9 for a, b, c in rows)]
    return min(feasible, key=lambda p: (p[0] - ux) ** 2 + (p[1] - uy) ** 2, default=None)


def test_the_quadratic_programme_matches_exhaustion_with_many_rows() -> None:
    """Thirty-two rows (twenty neighbours and the wheels' twelve), in rings like a crowd's: the incremental
    solver finds exactly the optimum that trying every corner finds, and None exactly when it finds none."""
    rng = random.Random(11)
    infeasible = 0
    for _ in range(300):
        rows = []
        for _ in range(32):
            angle = rng.uniform(-math.pi, math.pi)
            rows.append((math.cos(angle), math.sin(angle), rng.uniform(-0.3, 1.0)))
        ux, uy = rng.uniform(-1, 1), rng.uniform(-1, 1)
        got, want = solve_qp(ux, uy, rows), _enumerated_qp(ux, uy, rows)
        if want is None:
            infeasible += 1
            assert got is None
            continue
        assert got is not None and math.dist(got, want) < 1e-6
    assert 0 < infeasible < 300  # both outcomes were tried


def test_centre_safety_adds_the_look_ahead_as_far_as_the_robot_faces_away() -> None:
    f = BarrierFilter(safety_m=0.3, lookahead_m=0.04, centre_safety=True)
    n = Neighbour("n", 1.0, 0.0)
    px, py = f.lookahead_point(0.0, 0.0, 0.0)
    assert f.safety(n, px, py, 0.0) == pytest.approx(0.3)  # facing it: the centre is farther than the point
    assert f.safety(n, px, py, math.pi / 2) == pytest.approx(0.3)  # beside it
    px, py = f.lookahead_point(0.0, 0.0, math.pi)
    assert f.safety(n, px, py, math.pi) == pytest.approx(0.34)  # facing away: the centre is nearer
    assert BarrierFilter(safety_m=0.3).safety(n, px, py, math.pi) == pytest.approx(0.3)  # off: as given


def test_a_follower_keeping_pace_behind_and_beside_its_leader_is_not_held_back() -> None:
    """A formation's slot (0.35 m behind, 0.3 m aside: 0.46 m) with the agent's distance at its leader's speed
    (0.3 m and the margins: 0.36 m): the centres' distance leaves the follower free, the look-ahead point's
    distance plus the look-ahead (the filter before centre_safety) held it back as it caught up."""
    ex, ey = 0.35 / math.hypot(0.35, 0.3), 0.3 / math.hypot(0.35, 0.3)
    away = 0.08 * ex  # at the formation's speed along x, ahead and aside: of it, its moving away counts (the guard's)
    leader = Neighbour("lead", 0.35, 0.3, away * ex, away * ey)
    catching_up = (0.0, 0.0, 0.0, 0.18, 0.0)  # the follower closes in on its slot at 10 cm/s more than the leader
    held = BarrierFilter(safety_m=0.36 + 0.04, lookahead_m=0.04).filter(*catching_up, [leader])
    assert held.changed  # the old way: held back (the check below could fail)
    free = BarrierFilter(safety_m=0.36, lookahead_m=0.04, centre_safety=True).filter(*catching_up, [leader])
    assert not free.changed and (free.linear, free.angular) == (0.18, 0.0)


def test_the_passing_turn_judges_the_course_against_the_neighbours_whole_velocity() -> None:
    """A follower keeping pace behind its leader on a bend (the leader veering left, the follower not yet) is
    on no collision course with it, though the certificate counts only the leader's moving away: judged
    against that part (the filter before 2026-11-30), the follower's course ran at the leader and it was
    turned off its slot."""
    f = BarrierFilter(safety_m=0.36, lookahead_m=0.04, pass_right_rad=0.6, centre_safety=True)
    px, py = f.lookahead_point(0.0, 0.0, math.pi / 2)
    lx, ly, leader_v, u = -0.044, 0.458, (-0.037, 0.071), (-0.006, 0.078)
    dist = math.hypot(lx - px, ly - py)
    ex, ey = (lx - px) / dist, (ly - py) / dist
    away = leader_v[0] * ex + leader_v[1] * ey
    assert away > 0.0  # the leader moves away: the certificate counts that part of it
    as_counted = Neighbour("lead", lx, ly, away * ex, away * ey)
    assert f.passing_turn(px, py, *u, [as_counted]) > 0.5  # judged on the counted part: turned (could fail)
    whole = Neighbour("lead", lx, ly, away * ex, away * ey, course=leader_v)
    assert f.passing_turn(px, py, *u, [whole]) == 0.0


def test_the_passing_turn_is_whole_head_on_and_fades_for_a_grazing_course() -> None:
    f = BarrierFilter(safety_m=0.36, lookahead_m=0.04, pass_right_rad=0.6, centre_safety=True)
    safety = 0.36 + 0.04  # the course is judged at the distance the point kept before centre_safety

    def turn(miss: float) -> float:
        """Closing at 0.1 m/s along x on a neighbour at the edge of the distance, its centre ``miss`` aside."""
        ahead = math.sqrt(max(safety * safety - miss * miss, 0.01))
        return f.passing_turn(0.0, 0.0, 0.1, 0.0, [Neighbour("n", ahead, miss)])

    assert turn(0.0) == pytest.approx(0.6)
    assert turn(0.45 * safety) == pytest.approx(0.6)  # within half the distance: whole
    assert turn(0.9 * safety) == pytest.approx(0.6 * 0.2)  # grazing: a little
    assert turn(1.01 * safety) == 0.0  # clear of it: none
