"""One module per `invt-gateway` sub-command; each exposes `register(subparsers)`."""
