"""USD time: which time code a request reads a stage at, and the range `inspect` lists.

A `--time` in seconds counts from the stage's startTimeCode through its timeCodesPerSecond
(USD's fallback 24), so one number means the same moment for glTF and USD; `poster` is the
middle of the authored range (core.animation.poster_time's rule). Without a moment the stage is
read at its start time code (authored range) or its earliest samples, as before.
"""
from __future__ import annotations

from pxr import Usd

from core.animation import POSTER, Moment


def time_range(stage: Usd.Stage) -> dict | None:
    """start / end time codes, timeCodesPerSecond and the duration in seconds, when authored."""
    if not stage.HasAuthoredTimeCodeRange():
        return None
    start, end, tcps = stage.GetStartTimeCode(), stage.GetEndTimeCode(), stage.GetTimeCodesPerSecond()
    return {"start": start, "end": end, "time_codes_per_second": tcps,
            "duration": (end - start) / tcps if tcps > 0 else 0.0}


def time_code(stage: Usd.Stage, moment: Moment | None) -> Usd.TimeCode:
    """The time code to read the stage at for `moment` (None: its start)."""
    authored = stage.HasAuthoredTimeCodeRange()
    if moment is None:
        return Usd.TimeCode(stage.GetStartTimeCode()) if authored else Usd.TimeCode.EarliestTime()
    start = stage.GetStartTimeCode() if authored else 0.0
    if moment.time == POSTER:
        end = stage.GetEndTimeCode() if authored else start
        return Usd.TimeCode(start + 0.5 * (end - start))
    tcps = stage.GetTimeCodesPerSecond()
    return Usd.TimeCode(start + float(moment.time) * (tcps if tcps > 0 else 24.0))
