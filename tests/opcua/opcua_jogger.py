"""A client process for the vanishing-session test: logs in, powers an axis, starts a long jog, keeps a
subscription (so its session outlives a lost connection, OPC UA Part 4 6.7, until the session timeout),
prints ``jogging`` and waits to be killed.

    python opcua_jogger.py URL USER PASSWORD AXIS_NODE
"""
from __future__ import annotations

import asyncio
import sys

from znc_testing.opcua_testing import call, client, until, value


class _Quiet:
    def datachange_notification(self, node: object, val: object, data: object) -> None:
        pass


async def main(url: str, user: str, pw: str, axis: str) -> None:
    async with client(url, user, pw) as c:
        status, out = await call(c, axis, "Reset")
        status, out = await call(c, axis, "Power", True, 100.0)
        assert status == 0, (hex(status), out)
        await until(lambda: value(c, f"{axis}.Enabled"), 20, "enabled")
        status, out = await call(c, axis, "JogStart", 1, 50.0, 30.0)
        assert status == 0, (hex(status), out)
        sub = await c.create_subscription(100, _Quiet())
        from asyncua import ua
        await sub.subscribe_data_change(c.get_node(ua.NodeId(f"{axis}.ActPos", await c.get_namespace_index(
            "urn:zenoh-nc:nc-opcua"))))
        print("jogging", flush=True)
        await asyncio.sleep(3600)


if __name__ == "__main__":
    asyncio.run(main(*sys.argv[1:5]))
