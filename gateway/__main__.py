"""`python -m gateway` is the same as the `invt-gateway` command."""

from gateway.cli import main

raise SystemExit(main())
