"""nc-ads: an ADS (AMS/TCP) door to the zenoh NC, so pyads and other TwinCAT tools can talk to it.

Layout: `errors` (ADS codes), `ams` (pure wire codec), `device` (the AdsDevice interface a server
serves), `server` (asyncio AMS/TCP server), `nc_device` (the NC over zenoh), `cli` (nc-ads).

May import: ``nc_link`` (session, liveliness, claims, supplies), ``nc_schema``, zenoh; never ``nc_server``.
"""
