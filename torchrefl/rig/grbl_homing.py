"""How long a Grbl 1.1h homing cycle takes, from its `$$` settings.

Grbl 1.1h (limits.c, default config.h) homes Z first, then X and Y together. Each cycle makes four
moves: a search towards the switch at the seek rate `$25` (at most HOMING_AXIS_SEARCH_SCALAR x the
max travel `$13x`), a pull-off of `$27` at `$25`, a locate back onto the switch at the feed `$24`
(at most HOMING_AXIS_LOCATE_SCALAR x `$27`), and a final pull-off of `$27` at `$25`; each move ends
with the `$26` ms debounce delay. Every axis of a cycle moves at the cycle's rate, so the longest
axis sets the cycle's time. Grbl answers no `?` while homing, so the host can only bound the time.
Acceleration is left out (a fraction of a second per move; the margin covers it).
"""

from __future__ import annotations

HOMING_CYCLES = ((2,), (0, 1))  # axis indices: Z first, then X and Y (HOMING_CYCLE_0, HOMING_CYCLE_1)
SEARCH_SCALAR = 1.5  # HOMING_AXIS_SEARCH_SCALAR
LOCATE_SCALAR = 5.0  # HOMING_AXIS_LOCATE_SCALAR
MOVES_PER_CYCLE = 4
TIMEOUT_FACTOR = 1.25  # margin of the computed homing timeout over the longest cycle
TIMEOUT_EXTRA_S = 5.0


def cycle_seconds(search_mm: float, settings: dict, locate_mm: float | None = None) -> float:
    """Seconds of one homing cycle whose search covers search_mm and whose locate covers locate_mm
    (default: the found switch lies `$27` away, as after the pull-off)."""
    seek, feed, pull = float(settings[25]), float(settings[24]), float(settings[27])
    locate = pull if locate_mm is None else locate_mm
    minutes = (search_mm + 2.0 * pull) / seek + locate / feed
    return minutes * 60.0 + MOVES_PER_CYCLE * float(settings.get(26, 0.0)) / 1000.0


def homing_seconds(distances_mm, settings: dict) -> float:
    """Seconds of a `$H` when axis k's switch lies distances_mm[k] away (what the fake board takes)."""
    return sum(cycle_seconds(max(abs(distances_mm[k]) for k in axes), settings) for axes in HOMING_CYCLES)


def homing_timeout_s(settings: dict) -> float:
    """The longest a `$H` may take on these settings (every search at its full length, the locate at
    its longest), with a margin: TIMEOUT_FACTOR x that + TIMEOUT_EXTRA_S seconds."""
    locate = LOCATE_SCALAR * float(settings[27])
    worst = sum(
        cycle_seconds(SEARCH_SCALAR * max(float(settings[130 + k]) for k in axes), settings, locate)
        for axes in HOMING_CYCLES
    )
    return TIMEOUT_FACTOR * worst + TIMEOUT_EXTRA_S
