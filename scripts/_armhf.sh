# shellcheck shell=bash
# The armhf test environment (README, "Test environments"); sourced by scripts/_env.sh, not run.
#
# Debian 12 (bookworm) armhf, as a 32-bit ARM board runs it: Debian's Python 3.11, numpy 1.24
# (4-byte intp), OpenCV 4.6 and the rest of ARMHF_DEBIAN_PACKAGES, plus requirements/armhf.txt
# from PyPI. Programs run under qemu-user through proot, with no board, no binfmt_misc and no
# privileges beyond what debootstrap needs once:
#
#   setup_armhf        -> ARMHF_ROOTFS, built once and cached (see below)
#   armhf_exec DIR CMD -> CMD inside it, the checkout bound at its own path, DIR as /tmp
#
# The rootfs is built without running any package's maintainer scripts (minutes saved under
# emulation): `debootstrap --foreign` resolves and downloads the packages and unpacks the
# essential ones, the rest are unpacked with dpkg-deb, and the few things their scripts would
# have done that Python needs are done here (_armhf_fixups). No dpkg database is used after
# that: nothing is installed into it later, it is rebuilt instead.
#
# Cache: $STEREOCAM_ARMHF_CACHE or ~/.cache/stereocam/armhf/rootfs-<hash>, the hash of this
# file, requirements/armhf.txt and the helper the rootfs uses (scripts/_enosys_exec.py): change
# one and the next run builds a new rootfs (cached_build in scripts/_env.sh: under a lock, renamed
# into place only once it passed its checks); downloaded .debs stay in debs/ for the next build.
# The project is not installed in the rootfs: every process there has the checkout on PYTHONPATH
# (stereocam/ is the package as it is in git), so one rootfs serves every checkout on the machine.
#
# Knobs: STEREOCAM_ARMHF_CACHE (the cache folder), STEREOCAM_ARMHF_MIRROR (a Debian mirror).

ARMHF_SUITE=bookworm
ARMHF_MIRROR="${STEREOCAM_ARMHF_MIRROR:-http://deb.debian.org/debian}"
ARMHF_CACHE="${STEREOCAM_ARMHF_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/stereocam/armhf}"
# The runtime as a PYNQ-like armv7l userland has it from its distribution (pyproject.toml leaves
# OpenCV and scipy to the platform on armv7l). Recommends are not followed.
ARMHF_DEBIAN_PACKAGES=(python3 python3-numpy python3-opencv python3-pil python3-yaml
    python3-prometheus-client python3-scipy)
# Python modules that must import there: a new rootfs is used only once they do.
ARMHF_CHECK_IMPORTS="numpy cv2 PIL yaml scipy.io prometheus_client aiohttp pytest pytest_asyncio pytest_timeout"

# Debian packages on the host: debootstrap (first stage only), proot, qemu-user-static.
ensure_armhf_tools() {
    local -a missing=()
    [ -x /usr/sbin/debootstrap ] || command -v debootstrap >/dev/null 2>&1 || missing+=(debootstrap)
    command -v proot >/dev/null 2>&1 || missing+=(proot)
    command -v qemu-arm-static >/dev/null 2>&1 || missing+=(qemu-user-static)
    command -v dpkg-deb >/dev/null 2>&1 || missing+=(dpkg)
    if [ "${#missing[@]}" -gt 0 ]; then
        command -v apt-get >/dev/null 2>&1 || die "the armhf env needs ${missing[*]} and there is no apt-get: install them"
        apt_install "${missing[@]}"
    fi
}

_armhf_stamp() {
    cat "${BASH_SOURCE[0]}" "$ROOT/requirements/armhf.txt" "$ROOT/scripts/_enosys_exec.py" \
        | sha256sum | cut -c1-16
}

# The host's python3 (the seccomp helper and pip run there): its executable, not a shim, as the
# helper runs with an empty environment.
_ARMHF_HOST_PY=""
_armhf_host_python() {
    if [ -z "$_ARMHF_HOST_PY" ]; then
        local py
        py="$(find_current_python)" || die "the armhf env needs a python3 (>= 3.10) on the host"
        _ARMHF_HOST_PY="$("$py" -c 'import sys; print(sys.executable)')" || die "$py does not run"
    fi
    printf '%s\n' "$_ARMHF_HOST_PY"
}

# armhf_exec_in ROOTFS TMPDIR CMD...: run CMD in ROOTFS under qemu-arm, with a clean environment.
armhf_exec_in() {
    local rootfs="$1" tmp="$2" py
    shift 2
    py="$(_armhf_host_python)"
    local -a vars=(PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin HOME=/root LANG=C.UTF-8
        TERM="${TERM:-dumb}" PYTHONPATH="$ROOT" STEREOCAM_TEST_ENV=armhf)
    local v
    for v in CI PYTHONDONTWRITEBYTECODE PYTHONUNBUFFERED COLUMNS; do
        [ -n "${!v:-}" ] && vars+=("$v=${!v}")
    done
    env -i "${vars[@]}" "$py" "$ROOT/scripts/_enosys_exec.py" \
        "$(command -v proot)" -q "$(command -v qemu-arm-static)" -r "$rootfs" \
        -b /dev -b /proc -b /sys -b "$ROOT" -b "$tmp:/tmp" -w "$ROOT" "$@"
}

# armhf_exec TMPDIR CMD...: run CMD in the armhf env (setup_armhf first).
armhf_exec() { armhf_exec_in "$ARMHF_ROOTFS" "$@"; }

# What maintainer scripts would have done that the tests need.
_armhf_fixups() {
    local t="$1" f
    # debootstrap run in a container leaves /proc a symlink to the host's: proot binds a directory.
    if [ -L "$t/proc" ] || ! [ -d "$t/proc" ]; then rm -f "$t/proc" && mkdir -m 555 "$t/proc"; fi
    mkdir -p "$t/dev" "$t/sys" "$t/tmp" "$t/root" && chmod 1777 "$t/tmp"
    # base-passwd's postinst
    [ -e "$t/etc/passwd" ] || cp "$t/usr/share/base-passwd/passwd.master" "$t/etc/passwd"
    [ -e "$t/etc/group" ] || cp "$t/usr/share/base-passwd/group.master" "$t/etc/group"
    # update-alternatives of libblas3 and liblapack3 (numpy and scipy load them), mawk, debianutils
    local lib="$t/usr/lib/arm-linux-gnueabihf"
    for f in blas/libblas.so.3 lapack/liblapack.so.3; do
        [ -e "$lib/$f" ] || die "armhf rootfs: $f is missing"
        ln -sfn "$f" "$lib/$(basename "$f")"
    done
    [ -e "$t/usr/bin/awk" ] || ln -s mawk "$t/usr/bin/awk"
    [ -e "$t/usr/bin/which" ] || ln -s which.debianutils "$t/usr/bin/which"
}

# _armhf_build DIR LOG: build a rootfs in DIR (empty), every tool's output to LOG.
_armhf_build() {
    local t="$1" build_log="$2" step_start pkgs pyver site py
    py="$(_armhf_host_python)"
    mkdir -p "$ARMHF_CACHE/debs"

    step_start=$SECONDS
    pkgs="$(IFS=,; printf '%s' "${ARMHF_DEBIAN_PACKAGES[*]}")"
    log "armhf: debootstrap --foreign --arch=armhf $ARMHF_SUITE (download, unpack the essential packages)"
    "$(command -v debootstrap || echo /usr/sbin/debootstrap)" --foreign --arch=armhf --variant=minbase --include="$pkgs" \
        --cache-dir="$ARMHF_CACHE/debs" "$ARMHF_SUITE" "$t" "$ARMHF_MIRROR" </dev/null >>"$build_log" 2>&1 \
        || { tail -n 20 "$build_log" >&2; die "armhf: debootstrap failed (log: $build_log)"; }

    # The second stage would configure every package under emulation (about 10 minutes):
    # unpack the rest instead, as the first stage unpacked the essential ones.
    log "armhf: unpacking $(wc -l <"$t/debootstrap/debpaths") packages ($((SECONDS - step_start))s so far)"
    local name path required
    required=" $(tr -s ' \n' '  ' <"$t/debootstrap/required") "
    while read -r name path; do
        case "$required" in *" $name "*) continue ;; esac
        dpkg-deb --fsys-tarfile "$t$path" | tar --keep-directory-symlink -C "$t" -xf - \
            || die "armhf: unpacking $name ($path) failed"
    done <"$t/debootstrap/debpaths"
    _armhf_fixups "$t"
    rm -rf "$t/debootstrap" "$t"/var/cache/apt/archives/*.deb

    pyver="$(armhf_exec_in "$t" "$t/tmp" /usr/bin/python3 -c 'import platform; print(platform.python_version())' 2>>"$build_log")" \
        || { tail -n 20 "$build_log" >&2; die "armhf: Debian's python3 does not run under proot and qemu-arm (log: $build_log)"; }
    site="$t/usr/local/lib/python${pyver%.*}/dist-packages"

    # What Debian lacks: pure-Python wheels for armv7l, installed by the host's pip (seconds,
    # where pip under emulation takes minutes).
    log "armhf: pip install -r requirements/armhf.txt for Python $pyver armv7l"
    "$py" -m pip install --no-input --disable-pip-version-check --no-compile --target "$site" \
        --only-binary=:all: --implementation cp --python-version "$pyver" --abi "cp$(printf '%s' "${pyver%.*}" | tr -d .)" \
        --platform linux_armv7l --platform manylinux_2_36_armv7l \
        -r "$ROOT/requirements/armhf.txt" >>"$build_log" 2>&1 \
        || { grep -v "^WARNING: Location '" "$build_log" | tail -n 20 >&2; die "armhf: pip install failed (log: $build_log)"; }
    rm -rf "${site:?}/bin"  # console scripts with the host's interpreter in their #! line

    # Byte-compile once, so that no test run compiles (or writes into) the shared rootfs.
    log "armhf: byte-compiling its Python ($((SECONDS - step_start))s so far)"
    (unset PYTHONDONTWRITEBYTECODE; armhf_exec_in "$t" "$t/tmp" /usr/bin/python3 -m compileall -q -j 0 \
        /usr/lib/python3 "/usr/lib/python${pyver%.*}" "/usr/local/lib/python${pyver%.*}") >>"$build_log" 2>&1 || true

    # The check that makes it done: every module the tests need imports, numpy's intp is 32-bit.
    armhf_exec_in "$t" "$t/tmp" /usr/bin/python3 -c "
import importlib, platform, sys
import numpy
for name in '$ARMHF_CHECK_IMPORTS'.split():
    importlib.import_module(name)
assert platform.machine() == 'armv7l', platform.machine()
assert numpy.dtype(numpy.intp).itemsize == 4, 'numpy intp is not 32-bit'
" >>"$build_log" 2>&1 \
        || { tail -n 20 "$build_log" >&2; die "armhf: the new rootfs fails its import check (log: $build_log)"; }
    log "armhf: rootfs built in $((SECONDS - step_start))s"
}

# setup_armhf: make sure the armhf rootfs for this checkout's inputs exists; sets ARMHF_ROOTFS.
setup_armhf() {
    armhf_rootfs "$ARMHF_CACHE"
    ARMHF_ROOTFS="$ARMHF_BUILT"
}

# armhf_rootfs DIR [PACKAGE...]: the rootfs with ARMHF_DEBIAN_PACKAGES and PACKAGEs, cached in DIR
# (rootfs-<hash>, built when missing), in ARMHF_BUILT. Every build holds the armhf cache's lock: they
# all download into its debs/.
armhf_rootfs() {
    local dir="$1" stamp
    shift
    ensure_armhf_tools
    _ARMHF_HOST_PY="$(_armhf_host_python)"
    stamp="$({ _armhf_stamp; printf '%s\n' "$@"; } | sha256sum | cut -c1-16)"
    ARMHF_BUILT="$dir/rootfs-$stamp"
    cached_build "$ARMHF_CACHE" "$ARMHF_BUILT" _armhf_build_rootfs "$@"
}

# _armhf_build_rootfs DIR LOG [PACKAGE...]: a rootfs into DIR (cached_build's builder).
_armhf_build_rootfs() {
    local dir="$1" build_log="$2"
    shift 2
    [ "$(id -u)" -eq 0 ] || die "building an armhf rootfs needs root (debootstrap): run once as root"
    log "armhf: building a rootfs in ${dir%/*} (${*:+with $*, }log: $build_log)"
    (ARMHF_DEBIAN_PACKAGES+=("$@"); _armhf_build "$dir" "$build_log")
}
