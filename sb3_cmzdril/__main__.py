from sb3_cmzdril.cli import main

raise SystemExit(main())
