#!/usr/bin/env bash
# shellcheck disable=SC2016 # checks use bash -c '...' _ "$arg" on purpose: no expansion there
# CI check of deploy/: the systemd unit, its security exposure, the networkd file and
# install.sh (staged into a temporary directory, so no root and no real install needed).
#
#   bash deploy/verify.sh        (from anywhere; exits non-zero on any failure)
#
# Needs systemd-analyze >= 252 (for `security --offline/--threshold`) and /bin/kill (the
# unit's ExecReload). On Debian 12 they are installed if missing (apt-get, as root or
# through passwordless sudo). Builds nothing: the binary is a stub.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

# systemd-analyze's exposure scale x 10 (it takes an integer): 25 means 2.5.
THRESHOLD=25
UNIT=deploy/antisurge.service
NETWORK=deploy/80-can0.network
INSTALL=deploy/install.sh

PASSED=0
FAILED=0
pass() { PASSED=$((PASSED + 1)); printf 'ok    %s\n' "$*"; }
fail() { FAILED=$((FAILED + 1)); printf 'FAIL  %s\n' "$*"; }
check() { # description command...
    local d=$1
    shift
    if "$@"; then pass "$d"; else fail "$d"; fi
}
section() { printf '\n== %s\n' "$*"; }
indent() { sed 's/^/      /'; }

TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT

# ---------------------------------------------------------------------------- tools
section "tools"
as_root() {
    if [[ $(id -u) == 0 ]]; then
        "$@"
    elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
        sudo -n "$@"
    else
        echo "verify.sh: need root or passwordless sudo to install: $*" >&2
        return 1
    fi
}
missing=()
command -v systemd-analyze >/dev/null 2>&1 || missing+=(systemd)
[[ -x /bin/kill ]] || missing+=(procps)
if [[ ${#missing[@]} -gt 0 ]]; then
    echo "installing ${missing[*]} (apt-get)"
    as_root env DEBIAN_FRONTEND=noninteractive apt-get update -qq
    as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
        "${missing[@]}" >/dev/null
fi
sd_version=$(systemd-analyze --version | awk 'NR == 1 { print $2 }')
sd_full=$(systemd-analyze --version | sed -nE '1s/^systemd [0-9]+ \(([^)]*)\).*/\1/p')
echo "systemd-analyze: systemd $sd_version ${sd_full:+($sd_full)}"
check "systemd-analyze is systemd >= 252 (security --offline/--threshold)" \
    test "${sd_version%%[!0-9]*}" -ge 252

check "bash -n install.sh verify.sh" bash -n "$INSTALL" deploy/verify.sh
if command -v shellcheck >/dev/null 2>&1; then
    check "shellcheck install.sh verify.sh" shellcheck "$INSTALL" deploy/verify.sh
else
    echo "      (shellcheck not installed: lint skipped)"
fi

# ------------------------------------------------------------------- systemd unit
section "systemd-analyze verify $UNIT"
# verify insists that ExecStart's binary exists and is executable. The real binary is
# not built here, so the unit is copied to a temp dir with ONLY the ExecStart path
# replaced by a stub; every other line is checked to be byte-identical.
mkdir -p "$TMP/bin" "$TMP/unit"
printf '#!/bin/sh\nexit 0\n' >"$TMP/bin/antisurge"
chmod 0755 "$TMP/bin/antisurge"
sed -E "s#^(ExecStart|ExecReload)=/usr/local/bin/antisurge #\1=$TMP/bin/antisurge #" \
    "$UNIT" >"$TMP/unit/antisurge.service"
changed=$(diff "$UNIT" "$TMP/unit/antisurge.service" | grep -c '^>' || true)
check "only the ExecStart and the two ExecReload paths differ in the copy (3 lines, got $changed)" test "$changed" = 3
verify_rc=0
verify_out=$(systemd-analyze verify "$TMP/unit/antisurge.service" 2>&1) || verify_rc=$?
[[ -n $verify_out ]] && printf '%s\n' "$verify_out" | indent
check "systemd-analyze verify exits 0" test "$verify_rc" = 0
# Unknown or misspelt keys are only warnings (exit code 0): any message about our unit fails.
check "systemd-analyze verify has no warning about the unit" \
    bash -c '! grep -q antisurge <<<"$1"' _ "$verify_out"

section "unit invariants"
has() { grep -Eq "^$1\$" "$UNIT"; }
check "Type=notify (not notify-reload: needs systemd 253)" has 'Type=notify'
check "NotifyAccess=main, WatchdogSec=2s, TimeoutStartSec=30s" \
    bash -c 'grep -qx NotifyAccess=main "$1" && grep -qx WatchdogSec=2s "$1" && grep -qx TimeoutStartSec=30s "$1"' _ "$UNIT"
check "ExecStart runs the daemon with /etc/antisurge/antisurge.toml" \
    has 'ExecStart=/usr/local/bin/antisurge run --config /etc/antisurge/antisurge.toml'
check "ExecReload signals the daemon and waits for its answer" has 'ExecReload=/usr/local/bin/antisurge reload --pid \$MAINPID /etc/antisurge/antisurge.toml'
check "ExecReload runs check-config before the reload (a bad file fails systemctl reload)" \
    bash -c '[[ $(grep -E "^ExecReload=" "$1" | head -1) == "ExecReload=/usr/local/bin/antisurge check-config --against-running /etc/antisurge/antisurge.toml" && $(grep -E "^ExecReload=" "$1" | tail -1) == "ExecReload=/usr/local/bin/antisurge reload --pid \$MAINPID /etc/antisurge/antisurge.toml" ]]' _ "$UNIT"
check "Restart=always with RestartPreventExitStatus=78 (EX_CONFIG stops the restart loop)" \
    bash -c 'grep -qx "Restart=always" "$1" && grep -qx "RestartPreventExitStatus=78" "$1"' _ "$UNIT"

section "a config error stops the restart loop"
# No systemd runs here, so this checks the two halves of the contract: systemd does not
# restart a unit whose main process exits with a status in RestartPreventExitStatus=
# (systemd.service(5)), and the real binary exits with exactly that status for a config
# error, in `run` (ExecStart) and in `check-config` (ExecReload). ANTISURGE_REAL_BIN (or
# target/release/antisurge if built) is used; without a binary this part is skipped.
real_bin=${ANTISURGE_REAL_BIN:-target/release/antisurge}
prevent=$(sed -n 's/^RestartPreventExitStatus=//p' "$UNIT")
if [[ -x $real_bin ]]; then
    mkdir -p "$TMP/badcfg"
    printf '[plant]\nfile = "plants/none.toml"\n[control]\nlaw = "recycle-pi"\n' >"$TMP/badcfg/antisurge.toml"
    rc=0
    timeout 20 "$real_bin" run --config "$TMP/badcfg/antisurge.toml" --duration-s 2 >"$TMP/run.out" 2>&1 || rc=$?
    indent <"$TMP/run.out" | head -5
    check "antisurge run with a config error exits $rc, listed in RestartPreventExitStatus=$prevent" \
        bash -c '[[ $1 == 78 && " $2 " == *" $1 "* ]]' _ "$rc" "$prevent"
    rc=0
    timeout 20 "$real_bin" check-config "$TMP/badcfg/antisurge.toml" >/dev/null 2>&1 || rc=$?
    check "antisurge check-config with a config error exits $rc (non-zero: systemctl reload fails)" \
        test "$rc" = 78
    rc=0
    timeout 20 "$real_bin" run --config /nonexistent/dir/antisurge.toml --duration-s 2 >/dev/null 2>&1 || rc=$?
    check "a missing config file is a config error too (exit $rc)" test "$rc" = 78
else
    echo "      ($real_bin not built: the exit-status half is skipped; build it or set ANTISURGE_REAL_BIN)"
fi
check "capabilities are exactly CAP_SYS_NICE CAP_IPC_LOCK" \
    bash -c 'grep -qx "AmbientCapabilities=CAP_SYS_NICE CAP_IPC_LOCK" "$1" && grep -qx "CapabilityBoundingSet=CAP_SYS_NICE CAP_IPC_LOCK" "$1"' _ "$UNIT"
check "RestrictRealtime is not yes (SCHED_FIFO needed)" bash -c '! grep -Eq "^RestrictRealtime=(yes|true|1|on)" "$1"' _ "$UNIT"
check "AF_CAN allowed" bash -c 'grep -E "^RestrictAddressFamilies=" "$1" | grep -qw AF_CAN' _ "$UNIT"

section "system calls the daemon needs pass the unit's SystemCallFilter="
# Expand the unit's SystemCallFilter= lines in order (first line: allow list; "~" lines
# remove, later plain lines add back) with this systemd's own group definitions.
expand_filter() { # @group or syscall... -> syscall names, one per line
    local item sub
    for item in "$@"; do
        if [[ $item == @* ]]; then
            while read -r sub; do
                expand_filter "$sub"
            done < <(systemd-analyze syscall-filter --no-pager "$item" |
                awk 'NR > 1 && NF && $1 !~ /^#/ { print $1 }')
        else
            echo "$item"
        fi
    done
}
: >"$TMP/allowed"
while read -r value; do
    if [[ $value == ~* ]]; then
        # shellcheck disable=SC2086 # the value is a space-separated list
        expand_filter ${value#\~} | sort -u >"$TMP/filter"
        comm -23 "$TMP/allowed" "$TMP/filter" >"$TMP/allowed.new"
    else
        # shellcheck disable=SC2086
        expand_filter $value | sort -u | sort -u -m - "$TMP/allowed" >"$TMP/allowed.new"
    fi
    mv "$TMP/allowed.new" "$TMP/allowed"
done < <(sed -n 's/^SystemCallFilter=//p' "$UNIT")
echo "      $(wc -l <"$TMP/allowed") system calls allowed"
# What the runtime uses: real-time setup (rt_loop.rs), tokio, sockets, event-log fsync,
# config-directory watcher (inotify), sd_notify.
for sc in sched_setscheduler sched_setaffinity mlockall setrlimit prlimit64 clock_nanosleep \
    clock_gettime eventfd2 epoll_wait epoll_ctl socket connect sendmsg recvmsg setsockopt \
    ioctl fdatasync renameat2 inotify_init1 inotify_add_watch futex clone3 mmap mprotect \
    madvise getrandom flock timerfd_create; do
    check "$sc allowed" grep -qx "$sc" "$TMP/allowed"
done

section "systemd-analyze security --offline=true --threshold=$THRESHOLD"
sec_rc=0
sec_out=$(systemd-analyze security --no-pager --offline=true --threshold="$THRESHOLD" "$UNIT" 2>&1) || sec_rc=$?
printf '%s\n' "$sec_out" | grep -F '✗' | indent || true
score_line=$(printf '%s\n' "$sec_out" | grep 'Overall exposure level' || true)
echo "      $score_line"
score=$(sed -E 's/.*: ([0-9]+\.[0-9]+).*/\1/' <<<"$score_line")
echo "      exposure score: ${score:-?} (limit $((THRESHOLD / 10)).$((THRESHOLD % 10)))"
check "security exits 0 (exposure <= threshold)" test "$sec_rc" = 0
check "exposure score ${score:-?} <= 2.5" \
    awk -v s="${score:-99}" -v t="$THRESHOLD" 'BEGIN { exit !(s * 10 <= t) }'

# ----------------------------------------------------------------- networkd file
section "$NETWORK"
# systemd 252 has no offline parser for .network files (networkctl talks to the running
# systemd-networkd, systemd-analyze verify takes only units), so this is a syntax and
# key-name check against systemd.network(5), not networkd's own parse.
net_errors=$(awk '
    BEGIN {
        split("Name", k); for (i in k) known["Match", k[i]] = 1
        split("RequiredForOnline ActivationPolicy", k); for (i in k) known["Link", k[i]] = 1
        split("BitRate SamplePoint RestartSec Termination TripleSampling BusErrorReporting " \
              "ListenOnly Loopback OneShot PresumeAck ClassicDataLengthCode FDMode FDNonISO " \
              "DataBitRate DataSamplePoint", k); for (i in k) known["CAN", k[i]] = 1
    }
    /^[ \t]*([#;].*)?$/ { next }
    /^\[[A-Za-z]+\][ \t]*$/ { sec = $0; gsub(/[][ \t]/, "", sec); next }
    /^[A-Za-z]+=/ {
        key = substr($0, 1, index($0, "=") - 1)
        if (sec == "") print NR ": key before any section: " $0
        else if (!((sec, key) in known)) print NR ": unknown key [" sec "] " key
        next
    }
    { print NR ": not a section, key=value or comment: " $0 }
' "$NETWORK")
[[ -n $net_errors ]] && printf '%s\n' "$net_errors" | indent
check "every line is a comment, [Section] or known Key=value" test -z "$net_errors"
section_of() { # key -> the section it is in
    awk -v want="$1" '/^\[/ { s = $0 } index($0, want "=") == 1 { print s }' "$NETWORK"
}
check "[Match] Name=can0" bash -c 'grep -qx "Name=can0" "$1" && [[ $(awk "/^\\[/{s=\$0} /^Name=/{print s}" "$1") == "[Match]" ]]' _ "$NETWORK"
check "[CAN] BitRate= set (500K default)" test "$(section_of BitRate)" = "[CAN]"
check "BitRate value is a number with optional K/M" grep -Eqx 'BitRate=[0-9]+(\.[0-9]+)?[KM]?' "$NETWORK"
check "[CAN] RestartSec= set (bus-off auto restart)" test "$(section_of RestartSec)" = "[CAN]"
check "file name sorts as a networkd priority (NN-*.network)" \
    bash -c '[[ $(basename "$1") =~ ^[0-9]{2}-.+\.network$ ]]' _ "$NETWORK"

# ------------------------------------------------------------------- install.sh
section "install.sh --root (staged, fake binary, fake config)"
printf '#!/bin/sh\necho antisurge-fake "$@"\n' >"$TMP/fake-antisurge"
chmod 0755 "$TMP/fake-antisurge"
cfg=$TMP/cfg
mkdir -p "$cfg"/{conf.d,plants,maps/__pycache__,scenarios}
echo '# main v1' >"$cfg/antisurge.toml"
echo '# signals v1' >"$cfg/signals.toml"
echo 'VERSION ""' >"$cfg/skid.dbc"
echo '# site override' >"$cfg/conf.d/10-site.toml"
echo '# plant' >"$cfg/plants/p.toml"
echo '1,2' >"$cfg/maps/m.csv"
echo 'print(1)' >"$cfg/maps/gen.py"
echo x >"$cfg/maps/__pycache__/gen.pyc"
echo '# scenario' >"$cfg/scenarios/s.toml"
export ANTISURGE_BIN="$TMP/fake-antisurge"
st=$TMP/stage

out=$(bash "$INSTALL" --dry-run --root "$TMP/dry" --config-src "$cfg" 2>&1) || {
    printf '%s\n' "$out" | indent
    fail "install.sh --dry-run exits 0"
}
check "--dry-run creates nothing" test ! -e "$TMP/dry"

out=$(bash "$INSTALL" --root "$st" --config-src "$cfg" 2>&1) && rc=0 || rc=$?
printf '%s\n' "$out" | indent
check "install.sh --root exits 0" test "$rc" = 0
check "says it skips user creation/chown in staging mode" grep -q 'not creating user/group' <<<"$out"
check "says it skips systemctl in staging mode" grep -q 'daemon-reload skipped' <<<"$out"
check "prints the next steps" grep -q 'systemctl enable --now antisurge' <<<"$out"

mode_is() { # mode path
    local m
    m=$(stat -c %a "$st/$2" 2>/dev/null || echo missing)
    if [[ $m == "$1" ]]; then pass "$1 $2"; else fail "$2: mode $m, want $1"; fi
}
mode_is 755 usr/local/bin/antisurge
mode_is 644 usr/local/share/doc/antisurge/README.md
mode_is 644 etc/systemd/system/antisurge.service
mode_is 644 etc/systemd/network/80-can0.network
mode_is 750 etc/antisurge
mode_is 640 etc/antisurge/antisurge.toml
mode_is 640 etc/antisurge/signals.toml
mode_is 640 etc/antisurge/skid.dbc
mode_is 750 etc/antisurge/conf.d
mode_is 640 etc/antisurge/conf.d/10-site.toml
mode_is 750 etc/antisurge/plants
mode_is 640 etc/antisurge/plants/p.toml
mode_is 750 etc/antisurge/maps
mode_is 640 etc/antisurge/maps/m.csv
mode_is 750 etc/antisurge/scenarios
mode_is 640 etc/antisurge/scenarios/s.toml
mode_is 750 var/lib/antisurge
mode_is 750 var/log/antisurge
mode_is 640 etc/antisurge/operator.token
tok=$(head -1 "$st/etc/antisurge/operator.token" 2>/dev/null || true)
check "operator.token holds a random token (64 hex digits)" bash -c '[[ $1 =~ ^[0-9a-f]{64}$ ]]' _ "$tok"
[[ $(id -u) == 0 ]] && check "operator.token owned by root (staged as root)" test "$(stat -c %u "$st/etc/antisurge/operator.token")" = 0
check "operator.token is not world-readable" bash -c '[[ $(( 0$(stat -c %a "$1") & 07 )) == 0 ]]' _ "$st/etc/antisurge/operator.token"
check "developer files (*.py, __pycache__) not installed" \
    test ! -e "$st/etc/antisurge/maps/gen.py" -a ! -e "$st/etc/antisurge/maps/__pycache__"
check "installed binary is the given one" cmp -s "$TMP/fake-antisurge" "$st/usr/local/bin/antisurge"
check "installed unit is deploy/antisurge.service unchanged (default prefix)" \
    cmp -s "$UNIT" "$st/etc/systemd/system/antisurge.service"
check "installed .network is deploy/80-can0.network" cmp -s "$NETWORK" "$st/etc/systemd/network/80-can0.network"

out=$(bash "$INSTALL" --root "$st" --config-src "$cfg" 2>&1) && rc=0 || rc=$?
check "second run exits 0 and writes nothing (idempotent)" \
    bash -c '[[ $1 == 0 ]] && grep -q "0 file(s) written" <<<"$2"' _ "$rc" "$out"
check "second run keeps the operator token" test "$(head -1 "$st/etc/antisurge/operator.token")" = "$tok"
other=$(bash "$INSTALL" --root "$TMP/stage2" --config-src "$cfg" >/dev/null 2>&1; head -1 "$TMP/stage2/etc/antisurge/operator.token" 2>/dev/null || true)
check "another install gets another token" bash -c '[[ -n $1 && $1 != "$2" ]]' _ "$other" "$tok"

# Operator edits: antisurge.toml and conf.d are kept; shipped files are replaced with
# the previous version saved as .old.
echo '# operator edit' >>"$st/etc/antisurge/antisurge.toml"
echo '# operator override' >>"$st/etc/antisurge/conf.d/10-site.toml"
echo '# main v2' >"$cfg/antisurge.toml"
echo '# site override v2' >"$cfg/conf.d/10-site.toml"
echo '# signals v2' >"$cfg/signals.toml"
out=$(bash "$INSTALL" --root "$st" --config-src "$cfg" 2>&1) && rc=0 || rc=$?
printf '%s\n' "$out" | grep -E '^  (kept|saved|installed|updated) ' | indent || true
check "upgrade run exits 0" test "$rc" = 0
check "operator-edited antisurge.toml kept" grep -q '# operator edit' "$st/etc/antisurge/antisurge.toml"
check "new default installed as antisurge.toml.dist (0640)" \
    bash -c 'cmp -s "$1" "$2" && [[ $(stat -c %a "$2") == 640 ]]' _ "$cfg/antisurge.toml" "$st/etc/antisurge/antisurge.toml.dist"
check "install.sh says so (antisurge.toml.dist)" grep -q 'antisurge.toml.dist' <<<"$out"
check "operator's conf.d file kept" grep -q '# operator override' "$st/etc/antisurge/conf.d/10-site.toml"
check "shipped signals.toml updated, previous kept as .old" \
    bash -c 'cmp -s "$1" "$2/signals.toml" && grep -q "signals v1" "$2/signals.toml.old"' _ "$cfg/signals.toml" "$st/etc/antisurge"

out=$(bash "$INSTALL" --root "$TMP/opt" --prefix /opt/antisurge --config-src "$cfg" 2>&1) && rc=0 || rc=$?
check "--prefix /opt/antisurge: binary there and ExecStart rewritten" \
    bash -c '[[ $1 == 0 && -x $2/opt/antisurge/bin/antisurge ]] && grep -qx "ExecStart=/opt/antisurge/bin/antisurge run --config /etc/antisurge/antisurge.toml" "$2/etc/systemd/system/antisurge.service"' \
    _ "$rc" "$TMP/opt"

out=$(bash "$INSTALL" --uninstall --root "$st" 2>&1) && rc=0 || rc=$?
printf '%s\n' "$out" | indent
check "--uninstall exits 0" test "$rc" = 0
check "--uninstall removed binary, unit, .network, doc" \
    test ! -e "$st/usr/local/bin/antisurge" -a ! -e "$st/etc/systemd/system/antisurge.service" \
    -a ! -e "$st/etc/systemd/network/80-can0.network" -a ! -e "$st/usr/local/share/doc/antisurge"
check "--uninstall kept config, state and logs" \
    test -f "$st/etc/antisurge/antisurge.toml" -a -d "$st/var/lib/antisurge" -a -d "$st/var/log/antisurge"

section "install.sh --root with the repository's config/"
real=$TMP/real
out=$(bash "$INSTALL" --root "$real" 2>&1) && rc=0 || rc=$?
printf '%s\n' "$out" | grep -E 'warning|error' | indent || true
check "install.sh --root (repository config) exits 0" test "$rc" = 0
missing_files=$(cd config && find . -type f ! -name '*.py' ! -path '*/__pycache__/*' ! -name '.*' |
    while read -r f; do [[ -f $real/etc/antisurge/$f ]] || echo "$f"; done)
[[ -n $missing_files ]] && printf 'not installed: %s\n' "$missing_files" | indent
check "every file of config/ (but *.py) is in /etc/antisurge" test -z "$missing_files"
bad_modes=$(find "$real/etc/antisurge" \( -type f ! -perm 0640 \) -o \( -type d ! -perm 0750 \))
[[ -n $bad_modes ]] && printf '%s\n' "$bad_modes" | indent
check "config files 0640, dirs 0750" test -z "$bad_modes"
check "conf.d/ created even if the repository has none" test -d "$real/etc/antisurge/conf.d"

# ------------------------------------------------------------------------ result
printf '\n%s\n' "exposure score: ${score:-?} (systemd-analyze security, systemd ${sd_full:-$sd_version}, $(date -u +%F))"
printf 'verify.sh: %d passed, %d failed\n' "$PASSED" "$FAILED"
[[ $FAILED == 0 ]]
