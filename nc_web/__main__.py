"""``python -m nc_web``: the nc-web command (:func:`nc_web.cli.main`).

May import: this package.
"""
from .cli import main

raise SystemExit(main())
