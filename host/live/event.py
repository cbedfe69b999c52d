"""`skel event NAME`: the host as a source of a named event (a system file's `events:` entry
of kind host), for the processes that await it (`sync: event`).

Each event is one event_t on its channel (EVENT_CHANNEL_PREFIX + NAME) of the control URL,
with run_id 0: whichever run is going takes it; between runs the DPUs ignore it. A copy goes
to the record URL, for the log.
"""

from __future__ import annotations

import time

import lcm

import skelmsg
from skelmsg import contract

from ..sysfile.link import record_url


def send(url: str, name: str, count: int = 1, rate_hz: float = 10.0) -> int:
    """Publish COUNT events NAME at RATE_HZ, on an absolute grid (a slow publish does not
    stretch the rest); returns how many were sent."""
    channel = contract.EVENT_CHANNEL_PREFIX + name
    bus = lcm.LCM(url)
    log = bus if record_url(url) == url else lcm.LCM(record_url(url))  # the same, without ports
    msg = skelmsg.event_t()
    msg.run_id, msg.dpu, msg.process, msg.name = 0, 0, 0, name
    t0 = time.monotonic()
    for seq in range(count):
        delay = t0 + seq / rate_hz - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        msg.seq, msg.sent_ns = seq, time.monotonic_ns()
        data = msg.encode()
        bus.publish(channel, data)
        if log is not bus:
            log.publish(channel, data)
    return count
