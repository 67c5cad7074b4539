"""``python -m nc_opcua``: the nc-opcua command (:func:`nc_opcua.cli.main`).

May import: this package.
"""
from .cli import main

raise SystemExit(main())
