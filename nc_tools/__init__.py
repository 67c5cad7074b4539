"""Inspection tools for zenoh-nc: ``nc-status`` (a live table of every NC on a router) and
``nc-scope`` (records NCTOPLC fields at the NC cycle rate: CSV, PNG, interactive HTML).

May import: ``nc_schema``, zenoh, numpy, matplotlib; never ``nc_server``."""
