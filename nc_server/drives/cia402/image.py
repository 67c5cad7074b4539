"""The cyclic process data between the NC and its CiA 402 drives, and the link that carries it.

One column per axis of the link (numpy arrays), so a cycle is a few vector operations. Positions travel as
float64 increments: a link that carries INT32 on the wire (CANopen, EtherCAT) rounds when it packs; the
in-process simulation keeps the fraction (no quantisation, as the first-order-lag SimDrive had none).
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

import numpy as np


def _z(n: int, dtype: type | str = np.float64) -> np.ndarray:
    return np.zeros(n, dtype=dtype)


@dataclass
class RxImage:
    """NC -> drives (the drives' RxPDO), one entry per axis of the link.

    Attributes:
        controlword: 0x6040 (uint16).
        mode: 0x6060 modes of operation (int8; :class:`.objects.Mode`).
        target_position: 0x607A [inc] (CSP).
        target_velocity: 0x60FF [inc/s] (CSV; in CSP the velocity feed forward the drive may use).
        probe_function: 0x60B8 touch probe function (uint16; 0: off).
        cycle: the NC cycle that sent these outputs (a remote drive counts gaps and age with it).
    """

    controlword: np.ndarray
    mode: np.ndarray
    target_position: np.ndarray
    target_velocity: np.ndarray
    probe_function: np.ndarray
    cycle: int = 0

    @classmethod
    def zeros(cls, n: int) -> RxImage:
        return cls(_z(n, np.uint16), np.full(n, 8, dtype=np.int8), _z(n), _z(n), _z(n, np.uint16))


@dataclass
class TxImage:
    """Drives -> NC (the drives' TxPDO), one entry per axis of the link.

    Attributes:
        statusword: 0x6041 (uint16).
        mode_display: 0x6061 (int8).
        position_actual: 0x6064 [inc].
        velocity_actual: 0x606C [inc/s].
        torque_actual: 0x6077 [per mille of the rated torque].
        error_code: 0x603F (uint16; 0: no error).
        probe_status: 0x60B9 (uint16).
        probe_position: 0x60BA [inc] (probe 1, the latched index pulse).
        probe2_pos: 0x60BC [inc] (probe 2, touch probe input 2: the latched rising edge; MC_TouchProbe).
        probe2_neg: 0x60BD [inc] (probe 2: the latched falling edge).
        age: NC cycles since this axis's inputs last arrived (0: fresh in this cycle; the link counts).
        alive: the node answers (CANopen heartbeat / node guarding, a remote drive's liveliness);
            False: lost communication.
        rx_cycle: per axis the NC cycle (``RxImage.cycle``) of the outputs this statusword answers: the ones the
            drive had applied when it produced these inputs (int64; 0: none yet). Each link stamps it (the device
            itself, the CANopen SYNC the TPDO answers, the remote host's echo); empty: the link cannot tell (the
            drive then assumes the worst latency, ``max_age + 1`` cycles).
    """

    statusword: np.ndarray
    mode_display: np.ndarray
    position_actual: np.ndarray
    velocity_actual: np.ndarray
    torque_actual: np.ndarray
    error_code: np.ndarray
    probe_status: np.ndarray
    probe_position: np.ndarray
    probe2_pos: np.ndarray
    probe2_neg: np.ndarray
    age: np.ndarray
    alive: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    rx_cycle: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @classmethod
    def zeros(cls, n: int) -> TxImage:
        return cls(_z(n, np.uint16), np.full(n, 8, dtype=np.int8), _z(n), _z(n), _z(n), _z(n, np.uint16),
                   _z(n, np.uint16), _z(n), _z(n), _z(n), _z(n, np.int64), np.ones(n, dtype=bool), _z(n, np.int64))


class ProcessDataLink(ABC):
    """A fieldbus (or a simulation) carrying the process data of ``n`` CiA 402 drives.

    The NC calls :meth:`exchange` once per cycle from its cycle thread; it must never block on the bus or the
    network: the outputs go out (for the drives' next cycle), the inputs returned are the newest that have
    arrived, with their ``age`` in cycles.
    """

    n: int

    @abstractmethod
    def exchange(self, rx: RxImage) -> TxImage:
        """Send this cycle's outputs, return the newest inputs (never blocks)."""

    def peek(self) -> TxImage | None:
        """The newest inputs that have arrived, sending nothing (a standby NC that takes over the drives reads their
        current state with it: :meth:`.drive.Cia402Drive.resync`). Never blocks. Default: None (the link cannot
        read without sending)."""
        return None

    def figures(self) -> list[dict[str, Any]]:
        """Per column the link's figures for the NC's stats (``drive_link``): plain values (msgpack), ``"link"``
        naming the kind. Called from another thread while :meth:`exchange` runs: only reads. Default: none (an
        in-process link), ``[]``."""
        return []

    def close(self) -> None:
        """Stop the cyclic exchange and release the bus (idempotent)."""
