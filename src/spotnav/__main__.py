"""``python -m spotnav``."""

from spotnav.cli import main

raise SystemExit(main())
