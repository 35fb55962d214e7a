"""The daemon as EPICS Channel Access PVs (``graytrack epics``): one caproto PV group, fed by the client.

The position PVs follow the daemon's position stream (throttled by the daemon to ``rate`` messages
per second); STATE, and the read-back of TARGET_MM and CALIBRATE, follow ``/api/status``. Writes to
TARGET_MM and CALIBRATE are the daemon's move and calibration routes; a refusal is raised from the
putter, so the client's write fails with the daemon's sentence (ECA_PUTFAIL).

A control system must never mistake an old number for a live one: while the daemon cannot be
reached every PV is INVALID with status COMM, and while the daemon answers but sends no positions
(not tracking) the position PVs are INVALID with status TIMEOUT. Which value and alarm each PV
shows is decided by the pure functions :func:`position_readings`, :func:`silent_readings` and
:func:`state_reading`; the group only writes them.
"""

from __future__ import annotations

import asyncio
import logging
import math
from dataclasses import dataclass
from typing import Any

from caproto import AlarmSeverity, AlarmStatus, ChannelType
from caproto.server import PVGroup, pvproperty

from graytrack.client import AsyncClient, GraytrackClientError, Position, StreamRefused, StreamSilent, Unreachable
from graytrack.wire import Status

log = logging.getLogger("graytrack.epics")

DEFAULT_RATE_HZ = 10.0
STATUS_PERIOD_S = 0.5  # STATE needs no more; at most the position rate
MIN_SILENCE_S = 1.0  # no position for this long (or 3 periods of the rate, if longer): the position PVs go INVALID
RETRY_S = 1.0  # after a refused stream (wrong token, policy): try again, INVALID meanwhile
UNREACHABLE_STATE = "unreachable"
NO_ALARM = (AlarmSeverity.NO_ALARM, AlarmStatus.NO_ALARM)

POSITION_PVS = ("X_MM", "CRLB_UM", "LOCKED", "STALE")
LOCKED_STRINGS = ("Unlocked", "Locked")
STALE_STRINGS = ("Valid", "Stale")


@dataclass(frozen=True)
class Reading:
    """What one PV shows: ``value`` None keeps the last value (only the alarm changes)."""

    value: Any
    severity: AlarmSeverity = AlarmSeverity.NO_ALARM
    status: AlarmStatus = AlarmStatus.NO_ALARM


def pv_prefix(prefix: str) -> str:
    """``LAB:GT1`` and ``LAB:GT1:`` both give ``LAB:GT1:X_MM``; refuses what CA names cannot hold."""
    prefix = prefix.strip()
    if not prefix or any(c.isspace() for c in prefix):
        raise ValueError(f"the PV prefix must be non-empty and without spaces, got {prefix!r}")
    return prefix if prefix.endswith(":") else prefix + ":"


def position_readings(p: Position) -> dict[str, Reading]:
    """One stream message as the four position PVs.

    X_MM: INVALID/UDF when the frame could not be placed, MAJOR/STATE without lock (the fit may be
    on a wrong period), MINOR/STATE when the validity monitor says the model no longer holds."""
    if p.x_mm is None or not math.isfinite(p.x_mm):
        x = Reading(None, AlarmSeverity.INVALID_ALARM, AlarmStatus.UDF)
    elif not p.locked:
        x = Reading(p.x_mm, AlarmSeverity.MAJOR_ALARM, AlarmStatus.STATE)
    elif p.stale:
        x = Reading(p.x_mm, AlarmSeverity.MINOR_ALARM, AlarmStatus.STATE)
    else:
        x = Reading(p.x_mm)
    crlb = (Reading(p.crlb_um) if p.crlb_um is not None and math.isfinite(p.crlb_um)
            else Reading(None, AlarmSeverity.INVALID_ALARM, AlarmStatus.UDF))
    locked = Reading(LOCKED_STRINGS[p.locked], *((AlarmSeverity.NO_ALARM, AlarmStatus.NO_ALARM) if p.locked
                                                 else (AlarmSeverity.MAJOR_ALARM, AlarmStatus.STATE)))
    stale = Reading(STALE_STRINGS[p.stale], *((AlarmSeverity.MINOR_ALARM, AlarmStatus.STATE) if p.stale
                                              else NO_ALARM))
    return {"X_MM": x, "CRLB_UM": crlb, "LOCKED": locked, "STALE": stale}


def silent_readings(reachable: bool) -> dict[str, Reading]:
    """No position coming: INVALID, COMM when the daemon is gone, TIMEOUT when it answers but does not track."""
    status = AlarmStatus.TIMEOUT if reachable else AlarmStatus.COMM
    return {name: Reading(None, AlarmSeverity.INVALID_ALARM, status) for name in POSITION_PVS}


def state_reading(status: Status | None) -> Reading:
    """STATE from ``/api/status`` (None: unreachable). A fault is MAJOR; starting and stopping MINOR."""
    if status is None:
        return Reading(UNREACHABLE_STATE, AlarmSeverity.INVALID_ALARM, AlarmStatus.COMM)
    severity = {"fault": AlarmSeverity.MAJOR_ALARM, "starting": AlarmSeverity.MINOR_ALARM,
                "stopping": AlarmSeverity.MINOR_ALARM}.get(status.state, AlarmSeverity.NO_ALARM)
    return Reading(status.state, severity, AlarmStatus.NO_ALARM if severity == AlarmSeverity.NO_ALARM
                   else AlarmStatus.STATE)


def silence_s(rate_hz: float) -> float:
    return max(MIN_SILENCE_S, 3.0 / rate_hz)


class TrackerPVs(PVGroup):
    """The PVs of one daemon. Each PV has its own alarm (``alarm_group``), so a lost lock on X_MM
    does not colour STATE."""

    X_MM = pvproperty(value=0.0, dtype=float, read_only=True, precision=6, units="mm", alarm_group="X_MM",
                      doc="position from the daemon's stream")
    CRLB_UM = pvproperty(value=0.0, dtype=float, read_only=True, precision=4, units="um", alarm_group="CRLB_UM",
                         doc="Cramer-Rao bound of the position (1 sigma)")
    LOCKED = pvproperty(value=LOCKED_STRINGS[0], dtype=ChannelType.ENUM, enum_strings=LOCKED_STRINGS, read_only=True,
                        alarm_group="LOCKED", doc="1 while the tracker is locked on the grating")
    STALE = pvproperty(value=STALE_STRINGS[0], dtype=ChannelType.ENUM, enum_strings=STALE_STRINGS, read_only=True,
                       alarm_group="STALE", doc="1 when the validity monitor says: recalibrate")
    STATE = pvproperty(value="unknown", dtype=ChannelType.STRING, read_only=True, alarm_group="STATE",
                       doc="the daemon's state (starting, idle, calibrating, tracking, fault, stopping)")
    CALIBRATE = pvproperty(value=0, dtype=int, alarm_group="CALIBRATE",
                           doc="write 1 to start a calibration; reads 1 while one runs")
    TARGET_MM = pvproperty(value=0.0, dtype=float, precision=6, units="mm", alarm_group="TARGET_MM",
                           doc="write to move the stage; reads the daemon's last target")

    def __init__(self, *args: Any, client: AsyncClient, rate_hz: float = DEFAULT_RATE_HZ, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"the rate must be a positive number of updates/s, got {rate_hz}")
        self.client = client
        self.rate_hz = rate_hz
        self.reachable = False

    # -- writing what the daemon says ---------------------------------------------------------
    async def show(self, name: str, reading: Reading, timestamp: float | None = None) -> None:
        """Write ``reading`` to PV ``name`` (bypassing putters: this is the daemon talking, not a client)."""
        pv = getattr(self, name)
        if reading.value is None:
            if (pv.alarm.severity, pv.alarm.status) != (reading.severity, reading.status):
                await pv.alarm.write(severity=reading.severity, status=reading.status)
            return
        extra = {"timestamp": timestamp} if timestamp is not None else {}
        await pv.write(reading.value, verify_value=False, severity=reading.severity, status=reading.status, **extra)

    async def show_all(self, readings: dict[str, Reading], timestamp: float | None = None) -> None:
        for name, reading in readings.items():
            await self.show(name, reading, timestamp)

    async def show_unreachable(self) -> None:
        self.reachable = False
        await self.show_all(silent_readings(reachable=False))
        await self.show("STATE", state_reading(None))
        for name in ("CALIBRATE", "TARGET_MM"):
            await self.show(name, Reading(None, AlarmSeverity.INVALID_ALARM, AlarmStatus.COMM))

    async def show_status(self, status: Status) -> None:
        was_reachable, self.reachable = self.reachable, True
        await self.show("STATE", state_reading(status))
        if not was_reachable:  # the write PVs' alarm is otherwise their last write's
            for name in ("CALIBRATE", "TARGET_MM"):
                await self.show(name, Reading(None))
        calibrating = int(status.state == "calibrating")
        if self.CALIBRATE.value != calibrating:
            await self.CALIBRATE.write(calibrating, verify_value=False)
        if status.target_mm is not None and self.TARGET_MM.value != status.target_mm:
            await self.TARGET_MM.write(status.target_mm, verify_value=False)

    # -- the loops ----------------------------------------------------------------------------
    async def follow_status(self) -> None:
        period = max(1.0 / self.rate_hz, STATUS_PERIOD_S)
        while True:
            try:
                await self.show_status(await self.client.status())
            except Unreachable as exc:
                if self.reachable:
                    log.warning("daemon unreachable: %s", exc)
                await self.show_unreachable()
            except GraytrackClientError as exc:  # answered, but not a status this bridge can read
                log.warning("status: %s", exc)
                await self.show_unreachable()
            await asyncio.sleep(period)

    async def follow_positions(self) -> None:
        while True:
            try:
                async with self.client.stream(max_rate=self.rate_hz, silence_s=silence_s(self.rate_hz)) as stream:
                    async for p in stream:
                        await self.show_all(position_readings(p), p.t_unix)
            except StreamSilent:
                await self.show_all(silent_readings(await self.answers()))
            except (StreamRefused, GraytrackClientError) as exc:
                log.error("position stream: %s", exc)
                await self.show_all(silent_readings(await self.answers()))
                await asyncio.sleep(RETRY_S)

    async def answers(self) -> bool:
        """Whether the daemon answers at all (tells COMM from TIMEOUT for a silent stream)."""
        try:
            await self.client.status()
        except GraytrackClientError:
            return False
        return True

    @X_MM.startup  # type: ignore[misc]
    async def X_MM(self, instance: Any, async_lib: Any) -> None:
        """Until the first answer every PV is INVALID/UDF, then the two loops run for the server's life."""
        for name in (*POSITION_PVS, "STATE", "CALIBRATE", "TARGET_MM"):
            await self.show(name, Reading(None, AlarmSeverity.INVALID_ALARM, AlarmStatus.UDF))
        await asyncio.gather(self.follow_status(), self.follow_positions())

    # -- writes from Channel Access -----------------------------------------------------------
    @CALIBRATE.putter  # type: ignore[misc]
    async def CALIBRATE(self, instance: Any, value: int) -> int:
        if value not in (0, 1):
            raise ValueError(f"write 1 to start a calibration, not {value}")
        if value == 1:
            started = await self.client.calibrate(wait=False)
            log.info("calibration %s started", getattr(started, "id", "?"))
        await instance.alarm.write(severity=AlarmSeverity.NO_ALARM, status=AlarmStatus.NO_ALARM)
        return value

    @TARGET_MM.putter  # type: ignore[misc]
    async def TARGET_MM(self, instance: Any, value: float) -> float:
        await self.client.move(value, wait=False)
        await instance.alarm.write(severity=AlarmSeverity.NO_ALARM, status=AlarmStatus.NO_ALARM)
        return value
