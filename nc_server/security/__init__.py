"""Security of a zenoh-nc deployment: the roles file and the zenoh access control generated from it
(docs/roles.md).

* :mod:`.roles`: ``load_roles(path) -> Roles`` (observer / operator / engineer per client id, the
  NC servers and routers that may connect);
* :mod:`.acl`: ``access_control(roles)`` -> the zenoh ``access_control`` section (subjects by
  certificate CN), and the ``nc-acl`` command that prints it;

The TLS part of a zenoh config (the ``transport/link/tls`` section from a certificate directory made by
``deploy/certs/make-certs.sh``) is :mod:`nc_schema.tls`: the clients need it too, and no client imports
``nc_server``.
"""
from .roles import Roles, RolesError, load_roles, parse_roles

__all__ = ["Roles", "RolesError", "load_roles", "parse_roles"]
