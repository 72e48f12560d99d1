# invt-gateway: Modbus-TCP/MQTT gateway for INVT drives on RS-485.
#
#   docker build -t invt-gateway .
#   install -d -o 10001 -g 10001 -m 0750 /srv/invt-gateway     (config.yaml in it, 10001's too)
#   docker run -d --name invt-gateway --restart unless-stopped \
#     --device /dev/serial/by-id/usb-FTDI_...-if00-port0:/dev/ttyRS485-1 \
#     -v /srv/invt-gateway:/etc/invt-gateway -v invt-gateway-state:/var/lib/invt-gateway \
#     -p 5020:5020 -p 9102:9102 invt-gateway
# The configuration's directory is mounted writable and the container user's, not `:ro`: the
# console's editor writes a new config.yaml beside the old and renames it over (a file mounted
# on its own can't be renamed over). docs/pages/operations.md has the whole run.
#   docker kill -s HUP invt-gateway     (reloads the configuration without a restart)
#
# Behind a plant's inspecting proxy, pip needs the plant's own index and its CA certificate:
#   docker build --build-arg PIP_INDEX=https://pypi.plant.example/simple \
#     --secret id=pip_ca,src=/usr/local/share/ca-certificates/plant-ca.crt -t invt-gateway .
# The certificate is used by pip during the build only, never copied into the image. Labels:
#   --build-arg CREATED="$(date -u +%FT%TZ)" --build-arg SOURCE=<where your copy of the source is>
# podman and buildah keep the HEALTHCHECK only with `--format docker` (OCI images have none).
#
# The build stage installs the package from this source tree into a virtualenv; the runtime
# stage copies only that virtualenv, so no compiler, pip cache or source ends up in the image.
# The wheel, built once, compiles the engine room (the modules a transaction crosses) with mypyc,
# with the stage's gcc and the image's Python headers, on amd64 and arm64 (on arm/v7 mypy has no
# wheel: the engine room runs as Python there); the extras are installed from that wheel.

FROM python:3.11-slim-bookworm AS build
ENV PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_CACHE_DIR=1
# Debian's gcc of the base image's release, whichever its point release is today.
# hadolint ignore=DL3008
RUN apt-get update \
    && apt-get install -y --no-install-recommends gcc libc6-dev \
    && rm -rf /var/lib/apt/lists/*
# Empty: pip's own default index. Not PIP_INDEX_URL itself: pip would read an empty one.
ARG PIP_INDEX=
WORKDIR /src
COPY pyproject.toml README.md ./
COPY gateway ./gateway
# The service and the field tools only: the instruments (simulator, bench, stress, the demo's
# broker) stay out of the image; the CLI lists no command it doesn't have.
# uvloop (the event loop in C) comes as a wheel for amd64 and arm64; on arm/v7 pip would need a
# compiler for it, so there the gateway runs on asyncio's own loop (its log's first line says so).
# The OPC UA server (`opcua:`, off unless configured) is pure Python, but asyncua needs
# cryptography, whose wheels may be missing on arm/v7: there the image has no OPC UA server, and
# a configuration that turns it on is refused at start naming the missing package.
RUN --mount=type=secret,id=pip_ca,required=false \
    if [ -s /run/secrets/pip_ca ]; then export PIP_CERT=/run/secrets/pip_ca; fi \
    && if [ -n "$PIP_INDEX" ]; then export PIP_INDEX_URL="$PIP_INDEX"; fi \
    && rm -rf /src/gateway/instruments \
    && python -m venv /opt/invt-gateway \
    && /opt/invt-gateway/bin/pip wheel --no-cache-dir --no-deps --wheel-dir /tmp/wheels /src \
    && wheel=$(echo /tmp/wheels/invt_gateway-*.whl) \
    && /opt/invt-gateway/bin/pip install --no-cache-dir "$wheel" \
    && { /opt/invt-gateway/bin/pip install --no-cache-dir --only-binary uvloop "${wheel}[uvloop]" \
         || echo "no uvloop wheel for $(uname -m): asyncio's own event loop"; } \
    && { /opt/invt-gateway/bin/pip install --no-cache-dir --only-binary cryptography,cffi "${wheel}[opcua]" \
         || echo "no wheels of the OPC UA server's packages for $(uname -m): opcua: off"; }

FROM python:3.11-slim-bookworm
# The release (gateway.__version__: a test keeps the two equal), when and from what it was built.
ARG VERSION=0.2.0
ARG CREATED=unknown
ARG SOURCE=unknown
LABEL org.opencontainers.image.title="invt-gateway" \
      org.opencontainers.image.description="Modbus-TCP and MQTT gateway for INVT drives on RS-485" \
      org.opencontainers.image.version="$VERSION" \
      org.opencontainers.image.created="$CREATED" \
      org.opencontainers.image.source="$SOURCE" \
      org.opencontainers.image.licenses="LicenseRef-Proprietary"
# A system user without a home or shell; dialout lets it open serial devices passed in with
# --device (they keep the host's group, which is dialout, GID 20, on Debian and Ubuntu hosts).
RUN groupadd --system --gid 10001 invt-gateway \
    && useradd --system --uid 10001 --gid 10001 --groups dialout --no-create-home \
        --home-dir /nonexistent --shell /usr/sbin/nologin invt-gateway \
    && install -d -o 10001 -g 10001 -m 0750 /etc/invt-gateway \
    && install -d -o 10001 -g 10001 -m 0700 /var/lib/invt-gateway
COPY --from=build /opt/invt-gateway /opt/invt-gateway
# The user's, as a named volume over /etc/invt-gateway copies it: editable from the console.
COPY --chown=10001:10001 config/config.example.yaml /etc/invt-gateway/config.yaml
ENV PATH=/opt/invt-gateway/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1
# By number, so an orchestrator can tell it isn't root; no group given, so the user's
# supplementary groups (dialout) still apply.
USER 10001
# Modbus-TCP (modbus_tcp.port), metrics/health (metrics.port), the console (console.port: off by
# default, and on loopback unless console.host says 0.0.0.0) and OPC UA (opcua.port: off by
# default).
EXPOSE 5020 9102 8080 4840
# The configuration, and the store (events waiting for the broker, fault history: storage.path
# defaults to /var/lib/invt-gateway/events-<gateway_id>.db): a named volume keeps it across new
# images. The OPC UA server's certificate is kept there too.
VOLUME ["/etc/invt-gateway", "/var/lib/invt-gateway"]
HEALTHCHECK --interval=30s --timeout=5s --start-period=15s --retries=3 \
    CMD ["invt-gateway", "healthcheck", "--config", "/etc/invt-gateway/config.yaml"]
# Exec form: the gateway is PID 1 and gets SIGTERM itself (no shell in between to swallow it);
# it shuts down within 2 s, well inside Docker's 10 s before SIGKILL.
STOPSIGNAL SIGTERM
ENTRYPOINT ["invt-gateway"]
CMD ["run", "--config", "/etc/invt-gateway/config.yaml"]
