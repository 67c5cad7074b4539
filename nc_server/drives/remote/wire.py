"""The process data of remote CiA 402 drives on zenoh: keys and msgpack codec (schema/README.md, "Drive process data").

Keys below the NC's prefix, one drive host (an ``nc-drive-sim`` process, later a gateway to a fieldbus) each:

* ``nc/<nc>/drive/<host>/rx``     NC -> host, every NC cycle: the RxPDO columns of the host's slots;
* ``nc/<nc>/drive/<host>/tx``     host -> NC, every drive cycle: the TxPDO columns;
* ``nc/<nc>/drive/<host>/alive``  liveliness token of the host process (the NC sees it vanish);
* ``nc/<nc>/drive/<host>/status`` host, about every 100 ms: a readable msgpack map (:func:`status_map`).

A message is a msgpack map; each column is a ``bin`` of little-endian values of a fixed dtype, one per slot of
the host (slot order). Columns as bins cost the same for 4 or 64 axes (pack ~2.5 us, unpack ~6 us; msgpack
lists cost 5 / 24 us to pack and 9 / 32 us to unpack for 8 / 64 axes). Unknown keys are ignored (room for issue
21's lease), a missing column or a column of the wrong length, a float column with NaN or inf, a ``cycle``,
``rx_cycle`` or ``epoch`` that is not an integer in 0..2**63-1 make the message malformed (:class:`WireError`); a bad diagnostic field (``takeover_limit_ms``) does not.

Decisions: positions travel as float64 increments (as :class:`~nc_server.drives.cia402.image.RxImage`: no INT32
rounding on zenoh); ``rx`` carries the AxisIds of the slots so a host configured for other axes refuses the
message instead of moving the wrong motor; ``epoch`` is the sending NC's (0 without redundancy; a hot standby
numbers its takeovers: docs/standby.md): a host follows the highest epoch it has seen only, and ``tx`` reports
that epoch (``epoch``, 0 if absent) so an NC driving with a lower one learns it was replaced. ``rx`` also carries the
sending NC's ``takeover_limit_ms`` (the takeover limit its standby uses now, as its ha status publishes it;
nominally nc_server.drives.remote.config.takeover_bound; 0 or absent without redundancy): a drive host checks its
silence timeout against it. A diagnostic field like this one that is not a number >= 0 does not make the outputs
unusable: it is ignored (``RxMessage.takeover_limit_ms`` None; the host counts it).

It may import: numpy, msgpack, nc_server.drives.cia402.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import msgpack
import numpy as np

from ..cia402.image import RxImage, TxImage

#: The wire version (``v``); a message of another version is malformed. 2: tx carries touch probe 2's positions
#: (``p2p`` 0x60BC, ``p2n`` 0x60BD) for MC_TouchProbe; a version 1 peer (without them) is refused as a whole, by
#: its version, rather than column by column.
VERSION = 2

#: rx columns: key -> (RxImage attribute, dtype)
RX_COLUMNS: dict[str, tuple[str, str]] = {
    "cw": ("controlword", "<u2"), "mode": ("mode", "<i1"), "tp": ("target_position", "<f8"),
    "tv": ("target_velocity", "<f8"), "pf": ("probe_function", "<u2"),
}
#: tx columns: key -> (TxImage attribute, dtype)
TX_COLUMNS: dict[str, tuple[str, str]] = {
    "sw": ("statusword", "<u2"), "md": ("mode_display", "<i1"), "pa": ("position_actual", "<f8"),
    "va": ("velocity_actual", "<f8"), "ta": ("torque_actual", "<f8"), "ec": ("error_code", "<u2"),
    "ps": ("probe_status", "<u2"), "pp": ("probe_position", "<f8"), "p2p": ("probe2_pos", "<f8"),
    "p2n": ("probe2_neg", "<f8"),
}


class WireError(ValueError):
    """A drive message that cannot be used (not msgpack, wrong version, a column missing or of the wrong size, a
    float not finite, a counter out of range)."""


def prefix(nc: str, host: str) -> str:
    """``nc/<nc>/drive/<host>``."""
    return f"nc/{nc}/drive/{host}"


def rx_key(nc: str, host: str) -> str:
    return f"{prefix(nc, host)}/rx"


def tx_key(nc: str, host: str) -> str:
    return f"{prefix(nc, host)}/tx"


def alive_key(nc: str, host: str) -> str:
    return f"{prefix(nc, host)}/alive"


def status_key(nc: str, host: str) -> str:
    return f"{prefix(nc, host)}/status"


def host_of(key: str) -> str:
    """The ``<host>`` of a drive key ``nc/<nc>/drive/<host>/<what>`` ("" for any other key)."""
    parts = key.split("/")
    return parts[3] if len(parts) == 5 and parts[0] == "nc" and parts[2] == "drive" else ""


def check_host(host: Any, key: str = "host") -> str:
    """A drive host name: one key chunk of letters, digits, ``-`` and ``_`` (1..64 characters).

    Raises:
        ValueError: anything else (the message names ``key``).
    """
    if not isinstance(host, str) or not 1 <= len(host) <= 64 or not all(c.isascii() and (c.isalnum() or c in "-_")
                                                                          for c in host):
        raise ValueError(f"{key}: a drive host name is 1..64 characters of letters, digits, '-' and '_', got {host!r}")
    return host


_packer = msgpack.Packer()


def encode_rx(rx: RxImage, rows: np.ndarray | None, ids: np.ndarray | bytes, epoch: int = 0,
              takeover_limit_ms: float = 0.0) -> bytes:
    """One host's outputs: the columns of ``rx`` at ``rows`` (the link's rows in the host's slot order).

    Args:
        rx: the NC's outputs for every axis of the link.
        rows: link rows, slot order (int array; None: every row in order).
        ids: the AxisIds of the slots (uint32 array, or its ``<u4`` bytes; 0 = not named).
        epoch: the sending NC's epoch (docs/standby.md; 0 without redundancy).
        takeover_limit_ms: the sending NC's takeover limit [ms] (0: no redundancy; then not sent).
    """
    idb = ids if isinstance(ids, bytes) else np.asarray(ids).astype("<u4").tobytes()
    m: dict[str, Any] = {"v": VERSION, "cycle": int(rx.cycle), "epoch": int(epoch), "n": len(idb) // 4, "ids": idb}
    if takeover_limit_ms:
        m["takeover_limit_ms"] = float(takeover_limit_ms)
    for k, (attr, dt) in RX_COLUMNS.items():
        col = getattr(rx, attr)
        m[k] = (col if rows is None else col[rows]).astype(dt, copy=False).tobytes()
    return _packer.pack(m)


@dataclass
class RxMessage:
    """A decoded ``rx``: the image (one column per slot), the slots' AxisIds, the NC's epoch and takeover limit
    [ms] (0: none; None: the message's value was not a number >= 0 and is ignored)."""

    image: RxImage
    ids: np.ndarray
    epoch: int
    takeover_limit_ms: float | None = 0.0


@dataclass
class TxMessage:
    """A decoded ``tx``: the image (``age`` 0, ``alive`` True), the host's cycle, the NC cycle it last applied and the
    epoch it follows."""

    image: TxImage
    cycle: int
    rx_cycle: int
    epoch: int = 0


def _map(payload: bytes | bytearray | memoryview) -> Mapping[Any, Any]:
    try:
        m = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    except Exception as exc:  # msgpack raises several types for garbage
        raise WireError(f"not msgpack: {exc}") from None
    if not isinstance(m, dict):
        raise WireError("not a msgpack map")
    if m.get("v") != VERSION:
        raise WireError(f"wire version {m.get('v')!r}, expected {VERSION}")
    n = m.get("n")
    if isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= 4096:
        raise WireError(f"bad slot count {n!r}")
    return m


_SIZES = {dt: np.dtype(dt).itemsize for dt in ("<u2", "<i1", "<f8", "<u4")}


def _column(m: Mapping[Any, Any], key: str, dt: str, n: int) -> np.ndarray:
    """A column as a read-only view of the message's bytes (no copy); a float column must be all finite."""
    b = m.get(key)
    if not isinstance(b, bytes) or len(b) != n * _SIZES[dt]:
        raise WireError(f"column {key!r}: expected {n} values of {dt}")
    col = np.frombuffer(b, dtype=dt)
    if dt == "<f8" and not np.isfinite(col).all():  # (NaN/inf would become ActPos or a motor's target)
        raise WireError(f"column {key!r}: not finite")
    return col


_COUNTER_MAX = (1 << 63) - 1


def _counter(m: Mapping[Any, Any], key: str, default: int | None = None) -> int:
    """A cycle or epoch counter: an integer (not bool) in 0..2**63-1 (it is used in int64 arithmetic)."""
    v = m.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= _COUNTER_MAX:
        raise WireError(f"{key} must be an integer in 0..2**63-1, got {v!r}")
    return v


def decode_rx(payload: bytes | bytearray | memoryview) -> RxMessage:
    """Decode an ``rx`` message.

    Raises:
        WireError: see the module docstring.
    """
    m = _map(payload)
    n = m["n"]
    cols = {attr: _column(m, k, dt, n).copy() for k, (attr, dt) in RX_COLUMNS.items()}
    cycle, epoch = _counter(m, "cycle"), _counter(m, "epoch", 0)
    tk = m.get("takeover_limit_ms", 0.0)
    limit = None if isinstance(tk, bool) or not isinstance(tk, (int, float)) or not 0.0 <= tk < 1e12 else float(tk)
    return RxMessage(RxImage(cycle=cycle, **cols), _column(m, "ids", "<u4", n), epoch, limit)


def encode_tx(tx: TxImage, cycle: int, rx_cycle: int, epoch: int = 0) -> bytes:
    """A host's inputs for the NC: every column of ``tx`` (slot order), the host's cycle, the NC cycle it applied last,
    the highest NC epoch it has seen (it follows no other)."""
    m: dict[str, Any] = {"v": VERSION, "cycle": int(cycle), "rx_cycle": int(rx_cycle), "epoch": int(epoch),
                         "n": len(tx.statusword)}
    for k, (attr, dt) in TX_COLUMNS.items():
        m[k] = np.asarray(getattr(tx, attr)).astype(dt, copy=False).tobytes()
    return _packer.pack(m)


def decode_tx_columns(payload: bytes | bytearray | memoryview) -> tuple[dict[str, np.ndarray], int, int, int]:
    """A ``tx`` message as {TxImage attribute: read-only column}, the host's cycle, ``rx_cycle`` and ``epoch`` (the
    link's per-cycle path: no image built).

    Raises:
        WireError: see the module docstring.
    """
    m = _map(payload)
    n = m["n"]
    cols = {attr: _column(m, k, dt, n) for k, (attr, dt) in TX_COLUMNS.items()}
    cycle, rx_cycle, epoch = _counter(m, "cycle"), _counter(m, "rx_cycle", 0), _counter(m, "epoch", 0)
    return cols, cycle, rx_cycle, epoch


def decode_tx(payload: bytes | bytearray | memoryview) -> TxMessage:
    """Decode a ``tx`` message (columns copied: writable).

    Raises:
        WireError: see the module docstring.
    """
    cols, cycle, rx_cycle, epoch = decode_tx_columns(payload)
    n = len(cols["statusword"])
    image = TxImage(age=np.zeros(n, dtype=np.int64), alive=np.ones(n, dtype=bool),
                    rx_cycle=np.full(n, rx_cycle, dtype=np.int64),
                    **{a: c.astype(c.dtype.newbyteorder("=")) for a, c in cols.items()})
    return TxMessage(image, cycle, rx_cycle, epoch)
