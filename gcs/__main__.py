from gcs.commands.cli import main

raise SystemExit(main())
