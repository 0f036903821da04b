from benchmarks.inspection.run import main

raise SystemExit(main())
