"""nc-web: the browser commissioning panel of zenoh-nc (issue 22; docs/web.md).

* :mod:`nc_web.app` - :class:`~nc_web.app.WebDoor`, the Starlette app: pages, login, commands by role, live
  values and hold-to-run jogs over a WebSocket; one :class:`nc_link.door.NcDoor` per NC (the door logic it
  shares with nc-opcua), users from :mod:`nc_link.users`;
* :mod:`nc_web.cli` - the ``nc-web`` command (uvicorn);
* ``static/`` - the page's own script and style (the page loads nothing from elsewhere).

May import: ``starlette``, ``uvicorn``, ``nc_link``, ``nc_schema`` and this package.
"""
