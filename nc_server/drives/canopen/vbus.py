"""python-can's virtual bus with a cheaper frame copy, for the simulated slaves and the NC's link on it.

``can.interfaces.virtual.VirtualBus.send`` deep-copies every frame for every receiver (``copy.deepcopy`` of a
``can.Message``): about half of what a frame costs there (bench/canopen_cycle.py), paid under the GIL the NC's
cycle shares with the simulated slaves. :class:`VirtualBus` hands each receiver a new ``can.Message`` made from
the fields instead; everything else (channels, queues, receive_own_messages, periodic sends) is python-can's.
A real interface (socketcan, pcan, ...) copies nothing in Python, so this changes the simulation's cost only.

It may import: can.
"""
from __future__ import annotations

import queue
import time
from typing import Any

import can
from can.interfaces.virtual import VirtualBus as _VirtualBus


class VirtualBus(_VirtualBus):
    """A python-can virtual bus instance (same channels as ``can.Bus(interface="virtual")``), cheaper to send on."""

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        data = bytes(msg.data)
        all_sent = True
        for bus_queue in self.channel:
            if bus_queue is self.queue and not self.receive_own_messages:
                continue
            copy = can.Message(timestamp=timestamp, arbitration_id=msg.arbitration_id,
                               is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame,
                               is_error_frame=msg.is_error_frame, channel=self.channel_id, dlc=msg.dlc,
                               data=data, is_fd=msg.is_fd, is_rx=bus_queue is not self.queue,
                               bitrate_switch=msg.bitrate_switch, error_state_indicator=msg.error_state_indicator,
                               check=False)
            try:
                bus_queue.put(copy, block=True, timeout=timeout)
            except queue.Full:
                all_sent = False
        if not all_sent:
            raise can.CanOperationError("Could not send message to one or more recipients")


def open_bus(interface: str, channel: str, bitrate: int, **kwargs: Any) -> can.BusABC:
    """``can.Bus(interface=..., channel=..., bitrate=...)``; the virtual interface as :class:`VirtualBus`."""
    if interface == "virtual":
        return VirtualBus(channel=channel, **kwargs)
    return can.Bus(interface=interface, channel=channel, bitrate=bitrate, **kwargs)
