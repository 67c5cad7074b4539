"""CiA 402 drives outside the NC process, reached over zenoh (issue 20).

* :mod:`.wire`    the keys ``nc/<nc>/drive/<host>/{rx,tx,alive,status}`` and their msgpack codec;
* :mod:`.link`    :class:`~.link.RemoteLink`, the NC's :class:`~nc_server.drives.cia402.image.ProcessDataLink`
  over zenoh (never blocks the cycle);
* :mod:`.config`  ``[drives.remote]`` options and the per-axis ``Drive = { backend = "remote", host = ... }``;
* :mod:`.drive`   :class:`~.drive.RemoteDrive`, the ``remote`` backend (``Cia402Drive`` over the link);
* :mod:`.host`    ``nc-drive-sim``: a process hosting simulated CiA 402 drives for an NC.

It may import: numpy, msgpack, zenoh, nc_schema, nc_server.core.params, nc_server.drives.
"""
