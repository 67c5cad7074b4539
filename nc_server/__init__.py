"""nc_server: the NC process, the owner of the axes.

Owns: the pure NC core (:mod:`.core`: state machine, motion engine, pipeline, command registry), the drive
backends (:mod:`.drives`, found through entry points), the server process around the core (:mod:`.server`:
cycle loop, zenoh transport, request handler, frame publisher, retain) and the deployment's security
(:mod:`.security`: roles, ACL) and router (:mod:`.router`).

May import: ``nc_schema`` and the third-party packages; never a client package (``plc_client``, ``nc_ads``,
``nc_tools``, ``nc_link``) or ``nc_sim`` (``tests/test_import_graph.py`` checks the direction).
"""
