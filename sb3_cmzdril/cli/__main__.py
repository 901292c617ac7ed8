"""``python -m sb3_cmzdril.cli``: the ``sb3-cmzdril`` command, as ``python -m sb3_cmzdril`` is."""
from sb3_cmzdril.cli import main

raise SystemExit(main())
