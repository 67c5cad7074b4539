"""nc_opcua: the OPC UA door of zenoh-nc (``nc-opcua``), a client of the NCs built on the client link.

An asyncua server exposing every NC reachable on a zenoh router and its axes (OPC 40502 ``CncAxisType``
names where they fit, every NCTOPLC field, the MC_AxisPara parameters with their units), live values through
OPC UA subscriptions, the operator functions as methods allowed by the user's role from a users file, with OPC
UA user authentication and Basic256Sha256 security. Modules:

* :mod:`nc_opcua.server` - :class:`~nc_opcua.server.OpcuaDoor` (address space, values, methods, sessions);
* :class:`nc_link.door.NcDoor` - the door's link to one NC (shared with nc-web);
* :mod:`nc_link.users` - the users file (scrypt password hashes; shared with nc-web);
* :mod:`nc_opcua.certs` - application instance certificates with the ApplicationUri;
* :mod:`nc_opcua.cli` - the command line.

May import: ``nc_link``, ``nc_schema``, ``asyncua``, ``cryptography``. Never ``nc_server``
(tests/test_import_graph.py), nor another client package.
"""
