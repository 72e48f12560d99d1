#!/bin/sh
# Keepalived's notify script for a redundant pair of invt-gateway boxes (issue 48; docs:
# "Redundancy"). Keepalived calls it on every VRRP state change of the instance with
#   $1 INSTANCE or GROUP   $2 its name   $3 MASTER, BACKUP, FAULT or STOP   $4 its priority
# and it asks the gateway on this box for the matching role on the control socket:
#   MASTER                 invt-gateway role active   (the gateway listens to the line first,
#                                                      and takes it once it is silent)
#   BACKUP, FAULT, STOP    invt-gateway role standby  (it leaves the line at once)
# The gateway, not this script, makes sure there is never a second master on the line: a box
# told `active` while the other still polls (the link between them cut) stays off the line.
#
# `invt-gateway-notify.sh check` is Keepalived's track script: exit 0 while the gateway answers
# on its control socket (`invt-gateway role status`) and can reach its line (a port open within
# the last second: `role status` exits 1 once its adapter has been gone that long), so a dead or
# stuck gateway, or one whose adapter was unplugged, puts its box in FAULT and the virtual
# address moves. It starts in a tenth of a second. (An unplugged adapter is told sooner through
# the gateway's fault file, Keepalived's track_file: this check is the way a dead gateway,
# which writes nothing more, is found.)
#
# Install: /usr/local/sbin/invt-gateway-notify.sh, root's, mode 0755 (keepalived runs notify
# scripts as root with `enable_script_security` only when no other user can write them).
#
# Under systemd the gateway has a /tmp of its own (PrivateTmp=), where its control socket is:
# the script asks from inside the service's mount namespace (nsenter), as the service's user.
# A gateway run by hand (`invt-gateway run`) is asked directly.
set -u

CONFIG=${CONFIG:-/etc/invt-gateway/config.yaml}
GATEWAY=${GATEWAY:-/opt/invt-gateway/bin/invt-gateway}
UNIT=${UNIT:-invt-gateway.service}
SERVICE_USER=${SERVICE_USER:-invt-gateway}

say() {
    logger -t invt-gateway-notify "$*" 2>/dev/null || echo "invt-gateway-notify: $*" >&2
}

# `invt-gateway role ROLE` asked of this box's gateway: under systemd from inside the service's
# mount namespace (its PrivateTmp=, where the control socket is), as its user; else directly.
ask() {
    pid=0
    if command -v systemctl >/dev/null 2>&1; then
        pid=$(systemctl show --property MainPID --value "$UNIT" 2>/dev/null || echo 0)
    fi
    if [ -n "$pid" ] && [ "$pid" != 0 ]; then
        nsenter --target "$pid" --mount -- \
            setpriv --reuid="$SERVICE_USER" --regid="$SERVICE_USER" --init-groups \
            "$GATEWAY" role "$1" --config "$CONFIG"
    else
        "$GATEWAY" role "$1" --config "$CONFIG"
    fi
}

if [ "${1:-}" = check ]; then
    ask status >/dev/null
    exit $?
fi

state=${3:-}
case "$state" in
    MASTER) role=active ;;
    BACKUP | FAULT | STOP) role=standby ;;
    *)
        say "unknown state '$state' ($*): nothing asked"
        exit 0
        ;;
esac

answer=$(ask "$role" 2>&1)
code=$?
say "VRRP $state: role $role: $answer (exit $code)"
# Keepalived ignores a notify script's exit code; the log says what came of it. A gateway not
# running yet starts in the role its configuration says (`redundancy.role`), standby by default.
exit "$code"
