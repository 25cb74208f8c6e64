"""The receiver board's BOARD_STATUS reports, consistent with the transport effects.

Counters count what the receiver saw since it booted: radio packets
received, and per insole the radio packets it missed (radio loss). An unplug
power-cycles the receiver (it is USB powered): uptime and counters restart
at the replug. Battery and signal strength come from the session's seed:
each insole starts between 60 and 100 % and drains slowly.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from scotti.firmware_protocol.packets import BoardStatus, InsoleStatus
from scotti.sim.effects.schedule import STATUS, PacketSchedule
from scotti.sim.effects.transport import UnplugParams, unplug_spans_ns

_DRAIN_PCT_PER_HOUR: Final = 6.0
_LINK_WINDOW_NS: Final = 1_000_000_000  # link_up: the insole was heard in the last second
_U32: Final = 0xFFFFFFFF


def board_statuses(
    schedule: PacketSchedule,
    nominal_t_ns: np.ndarray,
    unplugs: list[UnplugParams],
    rng: np.random.Generator,
) -> dict[int, BoardStatus]:
    """Schedule index -> the BoardStatus sent there (nominal times; effects move bytes only)."""
    uptime0_ns = int(rng.integers(5, 3600)) * 1_000_000_000
    battery0 = rng.uniform(60.0, 100.0, 2)
    rssi = rng.integers(-72, -48, 2)

    boots = np.array(
        [schedule.t0_ns - uptime0_ns]
        + [end for _, end in unplug_spans_ns(unplugs, schedule.t0_ns)],
        dtype=np.int64,
    )
    is_frame = schedule.foot != STATUS
    received = is_frame & schedule.keep
    lost = is_frame & schedule.radio_lost & ~schedule.unplugged
    # Cumulative counts in nominal order (the arrays' order), 0 before the first packet.
    rx_cum = np.concatenate([[0], np.cumsum(received)])
    foot_rx = [np.concatenate([[0], np.cumsum(received & (schedule.foot == f))]) for f in (0, 1)]
    foot_lost = [np.concatenate([[0], np.cumsum(lost & (schedule.foot == f))]) for f in (0, 1)]

    out: dict[int, BoardStatus] = {}
    for i in np.flatnonzero(~is_frame).tolist():
        t = int(nominal_t_ns[i])
        boot = int(boots[np.searchsorted(boots, t, side="right") - 1])
        since = int(np.searchsorted(nominal_t_ns, boot, side="left"))
        heard_from = int(np.searchsorted(nominal_t_ns, max(boot, t - _LINK_WINDOW_NS)))
        hours = (t - schedule.t0_ns) / 3.6e12
        insoles = []
        for f in (0, 1):
            pct = float(np.clip(battery0[f] - _DRAIN_PCT_PER_HOUR * hours, 0.0, 100.0))
            heard = foot_rx[f][i] - foot_rx[f][heard_from] > 0
            insoles.append(
                InsoleStatus(
                    battery_mv=int(3300 + 9 * pct),
                    battery_pct=round(pct),
                    rssi_dbm=int(rssi[f]) if heard else None,
                    link_up=bool(heard),
                    packets_lost=int(foot_lost[f][i] - foot_lost[f][since]) & _U32,
                )
            )
        out[i] = BoardStatus(
            uptime_s=((t - boot) // 1_000_000_000) & _U32,
            rx_packets=int(rx_cum[i] - rx_cum[since]) & _U32,
            left=insoles[0],
            right=insoles[1],
        )
    return out
