"""The motion model of the simulated Grbl 1.1h board: one straight block at a time, accelerated
and braked at the block's acceleration (Grbl's trapezoid profile), with a feed hold that brakes
to a stop.

Each block starts and ends at rest (Grbl's planner would carry speed through junctions of
consecutive blocks; the rig sends one move at a time and waits for Idle, so this is what it sees).
The block's speed and acceleration are Grbl's: the programmed feed (G1) or the rapid rate (G0),
limited on every moving axis by `$11x` (mm/min) and `$12x` (mm/s^2) along the move's direction.
Times are in simulated seconds (the board scales wall time by its time_scale).
"""

from __future__ import annotations

import math

EPS = 1e-9


def block_limits(start, target, settings: dict) -> tuple[float, float, float]:
    """(length mm, rapid rate mm/s, acceleration mm/s^2) of a straight block, limited per axis
    as Grbl's planner does (limit_value_by_axis_maximum)."""
    delta = [b - a for a, b in zip(start, target)]
    length = math.sqrt(sum(d * d for d in delta))
    if length <= 0:
        return 0.0, 1.0, 1.0
    rate = accel = math.inf
    for k, d in enumerate(delta):
        if abs(d) > 0:
            share = abs(d) / length
            rate = min(rate, float(settings[110 + k]) / 60.0 / share)
            accel = min(accel, float(settings[120 + k]) / share)
    return length, rate, accel


def trapezoid_seconds(length: float, speed: float, accel: float) -> float:
    """Seconds to cover length from rest to rest at top speed `speed` and acceleration `accel`."""
    if length <= 0:
        return 0.0
    if length >= speed * speed / accel:
        return length / speed + speed / accel
    return 2.0 * math.sqrt(length / accel)


class Move:
    """A straight block from start to target (machine coordinates) at top speed `speed` (mm/s).

    progress (mm along the block) and speed_now (mm/s) advance with `advance`; holding=True brakes
    to a stop instead of going on. jog marks a `$J=` block; fault is an injected (kind, kwargs)
    that the board fires half-way.
    """

    def __init__(self, start, target, speed: float, accel: float, jog: bool = False):
        self.start, self.target = list(start), list(target)
        self.length = math.sqrt(sum((b - a) ** 2 for a, b in zip(start, target)))
        self.speed, self.accel, self.jog = float(speed), float(accel), jog
        self.progress = 0.0
        self.speed_now = 0.0
        self.fault = None

    @property
    def done(self) -> bool:
        return self.progress >= self.length - EPS and self.speed_now <= EPS

    @property
    def stopped(self) -> bool:
        return self.speed_now <= EPS

    def position(self) -> list[float]:
        f = 1.0 if self.length <= 0 else min(self.progress / self.length, 1.0)
        return [a + f * (b - a) for a, b in zip(self.start, self.target)]

    def restart_from(self, position) -> None:
        """Begin the block where the machine stands now (the planner's start may be stale)."""
        self.start = list(position)
        self.length = math.sqrt(sum((b - a) ** 2 for a, b in zip(self.start, self.target)))

    def _go(self, dt: float, accel: float) -> None:
        self.progress += self.speed_now * dt + 0.5 * accel * dt * dt
        self.speed_now = max(self.speed_now + accel * dt, 0.0)

    def advance(self, dt: float, holding: bool = False) -> float:
        """Move on by dt seconds (braking when holding); returns the seconds left over once the
        block is done or, when holding, stopped."""
        a = self.accel
        for _ in range(8):
            if dt <= 0:
                return 0.0
            left = self.length - self.progress
            braking = self.speed_now * self.speed_now / (2.0 * a)
            if holding or braking >= left - EPS * max(1.0, self.length):
                step = min(dt, self.speed_now / a)
                self._go(step, -a)
                dt -= step
                if self.stopped:
                    self.speed_now = 0.0
                    if not holding:
                        self.progress = self.length
                    return dt
            elif self.speed_now < self.speed - EPS:
                peak = min(self.speed, math.sqrt(a * left + 0.5 * self.speed_now**2))
                step = min(dt, (peak - self.speed_now) / a)
                self._go(step, a)
                dt -= step
            else:
                step = min(dt, (left - braking) / self.speed_now)
                self._go(step, 0.0)
                dt -= step
        return 0.0
