from layercam.cli import main

raise SystemExit(main())
