"""The NC server process around the pure core: the fixed-rate cycle loop (:mod:`.cycle`), the zenoh layer
(:mod:`.transport`, :mod:`.publisher`, :mod:`.frame_ring`), the one request handler every door uses
(:mod:`.handler`: claims, server-layer commands of the command registry, then the core), retain and the
application that wires them (:mod:`.app`, :mod:`.cli`).

May import: ``nc_server.core``, ``nc_server.drives``, ``nc_server.security``, ``nc_schema``, zenoh; never a
client package.
"""
