#!/usr/bin/env bash
# The Debian package, installed into a clean root (issue 13).
#
# 1. builds target/debian/antisurge_<version>-1_amd64.deb with cargo-deb (installed if missing),
#    with the man page and completions the binary generates;
# 2. makes a clean Debian 12 root with debootstrap (variant minbase: the Essential packages
#    and apt, nothing else; from the Debian mirror, DEBIAN_MIRROR overrides);
# 3. installs the package there with dpkg -i, which refuses it if a dependency it declares is
#    not in that root, and runs its postinst (system user antisurge, unit left disabled);
# 4. in that root, as an unprivileged user, from `/`, with an empty environment and no config:
#    `antisurge --version` must name the commit, `antisurge sim` must run the shipped plant
#    (built into the binary) to "STABLE — no surge", a bare `antisurge` must print help;
# 5. the installed unit: the operator token postinst made (0640 root:antisurge),
#    `systemd-analyze verify` on the unit with the package's drop-in (systemd added to the
#    root for it), and the unit's effective ExecReload check run as the service user:
#    exit 0 on the shipped config, non-zero on a bad one.
# Needs root (debootstrap, chroot).
set -euo pipefail
cd "$(dirname "$0")/.."
. .ci/lib.sh
[ "$(id -u)" = 0 ] || { echo "deb.sh: needs root (debootstrap and chroot)" >&2; exit 1; }
apt_get() {
    DEBIAN_FRONTEND=noninteractive apt-get -q -o DPkg::Lock::Timeout=300 "$@"
}
command -v cargo-deb >/dev/null || cargo install --locked cargo-deb
command -v debootstrap >/dev/null || { apt_get update >/dev/null && apt_get install -y --no-install-recommends debootstrap >/dev/null; }

ci_block ".deb 1/5: build, cargo deb"
# the shipped binary's profile (Cargo.toml [profile.dist]: release with fat LTO, one codegen
# unit: less code to lock, issue 25); cargo-deb takes the assets' target/release/ from it.
# DEB_PROFILE=release packages the release build instead (CI: the dist build takes ~10 min on
# 2 cores for the same code; the packaging checks below are the same)
profile=${DEB_PROFILE:-dist}
cargo build --profile "$profile"
bin=target/$profile/antisurge
mkdir -p target/deb-extra
"$bin" man | gzip -9n >target/deb-extra/antisurge.1.gz
# one page per command (antisurge-run.1, ...), the .deb's assets (Cargo.toml)
rm -rf target/deb-extra/man && "$bin" man --out target/deb-extra/man >/dev/null && gzip -9nf target/deb-extra/man/*.1
"$bin" completions bash >target/deb-extra/antisurge.bash
"$bin" completions zsh >target/deb-extra/_antisurge
"$bin" completions fish >target/deb-extra/antisurge.fish
deb=$(cargo deb --no-build --profile "$profile" --output target/debian/ | tail -n 1)
echo "package: $deb ($(du -h "$deb" | cut -f1))"
dpkg-deb --info "$deb" | sed -n '/Package:/,$p'
contents=$(dpkg-deb --contents "$deb")
for f in ./usr/bin/antisurge ./usr/share/man/man1/antisurge-run.1.gz ./etc/antisurge/antisurge.toml ./lib/systemd/system/antisurge.service \
    ./usr/lib/systemd/system/antisurge.service.d/usr-bin.conf ./usr/share/man/man1/antisurge.1.gz \
    ./usr/lib/systemd/system/antisurge-hmi.socket ./usr/lib/systemd/system/antisurge-metrics.socket \
    ./usr/share/bash-completion/completions/antisurge ./usr/share/doc/antisurge/copyright; do
    # the unit may sit in /lib or /usr/lib depending on the cargo-deb version
    alt=${f/#.\/lib\//./usr/lib/}
    grep -q -e " $f\$" -e " $alt\$" <<<"$contents" || { echo "deb.sh: $f is not in the package" >&2; exit 1; }
done

ci_block ".deb 2/5: clean root (debootstrap --variant=minbase bookworm, cached)"
root=$(mktemp -d /tmp/antisurge-deb-root.XXXXXX)
chmod 755 "$root" # mktemp makes it 0700: nobody could not enter its /
cleanup() {
    mountpoint -q "$root/proc" && umount "$root/proc"
    rm -rf --one-file-system "$root"
}
trap 'cleanup; ci_block_end' EXIT
t0=$(date +%s)
# The debootstrap'd root is cached as a tarball (per mirror; remade when older than 7 days or
# with DEB_ROOT_REFRESH=1), so a later run (or a re-run of this block) unpacks it in seconds
# instead of 2-2.6 min of debootstrap; every run still gets a root nothing else has touched.
mirror=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
root_cache=${ANTISURGE_CI_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/antisurge-ci}
root_tar=$root_cache/debootstrap-bookworm-minbase-$(printf '%s' "$mirror" | sha256sum | cut -c1-12).tar
if [ "${DEB_ROOT_REFRESH:-0}" != 1 ] && [ -n "$(find "$root_tar" -mtime -7 2>/dev/null)" ]; then
    tar -C "$root" --numeric-owner -xpf "$root_tar"
    how="unpacked from the cache $root_tar"
else
    debootstrap --variant=minbase bookworm "$root" "$mirror" \
        >"$root.debootstrap.log" 2>&1 || { tail -n 20 "$root.debootstrap.log" >&2; exit 1; }
    rm -f "$root.debootstrap.log"
    mkdir -p "$root_cache"
    tar -C "$root" --numeric-owner -cpf "$root_tar.tmp" . && mv "$root_tar.tmp" "$root_tar"
    how="debootstrap (cached as $root_tar)"
fi
echo "clean root in $(($(date +%s) - t0)) s, $how: $(chroot "$root" dpkg-query -W -f '.\n' | wc -l) packages, no antisurge"
chroot "$root" sh -c '! command -v antisurge && ! test -e /etc/antisurge'

ci_block ".deb 3/5: dpkg -i in the clean root"
cp "$deb" "$root/tmp/"
chroot "$root" env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin dpkg -i "/tmp/$(basename "$deb")"
chroot "$root" dpkg-query -W antisurge
chroot "$root" getent passwd antisurge
test -f "$root/etc/antisurge/antisurge.toml"
test -f "$root/lib/systemd/system/antisurge.service" || test -f "$root/usr/lib/systemd/system/antisurge.service"
if chroot "$root" sh -c 'ls /etc/systemd/system/*.wants/antisurge.service' 2>/dev/null; then
    echo "deb.sh: the package enabled the unit (it must stay disabled until configured)" >&2
    exit 1
fi
if file "$root/usr/bin/antisurge" | grep -q "not stripped"; then
    echo "deb.sh: the packaged binary is not stripped" >&2
    exit 1
fi
echo "binary: $(du -h "$root/usr/bin/antisurge" | cut -f1) (stripped)"

ci_block ".deb 4/5: antisurge from / as nobody in the clean root"
mount -t proc proc "$root/proc"
in_root() {
    chroot --userspec=nobody:nogroup "$root" env -i PATH=/usr/bin:/bin HOME=/nonexistent \
        LANG=C.UTF-8 sh -c 'cd / && exec "$@"' sh "$@"
}
commit=$(git rev-parse --short=12 HEAD)
version=$(in_root antisurge --version)
echo "$version"
grep -q "$commit" <<<"$version" || { echo "deb.sh: --version does not name commit $commit" >&2; exit 1; }
in_root antisurge sim | tee "$root/tmp/sim.txt"
grep -q "STABLE — no surge" "$root/tmp/sim.txt" || { echo "deb.sh: sim did not report STABLE" >&2; exit 1; }
in_root antisurge | grep -q "Usage: antisurge" || { echo "deb.sh: a bare antisurge does not print help" >&2; exit 1; }

ci_block ".deb 5/5: the installed unit (issue 25): systemd-analyze verify, token, ExecReload as installed"
test -f "$root/etc/antisurge/operator.token" || { echo "deb.sh: postinst made no operator token" >&2; exit 1; }
token_mode=$(chroot "$root" stat -c '%a %U:%G' /etc/antisurge/operator.token) # the root's names, not the host's
[ "$token_mode" = "640 root:antisurge" ] || { echo "deb.sh: operator token is $token_mode, not 640 root:antisurge" >&2; exit 1; }
# a minbase root has no systemd: add it now (the dependency check above is done)
cp /etc/resolv.conf "$root/etc/resolv.conf"
chroot "$root" env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin DEBIAN_FRONTEND=noninteractive \
    apt-get -q -o Dpkg::Use-Pty=0 install -y --no-install-recommends systemd >/dev/null
verify_out=$(chroot "$root" env -i PATH=/usr/sbin:/usr/bin:/sbin:/bin \
    systemd-analyze verify --man=no antisurge.service 2>&1) || { echo "$verify_out" >&2; echo "deb.sh: systemd-analyze verify failed on the installed unit" >&2; exit 1; }
if grep -q antisurge <<<"$verify_out"; then
    echo "$verify_out" >&2
    echo "deb.sh: systemd-analyze verify warns about the installed unit" >&2
    exit 1
fi
echo "systemd-analyze verify antisurge.service (unit + package drop-in): OK"
# the unit's effective ExecReload: the drop-in's lines after its reset
dropin=$root/usr/lib/systemd/system/antisurge.service.d/usr-bin.conf
reload_check=$(sed -n '/^ExecReload=$/,$ s/^ExecReload=\(.\+\)$/\1/p' "$dropin" | head -n 1)
case $reload_check in
    /usr/bin/antisurge\ check-config*) ;;
    *) echo "deb.sh: the installed ExecReload does not run the packaged check-config: '$reload_check'" >&2; exit 1 ;;
esac
test -x "$root${reload_check%% *}" || { echo "deb.sh: ExecReload's ${reload_check%% *} is not installed" >&2; exit 1; }
reload_signal=$(sed -n '/^ExecReload=$/,$ s/^ExecReload=\(.\+\)$/\1/p' "$dropin" | tail -n 1)
test -x "$root${reload_signal%% *}" || { echo "deb.sh: ExecReload's ${reload_signal%% *} is not installed" >&2; exit 1; }
run_reload_check() { # as the service user, with the unit's runtime directory, like systemd
    mkdir -p "$root/run/antisurge"
    # shellcheck disable=SC2086 # the command line is split like systemd splits it
    chroot --userspec=antisurge:antisurge "$root" env -i PATH=/usr/bin:/bin LANG=C.UTF-8 \
        RUNTIME_DIRECTORY=/run/antisurge sh -c 'cd / && exec "$@"' sh $reload_check
}
rc=0
run_reload_check >"$root/tmp/reload_good.txt" 2>&1 || rc=$?
cat "$root/tmp/reload_good.txt"
[ "$rc" = 0 ] || { echo "deb.sh: ExecReload's check exits $rc on the shipped config" >&2; exit 1; }
cp "$root/etc/antisurge/antisurge.toml" "$root/tmp/antisurge.toml.good"
printf '[control]\nlaw = "no-such-law"\n' >"$root/etc/antisurge/antisurge.toml"
rc=0
run_reload_check >"$root/tmp/reload_bad.txt" 2>&1 || rc=$?
cp "$root/tmp/antisurge.toml.good" "$root/etc/antisurge/antisurge.toml"
head -n 5 "$root/tmp/reload_bad.txt"
[ "$rc" != 0 ] || { echo "deb.sh: ExecReload's check accepted a bad config" >&2; exit 1; }
echo "ExecReload check as installed: 0 on the shipped config, $rc on a bad one"
ci_block_end
echo ".deb OK"
