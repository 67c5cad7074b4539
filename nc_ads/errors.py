"""ADS and AMS error codes (Beckhoff AdsLib `AdsDef.h`, reference section 4.4) and `AdsError`.

An `AdsError` raised by a device ends up as the 4-byte ADS `Result` of the reply. NC error codes (0x4xxx)
pass through the same way, as TwinCAT's NC does for rejected functions. The two router-level codes
(`AMS_TARGET_PORT_NOT_FOUND`, `AMS_TARGET_MACHINE_NOT_FOUND`) go into the AMS header's error code instead,
with no data after the header; the server does that itself, a device never raises them.
"""
from __future__ import annotations

# AMS router level (AMS header errorCode, no ADS data)
AMS_TARGET_PORT_NOT_FOUND = 0x006      # GLOBALERR_TARGET_PORT
AMS_TARGET_MACHINE_NOT_FOUND = 0x007   # GLOBALERR_MISSING_ROUTE
AMS_UNKNOWN_COMMAND = 0x008            # unknown AMS command id
AMS_INVALID_LENGTH = 0x00E             # invalid AMS length

NOERR = 0x000
ADSERR_DEVICE_ERROR = 0x700            # general device error
ADSERR_DEVICE_SRVNOTSUPP = 0x701       # service not supported by server
ADSERR_DEVICE_INVALIDGRP = 0x702       # invalid index group
ADSERR_DEVICE_INVALIDOFFSET = 0x703    # invalid index offset
ADSERR_DEVICE_INVALIDACCESS = 0x704    # reading/writing not permitted
ADSERR_DEVICE_INVALIDSIZE = 0x705      # parameter size not correct
ADSERR_DEVICE_INVALIDDATA = 0x706      # invalid parameter value(s)
ADSERR_DEVICE_NOTREADY = 0x707         # device not in ready state
ADSERR_DEVICE_BUSY = 0x708             # device busy
ADSERR_DEVICE_NOMEMORY = 0x70A         # out of memory
ADSERR_DEVICE_SYMBOLNOTFOUND = 0x710   # symbol not found
ADSERR_DEVICE_TRANSMODENOTSUPP = 0x713  # AdsTransMode not supported
ADSERR_DEVICE_NOTIFYHNDINVALID = 0x714  # notification handle invalid
ADSERR_DEVICE_NOMOREHDLS = 0x716       # no more handles
ADSERR_DEVICE_TIMEOUT = 0x719          # device timeout
ADSERR_DEVICE_ACCESSDENIED = 0x723     # access denied

MESSAGES: dict[int, str] = {
    NOERR: "no error",
    AMS_TARGET_PORT_NOT_FOUND: "target port not found",
    AMS_TARGET_MACHINE_NOT_FOUND: "target machine not found",
    AMS_UNKNOWN_COMMAND: "unknown command id",
    AMS_INVALID_LENGTH: "invalid AMS length",
    ADSERR_DEVICE_ERROR: "general device error",
    ADSERR_DEVICE_SRVNOTSUPP: "service not supported by server",
    ADSERR_DEVICE_INVALIDGRP: "invalid index group",
    ADSERR_DEVICE_INVALIDOFFSET: "invalid index offset",
    ADSERR_DEVICE_INVALIDACCESS: "reading/writing not permitted",
    ADSERR_DEVICE_INVALIDSIZE: "parameter size not correct",
    ADSERR_DEVICE_INVALIDDATA: "invalid parameter value(s)",
    ADSERR_DEVICE_NOTREADY: "device not in ready state",
    ADSERR_DEVICE_BUSY: "device busy",
    ADSERR_DEVICE_NOMEMORY: "out of memory",
    ADSERR_DEVICE_SYMBOLNOTFOUND: "symbol not found",
    ADSERR_DEVICE_TRANSMODENOTSUPP: "AdsTransMode not supported",
    ADSERR_DEVICE_NOTIFYHNDINVALID: "notification handle invalid",
    ADSERR_DEVICE_NOMOREHDLS: "no more handles",
    ADSERR_DEVICE_TIMEOUT: "device timeout",
    ADSERR_DEVICE_ACCESSDENIED: "access denied",
}


class AdsError(Exception):
    """An ADS request failed with `code` (ADS 0x7xx or an NC code 0x4xxx), `message` for logs."""

    def __init__(self, code: int, message: str | None = None) -> None:
        if not 0 < code <= 0xFFFFFFFF:
            raise ValueError(f"ADS error code must be a non-zero u32, got {code!r}")
        self.code = code
        self.message = message if message is not None else MESSAGES.get(code, "error")
        super().__init__(f"ADS error 0x{code:X}: {self.message}")
