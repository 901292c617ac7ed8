"""``python -m cmzdril_lab``: the lab's command line (``cmzdril-lab``)."""
from cmzdril_lab.cli import main

raise SystemExit(main())
