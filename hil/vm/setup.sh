#!/usr/bin/env bash
# Prepare everything the HIL virtual machine needs (idempotent).
#
#   hil/vm/setup.sh [--refresh] [--quiet] [--no-apt]
#
# 1. Installs the host packages the harness uses (apt-get, non-interactive):
#    qemu-system-x86 can-utils iproute2 rt-tests
# 2. Downloads (does not install) two Debian packages into the cache:
#    the concrete kernel image that `linux-image-amd64` depends on
#    (linux-image-6.1.0-NN-amd64) and busybox-static.
# 3. Extracts vmlinuz plus the kernel modules the guest needs (CAN, vcan,
#    virtio, 9p, overlayfs and their dependencies, resolved from each module's
#    own `depends=` field) and builds an uncompressed busybox initramfs around
#    hil/vm/init.
#
# Everything goes to ${ANTISURGE_HIL_CACHE:-hil/.cache}. A second run with an
# up-to-date cache only checks that the host packages are installed (well
# under a second). The cached kernel is kept until --refresh is given (or the
# cache is deleted), so a kernel update in Debian never changes a working
# cache behind your back; set ANTISURGE_HIL_KERNEL_PKG to pin a package name.
set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd -P)
repo=$(cd "$here/../.." && pwd -P)
cache=${ANTISURGE_HIL_CACHE:-$repo/hil/.cache}

# Host packages the harness needs at run time. Keep README.md in sync.
host_pkgs=(qemu-system-x86 can-utils iproute2 rt-tests)
# Kernel modules loaded in the guest (dependencies are added automatically).
guest_modules=(
    virtio_pci virtio_console virtio_rng 9pnet_virtio 9p overlay
    can can_raw can_bcm can_gw can_isotp can_dev vcan vxcan
)
# Bump when the layout of the generated files changes.
format=1

refresh=0
quiet=0
use_apt=1
for arg in "$@"; do
    case $arg in
        --refresh) refresh=1 ;;
        --quiet) quiet=1 ;;   # silent when there is nothing to do
        --no-apt) use_apt=0 ;;
        -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
        *) echo "setup.sh: unknown argument: $arg" >&2; exit 2 ;;
    esac
done

say() { printf '[hil-setup] %s\n' "$*" >&2; }
die() { printf '[hil-setup] error: %s\n' "$*" >&2; exit 1; }

mkdir -p "$cache"
export DEBIAN_FRONTEND=noninteractive
apt_updated=0
apt_update_once() {
    if [[ $apt_updated == 0 ]]; then
        say "apt-get update"
        apt-get update -q -o DPkg::Lock::Timeout=300 >"$cache/apt.log" 2>&1 \
            || { tail -n 20 "$cache/apt.log" >&2; die "apt-get update failed"; }
        apt_updated=1
    fi
}

pkg_installed() {
    [[ $(dpkg-query -W -f='${db:Status-Status}' "$1" 2>/dev/null) == installed ]]
}

install_host_packages() {
    local missing=() p
    for p in "${host_pkgs[@]}"; do
        pkg_installed "$p" || missing+=("$p")
    done
    [[ ${#missing[@]} == 0 ]] && return 0
    [[ $use_apt == 1 ]] || die "missing host packages: ${missing[*]} (and --no-apt given)"
    [[ $(id -u) == 0 ]] || die "missing host packages: ${missing[*]}; run as root or: sudo apt-get install --no-install-recommends ${missing[*]}"
    apt_update_once
    say "apt-get install ${missing[*]}"
    apt-get install -y -q -o DPkg::Lock::Timeout=300 --no-install-recommends "${missing[@]}" >"$cache/apt.log" 2>&1 \
        || { tail -n 20 "$cache/apt.log" >&2; die "apt-get install ${missing[*]} failed"; }
}

# Name of the concrete kernel image package behind linux-image-amd64.
resolve_kernel_pkg() {
    if [[ -n ${ANTISURGE_HIL_KERNEL_PKG:-} ]]; then
        printf '%s\n' "$ANTISURGE_HIL_KERNEL_PKG"
        return
    fi
    apt-cache depends linux-image-amd64 2>/dev/null \
        | awk '$1 == "Depends:" && $2 ~ /^linux-image-[0-9].*-amd64$/ { print $2; exit }'
}

# Download package $1 into $cache/debs unless a .deb of it is already there
# (or --refresh). Sets $fetched to the path of the .deb.
fetch_deb() {
    local pkg=$1 debs=$cache/debs existing=()
    mkdir -p "$debs"
    shopt -s nullglob
    existing=("$debs/${pkg}_"*.deb)
    shopt -u nullglob
    if [[ ${#existing[@]} -gt 0 && $refresh == 0 ]]; then
        fetched=${existing[-1]}
        return
    fi
    apt_update_once
    say "apt-get download $pkg"
    local tmp
    tmp=$(mktemp -d "$debs/.dl.XXXXXX")
    # apt drops privileges to _apt for downloads; let it write there.
    chmod 0777 "$tmp"
    (cd "$tmp" && apt-get download -q "$pkg" >/dev/null 2>"$tmp/.err") \
        || { cat "$tmp/.err" >&2; rm -rf "$tmp"; die "apt-get download $pkg failed"; }
    rm -f "${existing[@]}" "$tmp/.err"
    mv "$tmp"/*.deb "$debs/"
    rmdir "$tmp"
    shopt -s nullglob
    existing=("$debs/${pkg}_"*.deb)
    shopt -u nullglob
    [[ ${#existing[@]} -gt 0 ]] || die "apt-get download $pkg produced no .deb"
    fetched=${existing[-1]}
}

# Fingerprint of everything the generated VM files depend on.
recipe_key() {
    {
        echo "format=$format"
        echo "modules=${guest_modules[*]}"
        sha256sum "$here/setup.sh" "$here/init" | awk '{print $1}'
    } | sha256sum | awk '{print $1}'
}

vm=$cache/vm
key=$(recipe_key)
# One setup at a time (parallel runs may all call this).
exec 7>"$cache/.setup.lock"
flock 7

install_host_packages

if [[ $refresh == 0 && -f $vm/ready && $(cat "$vm/ready") == "$key" \
      && -f $vm/vmlinuz && -f $vm/initramfs.cpio ]]; then
    [[ $quiet == 1 ]] || say "up to date: $(cat "$vm/kernel-package" 2>/dev/null) in $vm"
    exit 0
fi

t0=$SECONDS
command -v dpkg-deb >/dev/null || die "dpkg-deb not found (Debian/Ubuntu host required)"

# --- kernel -------------------------------------------------------------
kpkg=""
if [[ $refresh == 0 && -z ${ANTISURGE_HIL_KERNEL_PKG:-} ]]; then
    # Reuse a cached kernel package if there is one: no network needed.
    shopt -s nullglob
    cached=("$cache"/debs/linux-image-[0-9]*-amd64_*.deb)
    shopt -u nullglob
    if [[ ${#cached[@]} -gt 0 ]]; then
        kpkg=$(basename "${cached[-1]}")
        kpkg=${kpkg%%_*}
    fi
fi
if [[ -z $kpkg ]]; then
    kpkg=$(resolve_kernel_pkg)
    if [[ -z $kpkg ]]; then
        apt_update_once
        kpkg=$(resolve_kernel_pkg)
    fi
    [[ -n $kpkg ]] || die "cannot resolve the kernel package behind linux-image-amd64"
fi
fetched=""
fetch_deb "$kpkg"
kdeb=$fetched
fetch_deb busybox-static
bdeb=$fetched
# Drop kernel packages other than the selected one.
for f in "$cache"/debs/linux-image-*.deb; do
    [[ $f == "$kdeb" ]] || rm -f "$f"
done

work=$(mktemp -d "$cache/.build.XXXXXX")
trap 'rm -rf "$work"' EXIT

say "extracting $(basename "$kdeb")"
mkdir -p "$work/k"
dpkg-deb --fsys-tarfile "$kdeb" \
    | tar -x -C "$work/k" --wildcards './boot/vmlinuz-*' './boot/config-*' './lib/modules/*'
shopt -s nullglob
kimgs=("$work"/k/boot/vmlinuz-*)
shopt -u nullglob
[[ ${#kimgs[@]} == 1 ]] || die "expected exactly one vmlinuz in $kdeb"
kver=${kimgs[0]##*/vmlinuz-}
mdir=$work/k/lib/modules/$kver
[[ -f $mdir/modules.order ]] || die "no modules.order in $kdeb"

# Map module name (with '-' folded to '_') -> path relative to $mdir.
declare -A mod_path=()
while IFS= read -r rel; do
    b=${rel##*/}
    b=${b%.ko}
    mod_path[${b//-/_}]=$rel
done <"$mdir/modules.order"

# The module's .modinfo section holds a NUL-terminated "depends=a,b,c".
mod_depends() {
    LC_ALL=C tr '\0' '\n' <"$mdir/$1" | LC_ALL=C grep -a -m1 '^depends=' | cut -d= -f2- | tr ',' ' '
}

declare -A mod_state=()
load_order=()
visit() {
    local name=${1//-/_} dep
    case ${mod_state[$name]:-} in
        done) return ;;
        active) die "module dependency cycle at $name" ;;
    esac
    if [[ -z ${mod_path[$name]:-} ]]; then
        # Built into the kernel?
        if grep -q "/${name}.ko\$\|/${name//_/-}.ko\$" "$mdir/modules.builtin" 2>/dev/null; then
            mod_state[$name]="done"
            return
        fi
        die "module $name not found in $kpkg"
    fi
    mod_state[$name]=active
    for dep in $(mod_depends "${mod_path[$name]}"); do
        visit "$dep"
    done
    mod_state[$name]="done"
    load_order+=("$name")
}
for m in "${guest_modules[@]}"; do
    visit "$m"
done

say "building initramfs (${#load_order[@]} modules, kernel $kver)"
ir=$work/initramfs
mkdir -p "$ir"/{bin,dev,proc,sys,job,host,newroot,ovl,lib/modules}
dpkg-deb --fsys-tarfile "$bdeb" | tar -x -O ./bin/busybox >"$ir/bin/busybox"
chmod 0755 "$ir/bin/busybox"
install -m 0755 "$here/init" "$ir/init"
i=0
for m in "${load_order[@]}"; do
    f=$(printf '%02d-%s.ko' "$i" "$m")
    cp "$mdir/${mod_path[$m]}" "$ir/lib/modules/$f"
    printf '%s\n' "$f" >>"$ir/lib/modules/load.list"
    i=$((i + 1))
done
printf '%s\n' "$kver" >"$ir/lib/modules/kernel-version"

# An uncompressed ELF vmlinux boots through PVH and skips the firmware's real
# mode loader and the in-guest decompression: ~3 s faster under TCG. The
# bzImage stays as the fallback.
extract_vmlinux() {
    local img=$1 out=$2 magic off
    # xz, zstd, gzip: whichever payload decompresses to an ELF file.
    for magic in '\xfd7zXZ\x00' '\x28\xb5\x2f\xfd' '\x1f\x8b\x08\x00'; do
        for off in $(LC_ALL=C grep -obUaP "$magic" "$img" 2>/dev/null | cut -d: -f1 | head -n 3); do
            case $magic in
                *7zXZ*) tail -c +$((off + 1)) "$img" | xz -dc --single-stream >"$out" 2>/dev/null ;;
                *b5*) tail -c +$((off + 1)) "$img" | zstd -dcq >"$out" 2>/dev/null ;;
                *) tail -c +$((off + 1)) "$img" | gzip -dcq >"$out" 2>/dev/null ;;
            esac
            if [[ $(head -c 4 "$out" | od -An -tx1 | tr -d ' ') == 7f454c46 ]]; then
                return 0
            fi
        done
    done
    rm -f "$out"
    return 1
}

mkdir -p "$vm"
rm -f "$vm/ready" "$vm/vmlinux"
if grep -q '^CONFIG_PVH=y' "$work/k/boot/config-$kver" 2>/dev/null \
    && extract_vmlinux "${kimgs[0]}" "$work/vmlinux"; then
    mv "$work/vmlinux" "$vm/vmlinux"
else
    say "no PVH-bootable vmlinux could be extracted; using the bzImage (slower boot)"
fi
(cd "$ir" && find . -mindepth 1 | LC_ALL=C sort | "$ir/bin/busybox" cpio -o -H newc 2>/dev/null) \
    >"$vm/initramfs.cpio.new"
mv "$vm/initramfs.cpio.new" "$vm/initramfs.cpio"
cp "${kimgs[0]}" "$vm/vmlinuz"
printf '%s\n' "$kpkg $(dpkg-deb -f "$kdeb" Version)" >"$vm/kernel-package"
printf '%s\n' "${load_order[@]}" >"$vm/modules"
printf '%s\n' "$key" >"$vm/ready"
say "done in $((SECONDS - t0)) s: $vm/vmlinuz ($kpkg), $vm/initramfs.cpio ($(du -k "$vm/initramfs.cpio" | cut -f1) KiB)"
