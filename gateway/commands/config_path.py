"""Where the service's configuration file is unless `--config` says otherwise: one place, that a
command can import without the service behind it (`role`, which Keepalived's notify script runs
on every VRRP change, starts in a tenth of the time `run`'s imports take)."""

DEFAULT_CONFIG = "/etc/invt-gateway/config.yaml"
