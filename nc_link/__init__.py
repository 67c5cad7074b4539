"""nc_link: the client link, one zenoh session of one client to one NC, below every client door.

What a client of the NC needs besides its own logic lives here, once: the PLC runtime (``plc_client``),
the ADS door (``nc_ads``), the OPC UA door (``nc_opcua``) and the coming web door use it.

Public API (everything else is private to the package):

* :class:`NcLink` - the session of client ``client_id`` to NC ``nc`` at one endpoint: opened with the one
  explicit client config (:func:`client_config`: client mode, the endpoint only, scouting off, lease,
  ``connect/retry``, mutual TLS with ``tls_dir``); declares the status-frame subscriber (newest frame only),
  the NC's liveliness (``nc/<nc>/alive``) and instance tokens (``nc/<nc>/alive/*``), optionally the claims
  map (``nc/<nc>/claims``), and - for a client that may hold axes - its liveliness token
  ``nc/<nc>/client/<client_id>`` and the PLCTONC publisher. It follows the NC instance
  (:class:`nc_schema.NcInstance`): :meth:`NcLink.follow_frame` and :meth:`NcLink.take_events` report a
  restart whichever evidence (frames, instance token) comes first, once. :meth:`NcLink.request` is the
  blocking command of a door (raises :class:`CommandError` with the NC's or the transport's code); a door
  that acts for its users sends as ``<door>.<user>`` (``request(..., sender=...)``) and declares that id's
  liveliness token and PLCTONC publisher on its own session (:meth:`NcLink.declare_holder`; docs/roles.md).
* :class:`LinkEvent` - what :meth:`NcLink.take_events` returns: the NC ``GONE`` (its liveliness token
  vanished: its data is invalid, no restart), ``BACK``, ``RESTART`` (a new NC instance, ``why``).
* :class:`Supplies` - the claim/supply machine of a door: the axes the door holds, the PLCTONC record it
  supplies for each (one PLC frame per period), the connection that supplies it, a release after a few
  enables-off periods, and the rules that end a supply (a new NC instance, the NC's claims map no longer
  naming this client).
* :func:`check_tls` - the certificate files and ``tls/`` endpoints a TLS client needs (raises early).
* :func:`client_config`, :data:`DEFAULT_LEASE_MS`, :data:`CONNECT_RETRY` - the config itself
  (:mod:`nc_schema.zenoh_config`, which nc-server shares ``CONNECT_RETRY`` with).

Threads: nothing of this package runs on zenoh's threads (channels, polled by the caller); an
:class:`NcLink` may be used from a frame thread and a supply thread at once (its instance rule has a lock).

May import: ``nc_schema`` and ``zenoh``. Never ``nc_server`` (tests/test_import_graph.py), nor a client
package (``plc_client``, ``nc_ads``, ``nc_tools``): they import this.
"""
from nc_schema.zenoh_config import CONNECT_RETRY, CONNECT_TIMEOUT_MS, DEFAULT_LEASE_MS, client_config

from .link import CommandError, LinkEvent, NcLink
from .session import check_tls, open_session
from .supply import Supplies, Supply

__all__ = ["NcLink", "LinkEvent", "CommandError", "Supplies", "Supply", "check_tls", "open_session",
           "client_config", "DEFAULT_LEASE_MS", "CONNECT_RETRY", "CONNECT_TIMEOUT_MS"]
