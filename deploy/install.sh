#!/usr/bin/env bash
# Install (or uninstall) the antisurge daemon on the skid's industrial PC (Debian 12).
#
#   sudo deploy/install.sh                 install or upgrade (safe to run again)
#   sudo deploy/install.sh --dry-run       show what would be done, change nothing
#   sudo deploy/install.sh --uninstall     remove binary and units, keep config and logs
#   deploy/install.sh --root /tmp/stage    stage the files into a directory (no root
#                                          needed; no user, no chown, no systemctl)
#
# Run from anywhere inside the repository checkout. See deploy/README.md.
set -euo pipefail

usage() {
    cat <<'EOF'
Usage: install.sh [options]

Options:
  --prefix DIR       where the binary and doc go (default /usr/local:
                     DIR/bin/antisurge, DIR/share/doc/antisurge/)
  --root DIR         stage everything under DIR instead of / (DESTDIR style).
                     Skips creating the user, chown and systemctl; needs no root.
  --bin FILE         binary to install (default: $ANTISURGE_BIN, else
                     target/release/antisurge, built with `cargo build --release`
                     if missing and cargo is available)
  --config-src DIR   configuration to install (default: the repository's config/)
  --dry-run          print what would be done; change nothing
  --uninstall        stop and disable the service, remove binary, unit, .network
                     file and doc; keep /etc/antisurge, /var/lib/antisurge,
                     /var/log/antisurge and the antisurge user
  -h, --help         this text
EOF
}

die() { printf 'install.sh: error: %s\n' "$*" >&2; exit 1; }
say() { printf '%s\n' "$*"; }
note() { printf 'install.sh: %s\n' "$*"; }

REPO=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
PREFIX=/usr/local
ROOT=""
DRY_RUN=0
UNINSTALL=0
BIN="${ANTISURGE_BIN:-}"
CONFIG_SRC="$REPO/config"

need_arg() { [[ $# -ge 2 && -n $2 ]] || die "$1 needs a value"; }
while [[ $# -gt 0 ]]; do
    case $1 in
        --prefix) need_arg "$@"; PREFIX=$2; shift 2 ;;
        --prefix=*) PREFIX=${1#*=}; shift ;;
        --root) need_arg "$@"; ROOT=$2; shift 2 ;;
        --root=*) ROOT=${1#*=}; shift ;;
        --bin) need_arg "$@"; BIN=$2; shift 2 ;;
        --bin=*) BIN=${1#*=}; shift ;;
        --config-src) need_arg "$@"; CONFIG_SRC=$2; shift 2 ;;
        --config-src=*) CONFIG_SRC=${1#*=}; shift ;;
        --dry-run) DRY_RUN=1; shift ;;
        --uninstall) UNINSTALL=1; shift ;;
        -h | --help) usage; exit 0 ;;
        *) usage >&2; die "unknown option: $1" ;;
    esac
done

[[ $PREFIX == /* ]] || die "--prefix must be an absolute path: $PREFIX"
PREFIX=${PREFIX%/}
[[ -n $PREFIX ]] || die "--prefix / is not supported (use /usr or /usr/local)"

STAGING=0
if [[ -n $ROOT && $ROOT != / ]]; then
    STAGING=1
    [[ $ROOT == /* ]] || ROOT="$PWD/$ROOT"
    ROOT=${ROOT%/}
else
    ROOT=""
fi

if [[ $STAGING == 0 && $(id -u) != 0 ]]; then
    if [[ $DRY_RUN == 1 ]]; then
        note "not root: dry run only (a real install needs root: sudo $0)"
    else
        die "must be run as root (sudo $0 ...), or with --root DIR to stage into a directory"
    fi
fi

# Installed locations (paths on the target system; $ROOT is prepended when writing).
BIN_PATH="$PREFIX/bin/antisurge"
DOC_PATH="$PREFIX/share/doc/antisurge/README.md"
UNIT_PATH=/etc/systemd/system/antisurge.service
NET_PATH=/etc/systemd/network/80-can0.network
CONF_DIR=/etc/antisurge
STATE_DIR=/var/lib/antisurge
LOG_DIR=/var/log/antisurge
SVC_USER=antisurge
SVC_GROUP=antisurge

TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT

CHANGED=0    # files written (new or different content)
UNCHANGED=0  # files already up to date
BINARY_OR_UNIT_CHANGED=0
NETWORK_CHANGED=0

# Run a command unless this is a dry run.
live() { [[ $DRY_RUN == 1 ]] || "$@"; }

# One line per change: "installed X", or "would install X" in a dry run.
report() { # past-tense present-tense what
    if [[ $DRY_RUN == 1 ]]; then
        printf '  %-16s %s\n' "would $2" "$3"
    else
        printf '  %-16s %s\n' "$1" "$3"
    fi
}

# chown, except when staging (the antisurge user does not exist in a staged tree).
own() { # owner:group path...
    [[ $STAGING == 1 ]] || chown "$@"
}

# Directory with a mode and owner, created if missing; mode and owner enforced.
ensure_dir() { # path mode owner:group
    local d="$ROOT$1"
    [[ -d $d ]] || report created create "$1/"
    [[ $DRY_RUN == 1 ]] && return 0
    mkdir -p "$d"
    chmod "$2" "$d"
    own "$3" "$d"
}

# Copy a file unless the destination already has the same content; mode and owner
# enforced. The copy is written next to the destination with its final mode and owner,
# then renamed over it: a running binary is never written into, and the daemon's
# config watcher never sees a half-written or unreadable file.
put_file() { # src dest-path mode owner:group
    local src=$1 dst="$ROOT$2" mode=$3 og=$4
    if [[ -f $dst ]] && cmp -s "$src" "$dst"; then
        UNCHANGED=$((UNCHANGED + 1))
    else
        if [[ -e $dst ]]; then
            report updated update "$2"
        else
            report installed install "$2"
        fi
        if [[ $DRY_RUN == 0 ]]; then
            mkdir -p "$(dirname "$dst")"
            install -m "$mode" "$src" "$dst.new.$$"
            own "$og" "$dst.new.$$"
            mv -f "$dst.new.$$" "$dst"
        fi
        CHANGED=$((CHANGED + 1))
    fi
    if [[ $DRY_RUN == 0 ]]; then
        chmod "$mode" "$dst"
        own "$og" "$dst"
    fi
}

# Shipped configuration (DBC, signal map, plants, machines, maps, scenarios): replaced by the
# new version; a differing old one is kept as FILE.old.
put_shipped_config() { # src dest-path
    local dst="$ROOT$2"
    if [[ -f $dst ]] && ! cmp -s "$1" "$dst"; then
        live cp -p "$dst" "$dst.old"
        report saved save "$2.old (your previous version)"
    fi
    put_file "$1" "$2" 0640 "root:$SVC_GROUP"
}

# Operator-owned configuration: never overwritten. A different new version goes next
# to it as FILE.dist.
put_operator_config() { # src dest-path
    local dst="$ROOT$2"
    if [[ -f $dst ]] && ! cmp -s "$1" "$dst"; then
        put_file "$1" "$2.dist" 0640 "root:$SVC_GROUP"
        report kept keep "$2 (yours, not overwritten); new default: $2.dist"
        if [[ $DRY_RUN == 0 ]]; then
            chmod 0640 "$dst"
            own "root:$SVC_GROUP" "$dst"
        fi
    else
        put_file "$1" "$2" 0640 "root:$SVC_GROUP"
    fi
}

# A directory tree of configuration; developer tools (*.py) are not installed.
put_config_tree() { # src-dir dest-dir policy(shipped|operator)
    local src=$1 dst=$2 policy=$3 rel
    ensure_dir "$dst" 0750 "root:$SVC_GROUP"
    [[ -d $src ]] || return 0
    while IFS= read -r -d '' rel; do
        rel=${rel#./}
        if [[ -d $src/$rel ]]; then
            ensure_dir "$dst/$rel" 0750 "root:$SVC_GROUP"
        else
            "put_${policy}_config" "$src/$rel" "$dst/$rel"
        fi
    done < <(cd "$src" && find . -mindepth 1 \
        \( -name __pycache__ -o -name '*.py' -o -name '*.pyc' -o -name '.*' \) -prune \
        -o -print0 | sort -z)
}

systemd_running() { [[ $STAGING == 0 && -d /run/systemd/system ]]; }

# ------------------------------------------------------------------------- uninstall
if [[ $UNINSTALL == 1 ]]; then
    note "uninstalling antisurge${ROOT:+ from staged tree $ROOT}"
    if systemd_running; then
        if systemctl is-active --quiet antisurge.service; then
            note "stopping antisurge: it commands the safe state (recycle valve open) on exit"
        fi
        if systemctl cat antisurge.service >/dev/null 2>&1; then
            live systemctl disable --now antisurge.service
            report "stopped, disabled" "stop and disable" antisurge.service
        fi
    elif [[ $STAGING == 1 ]]; then
        note "staging (--root): systemctl skipped"
    fi
    for f in "$BIN_PATH" "$UNIT_PATH" "$NET_PATH" "$DOC_PATH"; do
        if [[ -e $ROOT$f ]]; then
            live rm -f "$ROOT$f"
            report removed remove "$f"
        fi
    done
    if [[ -d $ROOT${DOC_PATH%/*} ]]; then
        live rmdir --ignore-fail-on-non-empty "$ROOT${DOC_PATH%/*}"
    fi
    if systemd_running; then
        live systemctl daemon-reload
        report ran run "systemctl daemon-reload"
    fi
    say ""
    say "Kept (delete by hand if you really want them gone):"
    say "  $CONF_DIR/            configuration"
    say "  $STATE_DIR/        state"
    say "  $LOG_DIR/        event log"
    say "  user and group $SVC_USER"
    [[ -d $ROOT/etc/systemd/system/antisurge.service.d ]] &&
        say "  /etc/systemd/system/antisurge.service.d/  your drop-ins"
    say "Purge: rm -rf $CONF_DIR $STATE_DIR $LOG_DIR && userdel $SVC_USER"
    exit 0
fi

# --------------------------------------------------------------------------- install
note "installing antisurge${ROOT:+ into staged tree $ROOT} (prefix $PREFIX)"
[[ $DRY_RUN == 1 ]] && note "dry run: nothing is changed"

# 1. The binary.
BUILD_PENDING=0  # dry run: the build would have made it
if [[ -z $BIN ]]; then
    BIN="$REPO/target/release/antisurge"
    if [[ ! -x $BIN ]]; then
        if command -v cargo >/dev/null 2>&1; then
            note "no $BIN yet: building it (cargo build --release)"
            [[ -n ${SUDO_USER:-} ]] &&
                note "(running under sudo: target/ may end up owned by root; building as your own user first avoids that)"
            if [[ $DRY_RUN == 1 ]]; then
                report built build "$BIN (cargo build --release)"
                BUILD_PENDING=1
            else
                (cd "$REPO" && cargo build --release)
            fi
        else
            die "no binary at $BIN and no cargo to build it: build it elsewhere and pass --bin FILE"
        fi
    fi
fi
if [[ $BUILD_PENDING == 0 ]]; then
    [[ -f $BIN && -x $BIN ]] || die "not an executable file: $BIN"
fi

# 2. User and group (system account: no login shell, no home directory).
if [[ $STAGING == 1 ]]; then
    note "staging (--root): not creating user/group $SVC_USER, not changing owners (chown)"
else
    if ! getent group "$SVC_GROUP" >/dev/null; then
        live groupadd --system "$SVC_GROUP"
        report created create "system group $SVC_GROUP"
    fi
    if ! getent passwd "$SVC_USER" >/dev/null; then
        live useradd --system --gid "$SVC_GROUP" --no-create-home --home-dir /nonexistent \
            --shell /usr/sbin/nologin --comment "antisurge controller daemon" "$SVC_USER"
        report created create "system user $SVC_USER (no login shell, no home)"
    fi
    getent group dialout >/dev/null ||
        note "warning: no group dialout on this machine: Modbus RTU serial ports will not be accessible"
fi

# 3. Binary and documentation.
if [[ $BUILD_PENDING == 0 ]]; then
    before=$CHANGED
    put_file "$BIN" "$BIN_PATH" 0755 root:root
    [[ $CHANGED -gt $before ]] && BINARY_OR_UNIT_CHANGED=1
else
    report installed install "$BIN_PATH (from $BIN, after the build)"
    BINARY_OR_UNIT_CHANGED=1
fi
put_file "$REPO/deploy/README.md" "$DOC_PATH" 0644 root:root

# 4. systemd unit (paths adjusted if --prefix is not /usr/local) and networkd file.
sed -e "s#/usr/local/bin/antisurge#$BIN_PATH#g" \
    -e "s#/usr/local/share/doc/antisurge/#${DOC_PATH%README.md}#g" \
    "$REPO/deploy/antisurge.service" >"$TMP/antisurge.service"
before=$CHANGED
put_file "$TMP/antisurge.service" "$UNIT_PATH" 0644 root:root
[[ $CHANGED -gt $before ]] && BINARY_OR_UNIT_CHANGED=1
# the socket units that hold the HMI and metrics ports from boot (not enabled here)
for sock in antisurge-hmi.socket antisurge-metrics.socket; do
    put_file "$REPO/deploy/$sock" "${UNIT_PATH%/*}/$sock" 0644 root:root
done
before=$CHANGED
put_file "$REPO/deploy/80-can0.network" "$NET_PATH" 0644 root:root
[[ $CHANGED -gt $before ]] && NETWORK_CHANGED=1

# 5. Configuration: /etc/antisurge, root:antisurge, dirs 0750, files 0640.
[[ -d $CONFIG_SRC ]] || die "no configuration directory $CONFIG_SRC"
ensure_dir "$CONF_DIR" 0750 "root:$SVC_GROUP"
if [[ -f $CONFIG_SRC/antisurge.toml ]]; then
    put_operator_config "$CONFIG_SRC/antisurge.toml" "$CONF_DIR/antisurge.toml"
else
    note "warning: $CONFIG_SRC/antisurge.toml not found: main configuration not installed"
fi
# the signal maps (signals.toml, signals_modbus.toml, …) and the DBC
shipped_files=(skid.dbc)
for m in "$CONFIG_SRC"/signals*.toml; do
    [[ -f $m ]] && shipped_files+=("$(basename "$m")")
done
[[ -f $CONFIG_SRC/signals.toml ]] || shipped_files+=(signals.toml)
# the example daemon config for a machine known only from vendor data (config/machines/)
[[ -f $CONFIG_SRC/vendor_example.toml ]] && shipped_files+=(vendor_example.toml)
for f in "${shipped_files[@]}"; do
    if [[ -f $CONFIG_SRC/$f ]]; then
        put_shipped_config "$CONFIG_SRC/$f" "$CONF_DIR/$f"
    else
        note "warning: $CONFIG_SRC/$f not found: not installed"
    fi
done
# conf.d/: the operator's overrides; example files from the repository are added if
# missing but an existing file is never touched.
put_config_tree "$CONFIG_SRC/conf.d" "$CONF_DIR/conf.d" operator
for d in plants machines maps scenarios; do
    if [[ -d $CONFIG_SRC/$d ]]; then
        put_config_tree "$CONFIG_SRC/$d" "$CONF_DIR/$d" shipped
    else
        note "warning: $CONFIG_SRC/$d/ not found: not installed"
    fi
done

# 5b. The operator token (web HMI and `antisurge operate`): created once, random, root-owned,
# readable by the service's group only; an existing token is never replaced (delete it and
# run install.sh again to issue a new one), its owner and mode are enforced.
TOKEN_PATH=$CONF_DIR/operator.token
if [[ -f $ROOT$TOKEN_PATH ]]; then
    UNCHANGED=$((UNCHANGED + 1))
else
    report created create "$TOKEN_PATH (operator token: random, root:$SVC_GROUP 0640)"
    if [[ $DRY_RUN == 0 ]]; then
        (
            umask 077
            head -c 32 /dev/urandom | od -An -tx1 | tr -d ' \n' >"$ROOT$TOKEN_PATH.new.$$"
            echo >>"$ROOT$TOKEN_PATH.new.$$"
        )
        own "root:$SVC_GROUP" "$ROOT$TOKEN_PATH.new.$$"
        chmod 0640 "$ROOT$TOKEN_PATH.new.$$"
        mv -f "$ROOT$TOKEN_PATH.new.$$" "$ROOT$TOKEN_PATH"
        CHANGED=$((CHANGED + 1))
    fi
fi
if [[ $DRY_RUN == 0 && -f $ROOT$TOKEN_PATH ]]; then
    chmod 0640 "$ROOT$TOKEN_PATH"
    own "root:$SVC_GROUP" "$ROOT$TOKEN_PATH"
fi

# 6. State and log directories (systemd would create them too, with the unit's modes).
ensure_dir "$STATE_DIR" 0750 "$SVC_USER:$SVC_GROUP"
ensure_dir "$LOG_DIR" 0750 "$SVC_USER:$SVC_GROUP"

# 7. Tell systemd.
if [[ $STAGING == 1 ]]; then
    note "staging (--root): systemctl daemon-reload skipped"
elif systemd_running; then
    live systemctl daemon-reload
    report ran run "systemctl daemon-reload"
else
    note "systemd is not running here (container or chroot?): daemon-reload skipped"
fi

say ""
note "$CHANGED file(s) written, $UNCHANGED already up to date"
if [[ -f $ROOT$CONF_DIR/antisurge.toml.dist ]]; then
    say ""
    say "$CONF_DIR/antisurge.toml is yours and was kept. Compare it with the new default:"
    say "  diff $CONF_DIR/antisurge.toml $CONF_DIR/antisurge.toml.dist"
fi
if systemd_running && systemctl is-active --quiet antisurge.service && [[ $BINARY_OR_UNIT_CHANGED == 1 ]]; then
    say ""
    say "antisurge is running the previous version. It was NOT restarted: restart it when"
    say "the compressor allows (the daemon commands the safe state while it restarts):"
    say "  systemctl restart antisurge"
fi
if [[ $NETWORK_CHANGED == 1 ]]; then
    say ""
    say "The CAN bus file $NET_PATH changed. Apply it (briefly takes can0 down):"
    say "  networkctl reload && networkctl reconfigure can0"
fi
cli=antisurge
[[ $PREFIX != /usr/local && $PREFIX != /usr ]] && cli=$BIN_PATH
cat <<EOF

Next steps:
  1. CAN bus via systemd-networkd (once):  systemctl enable --now systemd-networkd
     check:                                ip -details link show can0
  2. Check the configuration:              $cli check-config $CONF_DIR/antisurge.toml
  3. Start now and at every boot:          systemctl enable --now antisurge
  4. Follow the daemon's log:              journalctl -u antisurge -f
  5. Events of the last hour:              $cli events --since 1h
  6. Operator token (HMI, \`$cli operate\`):  sudo cat $TOKEN_PATH   (new token: delete it, run install.sh)
See $DOC_PATH
EOF
