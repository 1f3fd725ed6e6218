#!/usr/bin/env bash
# Build the Debian package and check it in a clean root: unpack it with dpkg -x into an empty
# directory and run its `antisurge sim` from `/` as an unprivileged user with an empty HOME
# and no config directory (the shipped plants are built into the binary).
set -euo pipefail
cd "$(dirname "$0")/.."
command -v cargo-deb >/dev/null || cargo install --locked cargo-deb
cargo build --release
bin=target/release/antisurge
mkdir -p target/deb-extra
"$bin" man | gzip -9n > target/deb-extra/antisurge.1.gz
"$bin" completions bash > target/deb-extra/antisurge.bash
"$bin" completions zsh > target/deb-extra/_antisurge
"$bin" completions fish > target/deb-extra/antisurge.fish
deb=$(cargo deb --no-build --output target/debian/ | tail -n 1)
echo "package: $deb ($(du -h "$deb" | cut -f1))"
root=$(mktemp -d)
trap 'rm -rf "$root"' EXIT
dpkg -x "$deb" "$root"
dpkg-deb --info "$deb" | sed -n '1,12p'
test -x "$root/usr/bin/antisurge"
test -f "$root/etc/antisurge/antisurge.toml"
test -f "$root/lib/systemd/system/antisurge.service" || test -f "$root/usr/lib/systemd/system/antisurge.service"
test -f "$root/usr/share/man/man1/antisurge.1.gz"
if file "$root/usr/bin/antisurge" | grep -q "not stripped"; then
    echo "the packaged binary is not stripped" >&2; exit 1
fi
echo "binary: $(du -h "$root/usr/bin/antisurge" | cut -f1) (stripped)"
"$root/usr/bin/antisurge" --version
# a fresh user's environment, from /, with no config anywhere
home=$(mktemp -d)
chmod 755 "$root" "$root/usr" "$root/usr/bin" "$home"
run_as() {
    if [ "$(id -u)" = 0 ] && id nobody >/dev/null 2>&1; then
        chown nobody "$home"
        (cd / && env -i PATH=/usr/bin:/bin HOME="$home" TMPDIR="$home" setpriv --reuid=nobody --regid=nogroup --clear-groups "$@")
    else
        (cd / && env -i PATH=/usr/bin:/bin HOME="$home" TMPDIR="$home" "$@")
    fi
}
run_as "$root/usr/bin/antisurge" sim --no-plots | tee "$home/sim.txt"
grep -q "STABLE — no surge" "$home/sim.txt"
run_as "$root/usr/bin/antisurge" | grep -q "Usage: antisurge"
rm -rf "$home"
echo "== .deb OK"
